//! The two methods' network line-ups: names (the authors' checkpoint prefixes, reference file §2.2 and
//! §2.4), input/output sizes, learned initializations, and our CPU-sized defaults.

use serde::{Deserialize, Serialize};

use crate::features::{GLOBALPOSE_INPUT, InputOrder, pip_input_len};
use crate::net::RnnSpec;

/// Which paper's networks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// PIP (CVPR 2022): rnn1 PL, rnn2 PA, rnn3 RA, rnn4 VA, rnn5 CF.
    Pip,
    /// GlobalPose (SIGGRAPH 2025): plnet PL, iknet.net1 PA, iknet.net2 RA, vrnet OV.
    GlobalPose,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Pip => "pip",
            Method::GlobalPose => "globalpose",
        }
    }

    pub fn parse(text: &str) -> Option<Method> {
        match text {
            "pip" => Some(Method::Pip),
            "globalpose" => Some(Method::GlobalPose),
            _ => None,
        }
    }

    /// The nets' names, in pipeline order.
    pub fn net_names(self) -> &'static [&'static str] {
        match self {
            Method::Pip => &["rnn1", "rnn2", "rnn3", "rnn4", "rnn5"],
            Method::GlobalPose => &["plnet", "iknet.net1", "iknet.net2", "vrnet"],
        }
    }

    /// Whether the method's networks can be sized for the sensors of `order`: PIP's for any set
    /// with the pelvis, which every order has (its inputs and its first net's leaf joints follow
    /// the set), GlobalPose's for the six-site set only (its nets' inputs hold the six's sensor
    /// positions and orientations in fixed blocks).
    pub fn takes(self, order: &InputOrder) -> bool {
        match self {
            Method::Pip => true,
            Method::GlobalPose => order.is_six(),
        }
    }

    /// `(input, output, init_input, input_linear)` of each net for the sensors of `order`
    /// ([`InputOrder::six`]: PIP's and GlobalPose's own), the sizes the method's data flow fixes;
    /// `None` for a net the method lacks or a set it cannot take ([`Method::takes`]).
    pub fn net_io(
        self,
        name: &str,
        order: &InputOrder,
    ) -> Option<(usize, usize, Option<usize>, bool)> {
        if !self.takes(order) {
            return None;
        }
        // PIP's inputs (72 for the six) and leaf joints (one per non-root sensor: 15 for the six).
        let (x, leaf) = (pip_input_len(order.len()), 3 * order.root());
        let io = match (self, name) {
            // PIP (reference §2.2): unidirectional, input linear layer, 2 layers.
            (Method::Pip, "rnn1") => (x, leaf, Some(leaf), true),
            (Method::Pip, "rnn2") => (leaf + x, 69, None, true),
            (Method::Pip, "rnn3") => (69 + x, 90, None, true),
            (Method::Pip, "rnn4") => (69 + x, 72, Some(72), true),
            (Method::Pip, "rnn5") => (69 + x, 2, None, true),
            // GlobalPose (reference §2.4): no input linear layer.
            (Method::GlobalPose, "plnet") => (GLOBALPOSE_INPUT, 18, Some(18), false),
            (Method::GlobalPose, "iknet.net1") => (45 + 3 + 15, 72, None, false),
            (Method::GlobalPose, "iknet.net2") => (45 + 3 + 69, 90, None, false),
            (Method::GlobalPose, "vrnet") => (135 + 69 + 18 + 18 + 3, 9, Some(9), false),
            _ => return None,
        };
        Some(io)
    }

    /// The authors' sizes: PIP H = 256 (rnn5: 64), 2 layers; GlobalPose H = 512, 3 layers.
    pub fn paper_sizes(self, name: &str) -> (usize, usize) {
        match (self, name) {
            (Method::Pip, "rnn5") => (64, 2),
            (Method::Pip, _) => (256, 2),
            (Method::GlobalPose, _) => (512, 3),
        }
    }

    /// Specs with hidden size `hidden` and `layers` layers for every net, for the sensors of
    /// `order` (PIP's contact net keeps a quarter of the hidden size, as in the paper: 64 of 256).
    pub fn specs(self, hidden: usize, layers: usize, order: &InputOrder) -> Vec<RnnSpec> {
        self.net_names()
            .iter()
            .map(|&name| {
                let (input, output, init_input, input_linear) =
                    self.net_io(name, order).unwrap_or((0, 0, None, false));
                let hidden = if self == Method::Pip && name == "rnn5" {
                    (hidden / 4).max(16)
                } else {
                    hidden
                };
                RnnSpec {
                    name: name.to_owned(),
                    input,
                    output,
                    hidden,
                    layers,
                    input_linear,
                    init_input,
                }
            })
            .collect()
    }
}
