//! Four-light photometric stereo: the slope along both axes from all four strips' colours
//! at once, with each strip's light direction fitted per cell of the frame, and the skin's
//! and camera's response fitted for the whole frame.
//!
//! For a matte skin lit by strip `k` from direction `l_k`, the normalised colour (flat
//! skin = 1) is `c_k = (n·l_k) / (n₀·l_k)` with `n = (−p, −q, 1) / |n|`, so
//! `c_k·|n| = 1 − a_k·p − b_k·q` where `(a_k, b_k)` is the light's horizontal direction
//! over its height. Unlike the per-axis models this keeps the cross term `b_k`: a strip
//! of point LEDs lights a pixel near one end of it from the side as well, so an x strip's
//! colour there also answers the y slope. The pairs `(a_k, b_k)` are fitted per cell by
//! least squares on the gentler part of the calibration's slopes, as the light model's
//! responses are ([`super::light`]).
//!
//! **The response.** A skin that is not matte, or a camera that is not linear, bends those
//! lines. The model is `c_k^P·|n|^e = 1 − a_k·p − b_k·q` ([`Response`]), which holds
//! exactly for two such departures and is matte at `P = e = 1`:
//! - a rough coating that follows Minnaert's law (`cos(i)^k·cos(r)^(k−1)`, the camera
//!   overhead): `P = 1/k`, `e = 2 − 1/k`;
//! - a camera with a response curve `c^(1/γ)` (display gamma) on a matte skin: `P = γ`,
//!   `e = 1`;
//! - both: `P = γ/k`, `e = 2 − 1/k`. So the responses these make lie in `P ≥ 1`, `e ≤ 1`,
//!   `P + e ≥ 2`, and the response is chosen there ([`COLOUR_POWERS`], [`NORM_POWERS`]).
//!
//! Gentle slopes barely tell the response apart (`|n|` stays near 1), steeper ones do: the
//! lights are fitted for each response of a grid on the gentler slopes, and the response
//! whose lights predict the colours of the steeper slopes best, which none of them was
//! fitted on, is kept ([`choose_response`]).
//!
//! Reading a pixel inverts the lines, which is what carries it past the calibration's
//! slopes:
//! - three or four lit strips (colour at least [`SHADOWED`]): `|n|^e` is treated as a
//!   third unknown `m`, and `c_k^P·m + a_k·p + b_k·q = 1` is linear: least squares (exact
//!   for three);
//! - two lit strips (steep walls shadow one strip of each phase): their ratio gives a
//!   line of slopes, and `c^P·|n|^e = 1 − a·p − b·q` one equation along it (a quadratic
//!   for `e = 1`, else solved by bracketing its roots); of its roots the one that keeps the
//!   lit strips lit and the shadowed ones dark is taken;
//! - fewer, or two of one phase (the other phase dark is no wall): the slope is not
//!   measured (`None`: the pixel is filled from its neighbours).
//!
//! A reading must explain the colours it came from: every lit strip near the colour it
//! predicts, every shadowed strip predicted dark, and with three or four lit strips the
//! third unknown `m` near the slopes' own `|n|^e`; otherwise the pixel is left unread.
//!
//! Numbers: fitted and inverted in f64; a NaN colour (a phase the colour filter
//! rejected) leaves the pixel unread, as do slopes that do not explain the colours; slopes
//! are bounded to ±[`MAX_SLOPE`]; a cell without enough samples takes the whole frame's
//! pair; a response outside [`COLOUR_POWERS`] and [`NORM_POWERS`] is refused when a model
//! file is loaded.

use std::ops::RangeInclusive;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

mod curves;

pub use curves::{Curves, Response};

use super::cells::cell_weights;
use super::light::SHADOWED;

/// The light directions are fitted on slopes up to this share of the calibration's
/// steepest (95th percentile of |slope|), as the light model's responses are.
const FIT_SHARE: f64 = 0.6;

/// The response is chosen by the colours of the slopes above the fit's and up to this
/// share of the calibration's steepest (the steepest sit at a press's rim, where the
/// colour no longer follows the sphere).
const CHOICE_SHARE: f64 = 0.9;

/// A cell whose slope weight is below this share of the mean cell's takes the whole
/// frame's pair.
const MIN_CELL_SHARE: f64 = 0.05;

/// Bound on a read slope (the integration's bound is 3 as well).
pub const MAX_SLOPE: f64 = 3.0;

/// The colour powers `P` the response is chosen from (and a model file may hold): a
/// Minnaert exponent down to 0.36, a camera gamma up to 2.8. None below 1: both known
/// departures make `P` at least 1 (a coating that darkens faster than the cosine law, or
/// a camera that undoes a gamma, is none we know of), and on the tuning families every
/// best response under 1 read the steep wall shallower than matte (`ours-random` and
/// `ours-finite-strips` skins 4, `P` 0.80).
pub const COLOUR_POWERS: RangeInclusive<f32> = 1.0..=2.8;

/// The powers `e` of `|n|` the response is chosen from (and a model file may hold):
/// Minnaert's law makes `e = 2 − 1/k ≤ 1`. The choice also keeps to `P + e ≥ 2`
/// ([`physical`]).
pub const NORM_POWERS: RangeInclusive<f32> = 0.0..=1.0;

/// Whether powers `P`, `e` (in thousandths) are a response a rough coating and a camera's
/// gamma can make: `P + e ≥ 2` (with `P = γ/k`, `e = 2 − 1/k`, `γ ≥ 1`).
fn physical(colour: i32, norm: i32) -> bool {
    colour + norm >= 2000
}

/// The coarse grid's step of both powers; the finer grids around its best are a quarter
/// and a twentieth of it.
const GRID_STEP: f64 = 0.2;

/// At most this many gentle samples fit the lights while a response is chosen, and at
/// most [`MAX_CHOICE_STEEP`] steeper ones judge them (evenly spaced: the presses' pixels
/// in turn); the chosen response's lights are then fitted on every gentle sample.
const MAX_CHOICE_GENTLE: usize = 60_000;

/// See [`MAX_CHOICE_GENTLE`].
const MAX_CHOICE_STEEP: usize = 30_000;

/// One training pixel: the four normalised colours `[r_dx, b_dx, r_dy, b_dy]` (NaN where
/// a phase was rejected), its position in [0, 1]² and its true slopes `[p, q]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointSample {
    /// Normalised colours of both phases.
    pub colours: [f32; 4],
    /// `x / width`, `y / height`.
    pub position: [f32; 2],
    /// `∂d/∂x`, `∂d/∂y`.
    pub slope: [f32; 2],
}

/// Each strip's light direction per cell, and the response.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhotometricModel {
    /// Cells across.
    pub cells_x: usize,
    /// Cells down.
    pub cells_y: usize,
    /// `cells_y × cells_x` entries, each `[a, b]` of the strips `[red dx, blue dx, red
    /// dy, blue dy]`: `colour^P·|n|^e = 1 − a·p − b·q`.
    pub lights: Vec<[[f32; 2]; 4]>,
    /// `P`, the colour's power (left out of files when 1, which files without it mean).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub colour_power: f32,
    /// `e`, the power of `|n|` (left out of files when 1, which files without it mean).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub norm_power: f32,
}

fn one() -> f32 {
    1.0
}

fn is_one(v: &f32) -> bool {
    *v == 1.0
}

impl PhotometricModel {
    /// Fits the response and the lights of `cells_x × cells_y` cells to `samples`.
    pub fn fit(samples: &[JointSample], cells_x: usize, cells_y: usize) -> Self {
        let (cells_x, cells_y) = (cells_x.max(1), cells_y.max(1));
        let usable: Vec<&JointSample> = samples
            .iter()
            .filter(|s| s.slope.iter().chain(&s.position).all(|v| v.is_finite()))
            .collect();
        let steepest = steepest(&usable);
        let limit = FIT_SHARE * steepest;
        let gentle: Vec<&JointSample> = usable
            .iter()
            .copied()
            .filter(|s| magnitude(s) <= limit)
            .collect();
        let steeper: Vec<&JointSample> = usable
            .iter()
            .copied()
            .filter(|s| {
                let m = magnitude(s);
                m > limit && m <= CHOICE_SHARE * steepest
            })
            .collect();
        let response = choose_response(&gentle, &steeper, cells_x, cells_y);
        let prepared: Vec<Prepared> = gentle.iter().map(|s| Prepared::of(s)).collect();
        Self::with_lights(&prepared, response, cells_x, cells_y)
    }

    /// The lights fitted to `gentle` under `response`.
    fn with_lights(
        gentle: &[Prepared],
        response: Response,
        cells_x: usize,
        cells_y: usize,
    ) -> Self {
        // Per cell and strip: Σ w·[p², p·q, q², p·y, q·y] with y = 1 − c^P·|n|^e = a·p + b·q.
        let cells = cells_x * cells_y;
        let mut sums = vec![[[0.0f64; 5]; 4]; cells];
        let mut all = [[0.0f64; 5]; 4];
        for s in gentle {
            let (p, q) = (s.slope[0], s.slope[1]);
            let norm = response.norm_factor(s.norm_sq);
            let weights = cell_weights(s.position[0], s.position[1], cells_x, cells_y);
            for (k, &c) in s.colours.iter().enumerate() {
                if !lit(c) {
                    continue;
                }
                let y = 1.0 - response.linear(f64::from(c)) * norm;
                let terms = [p * p, p * q, q * q, p * y, q * y];
                for (a, t) in all[k].iter_mut().zip(terms) {
                    *a += t;
                }
                for (cell, w) in weights {
                    for (a, t) in sums[cell][k].iter_mut().zip(terms) {
                        *a += f64::from(w) * t;
                    }
                }
            }
        }
        let frame: [[f64; 2]; 4] = all.map(|s| direction(&s).unwrap_or([0.0; 2]));
        let lights = sums
            .iter()
            .map(|cell| {
                let mut out = [[0.0f32; 2]; 4];
                for (k, (o, s)) in out.iter_mut().zip(cell).enumerate() {
                    let enough =
                        s[0] + s[2] >= MIN_CELL_SHARE * (all[k][0] + all[k][2]) / cells as f64;
                    let d = if enough {
                        direction(s).unwrap_or(frame[k])
                    } else {
                        frame[k]
                    };
                    *o = d.map(|v| v as f32);
                }
                out
            })
            .collect();
        Self {
            cells_x,
            cells_y,
            lights,
            colour_power: response.colour as f32,
            norm_power: response.norm as f32,
        }
    }

    /// The response the model reads with.
    pub fn response(&self) -> Response {
        Response {
            colour: f64::from(self.colour_power),
            norm: f64::from(self.norm_power),
        }
    }

    /// The lights at `(x, y)` ∈ [0, 1]², bilinear between cell centres; `None` when the
    /// entries do not match the model's cells (a damaged file).
    fn lights_at(&self, x: f32, y: f32) -> Option<[[f64; 2]; 4]> {
        let (cx, cy) = (self.cells_x.max(1), self.cells_y.max(1));
        if self.lights.len() < cx * cy {
            return None;
        }
        let mut out = [[0.0f64; 2]; 4];
        for (cell, w) in cell_weights(x, y, cx, cy) {
            for (o, l) in out.iter_mut().zip(&self.lights[cell]) {
                o[0] += f64::from(w) * f64::from(l[0]);
                o[1] += f64::from(w) * f64::from(l[1]);
            }
        }
        Some(out)
    }

    /// Slopes `[p, q]` of a pixel at `(x, y)` ∈ [0, 1]² with normalised colours
    /// `[r_dx, b_dx, r_dy, b_dy]`; `None` where they do not measure it (fewer than two
    /// strips lit, or colours no slope explains: fill such a pixel from its neighbours)
    /// or the model is damaged.
    pub fn read(&self, colours: [f32; 4], x: f32, y: f32) -> Option<[f32; 2]> {
        self.read_with(&Curves::exact(self.response()), colours, x, y)
    }

    /// [`read`](Self::read) with the response's `curves` (the model's own, as
    /// [`curves`](Self::curves) makes them: a reconstruction makes them once).
    pub fn read_with(
        &self,
        curves: &Curves,
        colours: [f32; 4],
        x: f32,
        y: f32,
    ) -> Option<[f32; 2]> {
        let lights = self.lights_at(x, y)?;
        invert(colours, &lights, curves).map(|s| s.map(|v| v as f32))
    }

    /// The response's curves, tabled for reading many pixels.
    pub fn curves(&self) -> Curves {
        Curves::tabled(self.response())
    }
}

/// A sample in f64 with `|n|²`, as the fits use it.
struct Prepared {
    colours: [f32; 4],
    position: [f32; 2],
    slope: [f64; 2],
    norm_sq: f64,
}

impl Prepared {
    fn of(s: &JointSample) -> Self {
        let slope = s.slope.map(f64::from);
        Self {
            colours: s.colours,
            position: s.position,
            slope,
            norm_sq: 1.0 + slope[0] * slope[0] + slope[1] * slope[1],
        }
    }
}

/// The response of the grid (`COLOUR_POWERS × NORM_POWERS` where [`physical`], in steps
/// of [`GRID_STEP`], then a quarter and a twentieth of it around the best) whose lights,
/// fitted on `gentle`, predict the lit colours of `steeper` best (mean squared colour
/// error), kept where it leaves at most [`MATTE_KEPT_ABOVE`] of matte's error. Matte when `steeper` is empty (nothing
/// tells the responses apart), and matte wins a tie.
fn choose_response(
    gentle: &[&JointSample],
    steeper: &[&JointSample],
    cells_x: usize,
    cells_y: usize,
) -> Response {
    let every = |set: &[&JointSample], most: usize| -> Vec<Prepared> {
        let stride = set.len().div_ceil(most.max(1)).max(1);
        set.iter()
            .step_by(stride)
            .map(|s| Prepared::of(s))
            .collect()
    };
    let (fit_on, judge_on) = (
        every(gentle, MAX_CHOICE_GENTLE),
        every(steeper, MAX_CHOICE_STEEP),
    );
    let error = |r: Response| -> f64 {
        let model = PhotometricModel::with_lights(&fit_on, r, cells_x, cells_y);
        let (mut sq, mut n) = (0.0f64, 0usize);
        for s in &judge_on {
            let Some(lights) = model.lights_at(s.position[0], s.position[1]) else {
                return f64::INFINITY;
            };
            for (&c, l) in s.colours.iter().zip(&lights) {
                if lit(c) {
                    let shade = 1.0 - l[0] * s.slope[0] - l[1] * s.slope[1];
                    sq += (r.predict(shade, s.norm_sq) - f64::from(c)).powi(2);
                    n += 1;
                }
            }
        }
        if n == 0 { f64::INFINITY } else { sq / n as f64 }
    };
    // Powers in thousandths, so that the grid holds 1 exactly.
    let thousandths = |v: f32| (f64::from(v) * 1000.0).round() as i32;
    let (colours, norms) = (
        thousandths(*COLOUR_POWERS.start())..=thousandths(*COLOUR_POWERS.end()),
        thousandths(*NORM_POWERS.start())..=thousandths(*NORM_POWERS.end()),
    );
    let allowed = |(c, e): (i32, i32)| colours.contains(&c) && norms.contains(&e) && physical(c, e);
    let response = |(c, e): (i32, i32)| Response {
        colour: f64::from(c) / 1000.0,
        norm: f64::from(e) / 1000.0,
    };
    // The best of `candidates` (in their order: the first of equals), or `best` itself.
    let best_of = |candidates: Vec<(i32, i32)>, best: (f64, (i32, i32))| {
        candidates
            .par_iter()
            .map(|&ce| (error(response(ce)), ce))
            .collect::<Vec<_>>()
            .into_iter()
            .fold(best, |b, c| if c.0 < b.0 { c } else { b })
    };
    let matte = (error(Response::MATTE), (1000, 1000));
    if !matte.0.is_finite() {
        return Response::MATTE;
    }
    let step = (GRID_STEP * 1000.0).round() as i32;
    let coarse: Vec<(i32, i32)> = colours
        .clone()
        .step_by(step as usize)
        .flat_map(|c| norms.clone().step_by(step as usize).map(move |e| (c, e)))
        .filter(|&ce| allowed(ce) && ce != matte.1)
        .collect();
    let mut best = best_of(coarse, matte);
    // Finer grids around the best so far: steps of a quarter, then a twentieth.
    for fine in [step / 4, step / 20] {
        let (c0, e0) = best.1;
        let around: Vec<(i32, i32)> = (-3..=3)
            .flat_map(|i| (-3..=3).map(move |j| (c0 + i * fine, e0 + j * fine)))
            .filter(|&ce| allowed(ce) && ce != (c0, e0))
            .collect();
        best = best_of(around, best);
    }
    let (error, best) = best;
    if error <= MATTE_KEPT_ABOVE * matte.0 {
        response(best)
    } else {
        Response::MATTE
    }
}

/// A response other than matte is kept only where its error on the steeper slopes is at
/// most this share of matte's. Chosen on the tuning families (skins 1–4 of each), on a
/// grid without [`physical`] and with `P` from 0.6: there the best response left
/// 0.96–1.00 of matte's error on `ours-nominal` and on `ours-random` and
/// `ours-finite-strips` skins 1 and 3, 0.86 and 0.90 on their skins 4 (where it read the
/// steep wall shallower than matte: `ours-random` 4 0.88 mm against 1.03), 0.04–0.68 on
/// the rough coatings (`ours-rough`) and 0.35–0.45 on the skins whose camera has a
/// response curve (`ours-random` and `ours-finite-strips` skins 2). On today's grid
/// matte is the best response of the matte skins (1.00); the others read 0.04–0.68
/// and 0.35–0.45 as before.
const MATTE_KEPT_ABOVE: f64 = 0.75;

/// The slope magnitude of a sample.
fn magnitude(s: &JointSample) -> f64 {
    f64::from(s.slope[0]).hypot(f64::from(s.slope[1]))
}

/// The calibration's steepest slope: the 95th percentile of the usable samples' slope
/// magnitudes (0 without any).
fn steepest(samples: &[&JointSample]) -> f64 {
    let mut magnitudes: Vec<f64> = samples.iter().copied().map(magnitude).collect();
    match magnitudes.len() {
        0 => 0.0,
        n => {
            let k = (n - 1) * 95 / 100;
            *magnitudes.select_nth_unstable_by(k, f64::total_cmp).1
        }
    }
}

/// A colour that measures its strip's light.
#[inline]
fn lit(c: f32) -> bool {
    c.is_finite() && c >= SHADOWED
}

/// `(a, b)` from the sums `[p², p·q, q², p·y, q·y]`; `None` when they do not determine it.
fn direction(s: &[f64; 5]) -> Option<[f64; 2]> {
    let det = s[0] * s[2] - s[1] * s[1];
    if det.abs().is_nan() || det.abs() <= 1e-9 * (s[0] * s[2]).max(1e-12) {
        return None;
    }
    let a = (s[3] * s[2] - s[4] * s[1]) / det;
    let b = (s[0] * s[4] - s[1] * s[3]) / det;
    (a.is_finite() && b.is_finite()).then_some([a, b])
}

/// Slopes from colours, lights and the response (see the module documentation); `None`
/// when a phase was rejected (NaN), fewer than two strips are lit (or two of one phase),
/// nothing solves (with three or four lit, no `m` near `|n|^e`), or the slopes found do
/// not explain the colours (see [`explains`]).
fn invert(colours: [f32; 4], lights: &[[f64; 2]; 4], response: &Curves) -> Option<[f64; 2]> {
    // A phase the colour filter rejected leaves its axis unmeasured, and the other
    // phase's two strips alone leave the slope along it free: nothing is read.
    if colours.iter().any(|c| c.is_nan()) {
        return None;
    }
    let (mut lit_strips, mut count) = ([0usize; 4], 0);
    for k in (0..4).filter(|&k| lit(colours[k])) {
        lit_strips[count] = k;
        count += 1;
    }
    let slopes = match count {
        3 | 4 => three_or_more(colours, lights, &lit_strips[..count], response),
        2 => two(colours, lights, [lit_strips[0], lit_strips[1]], response),
        _ => None,
    }?;
    // Judged as found, then bounded: a clamped slope would not explain the colours it
    // came from, and an unclamped wild one must not pass as the bound.
    (slopes.iter().all(|v| v.is_finite()) && explains(colours, lights, slopes, response))
        .then(|| slopes.map(|v| v.clamp(-MAX_SLOPE, MAX_SLOPE)))
}

/// Whether slopes `[p, q]` explain the colours: every lit strip within [`TOLERANCE`] of
/// the colour the lights predict, and no strip that reads shadowed predicted brighter
/// than [`SHADOWED`] by more than [`SHADOW_TOLERANCE`].
fn explains(
    colours: [f32; 4],
    lights: &[[f64; 2]; 4],
    [p, q]: [f64; 2],
    response: &Curves,
) -> bool {
    let norm = response.norm_factor(1.0 + p * p + q * q);
    colours.iter().zip(lights).all(|(&c, l)| {
        let predicted = response.colour_of(1.0 - l[0] * p - l[1] * q, norm);
        let c = f64::from(c);
        if c >= f64::from(SHADOWED) {
            (predicted - c).abs() <= TOLERANCE
        } else {
            predicted - f64::from(SHADOWED) <= SHADOW_TOLERANCE
        }
    })
}

/// How much brighter than [`SHADOWED`] the slopes read may predict a strip that reads
/// shadowed (0.25 tried on the tuning families: it cost the steep wall of the skin whose
/// camera has a response curve, 0.78 → 0.72 mm).
const SHADOW_TOLERANCE: f64 = 0.5;

/// How far (normalised colour, flat skin = 1) a colour may be from the one the slopes
/// read predict.
const TOLERANCE: f64 = 0.5;

/// Least squares of `c_k^P·m + a_k·p + b_k·q = 1` over the lit strips, for `(m, p, q)`.
#[allow(clippy::needless_range_loop)] // rows and columns of a matrix
fn three_or_more(
    colours: [f32; 4],
    lights: &[[f64; 2]; 4],
    lit: &[usize],
    response: &Curves,
) -> Option<[f64; 2]> {
    let mut ata = [[0.0f64; 3]; 3];
    let mut atb = [0.0f64; 3];
    for &k in lit {
        let row = [
            response.linear(f64::from(colours[k])),
            lights[k][0],
            lights[k][1],
        ];
        for i in 0..3 {
            for j in 0..3 {
                ata[i][j] += row[i] * row[j];
            }
            atb[i] += row[i];
        }
    }
    let [m, p, q] = solve3(ata, atb)?;
    // m stands for |n|^e: colours that need another one (a light that is not the
    // strips', a colour the model does not make) are not read.
    let norm = response.norm_factor(1.0 + p * p + q * q);
    ((m / norm - 1.0).abs() <= NORM_TOLERANCE).then_some([p, q])
}

/// How far (relative) the third unknown of [`three_or_more`] may be from the `|n|^e` of
/// the slopes it comes with (0.25 and 0.5 read the tuning families alike).
const NORM_TOLERANCE: f64 = 0.25;

/// Gaussian elimination with partial pivoting of a 3×3 system.
#[allow(clippy::needless_range_loop)] // rows and columns of a matrix
fn solve3(mut a: [[f64; 3]; 3], mut b: [f64; 3]) -> Option<[f64; 3]> {
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if scale.is_nan() || scale <= 0.0 {
        return None;
    }
    for i in 0..3 {
        let pivot = (i..3).max_by(|&r, &s| a[r][i].abs().total_cmp(&a[s][i].abs()))?;
        if a[pivot][i].abs().is_nan() || a[pivot][i].abs() <= 1e-10 * scale {
            return None;
        }
        a.swap(i, pivot);
        b.swap(i, pivot);
        for r in 0..3 {
            if r != i {
                let f = a[r][i] / a[i][i];
                for c in i..3 {
                    a[r][c] -= f * a[i][c];
                }
                b[r] -= f * b[i];
            }
        }
    }
    Some([0, 1, 2].map(|i| b[i] / a[i][i]))
}

/// Two lit strips `i`, `j`: on the line their ratio allows, the slope whose `|n|^e` makes
/// strip `i`'s colour; of the roots, the one that keeps both lit and the other strips
/// darkest where they are shadowed (a score that adds 0.01 of the slope's size, so
/// between equals the gentler one).
fn two(
    colours: [f32; 4],
    lights: &[[f64; 2]; 4],
    [i, j]: [usize; 2],
    response: &Curves,
) -> Option<[f64; 2]> {
    // Strips 0, 1 light the dx phase, 2, 3 the dy phase. Both strips of one phase dark is
    // no wall (a wall shadows the strip it turns from), and the two of the other barely
    // answer the slope along it.
    if i / 2 == j / 2 {
        return None;
    }
    let c1 = response.linear(f64::from(colours[i]));
    let c2 = response.linear(f64::from(colours[j]));
    let ([a1, b1], [a2, b2]) = (lights[i], lights[j]);
    // c1·(1 − a2·p − b2·q) = c2·(1 − a1·p − b1·q): u·p + v·q = r.
    let (u, v, r) = (c1 * a2 - c2 * a1, c1 * b2 - c2 * b1, c1 - c2);
    let len = u.hypot(v);
    if len.is_nan() || len <= 1e-9 {
        return None;
    }
    // The line's point nearest flat, and its direction (at right angles to it, so
    // |s₀ + t·d|² = |s₀|² + t²).
    let (p0, q0) = (u * r / (len * len), v * r / (len * len));
    let (dp, dq) = (-v / len, u / len);
    // c1·|n|^e = e0 + e1·t, with e = 1 − a1·p − b1·q along the line.
    let (e0, e1) = (1.0 - a1 * p0 - b1 * q0, -(a1 * dp + b1 * dq));
    let base = 1.0 + p0 * p0 + q0 * q0;
    let roots = if response.response.norm == 1.0 {
        matte_roots(c1, e0, e1, base, p0 * dp + q0 * dq)
    } else {
        // Slopes within the bound on both axes lie within |s|² ≤ 2·MAX_SLOPE².
        let span = (2.0 * MAX_SLOPE * MAX_SLOPE - (base - 1.0)).max(0.0).sqrt();
        bracketed_roots(span, |t| {
            c1 * response.norm_factor(base + t * t) - (e0 + e1 * t)
        })
    };
    let mut best: Option<(f64, [f64; 2])> = None;
    for t in roots.into_iter().filter(|t| t.is_finite()) {
        let (p, q) = (p0 + t * dp, q0 + t * dq);
        if 1.0 - a1 * p - b1 * q <= 0.0 {
            continue;
        }
        let norm = response.norm_factor(1.0 + p * p + q * q);
        // How much brighter the model says the unlit strips would be than they are.
        let too_bright: f64 = (0..4)
            .filter(|&k| k != i && k != j && colours[k].is_finite())
            .map(|k| {
                let predicted = response.colour_of(1.0 - lights[k][0] * p - lights[k][1] * q, norm);
                (predicted - f64::from(colours[k]).max(0.0)).max(0.0)
            })
            .sum();
        let score = too_bright + 0.01 * p.hypot(q);
        if best.is_none_or(|(s, _)| score < s) {
            best = Some((score, [p, q]));
        }
    }
    best.map(|(_, s)| s)
}

/// The roots `t` of `c1²·(base + t²) = (e0 + e1·t)²` (`e = 1`: the two-strip equation
/// squared; `cross` is `s₀·d`, 0 for the line's nearest point), or the nearest approach
/// when there is none; NaN fills the unused places.
fn matte_roots(c1: f64, e0: f64, e1: f64, base: f64, cross: f64) -> [f64; 2] {
    let k = c1 * c1;
    let qa = k - e1 * e1;
    let qb = 2.0 * (k * cross - e0 * e1);
    let qc = k * base - e0 * e0;
    let mut roots = [f64::NAN; 2];
    if qa.abs() > 1e-12 {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc >= 0.0 {
            let s = disc.sqrt();
            roots = [(-qb + s) / (2.0 * qa), (-qb - s) / (2.0 * qa)];
        } else {
            // No exact root: the nearest approach.
            roots[0] = -qb / (2.0 * qa);
        }
    } else if qb.abs() > 1e-12 {
        roots[0] = -qc / qb;
    }
    roots
}

/// Steps of the scan that brackets the roots of the two-strip equation.
const ROOT_STEPS: usize = 32;

/// The roots of `f` on `[−span, span]` (sign changes on a scan of [`ROOT_STEPS`], each
/// refined by the Illinois form of regula falsi; at most two kept, the nearest to 0
/// first), or the scan's point of least `|f|` when it changes sign nowhere (the nearest
/// approach, as [`matte_roots`] takes it); NaN fills the unused places.
fn bracketed_roots(span: f64, f: impl Fn(f64) -> f64) -> [f64; 2] {
    let step = 2.0 * span / ROOT_STEPS as f64;
    let mut found = [f64::NAN; 4];
    let mut count = 0;
    let (mut t0, mut f0) = (-span, f(-span));
    let mut nearest = (f0.abs(), t0);
    for s in 1..=ROOT_STEPS {
        let t1 = -span + s as f64 * step;
        let f1 = f(t1);
        if f1.abs() < nearest.0 {
            nearest = (f1.abs(), t1);
        }
        let root = if f0 == 0.0 {
            Some(t0)
        } else if f0 * f1 < 0.0 {
            Some(illinois(&f, (t0, f0), (t1, f1)))
        } else {
            None
        };
        if let Some(t) = root.filter(|_| count < found.len()) {
            found[count] = t;
            count += 1;
        }
        (t0, f0) = (t1, f1);
    }
    if count == 0 && nearest.0.is_finite() {
        found[0] = nearest.1;
        count = 1;
    }
    let found = &mut found[..count];
    found.sort_by(|a, b| a.abs().total_cmp(&b.abs()));
    let mut roots = [f64::NAN; 2];
    for (r, &t) in roots.iter_mut().zip(found.iter()) {
        *r = t;
    }
    roots
}

/// The root of `f` between `a` and `b` (`f` of opposite signs there): regula falsi with
/// the Illinois halving, to 1e-10 or 24 steps.
fn illinois(
    f: impl Fn(f64) -> f64,
    (mut a, mut fa): (f64, f64),
    (mut b, mut fb): (f64, f64),
) -> f64 {
    for _ in 0..24 {
        let c = b - fb * (b - a) / (fb - fa);
        let fc = f(c);
        if !fc.is_finite() {
            break;
        }
        if fc * fb < 0.0 {
            (a, fa) = (b, fb);
        } else {
            fa *= 0.5;
        }
        (b, fb) = (c, fc);
        if fb == 0.0 || (b - a).abs() < 1e-10 {
            break;
        }
    }
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lights that change across the frame, as point strips do: strip `k` at position
    /// `(x, y)`.
    fn light(k: usize, x: f32, y: f32) -> [f64; 2] {
        let (x, y) = (f64::from(x), f64::from(y));
        match k {
            0 => [-(0.9 + 0.8 * x), 0.3 * (y - 0.5)],
            1 => [1.6 - 0.7 * x, -0.2 * (y - 0.5)],
            2 => [0.25 * (x - 0.5), -(1.0 + 0.6 * y)],
            _ => [-0.3 * (x - 0.5), 1.5 - 0.5 * y],
        }
    }

    /// A matte skin's colours: `(1 − a·p − b·q) / |n|`, 0 where shadowed.
    fn colours(p: f64, q: f64, x: f32, y: f32) -> [f32; 4] {
        let norm = (1.0 + p * p + q * q).sqrt();
        [0, 1, 2, 3].map(|k| {
            let [a, b] = light(k, x, y);
            ((1.0 - a * p - b * q) / norm).max(0.0) as f32
        })
    }

    /// A skin: the four colours of slopes `p`, `q` at `(x, y)`.
    type Skin = dyn Fn(f64, f64, f32, f32) -> [f32; 4];

    /// A rough coating's colours (Minnaert's law with exponent `k`, the camera
    /// overhead): `(1 − a·p − b·q)^k / |n|^(2k − 1)`, 0 where shadowed.
    fn rough_colours(k: f64) -> impl Fn(f64, f64, f32, f32) -> [f32; 4] {
        move |p, q, x, y| {
            let norm = (1.0 + p * p + q * q).sqrt();
            [0, 1, 2, 3].map(|s| {
                let [a, b] = light(s, x, y);
                ((1.0 - a * p - b * q).max(0.0).powf(k) / norm.powf(2.0 * k - 1.0)) as f32
            })
        }
    }

    /// A matte skin seen by a camera with display gamma `g`: the matte colours to `1/g`.
    fn gamma_colours(g: f64) -> impl Fn(f64, f64, f32, f32) -> [f32; 4] {
        move |p, q, x, y| colours(p, q, x, y).map(|c| c.powf((1.0 / g) as f32))
    }

    /// Slopes of a ball's cap (as calibration sees them), up to `max` in magnitude, and
    /// flat skin, all over the frame.
    fn samples(max: f64) -> Vec<JointSample> {
        samples_of(max, colours)
    }

    /// [`samples`] with the colours of another skin.
    fn samples_of(max: f64, colours: impl Fn(f64, f64, f32, f32) -> [f32; 4]) -> Vec<JointSample> {
        let mut out = Vec::new();
        for i in 0..40 {
            for j in 0..30 {
                let (x, y) = ((i as f32 + 0.5) / 40.0, (j as f32 + 0.5) / 30.0);
                for r in 0..8 {
                    let angle = (i * 7 + j * 3 + r) as f64 * 0.7;
                    let m = max * f64::from(r) / 7.0;
                    let (p, q) = (m * angle.cos(), m * angle.sin());
                    out.push(JointSample {
                        colours: colours(p, q, x, y),
                        position: [x, y],
                        slope: [p as f32, q as f32],
                    });
                }
            }
        }
        out
    }

    /// Walls of 0.2–1.6 all round four places: `(x, y, p, q)`.
    fn walls() -> impl Iterator<Item = (f32, f32, f64, f64)> {
        [(0.3f32, 0.4f32), (0.5, 0.5), (0.81, 0.25), (0.12, 0.9)]
            .into_iter()
            .flat_map(|(x, y)| {
                (0..24).flat_map(move |k| {
                    let angle = k as f64 * std::f64::consts::TAU / 24.0;
                    [0.2, 0.7, 1.1, 1.6].map(|m| (x, y, m * angle.cos(), m * angle.sin()))
                })
            })
    }

    #[test]
    fn reads_a_matte_skin_past_the_slopes_it_was_fitted_on() {
        let model = PhotometricModel::fit(&samples(0.9), 8, 6);
        // Fitted on slopes up to 0.54 (0.6 of 0.9); read up to 1.6, with strips shadowed.
        let mut worst = 0.0f64;
        let mut shadowed_cases = [0usize; 5];
        for (x, y, p, q) in walls() {
            let c = colours(p, q, x, y);
            shadowed_cases[c.iter().filter(|&&v| v < SHADOWED).count()] += 1;
            if c.iter().filter(|&&v| v >= SHADOWED).count() >= 2 {
                let [rp, rq] = model.read(c, x, y).expect("two strips lit");
                let e = (f64::from(rp) - p).hypot(f64::from(rq) - q);
                worst = worst.max(e);
            }
        }
        // Lights vary bilinearly between cells only approximately: small error.
        assert!(worst < 0.05, "worst slope error {worst}");
        // The test reached one and two shadowed strips.
        assert!(
            shadowed_cases[1] > 0 && shadowed_cases[2] > 0,
            "{shadowed_cases:?}"
        );
    }

    /// The worst slope error of `model` over [`walls`], on the skin `colours` makes
    /// (pixels with fewer than two lit strips skipped), and how many of those it left
    /// unread.
    fn worst_reading(
        model: &PhotometricModel,
        colours: &impl Fn(f64, f64, f32, f32) -> [f32; 4],
    ) -> (f64, usize) {
        let (mut worst, mut unread) = (0.0f64, 0);
        for (x, y, p, q) in walls() {
            let c = colours(p, q, x, y);
            if c.iter().filter(|&&v| v >= SHADOWED).count() < 2 {
                continue;
            }
            match model.read(c, x, y) {
                Some([rp, rq]) => {
                    worst = worst.max((f64::from(rp) - p).hypot(f64::from(rq) - q));
                }
                None => unread += 1,
            }
        }
        (worst, unread)
    }

    #[test]
    fn a_matte_skin_keeps_the_matte_response() {
        let model = PhotometricModel::fit(&samples(0.9), 8, 6);
        assert_eq!(model.response(), Response::MATTE);
        // Left out of the file, and a file without it reads matte.
        let json = serde_json::to_string(&model).unwrap();
        assert!(!json.contains("power"), "{json}");
        let back: PhotometricModel = serde_json::from_str(&json).unwrap();
        assert_eq!(back, model);
    }

    #[test]
    fn a_rough_skin_and_a_gamma_camera_are_fitted_and_read_past_the_fit() {
        // (skin, its true P and e): Minnaert k = 0.7 has P = 1/k, e = 2 − 1/k.
        let cases: [(Box<Skin>, f64, f64); 2] = [
            (Box::new(rough_colours(0.7)), 1.0 / 0.7, 2.0 - 1.0 / 0.7),
            (Box::new(gamma_colours(2.2)), 2.2, 1.0),
        ];
        for (skin, colour, norm) in cases {
            let set = samples_of(0.9, &skin);
            let model = PhotometricModel::fit(&set, 8, 6);
            let r = model.response();
            assert!(
                (r.colour - colour).abs() <= 0.06 && (r.norm - norm).abs() <= 0.06,
                "fitted {r:?}, true P {colour}, e {norm}"
            );
            let (worst, unread) = worst_reading(&model, &skin);
            assert!(
                worst < 0.08 && unread == 0,
                "worst {worst}, unread {unread}"
            );
            // The matte model on the same presses reads that skin far worse: the response
            // is what reads it.
            let gentle: Vec<Prepared> = {
                let usable: Vec<&JointSample> = set.iter().collect();
                let limit = FIT_SHARE * steepest(&usable);
                usable
                    .into_iter()
                    .filter(|s| magnitude(s) <= limit)
                    .map(Prepared::of)
                    .collect()
            };
            let matte = PhotometricModel::with_lights(&gentle, Response::MATTE, 8, 6);
            let (matte_worst, matte_unread) = worst_reading(&matte, &skin);
            assert!(
                matte_worst > 3.0 * worst || matte_unread > 0,
                "matte {matte_worst} ({matte_unread} unread) against {worst}"
            );
        }
    }

    #[test]
    fn tabled_curves_are_the_exact_ones() {
        let responses = [
            Response {
                colour: 1.0 / 0.7,
                norm: 2.0 - 1.0 / 0.7,
            },
            Response {
                colour: 2.2,
                norm: 1.0,
            },
            Response {
                colour: 0.6,
                norm: 0.0,
            },
            Response {
                colour: 2.8,
                norm: 1.6,
            },
        ];
        for r in responses {
            let (tabled, exact) = (Curves::tabled(r), Curves::exact(r));
            let mut worst = 0.0f64;
            for i in 0..=5000 {
                let c = i as f64 * 0.001;
                let norm_sq = 1.0 + i as f64 * 0.004;
                for (t, e) in [
                    (tabled.linear(c), exact.linear(c)),
                    (tabled.norm_factor(norm_sq), exact.norm_factor(norm_sq)),
                    (tabled.predict(c, norm_sq), exact.predict(c, norm_sq)),
                    (tabled.predict(c, 1.0), exact.predict(c, 1.0)),
                ] {
                    worst = worst.max((t - e).abs());
                }
            }
            assert!(worst <= 2e-5, "{r:?}: {worst}");
            // NaN stays NaN.
            assert!(tabled.linear(f64::NAN).is_nan());
        }
        // Matte curves are exact: the matte model reads bit for bit as before.
        let matte = Curves::tabled(Response::MATTE);
        for c in [0.0, 0.1234, 1.0, 2.5, 7.0] {
            assert_eq!(matte.linear(c), c);
            assert_eq!(matte.predict(c, 1.7), (c / 1.7f64.sqrt()).max(0.0));
        }
        // And a model reads with its tables as it does exactly.
        let skin = rough_colours(0.7);
        let model = PhotometricModel::fit(&samples_of(0.9, &skin), 8, 6);
        let curves = model.curves();
        for (p, q) in [(0.3, -0.2), (1.2, 0.4), (-1.3, -1.1), (0.0, 1.5)] {
            let c = skin(p, q, 0.4, 0.6);
            let (t, e) = (
                model.read_with(&curves, c, 0.4, 0.6).unwrap(),
                model.read(c, 0.4, 0.6).unwrap(),
            );
            assert!(
                (t[0] - e[0]).abs() < 1e-3 && (t[1] - e[1]).abs() < 1e-3,
                "({p}, {q}): {t:?} against {e:?}"
            );
        }
    }

    #[test]
    fn the_roots_are_bracketed_or_the_nearest_approach_is_taken() {
        let [a, b] = bracketed_roots(4.5, |t| t * t - 1.0);
        assert!((a.abs() - 1.0).abs() < 1e-9 && (b.abs() - 1.0).abs() < 1e-9);
        assert!(a * b < 0.0, "{a}, {b}");
        // One root, off the scan's points.
        let [a, b] = bracketed_roots(4.5, |t| 2.0 * t - 0.123);
        assert!((a - 0.0615).abs() < 1e-9 && b.is_nan(), "{a}, {b}");
        // No root: the nearest approach (the scan's point nearest the minimum at 0.3).
        let [a, b] = bracketed_roots(4.5, |t| (t - 0.3).powi(2) + 0.5);
        assert!((a - 0.3).abs() <= 0.15 && b.is_nan(), "{a}, {b}");
        // NaN everywhere: nothing.
        assert!(
            bracketed_roots(4.5, |_| f64::NAN)
                .iter()
                .all(|t| t.is_nan())
        );
    }

    #[test]
    fn the_fitted_lights_are_the_true_ones() {
        let model = PhotometricModel::fit(&samples(0.9), 8, 6);
        for &(x, y) in &[(0.3f32, 0.4f32), (0.7, 0.6)] {
            let lights = model.lights_at(x, y).unwrap();
            for (k, l) in lights.iter().enumerate() {
                let t = light(k, x, y);
                assert!(
                    (l[0] - t[0]).abs() < 0.03 && (l[1] - t[1]).abs() < 0.03,
                    "strip {k} at ({x}, {y}): {l:?} vs {t:?}"
                );
            }
        }
    }

    #[test]
    fn two_lit_strips_read_a_diagonal_wall() {
        // A matte skin (the quadratic) and a rough one (the bracketed roots), each read
        // with the response fitted to it.
        let cases: [(Box<Skin>, f64); 2] = [
            (Box::new(colours), 0.05),
            (Box::new(rough_colours(0.7)), 0.06),
        ];
        for (skin, tolerance) in cases {
            let model = PhotometricModel::fit(&samples_of(0.9, &skin), 8, 6);
            let (x, y) = (0.5, 0.5);
            // Steep towards both blue strips: the red ones are shadowed.
            let (p, q) = (-1.3, -1.1);
            let c = skin(p, q, x, y);
            assert_eq!(c.iter().filter(|&&v| v >= SHADOWED).count(), 2, "{c:?}");
            let [rp, rq] = model.read(c, x, y).expect("two strips lit");
            assert!(
                (f64::from(rp) - p).abs() < tolerance && (f64::from(rq) - q).abs() < tolerance,
                "{:?}: ({rp}, {rq})",
                model.response()
            );
        }
    }

    #[test]
    fn unmeasured_and_inconsistent_colours_are_left_unread_not_guessed() {
        let model = PhotometricModel::fit(&samples(0.9), 4, 3);
        // One strip lit, none, a rejected phase, infinities: nothing is read.
        for c in [
            [1.0, 0.0, 0.0, 0.0],
            [0.0; 4],
            [f32::NAN; 4],
            [f32::NAN, f32::NAN, 1.0, 1.2],
            [f32::INFINITY, 1.0, 1.0, 1.0],
        ] {
            assert_eq!(model.read(c, 0.5, 0.5), None, "{c:?}");
        }
        // Colours no slope makes: both x strips far brighter than flat skin (a light
        // that is not the strips'), the y strips as flat skin.
        assert_eq!(model.read([2.5, 2.5, 1.0, 1.0], 0.5, 0.5), None);
        // Flat skin reads flat, wherever it is.
        for (x, y) in [(0.0, 0.0), (1.0, 1.0), (0.5, 0.2)] {
            let [p, q] = model.read([1.0; 4], x, y).expect("flat skin");
            assert!(p.abs() < 0.02 && q.abs() < 0.02, "({x}, {y}): ({p}, {q})");
        }
        // Colours of one brightness but not flat skin's (a dimmer light all round): no
        // slope makes them with the |n| the solve needs.
        assert_eq!(model.read([0.6; 4], 0.5, 0.5), None);
        // A slope past the bound, from colours that measure it, reads as the bound: it
        // is judged as found (clamped first, it would not explain its colours).
        let c = colours(-10.0, -2.0, 0.5, 0.5);
        assert_eq!(c.iter().filter(|&&v| v >= SHADOWED).count(), 2, "{c:?}");
        let [p, q] = model.read(c, 0.5, 0.5).expect("two strips lit");
        assert!(
            p == -MAX_SLOPE as f32 && (q + 2.0).abs() < 0.1,
            "({p}, {q})"
        );
        // Two lit strips of one phase (the other phase dark) are no wall: not solved.
        let lights = model.lights_at(0.5, 0.5).unwrap();
        assert_eq!(
            two(
                [1.2, 0.9, 0.0, 0.0],
                &lights,
                [0, 1],
                &Curves::exact(Response::MATTE)
            ),
            None
        );
        // A damaged model (too few entries) and a fit without samples read nothing.
        let damaged = PhotometricModel {
            cells_x: 4,
            cells_y: 3,
            lights: vec![[[1.0, 0.0]; 4]; 2],
            colour_power: 1.0,
            norm_power: 1.0,
        };
        assert_eq!(damaged.read([1.2, 0.8, 1.0, 1.0], 0.5, 0.5), None);
        let empty = PhotometricModel::fit(&[], 0, 0);
        assert_eq!(
            (empty.cells_x, empty.cells_y, empty.lights.len()),
            (1, 1, 1)
        );
        assert_eq!(empty.read([1.2, 0.8, 1.0, 1.0], 0.5, 0.5), None);
    }
}
