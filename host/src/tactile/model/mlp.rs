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
/// Pixels whose sums for one neuron are kept in registers: four vectors of AVX2's eight
/// lanes (sixteen of its registers would spill at eight vectors).
const GROUP: usize = 32;

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

    /// Slopes for a batch of feature rows `[r, b, x, y]`, written to `out`. Runs the
    /// copy of the layers compiled for AVX2 with fused multiply-adds when the CPU has them
    /// (the sums then round once per product instead of twice: outputs differ from the
    /// portable copy's by a few units in the last place).
    pub fn eval_batch(&self, features: &[[f32; 4]], out: &mut [f32]) {
        assert_eq!(features.len(), out.len());
        #[cfg(target_arch = "x86_64")]
        if crate::cpu::avx2_fma() {
            // SAFETY: `forward_avx2` only needs AVX2 and FMA, detected just above.
            #[allow(unsafe_code)]
            unsafe {
                self.forward_avx2(features, out)
            };
        } else {
            self.forward::<false>(features, out);
        }
        #[cfg(not(target_arch = "x86_64"))]
        self.forward::<false>(features, out);
        if let Some(curve) = &self.response {
            out.iter_mut().for_each(|o| *o = curve.invert(*o));
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn forward_avx2(&self, features: &[[f32; 4]], out: &mut [f32]) {
        self.forward::<true>(features, out);
    }

    /// The network's raw outputs, [`BLOCK`] pixels at a time with activations laid out
    /// neuron-major. Each neuron's sums for [`GROUP`] pixels stay in registers while its
    /// weights go by (one load of each input run and one weight per multiply-add of
    /// [`GROUP`] lanes, where summing into memory took two loads and a store); `FUSED`
    /// makes each multiply-add one rounding (for a CPU with FMA).
    #[inline(always)]
    fn forward<const FUSED: bool>(&self, features: &[[f32; 4]], out: &mut [f32]) {
        let widest = self
            .layers
            .iter()
            .map(|l| l.outputs.max(l.inputs))
            .max()
            .unwrap_or(4)
            .max(4);
        let mut a = vec![0.0f32; widest * BLOCK];
        let mut b = vec![0.0f32; widest * BLOCK];
        for (chunk, out) in features.chunks(BLOCK).zip(out.chunks_mut(BLOCK)) {
            // A last, partial block computes every lane: the ones past `chunk` start from
            // what the previous block left (lanes never mix) and are not read back.
            for j in 0..4 {
                for (p, f) in chunk.iter().enumerate() {
                    a[j * BLOCK + p] = (f[j] - self.input_offset[j]) * self.input_scale[j];
                }
            }
            for (l, layer) in self.layers.iter().enumerate() {
                let relu = l + 1 < self.layers.len();
                let rows = layer.weights.chunks_exact(layer.inputs.max(1));
                for (o, (row, &bias)) in rows.zip(&layer.bias).enumerate() {
                    for g in (0..BLOCK).step_by(GROUP) {
                        let mut acc = [bias; GROUP];
                        for (i, &w) in row.iter().enumerate() {
                            let x = &a[i * BLOCK + g..i * BLOCK + g + GROUP];
                            for (s, &x) in acc.iter_mut().zip(x) {
                                *s = if FUSED { w.mul_add(x, *s) } else { *s + w * x };
                            }
                        }
                        if relu {
                            for s in acc.iter_mut() {
                                *s = s.max(0.0);
                            }
                        }
                        b[o * BLOCK + g..o * BLOCK + g + GROUP].copy_from_slice(&acc);
                    }
                }
                std::mem::swap(&mut a, &mut b);
            }
            out.copy_from_slice(&a[..chunk.len()]);
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

    /// A network with random weights (no response curve) of the default shape.
    fn random_net(seed: u64) -> Mlp {
        let mut rng = Rng::new(seed);
        let sizes = [4, 16, 16, 16, 1];
        let layers = sizes
            .windows(2)
            .map(|io| Layer {
                inputs: io[0],
                outputs: io[1],
                weights: (0..io[0] * io[1])
                    .map(|_| rng.gaussian() as f32 * 0.5)
                    .collect(),
                bias: (0..io[1]).map(|_| rng.gaussian() as f32 * 0.1).collect(),
            })
            .collect();
        Mlp {
            input_offset: [1.0, 1.0, 0.5, 0.5],
            input_scale: [2.0, 2.0, 3.0, 3.0],
            layers,
            response: None,
        }
    }

    /// The network one sample at a time, as training runs it.
    fn one_at_a_time(mlp: &Mlp, f: &[f32; 4]) -> f32 {
        let mut act: Vec<f32> = (0..4)
            .map(|j| (f[j] - mlp.input_offset[j]) * mlp.input_scale[j])
            .collect();
        for (l, layer) in mlp.layers.iter().enumerate() {
            let mut next = vec![0.0; layer.outputs];
            forward_one(layer, &act, &mut next, l + 1 < mlp.layers.len());
            act = next;
        }
        act[0]
    }

    #[test]
    fn batched_layers_match_one_sample_at_a_time_across_block_edges() {
        let mlp = random_net(11);
        let mut rng = Rng::new(12);
        for n in [
            0,
            1,
            GROUP - 1,
            GROUP + 1,
            BLOCK - 1,
            BLOCK,
            BLOCK + 1,
            3 * BLOCK + 17,
        ] {
            let features: Vec<[f32; 4]> = (0..n)
                .map(|_| {
                    [
                        rng.range(0.3, 1.7) as f32,
                        rng.range(0.3, 1.7) as f32,
                        rng.uniform() as f32,
                        rng.uniform() as f32,
                    ]
                })
                .collect();
            let expected: Vec<f32> = features.iter().map(|f| one_at_a_time(&mlp, f)).collect();
            // The dispatched copy (AVX2 with FMA where the CPU has it) and the portable one.
            let mut dispatched = vec![f32::NAN; n];
            mlp.eval_batch(&features, &mut dispatched);
            let mut portable = vec![f32::NAN; n];
            mlp.forward::<false>(&features, &mut portable);
            for k in 0..n {
                let tol = 1e-4 * (1.0 + expected[k].abs());
                for (what, got) in [("dispatched", dispatched[k]), ("portable", portable[k])] {
                    assert!(
                        (got - expected[k]).abs() <= tol,
                        "{what}, {n} pixels, pixel {k}: {got} against {}",
                        expected[k]
                    );
                }
            }
        }
    }

    #[test]
    fn a_pixel_with_a_non_finite_feature_spoils_only_its_own_slope() {
        let mlp = random_net(13);
        let mut features = vec![[1.0f32, 0.9, 0.5, 0.5]; BLOCK + 5];
        features[3][0] = f32::NAN;
        features[BLOCK + 1][1] = f32::INFINITY;
        let mut out = vec![0.0; features.len()];
        mlp.eval_batch(&features, &mut out);
        let clean = one_at_a_time(&mlp, &features[0]);
        for (k, o) in out.iter().enumerate() {
            if k == 3 || k == BLOCK + 1 {
                continue;
            }
            assert!(
                (o - clean).abs() <= 1e-4 * (1.0 + clean.abs()),
                "pixel {k}: {o}"
            );
        }
    }

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
