//! A small multilayer perceptron from `(r, b, x, y)` to slope: three hidden ReLU layers,
//! trained in Rust with Adam (decoupled weight decay) on mean squared error. Its output
//! goes through the inverse of its mean reading of each true slope
//! ([`ResponseCurve`]): least squares on noisy colours reads steep slopes short.
//!
//! Inference runs in blocks of pixels with activations laid out neuron-major
//! (`[neuron][pixel]`), so each weight multiplies a contiguous run of pixels and the
//! compiler vectorises the inner loop.

use serde::{Deserialize, Serialize};

use super::Sample;
use super::response::ResponseCurve;
use crate::rng::Rng;

/// Pixels evaluated together.
const BLOCK: usize = 64;

/// One fully connected layer: `out = W · in + b`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Layer {
    /// Inputs.
    pub inputs: usize,
    /// Outputs.
    pub outputs: usize,
    /// `outputs × inputs`, row-major.
    pub weights: Vec<f32>,
    /// `outputs`.
    pub bias: Vec<f32>,
}

/// The network with its input normalisation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mlp {
    /// Subtracted from each input.
    pub input_offset: [f32; 4],
    /// Then multiplied into each input.
    pub input_scale: [f32; 4],
    /// Hidden layers (ReLU) then the linear output layer.
    pub layers: Vec<Layer>,
    /// The network's mean reading of each true slope on its training samples; outputs
    /// are mapped through its inverse. Absent from models calibrated before it existed
    /// (their outputs stand as they are).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub response: Option<ResponseCurve>,
}

/// Training settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MlpTraining {
    /// Hidden layer widths.
    pub hidden: [usize; 3],
    /// Passes over the samples.
    pub epochs: usize,
    /// Samples per Adam step.
    pub batch: usize,
    /// Initial learning rate (decays to a tenth by the last epoch).
    pub learning_rate: f32,
    /// Decoupled (AdamW) weight decay. With a dozen ball presses the net otherwise learns
    /// where the presses were (x, y) instead of the colour law: held-out slope RMS 0.058
    /// without, 0.035 with 0.3 (15 epochs; more epochs overfit further).
    pub weight_decay: f32,
    /// Initialisation and shuffling seed.
    pub seed: u64,
}

impl Default for MlpTraining {
    fn default() -> Self {
        Self {
            hidden: [16, 16, 16],
            epochs: 15,
            batch: 128,
            learning_rate: 3e-3,
            weight_decay: 0.3,
            seed: 7,
        }
    }
}

impl Mlp {
    /// Trains on `samples`; `progress(epoch, rms)` is called after each epoch.
    pub fn fit(
        samples: &[Sample],
        settings: &MlpTraining,
        mut progress: impl FnMut(usize, f32),
    ) -> Self {
        let mut rng = Rng::new(settings.seed);
        let (input_offset, input_scale) = normalisation(samples);
        let sizes = [
            4,
            settings.hidden[0],
            settings.hidden[1],
            settings.hidden[2],
            1,
        ];
        let mut layers: Vec<Layer> = sizes
            .windows(2)
            .map(|io| {
                let (i, o) = (io[0], io[1]);
                let std = (2.0 / i as f64).sqrt();
                Layer {
                    inputs: i,
                    outputs: o,
                    weights: (0..i * o).map(|_| (rng.gaussian() * std) as f32).collect(),
                    bias: vec![0.0; o],
                }
            })
            .collect();
        let mut mlp = Self {
            input_offset,
            input_scale,
            layers: Vec::new(),
            response: None,
        };
        if samples.is_empty() {
            mlp.layers = layers;
            return mlp;
        }
        let mut adam = Adam::new(&layers);
        let mut order: Vec<usize> = (0..samples.len()).collect();
        let mut grads: Vec<Layer> = layers.iter().map(zeroed).collect();
        let mut acts: Vec<Vec<f32>> = sizes.iter().map(|&n| vec![0.0; n]).collect();
        let mut deltas: Vec<Vec<f32>> = sizes.iter().map(|&n| vec![0.0; n]).collect();
        let epochs = settings.epochs.max(1);
        for epoch in 0..epochs {
            for i in (1..order.len()).rev() {
                order.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
            }
            let lr = settings.learning_rate * 0.1f32.powf(epoch as f32 / epochs as f32);
            let mut sq = 0.0f64;
            for batch in order.chunks(settings.batch.max(1)) {
                grads.iter_mut().for_each(|g| {
                    g.weights.fill(0.0);
                    g.bias.fill(0.0);
                });
                for &k in batch {
                    let s = &samples[k];
                    for (j, a) in acts[0].iter_mut().enumerate() {
                        *a = (s.features[j] - input_offset[j]) * input_scale[j];
                    }
                    for (l, layer) in layers.iter().enumerate() {
                        let (before, after) = acts.split_at_mut(l + 1);
                        let last = l + 1 == layers.len();
                        forward_one(layer, &before[l], &mut after[0], !last);
                    }
                    let err = acts[sizes.len() - 1][0] - s.target;
                    sq += (err as f64).powi(2);
                    deltas[sizes.len() - 1][0] = err;
                    for l in (0..layers.len()).rev() {
                        let layer = &layers[l];
                        let g = &mut grads[l];
                        let (lower, upper) = deltas.split_at_mut(l + 1);
                        let delta_out = &upper[0];
                        for (o, &d_o) in delta_out.iter().enumerate() {
                            g.bias[o] += d_o;
                            let row = &mut g.weights[o * layer.inputs..(o + 1) * layer.inputs];
                            for (gw, a) in row.iter_mut().zip(&acts[l]) {
                                *gw += d_o * a;
                            }
                        }
                        if l > 0 {
                            let delta_in = &mut lower[l];
                            for (i, (di, &a)) in delta_in.iter_mut().zip(&acts[l]).enumerate() {
                                let d: f32 = delta_out
                                    .iter()
                                    .enumerate()
                                    .map(|(o, d_o)| layer.weights[o * layer.inputs + i] * d_o)
                                    .sum();
                                // ReLU derivative on the hidden activation.
                                *di = if a > 0.0 { d } else { 0.0 };
                            }
                        }
                    }
                }
                let scale = 1.0 / batch.len() as f32;
                adam.step(&mut layers, &grads, lr, scale, settings.weight_decay);
            }
            progress(epoch + 1, (sq / samples.len() as f64).sqrt() as f32);
        }
        mlp.layers = layers;
        let features: Vec<[f32; 4]> = samples.iter().map(|s| s.features).collect();
        let mut readings = vec![0.0; samples.len()];
        mlp.eval_batch(&features, &mut readings);
        mlp.response = ResponseCurve::fit(samples.iter().map(|s| s.target).zip(readings));
        mlp
    }

    /// Slopes for a batch of feature rows `[r, b, x, y]`, written to `out`.
    pub fn eval_batch(&self, features: &[[f32; 4]], out: &mut [f32]) {
        assert_eq!(features.len(), out.len());
        let widest = self
            .layers
            .iter()
            .map(|l| l.outputs.max(l.inputs))
            .max()
            .unwrap_or(4);
        let mut a = vec![0.0f32; widest * BLOCK];
        let mut b = vec![0.0f32; widest * BLOCK];
        for (chunk, out) in features.chunks(BLOCK).zip(out.chunks_mut(BLOCK)) {
            let n = chunk.len();
            for j in 0..4 {
                for (p, f) in chunk.iter().enumerate() {
                    a[j * BLOCK + p] = (f[j] - self.input_offset[j]) * self.input_scale[j];
                }
            }
            for (l, layer) in self.layers.iter().enumerate() {
                let relu = l + 1 < self.layers.len();
                for o in 0..layer.outputs {
                    let acc = &mut b[o * BLOCK..o * BLOCK + BLOCK];
                    acc.fill(layer.bias[o]);
                    for i in 0..layer.inputs {
                        let w = layer.weights[o * layer.inputs + i];
                        let input = &a[i * BLOCK..i * BLOCK + BLOCK];
                        for (s, x) in acc.iter_mut().zip(input) {
                            *s += w * x;
                        }
                    }
                    if relu {
                        for s in acc.iter_mut() {
                            *s = s.max(0.0);
                        }
                    }
                }
                std::mem::swap(&mut a, &mut b);
            }
            out[..n].copy_from_slice(&a[..n]);
        }
        if let Some(curve) = &self.response {
            out.iter_mut().for_each(|o| *o = curve.invert(*o));
        }
    }
}

fn forward_one(layer: &Layer, input: &[f32], output: &mut [f32], relu: bool) {
    for ((out, row), bias) in output
        .iter_mut()
        .zip(layer.weights.chunks_exact(layer.inputs))
        .zip(&layer.bias)
    {
        let s = bias + row.iter().zip(input).map(|(w, x)| w * x).sum::<f32>();
        *out = if relu { s.max(0.0) } else { s };
    }
}

fn zeroed(l: &Layer) -> Layer {
    Layer {
        inputs: l.inputs,
        outputs: l.outputs,
        weights: vec![0.0; l.weights.len()],
        bias: vec![0.0; l.bias.len()],
    }
}

/// Per-feature mean and 1/std (1 where the feature is constant).
fn normalisation(samples: &[Sample]) -> ([f32; 4], [f32; 4]) {
    let n = samples.len().max(1) as f64;
    let mut mean = [0.0f64; 4];
    let mut sq = [0.0f64; 4];
    for s in samples {
        for j in 0..4 {
            mean[j] += s.features[j] as f64 / n;
            sq[j] += (s.features[j] as f64).powi(2) / n;
        }
    }
    let mut offset = [0.0f32; 4];
    let mut scale = [1.0f32; 4];
    for j in 0..4 {
        let var = (sq[j] - mean[j] * mean[j]).max(0.0);
        offset[j] = mean[j] as f32;
        scale[j] = if var > 1e-12 {
            (1.0 / var.sqrt()) as f32
        } else {
            1.0
        };
    }
    (offset, scale)
}

/// Adam optimiser state, one moment pair per parameter.
struct Adam {
    m: Vec<Layer>,
    v: Vec<Layer>,
    t: i32,
}

impl Adam {
    fn new(layers: &[Layer]) -> Self {
        Self {
            m: layers.iter().map(zeroed).collect(),
            v: layers.iter().map(zeroed).collect(),
            t: 0,
        }
    }

    fn step(&mut self, layers: &mut [Layer], grads: &[Layer], lr: f32, scale: f32, decay: f32) {
        const B1: f32 = 0.9;
        const B2: f32 = 0.999;
        const EPS: f32 = 1e-8;
        self.t += 1;
        let c1 = 1.0 - B1.powi(self.t);
        let c2 = 1.0 - B2.powi(self.t);
        for (((layer, g), m), v) in layers
            .iter_mut()
            .zip(grads)
            .zip(&mut self.m)
            .zip(&mut self.v)
        {
            // Decoupled weight decay (AdamW) on the weights, not the biases.
            for w in layer.weights.iter_mut() {
                *w -= lr * decay * *w;
            }
            let params = layer.weights.iter_mut().chain(layer.bias.iter_mut());
            let gs = g.weights.iter().chain(&g.bias);
            let ms = m.weights.iter_mut().chain(m.bias.iter_mut());
            let vs = v.weights.iter_mut().chain(v.bias.iter_mut());
            for (((p, g), m), v) in params.zip(gs).zip(ms).zip(vs) {
                let g = g * scale;
                *m = B1 * *m + (1.0 - B1) * g;
                *v = B2 * *v + (1.0 - B2) * g * g;
                *p -= lr * (*m / c1) / ((*v / c2).sqrt() + EPS);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_a_smooth_function_of_colour_and_position() {
        let f = |s: &[f32; 4]| 1.5 * (s[0] - s[1]) / (s[0] + s[1]) * (1.0 + 0.2 * s[2]);
        let mut rng = Rng::new(3);
        let samples: Vec<Sample> = (0..6000)
            .map(|_| {
                let features = [
                    rng.range(0.3, 1.7) as f32,
                    rng.range(0.3, 1.7) as f32,
                    rng.uniform() as f32,
                    rng.uniform() as f32,
                ];
                Sample {
                    target: f(&features),
                    features,
                }
            })
            .collect();
        let settings = MlpTraining {
            epochs: 40,
            ..Default::default()
        };
        let mut last = f32::MAX;
        let mlp = Mlp::fit(&samples, &settings, |_, rms| last = rms);
        assert!(last < 0.03, "training rms {last}");
        let probe: Vec<[f32; 4]> = samples.iter().take(200).map(|s| s.features).collect();
        let mut out = vec![0.0; probe.len()];
        mlp.eval_batch(&probe, &mut out);
        let rms = (probe
            .iter()
            .zip(&out)
            .map(|(p, o)| (f(p) - o).powi(2))
            .sum::<f32>()
            / 200.0)
            .sqrt();
        assert!(rms < 0.04, "batched inference rms {rms}");
        // The outputs went through the network's response curve, fitted on its samples.
        let curve = mlp.response.clone().expect("a response curve");
        curve.check().unwrap();
        let mut raw = vec![0.0; probe.len()];
        let bare = Mlp {
            response: None,
            ..mlp.clone()
        };
        bare.eval_batch(&probe, &mut raw);
        for (r, o) in raw.iter().zip(&out) {
            assert_eq!(curve.invert(*r).to_bits(), o.to_bits());
        }
    }
}
