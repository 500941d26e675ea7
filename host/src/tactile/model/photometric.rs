//! Four-light photometric stereo: the slope along both axes from all four strips' colours
//! at once, with each strip's light direction fitted per cell of the frame.
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
//! Reading a pixel inverts the lines, which is what carries it past the calibration's
//! slopes:
//! - three or four lit strips (colour at least [`SHADOWED`]): `|n|` is treated as a third
//!   unknown `m`, and `c_k·m + a_k·p + b_k·q = 1` is linear: least squares (exact for
//!   three);
//! - two lit strips (steep walls shadow one strip of each phase): their ratio gives a
//!   line of slopes, and `c·|n| = 1 − a·p − b·q` a quadratic along it; of its roots the
//!   one that keeps the lit strips lit and the shadowed ones dark is taken;
//! - fewer, or two of one phase (the other phase dark is no wall): the slope is not
//!   measured (`None`: the pixel is filled from its neighbours).
//!
//! A reading must explain the colours it came from: every lit strip near the colour it
//! predicts, every shadowed strip predicted dark, and with three or four lit strips the
//! third unknown `m` near the slopes' own `|n|`; otherwise the pixel is left unread.
//!
//! Numbers: fitted and inverted in f64; a NaN colour (a phase the colour filter
//! rejected) leaves the pixel unread, as do slopes that do not explain the colours; slopes are bounded to ±[`MAX_SLOPE`]; a cell without
//! enough samples takes the whole frame's pair.

use serde::{Deserialize, Serialize};

use super::cells::cell_weights;
use super::light::SHADOWED;

/// The light directions are fitted on slopes up to this share of the calibration's
/// steepest (95th percentile of |slope|), as the light model's responses are.
const FIT_SHARE: f64 = 0.6;

/// A cell whose slope weight is below this share of the mean cell's takes the whole
/// frame's pair.
const MIN_CELL_SHARE: f64 = 0.05;

/// Bound on a read slope (the integration's bound is 3 as well).
pub const MAX_SLOPE: f64 = 3.0;

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

/// Each strip's light direction per cell.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhotometricModel {
    /// Cells across.
    pub cells_x: usize,
    /// Cells down.
    pub cells_y: usize,
    /// `cells_y × cells_x` entries, each `[a, b]` of the strips `[red dx, blue dx, red
    /// dy, blue dy]`: `colour·|n| = 1 − a·p − b·q`.
    pub lights: Vec<[[f32; 2]; 4]>,
}

impl PhotometricModel {
    /// Fits the lights of `cells_x × cells_y` cells to `samples`.
    pub fn fit(samples: &[JointSample], cells_x: usize, cells_y: usize) -> Self {
        let (cells_x, cells_y) = (cells_x.max(1), cells_y.max(1));
        let usable: Vec<&JointSample> = samples
            .iter()
            .filter(|s| s.slope.iter().chain(&s.position).all(|v| v.is_finite()))
            .collect();
        let limit = fit_limit(&usable);
        // Per cell and strip: Σ w·[p², p·q, q², p·y, q·y] with y = 1 − c·|n| = a·p + b·q.
        let cells = cells_x * cells_y;
        let mut sums = vec![[[0.0f64; 5]; 4]; cells];
        let mut all = [[0.0f64; 5]; 4];
        for s in usable.iter().filter(|s| magnitude(s) <= limit) {
            let (p, q) = (f64::from(s.slope[0]), f64::from(s.slope[1]));
            let norm = (1.0 + p * p + q * q).sqrt();
            let weights = cell_weights(s.position[0], s.position[1], cells_x, cells_y);
            for (k, &c) in s.colours.iter().enumerate() {
                if !lit(c) {
                    continue;
                }
                let y = 1.0 - f64::from(c) * norm;
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
        let lights = self.lights_at(x, y)?;
        invert(colours, &lights).map(|s| s.map(|v| v as f32))
    }
}

/// The slope magnitude of a sample.
fn magnitude(s: &JointSample) -> f64 {
    f64::from(s.slope[0]).hypot(f64::from(s.slope[1]))
}

/// The steepest slope the lights are fitted on: [`FIT_SHARE`] of the 95th percentile of
/// the usable samples' slope magnitudes (0 without any).
fn fit_limit(samples: &[&JointSample]) -> f64 {
    let mut magnitudes: Vec<f64> = samples.iter().copied().map(magnitude).collect();
    match magnitudes.len() {
        0 => 0.0,
        n => {
            let k = (n - 1) * 95 / 100;
            FIT_SHARE * *magnitudes.select_nth_unstable_by(k, f64::total_cmp).1
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

/// Slopes from colours and lights (see the module documentation); `None` when a phase
/// was rejected (NaN), fewer than two strips are lit (or two of one phase), nothing
/// solves (with three or four lit, no `m` near `|n|`), or the slopes found do not explain
/// the colours (see [`explains`]).
fn invert(colours: [f32; 4], lights: &[[f64; 2]; 4]) -> Option<[f64; 2]> {
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
        3 | 4 => three_or_more(colours, lights, &lit_strips[..count]),
        2 => two(colours, lights, [lit_strips[0], lit_strips[1]]),
        _ => None,
    }?;
    // Judged as found, then bounded: a clamped slope would not explain the colours it
    // came from, and an unclamped wild one must not pass as the bound.
    (slopes.iter().all(|v| v.is_finite()) && explains(colours, lights, slopes))
        .then(|| slopes.map(|v| v.clamp(-MAX_SLOPE, MAX_SLOPE)))
}

/// Whether slopes `[p, q]` explain the colours: every lit strip within [`TOLERANCE`] of
/// the colour the lights predict, and no strip that reads shadowed predicted brighter
/// than [`SHADOWED`] by more than [`SHADOW_TOLERANCE`].
fn explains(colours: [f32; 4], lights: &[[f64; 2]; 4], [p, q]: [f64; 2]) -> bool {
    let norm = (1.0 + p * p + q * q).sqrt();
    colours.iter().zip(lights).all(|(&c, l)| {
        let predicted = ((1.0 - l[0] * p - l[1] * q) / norm).max(0.0);
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

/// Least squares of `c_k·m + a_k·p + b_k·q = 1` over the lit strips, for `(m, p, q)`.
#[allow(clippy::needless_range_loop)] // rows and columns of a matrix
fn three_or_more(colours: [f32; 4], lights: &[[f64; 2]; 4], lit: &[usize]) -> Option<[f64; 2]> {
    let mut ata = [[0.0f64; 3]; 3];
    let mut atb = [0.0f64; 3];
    for &k in lit {
        let row = [f64::from(colours[k]), lights[k][0], lights[k][1]];
        for i in 0..3 {
            for j in 0..3 {
                ata[i][j] += row[i] * row[j];
            }
            atb[i] += row[i];
        }
    }
    let [m, p, q] = solve3(ata, atb)?;
    // m stands for |n| = √(1 + p² + q²): colours that need another one (a light that is
    // not the strips', a colour the model does not make) are not read.
    let norm = (1.0 + p * p + q * q).sqrt();
    ((m / norm - 1.0).abs() <= NORM_TOLERANCE).then_some([p, q])
}

/// How far (relative) the third unknown of [`three_or_more`] may be from the `|n|` of
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

/// Two lit strips `i`, `j`: on the line their ratio allows, the slope whose `|n|` makes
/// strip `i`'s colour; of the quadratic's roots, the one that keeps both lit and the
/// other strips darkest where they are shadowed (a score that adds 0.01 of the slope's
/// size, so between equals the gentler one).
fn two(colours: [f32; 4], lights: &[[f64; 2]; 4], [i, j]: [usize; 2]) -> Option<[f64; 2]> {
    // Strips 0, 1 light the dx phase, 2, 3 the dy phase. Both strips of one phase dark is
    // no wall (a wall shadows the strip it turns from), and the two of the other barely
    // answer the slope along it.
    if i / 2 == j / 2 {
        return None;
    }
    let (c1, c2) = (f64::from(colours[i]), f64::from(colours[j]));
    let ([a1, b1], [a2, b2]) = (lights[i], lights[j]);
    // c1·(1 − a2·p − b2·q) = c2·(1 − a1·p − b1·q): u·p + v·q = r.
    let (u, v, r) = (c1 * a2 - c2 * a1, c1 * b2 - c2 * b1, c1 - c2);
    let len = u.hypot(v);
    if len.is_nan() || len <= 1e-9 {
        return None;
    }
    // The line's point nearest flat, and its direction.
    let (p0, q0) = (u * r / (len * len), v * r / (len * len));
    let (dp, dq) = (-v / len, u / len);
    // c1²·(1 + |s₀ + t·d|²) = (e0 + e1·t)², with e = 1 − a1·p − b1·q along the line.
    let (e0, e1) = (1.0 - a1 * p0 - b1 * q0, -(a1 * dp + b1 * dq));
    let k = c1 * c1;
    let qa = k - e1 * e1;
    let qb = 2.0 * (k * (p0 * dp + q0 * dq) - e0 * e1);
    let qc = k * (1.0 + p0 * p0 + q0 * q0) - e0 * e0;
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
    let mut best: Option<(f64, [f64; 2])> = None;
    for t in roots.into_iter().filter(|t| t.is_finite()) {
        let (p, q) = (p0 + t * dp, q0 + t * dq);
        if 1.0 - a1 * p - b1 * q <= 0.0 {
            continue;
        }
        let norm = (1.0 + p * p + q * q).sqrt();
        // How much brighter the model says the unlit strips would be than they are.
        let too_bright: f64 = (0..4)
            .filter(|&k| k != i && k != j && colours[k].is_finite())
            .map(|k| {
                let predicted = (1.0 - lights[k][0] * p - lights[k][1] * q) / norm;
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

    /// Slopes of a ball's cap (as calibration sees them), up to `max` in magnitude, and
    /// flat skin, all over the frame.
    fn samples(max: f64) -> Vec<JointSample> {
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

    #[test]
    fn reads_a_matte_skin_past_the_slopes_it_was_fitted_on() {
        let model = PhotometricModel::fit(&samples(0.9), 8, 6);
        // Fitted on slopes up to 0.54 (0.6 of 0.9); read up to 1.6, with strips shadowed.
        let mut worst = 0.0f64;
        let mut shadowed_cases = [0usize; 5];
        for &(x, y) in &[(0.3f32, 0.4f32), (0.5, 0.5), (0.81, 0.25), (0.12, 0.9)] {
            for k in 0..24 {
                let angle = k as f64 * std::f64::consts::TAU / 24.0;
                for m in [0.2, 0.7, 1.1, 1.6] {
                    let (p, q) = (m * angle.cos(), m * angle.sin());
                    let c = colours(p, q, x, y);
                    shadowed_cases[c.iter().filter(|&&v| v < SHADOWED).count()] += 1;
                    if c.iter().filter(|&&v| v >= SHADOWED).count() >= 2 {
                        let [rp, rq] = model.read(c, x, y).expect("two strips lit");
                        let e = (f64::from(rp) - p).hypot(f64::from(rq) - q);
                        worst = worst.max(e);
                    }
                }
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
        let model = PhotometricModel::fit(&samples(0.9), 8, 6);
        let (x, y) = (0.5, 0.5);
        // Steep towards both blue strips: the red ones are shadowed.
        let (p, q) = (-1.3, -1.1);
        let c = colours(p, q, x, y);
        assert_eq!(c.iter().filter(|&&v| v >= SHADOWED).count(), 2, "{c:?}");
        let [rp, rq] = model.read(c, x, y).expect("two strips lit");
        assert!(
            (f64::from(rp) - p).abs() < 0.05 && (f64::from(rq) - q).abs() < 0.05,
            "({rp}, {rq})"
        );
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
        assert_eq!(two([1.2, 0.9, 0.0, 0.0], &lights, [0, 1]), None);
        // A damaged model (too few entries) and a fit without samples read nothing.
        let damaged = PhotometricModel {
            cells_x: 4,
            cells_y: 3,
            lights: vec![[[1.0, 0.0]; 4]; 2],
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
