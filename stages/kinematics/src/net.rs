//! The recurrent building block of every PIP and GlobalPose network (reference file §2.0): articulate's
//! `RNN` / `RNNWithInit`, with PyTorch's parameter names so the authors' checkpoints map 1:1.
//!
//! ```text
//! x ─► [linear1 ─► ReLU ─► dropout]? ─► LSTM (L layers, dropout between) ─► linear2 ─► y
//!                 init vector ─► init_net (Linear, ReLU, Linear, ReLU, Linear) ─► (h0, c0)
//! ```
//!
//! Parameters (prefix `<net>.`): `linear1.{weight,bias}` (only with an input linear layer),
//! `rnn.{weight_ih_lk, weight_hh_lk, bias_ih_lk, bias_hh_lk}` for k < L, `linear2.{weight,bias}`,
//! `init_net.{0,2,4}.{weight,bias}` (only with a learned initialization). LSTM gates are in PyTorch's
//! order i, f, g, o; both biases are added.
//!
//! Tensors are time-major inside (`[T, B, ·]`) so that one time step is a contiguous slice; the public
//! sequence API takes and returns batch-major `[B, T, ·]` like PyTorch's `batch_first`.

use std::collections::HashMap;

use candle_core::{D, DType, Device, Result as CandleResult, Tensor, Var};
use serde::{Deserialize, Serialize};

use crate::error::WeightsError;

/// Shape of one network; everything else (parameter shapes, state sizes) follows from it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RnnSpec {
    /// Parameter-name prefix, e.g. `rnn1` or `iknet.net1`.
    pub name: String,
    /// Input features per frame.
    pub input: usize,
    /// Output features per frame.
    pub output: usize,
    /// LSTM hidden size H.
    pub hidden: usize,
    /// LSTM layers L.
    pub layers: usize,
    /// articulate's `input_linear`: a Linear(input→H) + ReLU before the LSTM (PIP); without it the LSTM
    /// takes the input directly (GlobalPose).
    pub input_linear: bool,
    /// Size of the learned-initialization input (`RNNWithInit`), or `None` for zero initial states.
    pub init_input: Option<usize>,
}

impl RnnSpec {
    /// Every parameter with its shape, in a stable order.
    pub fn parameter_shapes(&self) -> Vec<(String, Vec<usize>)> {
        let (h, l) = (self.hidden, self.layers);
        let mut out = Vec::new();
        let p = |k: &str| format!("{}.{k}", self.name);
        let lstm_input = if self.input_linear {
            out.push((p("linear1.weight"), vec![h, self.input]));
            out.push((p("linear1.bias"), vec![h]));
            h
        } else {
            self.input
        };
        for k in 0..l {
            let inp = if k == 0 { lstm_input } else { h };
            out.push((p(&format!("rnn.weight_ih_l{k}")), vec![4 * h, inp]));
            out.push((p(&format!("rnn.weight_hh_l{k}")), vec![4 * h, h]));
            out.push((p(&format!("rnn.bias_ih_l{k}")), vec![4 * h]));
            out.push((p(&format!("rnn.bias_hh_l{k}")), vec![4 * h]));
        }
        out.push((p("linear2.weight"), vec![self.output, h]));
        out.push((p("linear2.bias"), vec![self.output]));
        if let Some(init) = self.init_input {
            let dims = [(h, init), (h * l, h), (2 * l * h, h * l)];
            for (i, (o, n)) in [0, 2, 4].into_iter().zip(dims) {
                out.push((p(&format!("init_net.{i}.weight")), vec![o, n]));
                out.push((p(&format!("init_net.{i}.bias")), vec![o]));
            }
        }
        out
    }

    /// Read the spec back from a set of tensors (sizes come from the weights, so both our CPU-sized
    /// defaults and the authors' full sizes load). `input`/`output`/`init_input` are checked against
    /// what the method needs by the caller.
    pub fn infer(name: &str, tensors: &HashMap<String, Tensor>) -> Result<RnnSpec, WeightsError> {
        let shape = |key: &str| -> Result<Vec<usize>, WeightsError> {
            let full = format!("{name}.{key}");
            tensors
                .get(&full)
                .map(|t| t.dims().to_vec())
                .ok_or(WeightsError::MissingTensor { name: full })
        };
        let hh = shape("rnn.weight_hh_l0")?;
        let hidden = *hh
            .get(1)
            .ok_or_else(|| bad_rank(name, "rnn.weight_hh_l0", &hh))?;
        let layers = (0..)
            .take_while(|k| tensors.contains_key(&format!("{name}.rnn.weight_ih_l{k}")))
            .count();
        let input_linear = tensors.contains_key(&format!("{name}.linear1.weight"));
        let input = if input_linear {
            shape("linear1.weight")?[1..].first().copied()
        } else {
            shape("rnn.weight_ih_l0")?[1..].first().copied()
        }
        .ok_or_else(|| bad_rank(name, "rnn.weight_ih_l0", &hh))?;
        let output = shape("linear2.weight")?[0];
        let init_input = tensors
            .get(&format!("{name}.init_net.0.weight"))
            .map(|t| t.dims().get(1).copied().unwrap_or(0));
        Ok(RnnSpec {
            name: name.to_owned(),
            input,
            output,
            hidden,
            layers,
            input_linear,
            init_input,
        })
    }
}

fn bad_rank(net: &str, key: &str, dims: &[usize]) -> WeightsError {
    WeightsError::Shape {
        name: format!("{net}.{key}"),
        expected: "a 2-D matrix".to_owned(),
        found: dims.to_vec(),
    }
}

/// Fresh parameters with PyTorch's default initialization: U(−1/√fan_in, 1/√fan_in) for Linear
/// weights and biases, U(−1/√H, 1/√H) for every LSTM parameter. Drawn from `rng` on the host and
/// then placed on `device`, so that a seed gives the same starting weights on every device (candle's
/// own CPU generator cannot be seeded).
pub fn init_parameters(
    spec: &RnnSpec,
    device: &Device,
    rng: &mut impl rand::Rng,
) -> CandleResult<Vec<(String, Var)>> {
    let mut out = Vec::new();
    for (name, shape) in spec.parameter_shapes() {
        let bound = if name.contains(".rnn.") {
            1.0 / (spec.hidden as f64).sqrt()
        } else {
            // Linear: fan_in is the weight's second dimension (the bias shares its layer's bound).
            let fan_in = spec
                .parameter_shapes()
                .into_iter()
                .find(|(n, _)| *n == name.replace(".bias", ".weight"))
                .map(|(_, s)| s[1])
                .unwrap_or(1);
            1.0 / (fan_in as f64).sqrt()
        } as f32;
        let count: usize = shape.iter().product();
        let values: Vec<f32> = (0..count)
            .map(|_| rng.random_range(-bound..bound))
            .collect();
        let t = Tensor::from_vec(values, shape, &Device::Cpu)?.to_device(device)?;
        out.push((name, Var::from_tensor(&t)?));
    }
    Ok(out)
}

/// LSTM state: per layer `h` and `c`, each `[B, H]`.
#[derive(Clone, Debug)]
pub struct LstmState {
    pub h: Vec<Tensor>,
    pub c: Vec<Tensor>,
}

impl LstmState {
    /// Detached copy (truncated back-propagation, streaming).
    pub fn detach(&self) -> LstmState {
        LstmState {
            h: self.h.iter().map(Tensor::detach).collect(),
            c: self.c.iter().map(Tensor::detach).collect(),
        }
    }
}

// Fields are crate-visible so that `lean::LeanRnn` can copy the weights out once. Cloning shares
// the tensors (candle's storage is reference-counted).
#[derive(Clone)]
pub(crate) struct LstmLayer {
    pub(crate) w_ih: Tensor,
    pub(crate) w_hh: Tensor,
    pub(crate) b_ih: Tensor,
    pub(crate) b_hh: Tensor,
}

#[derive(Clone)]
pub(crate) struct Linear {
    pub(crate) weight: Tensor,
    pub(crate) bias: Tensor,
}

impl Linear {
    /// `x [N, in] -> [N, out]`.
    fn forward(&self, x: &Tensor) -> CandleResult<Tensor> {
        x.matmul(&self.weight.t()?)?.broadcast_add(&self.bias)
    }
}

/// One network: optional input layer, LSTM stack, output layer, optional learned initialization.
#[derive(Clone)]
pub struct Rnn {
    pub spec: RnnSpec,
    pub(crate) linear1: Option<Linear>,
    pub(crate) layers: Vec<LstmLayer>,
    pub(crate) linear2: Linear,
    init_net: Option<[Linear; 3]>,
}

impl Rnn {
    /// Build from named tensors (trainable `Var`s' tensors or loaded weights), checking every shape.
    pub fn from_tensors(
        spec: &RnnSpec,
        tensors: &HashMap<String, Tensor>,
    ) -> Result<Rnn, WeightsError> {
        for (name, shape) in spec.parameter_shapes() {
            let t = tensors
                .get(&name)
                .ok_or_else(|| WeightsError::MissingTensor { name: name.clone() })?;
            if t.dims() != shape.as_slice() {
                return Err(WeightsError::Shape {
                    name,
                    expected: format!("{shape:?}"),
                    found: t.dims().to_vec(),
                });
            }
            if t.dtype() != DType::F32 {
                return Err(WeightsError::DType {
                    name,
                    found: format!("{:?}", t.dtype()),
                });
            }
        }
        let get = |k: &str| tensors[&format!("{}.{k}", spec.name)].clone();
        let linear = |prefix: &str| Linear {
            weight: get(&format!("{prefix}.weight")),
            bias: get(&format!("{prefix}.bias")),
        };
        let layers = (0..spec.layers)
            .map(|k| LstmLayer {
                w_ih: get(&format!("rnn.weight_ih_l{k}")),
                w_hh: get(&format!("rnn.weight_hh_l{k}")),
                b_ih: get(&format!("rnn.bias_ih_l{k}")),
                b_hh: get(&format!("rnn.bias_hh_l{k}")),
            })
            .collect();
        Ok(Rnn {
            spec: spec.clone(),
            linear1: spec.input_linear.then(|| linear("linear1")),
            layers,
            linear2: linear("linear2"),
            init_net: spec.init_input.map(|_| {
                [
                    linear("init_net.0"),
                    linear("init_net.2"),
                    linear("init_net.4"),
                ]
            }),
        })
    }

    /// Initial state for a batch: from the learned initialization if the net has one and `init` is
    /// given (`[B, init_input]`), else zeros.
    pub fn initial_state(&self, batch: usize, init: Option<&Tensor>) -> CandleResult<LstmState> {
        let (h, l) = (self.spec.hidden, self.spec.layers);
        match (&self.init_net, init) {
            (Some([a, b, c]), Some(x)) => {
                let v = c.forward(&b.forward(&a.forward(x)?.relu()?)?.relu()?)?;
                // Layout [h_l0 … h_l(L−1), c_l0 … c_l(L−1)] (reference §2.0). Each piece is made
                // contiguous: candle's CUDA matmul takes no row-strided operand.
                let chunk = |i: usize| v.narrow(1, i * h, h)?.contiguous();
                Ok(LstmState {
                    h: (0..l).map(chunk).collect::<CandleResult<_>>()?,
                    c: (l..2 * l).map(chunk).collect::<CandleResult<_>>()?,
                })
            }
            _ => {
                let z = Tensor::zeros((batch, h), DType::F32, self.linear2.weight.device())?;
                Ok(LstmState {
                    h: vec![z.clone(); l],
                    c: vec![z; l],
                })
            }
        }
    }

    /// Whole sequences: `x [B, T, input]` from `state` → (`y [B, T, output]`, final state).
    /// `dropout` > 0 only while training (after linear1's ReLU and between LSTM layers, as articulate).
    ///
    /// Every step works on its own `[B, ·]` tensors: slicing one big per-sequence tensor per step would
    /// make back-propagation scatter each step's gradient into a full-size zero tensor (O(T²) work).
    pub fn forward(
        &self,
        x: &Tensor,
        state: &LstmState,
        dropout: f32,
    ) -> CandleResult<(Tensor, LstmState)> {
        let (_, t, _) = x.dims3()?;
        let x = x.transpose(0, 1)?.contiguous()?;
        let mut seq: Vec<Tensor> = (0..t).map(|k| x.get(k)).collect::<CandleResult<_>>()?;
        if let Some(l1) = &self.linear1 {
            seq = seq
                .iter()
                .map(|xt| maybe_dropout(&l1.forward(xt)?.relu()?, dropout))
                .collect::<CandleResult<_>>()?;
        }
        let mut next = LstmState {
            h: Vec::with_capacity(self.layers.len()),
            c: Vec::with_capacity(self.layers.len()),
        };
        for (k, layer) in self.layers.iter().enumerate() {
            if k > 0 && dropout > 0.0 {
                seq = seq
                    .iter()
                    .map(|xt| maybe_dropout(xt, dropout))
                    .collect::<CandleResult<_>>()?;
            }
            let (h, c) = layer.run(&mut seq, &state.h[k], &state.c[k])?;
            next.h.push(h);
            next.c.push(c);
        }
        let hs = Tensor::stack(&seq, 1)?;
        let (b, t, hidden) = hs.dims3()?;
        let y = self
            .linear2
            .forward(&hs.reshape((b * t, hidden))?)?
            .reshape((b, t, ()))?;
        Ok((y, next))
    }

    /// One frame: `x [B, input]` → `y [B, output]`, advancing `state`. Same arithmetic as
    /// [`Rnn::forward`] with T = 1.
    pub fn step(&self, x: &Tensor, state: &mut LstmState) -> CandleResult<Tensor> {
        let (y, next) = self.forward(&x.unsqueeze(1)?, state, 0.0)?;
        *state = next;
        y.squeeze(1)
    }
}

impl LstmLayer {
    /// Replaces each step's input `[B, in]` in `seq` by the layer's output `[B, H]`; returns the last
    /// h and c.
    fn run(&self, seq: &mut [Tensor], h0: &Tensor, c0: &Tensor) -> CandleResult<(Tensor, Tensor)> {
        let hidden = self.w_hh.dim(1)?;
        let bias = (&self.b_ih + &self.b_hh)?;
        let (w_ih_t, w_hh_t) = (self.w_ih.t()?, self.w_hh.t()?);
        let (mut h, mut c) = (h0.clone(), c0.clone());
        for xt in seq.iter_mut() {
            let gates = (xt.matmul(&w_ih_t)? + h.matmul(&w_hh_t)?)?.broadcast_add(&bias)?;
            // PyTorch gate order i, f, g, o: one sigmoid over all four, tanh for g.
            let sig = candle_nn::ops::sigmoid(&gates)?;
            let i = sig.narrow(D::Minus1, 0, hidden)?;
            let f = sig.narrow(D::Minus1, hidden, hidden)?;
            let g = gates.narrow(D::Minus1, 2 * hidden, hidden)?.tanh()?;
            let o = sig.narrow(D::Minus1, 3 * hidden, hidden)?;
            c = ((f * &c)? + (i * g)?)?;
            h = (o * c.tanh()?)?;
            *xt = h.clone();
        }
        Ok((h, c))
    }
}

fn maybe_dropout(x: &Tensor, p: f32) -> CandleResult<Tensor> {
    if p > 0.0 {
        candle_nn::ops::dropout(x, p)
    } else {
        Ok(x.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_net(spec: &RnnSpec) -> (Rnn, HashMap<String, Tensor>) {
        let vars = init_parameters(
            spec,
            &Device::Cpu,
            &mut <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(7),
        )
        .unwrap();
        let tensors: HashMap<String, Tensor> = vars
            .into_iter()
            .map(|(n, v)| (n, v.as_tensor().clone()))
            .collect();
        (Rnn::from_tensors(spec, &tensors).unwrap(), tensors)
    }

    fn spec(input_linear: bool, init: Option<usize>) -> RnnSpec {
        RnnSpec {
            name: "net".into(),
            input: 5,
            output: 3,
            hidden: 8,
            layers: 2,
            input_linear,
            init_input: init,
        }
    }

    /// A one-unit LSTM computed by hand with scalar formulas (PyTorch's gate equations).
    #[test]
    fn one_unit_lstm_matches_hand_computation() {
        let s = RnnSpec {
            name: "n".into(),
            input: 1,
            output: 1,
            hidden: 1,
            layers: 1,
            input_linear: false,
            init_input: None,
        };
        let t = |v: &[f32], shape: &[usize]| Tensor::from_slice(v, shape, &Device::Cpu).unwrap();
        let (w_ih, w_hh) = ([0.5f32, -0.3, 0.8, 0.2], [0.1f32, 0.4, -0.6, 0.7]);
        let (b_ih, b_hh) = ([0.05f32, 0.1, -0.2, 0.0], [0.0f32, -0.05, 0.1, 0.3]);
        let tensors = HashMap::from([
            ("n.rnn.weight_ih_l0".to_owned(), t(&w_ih, &[4, 1])),
            ("n.rnn.weight_hh_l0".to_owned(), t(&w_hh, &[4, 1])),
            ("n.rnn.bias_ih_l0".to_owned(), t(&b_ih, &[4])),
            ("n.rnn.bias_hh_l0".to_owned(), t(&b_hh, &[4])),
            ("n.linear2.weight".to_owned(), t(&[2.0], &[1, 1])),
            ("n.linear2.bias".to_owned(), t(&[-1.0], &[1])),
        ]);
        let net = Rnn::from_tensors(&s, &tensors).unwrap();
        let xs = [0.7f64, -1.2, 0.3];
        let x = Tensor::from_slice(&xs.map(|v| v as f32), (1, 3, 1), &Device::Cpu).unwrap();
        let state = net.initial_state(1, None).unwrap();
        let (y, _) = net.forward(&x, &state, 0.0).unwrap();
        let y: Vec<f32> = y.flatten_all().unwrap().to_vec1().unwrap();
        let sig = |v: f64| 1.0 / (1.0 + (-v).exp());
        let (mut h, mut c) = (0.0f64, 0.0f64);
        for (k, &xv) in xs.iter().enumerate() {
            let gate = |g: usize| {
                w_ih[g] as f64 * xv + b_ih[g] as f64 + w_hh[g] as f64 * h + b_hh[g] as f64
            };
            let (i, f, g, o) = (sig(gate(0)), sig(gate(1)), gate(2).tanh(), sig(gate(3)));
            c = f * c + i * g;
            h = o * c.tanh();
            let want = 2.0 * h - 1.0;
            assert!(
                (y[k] as f64 - want).abs() < 1e-6,
                "step {k}: {} vs {want}",
                y[k]
            );
        }
    }

    /// Streaming one frame at a time gives the whole-sequence outputs (same state carried over).
    #[test]
    fn streaming_equals_whole_sequence() {
        let s = spec(true, Some(4));
        let (net, _) = random_net(&s);
        let x = Tensor::randn(0f32, 1.0, (2, 40, 5), &Device::Cpu).unwrap();
        let init = Tensor::randn(0f32, 1.0, (2, 4), &Device::Cpu).unwrap();
        let state = net.initial_state(2, Some(&init)).unwrap();
        let (whole, _) = net.forward(&x, &state, 0.0).unwrap();
        let mut st = state.clone();
        let mut max_diff = 0.0f32;
        for t in 0..40 {
            let y = net
                .step(&x.narrow(1, t, 1).unwrap().squeeze(1).unwrap(), &mut st)
                .unwrap();
            let w = whole.narrow(1, t, 1).unwrap().squeeze(1).unwrap();
            let d = (y - w)
                .unwrap()
                .abs()
                .unwrap()
                .max_all()
                .unwrap()
                .to_scalar::<f32>()
                .unwrap();
            max_diff = max_diff.max(d);
        }
        assert!(max_diff <= 1e-6, "streaming differs by {max_diff}");
    }

    /// The learned initialization changes the outputs; without an init input the state is zero.
    #[test]
    fn learned_initialization_sets_the_state() {
        let s = spec(false, Some(4));
        let (net, _) = random_net(&s);
        let init = Tensor::ones((1, 4), DType::F32, &Device::Cpu).unwrap();
        let st = net.initial_state(1, Some(&init)).unwrap();
        let zero = net.initial_state(1, None).unwrap();
        assert_eq!(st.h.len(), 2);
        let norm = |t: &Tensor| {
            t.abs()
                .unwrap()
                .sum_all()
                .unwrap()
                .to_scalar::<f32>()
                .unwrap()
        };
        assert!(norm(&st.h[1]) > 0.0 && norm(&st.c[0]) > 0.0);
        assert_eq!(norm(&zero.h[0]), 0.0);
    }

    /// Sizes read back from the tensors equal the spec they were made from; a wrong shape and a missing
    /// tensor are errors naming the tensor.
    #[test]
    fn spec_inference_and_shape_errors() {
        for (linear, init) in [(true, None), (false, Some(3))] {
            let s = spec(linear, init);
            let (_, tensors) = random_net(&s);
            assert_eq!(RnnSpec::infer("net", &tensors).unwrap(), s);
        }
        let s = spec(true, None);
        let (_, mut tensors) = random_net(&s);
        let good = tensors.clone();
        tensors.insert(
            "net.rnn.weight_hh_l1".into(),
            Tensor::zeros((32, 7), DType::F32, &Device::Cpu).unwrap(),
        );
        let err = Rnn::from_tensors(&s, &tensors).err().unwrap().to_string();
        assert!(
            err.contains("net.rnn.weight_hh_l1") && err.contains("[32, 7]"),
            "{err}"
        );
        let mut tensors = good;
        tensors.remove("net.linear2.bias");
        let err = Rnn::from_tensors(&s, &tensors).err().unwrap().to_string();
        assert!(
            err.contains("net.linear2.bias") && err.contains("missing"),
            "{err}"
        );
    }
}
