//! Light-response model: each strip's normalised colour as a straight line in the
//! slope, fitted per cell of the frame, and inverted. The one model that extrapolates
//! past the steepest slope the calibration ball made.
//!
//! For a matte skin lit from elevation `e`, a phase's cross-normalised colours (see
//! [`super::colour_features`]) are `1 + a·p` for the strip the slope faces and `1 − a'·p`
//! for the other, `a = cot e`, until the other strip is shadowed (its colour reaches 0).
//! So per cell (the elevation changes across the frame) each colour's response `a` is
//! fitted by least squares through flat skin (`colour = 1` at slope 0),  on the gentler
//! part of the calibration's slopes: the steepest ones sit at a press's rim, where the
//! skin and the camera blur the edge and the colour no longer follows the sphere.
//! Reading a pixel inverts the lines: the least-squares slope of both colours, or of the
//! lit one alone where the other is shadowed (below [`SHADOWED`]), which is what carries
//! it past the calibration's slopes. Where the physics is not a matte skin (gloss,
//! gamma, inverse-square fall-off) the lines are a first-order fit, measured against
//! the lookup table and the perceptron by `bench skins --model light`.

use serde::{Deserialize, Serialize};

use super::Sample;
use super::cells::{cell_weights, locate};

/// A colour below this (normalised, flat skin = 1) is a shadowed strip: it bounds the
/// slope but does not measure it.
pub const SHADOWED: f32 = 0.15;

/// The responses are fitted on slopes up to this share of the calibration's steepest
/// (its 95th percentile of |slope|).
const FIT_SHARE: f32 = 0.6;

/// A cell whose colour-times-slope weight is below this share of the mean cell's takes
/// the whole frame's response.
const MIN_CELL_SHARE: f64 = 0.05;

/// Colour responses per cell.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightModel {
    /// Cells across.
    pub cells_x: usize,
    /// Cells down.
    pub cells_y: usize,
    /// `cells_y × cells_x` pairs `[red, blue]`: colour change per unit slope.
    pub response: Vec<[f32; 2]>,
}

impl LightModel {
    /// Fits the responses of `cells_x × cells_y` cells to `samples` (slope and
    /// features `[r, b, x, y]`).
    pub fn fit(samples: &[Sample], cells_x: usize, cells_y: usize) -> Self {
        let (cells_x, cells_y) = (cells_x.max(1), cells_y.max(1));
        let usable: Vec<&Sample> = samples
            .iter()
            .filter(|s| s.target.is_finite() && s.features.iter().all(|f| f.is_finite()))
            .collect();
        let mut magnitudes: Vec<f32> = usable.iter().map(|s| s.target.abs()).collect();
        let limit = match magnitudes.len() {
            0 => 0.0,
            n => {
                let k = (n - 1) * 95 / 100;
                FIT_SHARE * *magnitudes.select_nth_unstable_by(k, f32::total_cmp).1
            }
        };
        let fit_set: Vec<&Sample> = usable
            .into_iter()
            .filter(|s| s.target.abs() <= limit)
            .collect();
        let mut response = vec![[0.0f32; 2]; cells_x * cells_y];
        for c in 0..2 {
            for (r, a) in response
                .iter_mut()
                .zip(fit_colour(&fit_set, c, cells_x, cells_y))
            {
                r[c] = a;
            }
        }
        Self {
            cells_x,
            cells_y,
            response,
        }
    }

    /// Slope for normalised colour `(r, b)` at normalised position `(x, y)` ∈ [0, 1]²;
    /// 0 where neither colour measures it (both shadowed or not numbers) or the model's
    /// cells do not match its size (a damaged file).
    pub fn eval(&self, r: f32, b: f32, x: f32, y: f32) -> f32 {
        self.response_at(x, y).map_or(0.0, |a| invert([r, b], a))
    }

    /// The responses at `(x, y)`, bilinear between cell centres; `None` when the cells do
    /// not match the model's size (a damaged file).
    fn response_at(&self, x: f32, y: f32) -> Option<[f32; 2]> {
        let (cells_x, cells_y) = (self.cells_x.max(1), self.cells_y.max(1));
        if self.response.len() < cells_x * cells_y {
            return None;
        }
        let mut a = [0.0f32; 2];
        for (cell, w) in cell_weights(x, y, cells_x, cells_y) {
            for (a, r) in a.iter_mut().zip(self.response[cell]) {
                *a += w * r;
            }
        }
        Some(a)
    }

    /// [`Self::eval`] over feature rows `[r, b, x, y]`.
    ///
    /// Rows come a region row at a time: the responses blended down the frame are
    /// computed once per row position `y`, leaving one blend across per pixel.
    pub fn eval_batch(&self, features: &[[f32; 4]], out: &mut [f32]) {
        let Some(mut responses) = Responses::new(self) else {
            out.iter_mut().for_each(|o| *o = 0.0);
            return;
        };
        for (f, o) in features.iter().zip(out.iter_mut()) {
            *o = invert([f[0], f[1]], responses.at(f[2], f[3]));
        }
    }
}

/// The responses per cell of colour `c`: the line through flat skin (`colour − 1 = a·p`)
/// by weighted least squares, the whole frame's where a cell has too few samples.
fn fit_colour(samples: &[&Sample], c: usize, cells_x: usize, cells_y: usize) -> Vec<f32> {
    let cells = cells_x * cells_y;
    // Σ w·p·(colour − 1) and Σ w·p² per cell, and over the whole frame.
    let mut sums = vec![[0.0f64; 2]; cells];
    let mut all = [0.0f64; 2];
    for s in samples {
        let colour = s.features[c];
        if colour < SHADOWED {
            continue;
        }
        let p = f64::from(s.target);
        let terms = [p * (f64::from(colour) - 1.0), p * p];
        for (a, t) in all.iter_mut().zip(terms) {
            *a += t;
        }
        for (cell, w) in cell_weights(s.features[2], s.features[3], cells_x, cells_y) {
            for (a, t) in sums[cell].iter_mut().zip(terms) {
                *a += f64::from(w) * t;
            }
        }
    }
    let line = |[py, pp]: [f64; 2]| {
        let a = py / pp;
        (pp > 0.0 && a.is_finite()).then_some(a as f32)
    };
    let whole = line(all).unwrap_or(0.0);
    sums.iter()
        .map(|&cell| {
            (cell[1] > MIN_CELL_SHARE * all[1] / cells as f64)
                .then(|| line(cell))
                .flatten()
                .unwrap_or(whole)
        })
        .collect()
}

/// Rounds of [`read_pair`]'s fixed-point iteration, at most.
const PAIR_ROUNDS: usize = 4;
/// A round that moves neither slope by more than this ends the iteration.
const SETTLED: f32 = 1e-3;

/// Both slopes `[p, q]` of a pixel seen in both phases: features `[r, b]` of the dx
/// phase (`fx`) and the dy phase (`fy`) at normalised position `(x, y)`.
///
/// Each phase's features were divided by the other phase's brightness
/// ([`super::cross_factor`]), which is `2 / |n|` for a matte skin only while neither of
/// its strips is shadowed; past that (a wall steep along both axes) the features read
/// shallow. Under the lines, a phase's raw colours are `(1 + a·s)⁺ / |n|`, so the
/// factor the other phase applied is known from the slopes: starting from the
/// per-phase reading, each round undoes the factor the current slopes imply and reads
/// again ([`PAIR_ROUNDS`] rounds; where no strip is shadowed the factor is 1 and nothing
/// changes). Where both phases have a shadowed strip the features hold only the ratio
/// `(1 + a·p) / (1 + a·q)`, not the slopes' size (the factors took out `|n|`): the
/// steeper axis keeps its one-phase reading and the gentler one, which one phase alone
/// reads far too gentle, follows the ratio. A diagonal wall steeper than the light's
/// elevation therefore still reads gentle.
pub fn read_pair(models: [&LightModel; 2], fx: [f32; 2], fy: [f32; 2], x: f32, y: f32) -> [f32; 2] {
    match (models[0].response_at(x, y), models[1].response_at(x, y)) {
        (Some(ax), Some(ay)) => pair_slopes([fx], [fy], [ax], [ay])[0],
        _ => [0.0; 2],
    }
}

/// Pixels whose fixed-point rounds run side by side ([`PairReader::queue`],
/// [`read_rows`]): each round is a chain of divisions and a square root, whose latency
/// one pixel at a time leaves the CPU idle (about 130 ns a pixel; independent pixels
/// overlap in vector lanes). Sixteen fill two AVX2 vectors of eight, whose divisions and
/// square roots then overlap too (about 23 ns a pixel with the responses' lookup; eight
/// took 35).
pub const LANES: usize = 16;

/// A pixel waiting in [`PairReader`]'s queue: its caller's key, its features and the
/// responses at its position.
#[derive(Debug, Clone, Copy, Default)]
struct Queued {
    key: usize,
    features: [[f32; 2]; 2],
    responses: [[f32; 2]; 2],
}

/// [`read_pair`] for pixels of one frame row after another: each model's responses are
/// blended down the frame once per row position `y` (as [`read_rows`] does). Pixels are
/// read one at a time ([`Self::read`]) or queued and read [`LANES`] at a time
/// ([`Self::queue`], then [`Self::flush`]); both read the same slopes, bit for bit.
pub struct PairReader<'a> {
    at: [Responses<'a>; 2],
    queued: [Queued; LANES],
    len: usize,
}

impl<'a> PairReader<'a> {
    /// `None` for a damaged model (fewer responses than cells), which reads 0.
    pub fn new(models: [&'a LightModel; 2]) -> Option<Self> {
        Some(Self {
            at: [Responses::new(models[0])?, Responses::new(models[1])?],
            queued: [Queued::default(); LANES],
            len: 0,
        })
    }

    /// [`read_pair`] of the pixel at `(x, y)`.
    #[inline]
    pub fn read(&mut self, fx: [f32; 2], fy: [f32; 2], x: f32, y: f32) -> [f32; 2] {
        let [at_x, at_y] = &mut self.at;
        pair_slopes([fx], [fy], [at_x.at(x, y)], [at_y.at(x, y)])[0]
    }

    /// The slope along `axis` (0: x, 1: y) of a pixel only that phase saw: its features
    /// `f` read by that phase's model alone.
    #[inline]
    pub fn read_one(&mut self, axis: usize, f: [f32; 2], x: f32, y: f32) -> f32 {
        invert(f, self.at[axis & 1].at(x, y))
    }

    /// Queues the pixel at `(x, y)` under `key`; when [`LANES`] are queued they are read
    /// together and `done(key, [p, q])` is called for each, in the order queued. Call
    /// [`Self::flush`] after the last.
    #[inline]
    pub fn queue(
        &mut self,
        key: usize,
        fx: [f32; 2],
        fy: [f32; 2],
        x: f32,
        y: f32,
        done: impl FnMut(usize, [f32; 2]),
    ) {
        let [at_x, at_y] = &mut self.at;
        self.queued[self.len] = Queued {
            key,
            features: [fx, fy],
            responses: [at_x.at(x, y), at_y.at(x, y)],
        };
        self.len += 1;
        if self.len == LANES {
            self.flush(done);
        }
    }

    /// Reads the pixels queued so far (the lanes past them are read and dropped) and
    /// calls `done(key, [p, q])` for each.
    pub fn flush(&mut self, mut done: impl FnMut(usize, [f32; 2])) {
        if self.len == 0 {
            return;
        }
        let q = &self.queued;
        let read = pair_slopes_lanes(q);
        for (e, r) in q[..self.len].iter().zip(read) {
            done(e.key, r);
        }
        self.len = 0;
    }
}

/// [`pair_slopes`] of the [`LANES`] queued pixels, in AVX2 lanes when the CPU has them
/// (8 pixels a vector instead of 4; divisions and square roots are exact in both, so
/// the slopes are the same bit for bit).
#[allow(unsafe_code)]
fn pair_slopes_lanes(queued: &[Queued; LANES]) -> [[f32; 2]; LANES] {
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::avx2() {
        // SAFETY: `pair_slopes_avx2` only needs AVX2, detected just above.
        return unsafe { pair_slopes_avx2(queued) };
    }
    pair_slopes_queued(queued)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn pair_slopes_avx2(queued: &[Queued; LANES]) -> [[f32; 2]; LANES] {
    pair_slopes_queued(queued)
}

#[inline(always)]
fn pair_slopes_queued(q: &[Queued; LANES]) -> [[f32; 2]; LANES] {
    pair_slopes(
        q.map(|e| e.features[0]),
        q.map(|e| e.features[1]),
        q.map(|e| e.responses[0]),
        q.map(|e| e.responses[1]),
    )
}

/// [`read_pair`] of `N` pixels at once with the responses at each given: the same
/// rounds in every lane, each lane's slopes kept from the round its iteration ends (as
/// one pixel alone would end it), so a pixel reads the same whichever lane it is in.
/// Every step runs across the lanes without branches (one array per quantity), so the
/// compiler makes it vector instructions.
#[inline(always)]
fn pair_slopes<const N: usize>(
    fx: [[f32; 2]; N],
    fy: [[f32; 2]; N],
    ax: [[f32; 2]; N],
    ay: [[f32; 2]; N],
) -> [[f32; 2]; N] {
    // Plain loops over fixed-size arrays throughout (no closures building arrays): the
    // shape the compiler turns into one vector instruction per step.
    let column = |v: &[[f32; 2]; N], c: usize| {
        let mut out = [0.0f32; N];
        for l in 0..N {
            out[l] = v[l][c];
        }
        out
    };
    let (fx, fy) = (
        [column(&fx, 0), column(&fx, 1)],
        [column(&fy, 0), column(&fy, 1)],
    );
    let (ax, ay) = (
        [column(&ax, 0), column(&ax, 1)],
        [column(&ay, 0), column(&ay, 1)],
    );
    let mut p = invert_lanes(fx, ax);
    let mut q = invert_lanes(fy, ay);
    let mut open = [true; N];
    for _ in 0..PAIR_ROUNDS {
        let mut norm = [0.0f32; N];
        for l in 0..N {
            norm[l] = (1.0 + p[l] * p[l] + q[l] * q[l]).sqrt();
        }
        // Each phase's features were multiplied by the other phase's factor,
        // `cross_factor(Σ (1 + a·s)⁺ / |n|)`; times `|n| / factor` they are `(1 + a·s)⁺`
        // again. Unbounded, `|n| / factor` is `Σ (1 + a·s)⁺ / 2`.
        let undone = |f: [[f32; N]; 2], a: &[[f32; N]; 2], s: &[f32; N]| {
            let mut out = f;
            for l in 0..N {
                let sum = (1.0 + a[0][l] * s[l]).max(0.0) + (1.0 + a[1][l] * s[l]).max(0.0);
                let u = norm[l] / super::cross_factor(sum / norm[l], 0.0);
                out[0][l] = f[0][l] * u;
                out[1][l] = f[1][l] * u;
            }
            out
        };
        let next_p = invert_lanes(undone(fx, &ay, &q), ax);
        let next_q = invert_lanes(undone(fy, &ax, &p), ay);
        for l in 0..N {
            // A round that goes non-finite ends the iteration with the slopes before it;
            // one that moves neither slope by more than `SETTLED` ends it with its own.
            let finite = next_p[l].is_finite() & next_q[l].is_finite();
            let settled = (next_p[l] - p[l]).abs().max((next_q[l] - q[l]).abs()) < SETTLED;
            let take = open[l] & finite;
            p[l] = if take { next_p[l] } else { p[l] };
            q[l] = if take { next_q[l] } else { q[l] };
            open[l] = take & !settled;
        }
        if !open.contains(&true) {
            break;
        }
    }
    let mut out = [[0.0f32; 2]; N];
    for l in 0..N {
        out[l] = [p[l], q[l]];
    }
    out
}

/// The slopes of a region's pixels from both phases' feature rows (`[r, b, x, y]`, in
/// raster order) and the region index each row's pixel has (`targets`, increasing):
/// a pixel in both phases is read with [`read_pair`], one in a single phase (the colour
/// filter rejected the other) by that phase alone. Slopes go to `slopes` (`[p, q]`
/// grids of the region); other entries are left as they are. A damaged model reads 0.
pub fn read_rows(
    models: [&LightModel; 2],
    rows: [&[[f32; 4]]; 2],
    targets: [&[usize]; 2],
    slopes: [&mut [f32]; 2],
) {
    let Some(mut reader) = PairReader::new(models) else {
        return;
    };
    let [p, q] = slopes;
    let (mut i, mut j) = (0, 0);
    let (nx, ny) = (
        rows[0].len().min(targets[0].len()),
        rows[1].len().min(targets[1].len()),
    );
    while i < nx || j < ny {
        let (kx, ky) = (
            targets[0].get(i).copied().filter(|_| i < nx),
            targets[1].get(j).copied().filter(|_| j < ny),
        );
        match (kx, ky) {
            (Some(a), Some(b)) if a == b => {
                let (fx, fy) = (rows[0][i], rows[1][j]);
                let (x, y) = (fx[2], fx[3]);
                reader.queue(a, [fx[0], fx[1]], [fy[0], fy[1]], x, y, |k, [sp, sq]| {
                    (p[k], q[k]) = (sp, sq);
                });
                i += 1;
                j += 1;
            }
            (Some(a), b) if b.is_none_or(|b| a < b) => {
                let f = rows[0][i];
                p[a] = reader.read_one(0, [f[0], f[1]], f[2], f[3]);
                i += 1;
            }
            (_, Some(b)) => {
                let f = rows[1][j];
                q[b] = reader.read_one(1, [f[0], f[1]], f[2], f[3]);
                j += 1;
            }
            _ => break,
        }
    }
    reader.flush(|k, [sp, sq]| (p[k], q[k]) = (sp, sq));
}

/// A model's responses at successive positions: blended down the frame once per row
/// position `y`, leaving one blend across per pixel.
struct Responses<'a> {
    model: &'a LightModel,
    cells: (usize, usize),
    across: Vec<[f32; 2]>,
    row_y: Option<u32>,
}

impl<'a> Responses<'a> {
    /// `None` for a damaged model (fewer responses than cells).
    fn new(model: &'a LightModel) -> Option<Self> {
        let cells = (model.cells_x.max(1), model.cells_y.max(1));
        (model.response.len() >= cells.0 * cells.1).then(|| Self {
            model,
            cells,
            across: vec![[0.0; 2]; cells.0],
            row_y: None,
        })
    }

    #[inline(always)]
    fn at(&mut self, x: f32, y: f32) -> [f32; 2] {
        let (cells_x, cells_y) = self.cells;
        if self.row_y != Some(y.to_bits()) {
            self.row_y = Some(y.to_bits());
            let (cy, fy) = locate(y * cells_y as f32 - 0.5, cells_y);
            let cyn = (cy + 1).min(cells_y - 1);
            let r = &self.model.response;
            for (i, a) in self.across.iter_mut().enumerate() {
                let (top, bottom) = (r[cy * cells_x + i], r[cyn * cells_x + i]);
                *a = [0, 1].map(|c| top[c] * (1.0 - fy) + bottom[c] * fy);
            }
        }
        let (cx, fx) = locate(x * cells_x as f32 - 0.5, cells_x);
        let (left, right) = (self.across[cx], self.across[(cx + 1).min(cells_x - 1)]);
        [0, 1].map(|c| left[c] * (1.0 - fx) + right[c] * fx)
    }
}

/// The least-squares slope of the colours that are lit (not below [`SHADOWED`], not
/// NaN) given their responses: `Σ a (colour − 1) / Σ a²`; 0 when none measures it.
fn invert(colour: [f32; 2], response: [f32; 2]) -> f32 {
    let (mut num, mut den) = (0.0f32, 0.0f32);
    for (c, a) in colour.into_iter().zip(response) {
        if c >= SHADOWED && c.is_finite() && a.is_finite() {
            num += a * (c - 1.0);
            den += a * a;
        }
    }
    if den > 1e-6 { num / den } else { 0.0 }
}

/// [`invert`] across lanes: `colour[c][l]` and `response[c][l]` are strip `c`'s colour
/// and response in lane `l` (the same sums in the same order: the same results).
#[inline(always)]
fn invert_lanes<const N: usize>(colour: [[f32; N]; 2], response: [[f32; N]; 2]) -> [f32; N] {
    let mut out = [0.0f32; N];
    for l in 0..N {
        let (mut num, mut den) = (0.0f32, 0.0f32);
        for c in 0..2 {
            let (c, a) = (colour[c][l], response[c][l]);
            // Adding 0 where a colour says nothing leaves the sums as skipping it does
            // (they never hold -0: each starts at +0).
            let used = (c >= SHADOWED) & c.is_finite() & a.is_finite();
            num += if used { a * (c - 1.0) } else { 0.0 };
            den += if used { a * a } else { 0.0 };
        }
        let ratio = num / den;
        out[l] = if den > 1e-6 { ratio } else { 0.0 };
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tactile::model::matte_features;

    /// A matte skin whose light elevation changes across the frame: the facing strip's
    /// colour `1 + a·p`, the other's `1 − a'·p`, shadowed at 0.
    fn matte(p: f32, x: f32, y: f32) -> [f32; 2] {
        let (a_red, a_blue) = (1.2 + 0.6 * x, 1.8 - 0.4 * y);
        [(1.0 + a_red * p).max(0.0), (1.0 - a_blue * p).max(0.0)]
    }

    fn samples(max_slope: f32) -> Vec<Sample> {
        let mut out = Vec::new();
        for i in 0..=60 {
            for j in 0..=40 {
                let (x, y) = (i as f32 / 60.0, j as f32 / 40.0);
                for k in -9..=9 {
                    let p = max_slope * k as f32 / 9.0;
                    let [r, b] = matte(p, x, y);
                    out.push(Sample {
                        features: [r, b, x, y],
                        target: p,
                    });
                }
            }
        }
        out
    }

    #[test]
    fn inverts_a_matte_skin_past_the_slopes_it_was_fitted_on() {
        let model = LightModel::fit(&samples(0.9), 6, 4);
        // Inside and well past the calibration's slopes (0.9), where one strip is
        // shadowed, at cell centres and between them.
        for (x, y) in [(0.5, 0.5), (1.0 / 12.0, 0.125), (0.3, 0.8), (0.95, 0.05)] {
            for p in [-1.8f32, -1.31, -0.79, -0.2, 0.0, 0.35, 0.79, 1.31, 1.8] {
                let [r, b] = matte(p, x, y);
                let got = model.eval(r, b, x, y);
                // Bilinear responses between cell centres of a linear trend are exact;
                // at the border the nearest cell's is used.
                assert!(
                    (got - p).abs() < 0.03 * p.abs().max(1.0),
                    "({x}, {y}) p {p}: {got}"
                );
            }
        }
    }

    #[test]
    fn reads_walls_steep_along_both_axes_from_both_phases() {
        let k = 1.6f32;
        // Calibration-like samples: slopes up to 0.9 in any direction.
        let mut sets = [Vec::new(), Vec::new()];
        for i in -18..=18 {
            for j in -18..=18 {
                let (p, q) = (i as f32 * 0.05, j as f32 * 0.05);
                if p.hypot(q) > 0.9 {
                    continue;
                }
                let f = matte_features(p, q, k);
                for (axis, (set, s)) in sets.iter_mut().zip([p, q]).enumerate() {
                    for (x, y) in [(0.2, 0.3), (0.7, 0.6)] {
                        set.push(Sample {
                            features: [f[axis][0], f[axis][1], x, y],
                            target: s,
                        });
                    }
                }
            }
        }
        let [mx, my] = sets.map(|s| LightModel::fit(&s, 2, 2));
        let read = |p: f32, q: f32| {
            let [fx, fy] = matte_features(p, q, k);
            let alone = [
                mx.eval(fx[0], fx[1], 0.5, 0.5),
                my.eval(fy[0], fy[1], 0.5, 0.5),
            ];
            (read_pair([&mx, &my], fx, fy, 0.5, 0.5), alone)
        };
        // Walls past the calibration's slopes where the other phase has both strips lit:
        // right, from either reading.
        for (p, q) in [(1.31f32, 0.0f32), (-1.2, 0.3), (0.3, -0.2), (0.0, -1.5)] {
            let ([gp, gq], _) = read(p, q);
            assert!(
                (gp - p).abs() < 0.03 && (gq - q).abs() < 0.03,
                "({p}, {q}): ({gp}, {gq})"
            );
        }
        // Both phases with a shadowed strip: alone, the gentler axis reads far too gentle
        // (0.28 for 0.7); together it is corrected, within what the features still hold
        // (they keep only the ratio (1 + k·p) / (1 + k·q), not the slopes' size).
        for (p, q) in [(1.2f32, 0.7f32), (-0.6, 1.3), (0.93, 0.93)] {
            let (pair, alone) = read(p, q);
            for (axis, truth) in [p, q].into_iter().enumerate() {
                let (e_pair, e_alone) = ((pair[axis] - truth).abs(), (alone[axis] - truth).abs());
                assert!(
                    e_pair <= e_alone + 1e-4,
                    "({p}, {q}) axis {axis}: {pair:?} vs {alone:?}"
                );
            }
        }
        let ([_, gq], [_, alone_q]) = read(1.2, 0.7);
        assert!(
            (gq - 0.7).abs() < 0.1 && (alone_q - 0.7).abs() > 0.3,
            "{gq} {alone_q}"
        );
        let [fx, _] = matte_features(0.93, 0.93, k);
        // A damaged model: zero, never a panic; no reader either.
        let mut broken = mx.clone();
        broken.response.clear();
        assert_eq!(read_pair([&broken, &my], fx, fx, 0.5, 0.5), [0.0, 0.0]);
        assert!(PairReader::new([&broken, &my]).is_none());
        // Queued (a full batch and a partial one), the reader reads each pixel as it
        // reads it alone, bit for bit, and hands them back in order.
        let mut reader = PairReader::new([&mx, &my]).expect("whole models");
        let pixel = |i: usize| {
            let (x, y) = (i as f32 / 10.0, 0.3 + 0.04 * i as f32);
            (matte_features(1.5 * x - 0.75, 1.2 - 2.0 * y, k), x, y)
        };
        let mut queued = Vec::new();
        for i in 0..LANES + 3 {
            let ([fx, fy], x, y) = pixel(i);
            reader.queue(i, fx, fy, x, y, |key, r| queued.push((key, r)));
        }
        assert_eq!(queued.len(), LANES);
        reader.flush(|key, r| queued.push((key, r)));
        reader.flush(|_, _| panic!("nothing left to read"));
        for (i, (key, r)) in queued.into_iter().enumerate() {
            let ([fx, fy], x, y) = pixel(i);
            assert_eq!(key, i);
            assert_eq!(r, reader.read(fx, fy, x, y), "pixel {i}");
        }
        // The reader, row after row, reads as `read_pair` (the responses blended in
        // another order: equal to rounding).
        for y in [0.1f32, 0.45, 0.9] {
            for i in 0..12 {
                let x = i as f32 / 11.0;
                let (p, q) = (1.4 * x - 0.7, 1.1 - 1.3 * y);
                let [fx, fy] = matte_features(p, q, k);
                let (got, want) = (
                    reader.read(fx, fy, x, y),
                    read_pair([&mx, &my], fx, fy, x, y),
                );
                for (g, w) in got.into_iter().zip(want) {
                    assert!((g - w).abs() < 1e-4, "({x}, {y}): {got:?} vs {want:?}");
                }
            }
        }
    }

    /// [`pair_slopes`] for one pixel, written plainly (as it was before the lanes).
    fn pair_slopes_plain(fx: [f32; 2], fy: [f32; 2], ax: [f32; 2], ay: [f32; 2]) -> [f32; 2] {
        let mut slopes = [invert(fx, ax), invert(fy, ay)];
        for _ in 0..PAIR_ROUNDS {
            let [p, q] = slopes;
            let norm = (1.0 + p * p + q * q).sqrt();
            let undo = |a: [f32; 2], s: f32| {
                let sum = (1.0 + a[0] * s).max(0.0) + (1.0 + a[1] * s).max(0.0);
                norm / crate::tactile::model::cross_factor(sum / norm, 0.0)
            };
            let (ux, uy) = (undo(ay, q), undo(ax, p));
            let next = [
                invert(fx.map(|c| c * ux), ax),
                invert(fy.map(|c| c * uy), ay),
            ];
            if !(next[0].is_finite() && next[1].is_finite()) {
                break;
            }
            let settled = (next[0] - p).abs().max((next[1] - q).abs()) < SETTLED;
            slopes = next;
            if settled {
                break;
            }
        }
        slopes
    }

    #[test]
    fn pixels_read_side_by_side_read_as_one_at_a_time_bit_for_bit() {
        let mut rng = crate::rng::Rng::new(21);
        let mut pick = |lo: f64, hi: f64| rng.range(lo, hi) as f32;
        // Colours from shadowed (under `SHADOWED`) to bright, responses of either sign,
        // and a few that are not finite: lanes end their rounds at different times.
        let mut pixels = Vec::new();
        for n in 0..4000 {
            let mut colour = [0; 4].map(|_| pick(-0.2, 3.5));
            let response = [0; 4].map(|_| pick(-3.0, 3.0));
            match n % 50 {
                0 => colour[1] = f32::NAN,
                1 => colour[2] = f32::INFINITY,
                2 => colour = [0.0; 4],
                _ => {}
            }
            pixels.push((colour, response));
        }
        // Each pixel as `[fx, fy, ax, ay]`.
        let split = |(c, a): &([f32; 4], [f32; 4])| {
            [[c[0], c[1]], [c[2], c[3]], [a[0], a[1]], [a[2], a[3]]]
        };
        for batch in pixels.chunks_exact(LANES) {
            let lanes: [[[f32; 2]; LANES]; 4] =
                std::array::from_fn(|v| std::array::from_fn(|l| split(&batch[l])[v]));
            let side_by_side = pair_slopes(lanes[0], lanes[1], lanes[2], lanes[3]);
            // The queue's reading, in AVX2 lanes where this CPU has them.
            let queued = std::array::from_fn(|l| Queued {
                key: l,
                features: [lanes[0][l], lanes[1][l]],
                responses: [lanes[2][l], lanes[3][l]],
            });
            let in_lanes = pair_slopes_lanes(&queued);
            for ((pixel, got), lanes) in batch.iter().zip(side_by_side).zip(in_lanes) {
                let [fx, fy, ax, ay] = split(pixel);
                let plain = pair_slopes_plain(fx, fy, ax, ay);
                let alone = pair_slopes([fx], [fy], [ax], [ay])[0];
                let reads = [("side by side", got), ("alone", alone), ("lanes", lanes)];
                for (what, read) in reads {
                    assert_eq!(
                        read.map(f32::to_bits),
                        plain.map(f32::to_bits),
                        "{what}: {pixel:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn rows_of_a_region_are_read_in_pairs_where_both_phases_saw_the_pixel() {
        let k = 1.6f32;
        let samples: Vec<Sample> = (-900..=900)
            .map(|i| {
                let p = i as f32 / 1000.0;
                let [f, _] = matte_features(p, 0.0, k);
                Sample {
                    features: [f[0], f[1], 0.5, 0.5],
                    target: p,
                }
            })
            .collect();
        let model = LightModel::fit(&samples, 1, 1);
        // A region of 6 pixels: 0, 2, 5 in both phases, 1 and 4 in dx only, 3 in dy only.
        let slopes = [
            (1.2f32, 0.7f32),
            (0.3, 0.0),
            (0.93, 0.93),
            (0.0, -0.4),
            (-1.3, 0.0),
            (0.2, 0.1),
        ];
        let (mut rows, mut targets) = ([Vec::new(), Vec::new()], [Vec::new(), Vec::new()]);
        for (i, &(p, q)) in slopes.iter().enumerate() {
            let f = matte_features(p, q, k);
            let x = i as f32 / 6.0;
            for axis in 0..2 {
                let seen = match i {
                    1 | 4 => axis == 0,
                    3 => axis == 1,
                    _ => true,
                };
                if seen {
                    rows[axis].push([f[axis][0], f[axis][1], x, 0.25]);
                    targets[axis].push(i);
                }
            }
        }
        let (mut p, mut q) = (vec![9.0f32; 6], vec![9.0f32; 6]);
        read_rows(
            [&model, &model],
            [&rows[0], &rows[1]],
            [&targets[0], &targets[1]],
            [&mut p, &mut q],
        );
        for (i, &(tp, tq)) in slopes.iter().enumerate() {
            let f = matte_features(tp, tq, k);
            let x = i as f32 / 6.0;
            let want = match i {
                1 | 4 => [model.eval(f[0][0], f[0][1], x, 0.25), 9.0],
                3 => [9.0, model.eval(f[1][0], f[1][1], x, 0.25)],
                _ => read_pair([&model, &model], f[0], f[1], x, 0.25),
            };
            assert_eq!([p[i], q[i]], want, "pixel {i}");
        }
        // Past the ball's slopes in one phase alone (pixel 4): right.
        assert!((p[4] + 1.3).abs() < 0.03, "{}", p[4]);
    }

    #[test]
    fn degenerate_inputs_give_zero_not_nonsense() {
        // No samples: no response, slope 0 everywhere.
        let empty = LightModel::fit(&[], 4, 3);
        assert_eq!(empty.eval(2.0, 0.1, 0.5, 0.5), 0.0);
        let model = LightModel::fit(&samples(0.9), 4, 3);
        // Both strips shadowed, NaN, infinite: 0.
        assert_eq!(model.eval(0.0, 0.05, 0.5, 0.5), 0.0);
        assert_eq!(model.eval(f32::NAN, f32::NAN, 0.5, 0.5), 0.0);
        // One colour NaN: the other alone.
        let [r, _] = matte(0.5, 0.5, 0.5);
        let got = model.eval(r, f32::NAN, 0.5, 0.5);
        assert!((got - 0.5).abs() < 0.03, "{got}");
        assert!(model.eval(f32::INFINITY, 1.0, 0.5, 0.5).is_finite());
        // NaN positions land on the first cell, never out of bounds.
        assert!(model.eval(1.2, 0.8, f32::NAN, 2.0).is_finite());
        // A damaged model (fewer responses than cells) reads 0.
        let mut broken = model.clone();
        broken.response.truncate(2);
        assert_eq!(broken.eval(1.5, 0.5, 0.5, 0.5), 0.0);
        // Samples with NaN are left out of the fit.
        let mut noisy = samples(0.9);
        for s in noisy.iter_mut().step_by(3) {
            s.features[0] = f32::NAN;
        }
        let fitted = LightModel::fit(&noisy, 4, 3);
        assert!(fitted.response.iter().flatten().all(|a| a.is_finite()));
        // The batch gives the one-by-one slopes (within rounding: the blend's order
        // differs), rows of several positions in raster order and out of it.
        let mut batch_in = Vec::new();
        for y in [0.0f32, 0.13, 0.13, 0.5, 0.97, 0.2, f32::NAN] {
            for x in [0.0f32, 0.05, 0.4, 0.41, 0.99, 1.0] {
                batch_in.push([1.3 + x, 0.7 - y, x, y]);
            }
        }
        batch_in.push([f32::NAN, 1.0, 0.5, 0.5]);
        let mut out = vec![9.0; batch_in.len()];
        fitted.eval_batch(&batch_in, &mut out);
        for (f, got) in batch_in.iter().zip(&out) {
            let want = fitted.eval(f[0], f[1], f[2], f[3]);
            assert!(
                (got - want).abs() <= 1e-5 * want.abs().max(1.0),
                "{f:?}: {got} vs {want}"
            );
        }
        let mut short = vec![9.0; 3];
        broken.eval_batch(&batch_in[..3], &mut short);
        assert_eq!(short, [0.0; 3]);
    }
}
