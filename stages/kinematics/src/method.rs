//! The two methods' network line-ups: names (the authors' checkpoint prefixes, reference file §2.2 and
//! §2.4), input/output sizes, learned initializations, and our CPU-sized defaults.

use serde::{Deserialize, Serialize};

use crate::features::{GLOBALPOSE_INPUT, PIP_INPUT};
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

    /// `(input, output, init_input, input_linear)` of each net, the sizes the method's data flow fixes.
    pub fn net_io(self, name: &str) -> Option<(usize, usize, Option<usize>, bool)> {
        let io = match (self, name) {
            // PIP (reference §2.2): unidirectional, input linear layer, 2 layers.
            (Method::Pip, "rnn1") => (PIP_INPUT, 15, Some(15), true),
            (Method::Pip, "rnn2") => (15 + PIP_INPUT, 69, None, true),
            (Method::Pip, "rnn3") => (69 + PIP_INPUT, 90, None, true),
            (Method::Pip, "rnn4") => (69 + PIP_INPUT, 72, Some(72), true),
            (Method::Pip, "rnn5") => (69 + PIP_INPUT, 2, None, true),
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

    /// Specs with hidden size `hidden` and `layers` layers for every net (PIP's contact net keeps
    /// a quarter of the hidden size, as in the paper: 64 of 256).
    pub fn specs(self, hidden: usize, layers: usize) -> Vec<RnnSpec> {
        self.net_names()
            .iter()
            .map(|&name| {
                let (input, output, init_input, input_linear) =
                    self.net_io(name).unwrap_or((0, 0, None, false));
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
