//! Blocks sure to be at rest, from whole-number sums: the glance at a pair
//! ([`contact::glance`]) without its floating-point pass over every block.
//!
//! A pair at rest is mostly memory traffic: the glance reads the middle rows of every
//! block of both frames, writes their means, reads them back with five `f32` reference
//! planes per phase and weighs each block's departure. Here each block gets budgets
//! instead: how far its two middle rows' sums may move from the reference's (`D =
//! |Δ(R − G)| + |Δ(B − G)|` and `E = |ΔG|` per phase, and `D_dx + D_dy` together) and
//! still be sure to be lit in both phases (the colour filter accepts it) and to depart
//! by no more than the glance's bar. The budgets are the least the filter's and the
//! departure's bounds allow (see [`QuietBlocks::new`]; each a triangle inequality on
//! sums of absolute values, so a block within them is quiet whatever the noise did).
//! Each band's sums are compared with the budgets while they are in the cache, against
//! eleven 16-bit planes in all; only the few blocks over budget (noise in the tail, a
//! press) are weighed as the glance weighs them, from the same sums. A quiet block
//! cannot count towards contact nor be unlit, so the answer is the glance's, block for
//! block: a test holds them equal, another holds the budgets to their promise.
//!
//! A contact is told as early: once two touching blocks count towards it, the glance
//! would read every row, so the budgets stop there and say so ([`Verdict`]), and the
//! reconstructor reads every row at once ([`contact::look_at_every_row`]) instead of
//! reading the middle rows a second time for the glance first.

use image::RgbImage;

use super::colour::ColourFilter;
use super::contact::{self, ContactParams, GLANCE_SHARE, References};
use super::smooth::{self, BlockMeans};

/// Share of each budget kept as a margin for the rounding of `f32` arithmetic in the
/// exact departure and the filter's rules: the departure's slack it leaves is at least
/// `1.25 · MARGIN` times a block's cost (`K·m ≥ 2/500`), about 5e-5, against at most
/// 1–2e-6 of rounding.
const MARGIN: f64 = 1e-2;

/// One phase's reference at block resolution in sums of the 8 pixels of a block's two
/// middle rows (rounded), and each block's budget (`-1` where none: never quiet).
#[derive(Debug, Clone, PartialEq)]
struct Phase {
    red_minus_green: Vec<i16>,
    blue_minus_green: Vec<i16>,
    green: Vec<i16>,
    /// Of `|Δ(R − G)| + |Δ(B − G)|`.
    budget: Vec<i16>,
    /// Of `|ΔG|`.
    green_budget: Vec<i16>,
}

/// The budgets of every block of both phases, for one set of block references, colour
/// filter and contact threshold.
#[derive(Debug, Clone, PartialEq)]
pub struct QuietBlocks {
    /// Blocks across and down.
    width: usize,
    height: usize,
    /// The colour filter and threshold the budgets hold for.
    filter: ColourFilter,
    threshold: f32,
    phases: [Phase; 2],
    /// Per block, the budget of `D_dx + D_dy` that keeps the two departures' sum under
    /// the glance's bar (`-1`: never quiet).
    joint: Vec<i16>,
}

impl QuietBlocks {
    /// Budgets for the no-contact frames `ref_dx`, `ref_dy` (the frames `block_refs`
    /// were made from, [`contact::block_references`]), `filter` and `params`; `None`
    /// where the glance's blocks are not 4×4 px or the frame is not whole blocks.
    ///
    /// Per block, with the reference's mean `(R, G, B)`, `a = R − G`, `b = B − G` and its
    /// LED light `ℓ = max(a, b)`: a mean with `|Δa| + |Δb| ≤ D` and `|Δg| ≤ E` moves `ℓ`
    /// and each unmixed LED colour by at most `D` (times the unmixing's larger column
    /// sum `m`) and each channel by at most `D + E`, so it is
    /// - accepted by the filter when `D ≤ ℓ − min_led`, `D + E < saturation − max(R, G,
    ///   B)`, `w·D + |1 − w|·E ≤ w·ℓ − (1 − w)·G` (white ratio `w`) and `rise·D + E ≤
    ///   rise·ℓ` (green rise), each holding for the reference itself;
    /// - departs by at most `K·m·D + d_ref` (`K` the weight over the reference light, the
    ///   same for both colours, and `d_ref` the reference's own departure, non-zero where
    ///   its light is floored), so both phases together by at most the glance's bar when
    ///   `D_dx + D_dy ≤ (bar − d_ref,dx − d_ref,dy) / max(K·m)`.
    ///
    /// A phase's `D` takes at most half of each margin it shares with `E`, `E` the least
    /// of what they leave; each budget less [`MARGIN`], in counts of the 8 pixels' sums
    /// less the references' rounding.
    pub fn new(
        ref_dx: &RgbImage,
        ref_dy: &RgbImage,
        block_refs: &References,
        filter: &ColourFilter,
        params: &ContactParams,
    ) -> Option<Self> {
        let (w, h) = (ref_dx.width() as usize, ref_dx.height() as usize);
        if params.coarse_step != 4 || w == 0 || w % 4 != 0 || h % 4 != 0 {
            return None;
        }
        if ref_dy.dimensions() != ref_dx.dimensions() {
            return None;
        }
        let (bw, bh) = (w / 4, h / 4);
        // A phase's budgets, and per block the joint budget's terms: what a count of `D`
        // can add to the departure (`K·m`) and the reference's own departure (infinite
        // where the filter rejects the reference).
        let phase = |image: &RgbImage,
                     reference: &super::colour::Reference|
         -> Option<(Phase, Vec<[f64; 2]>)> {
            let means = BlockMeans::of(image, 4);
            if means.len() != bw * bh || reference.width() * reference.height() != bw * bh {
                return None;
            }
            let planes = reference.planes(0..bw * bh);
            // The unmixing's larger column sum: how much a change of `R − G` or `B − G`
            // moves the two LED colours together.
            let unmix = planes.unmix;
            let m = f64::from(
                (unmix.red[0].abs() + unmix.blue[0].abs())
                    .max(unmix.red[1].abs() + unmix.blue[1].abs()),
            );
            let mut out = Phase {
                red_minus_green: Vec::with_capacity(bw * bh),
                blue_minus_green: Vec::with_capacity(bw * bh),
                green: Vec::with_capacity(bw * bh),
                budget: Vec::with_capacity(bw * bh),
                green_budget: Vec::with_capacity(bw * bh),
            };
            let mut terms = Vec::with_capacity(bw * bh);
            for i in 0..bw * bh {
                let mean = means.mean(i);
                let (d_ref, lit) = planes.departure(filter, i, mean);
                let k = f64::from(
                    (planes.weight_red[i] * planes.inv_red[i])
                        .max(planes.weight_blue[i] * planes.inv_blue[i]),
                );
                let [r, g, b] = mean.map(f64::from);
                let (a, bb) = (r - g, b - g);
                let led = a.max(bb);
                let white = f64::from(filter.max_white_ratio);
                let rise = f64::from(filter.max_green_rise);
                // Bounds on `D = |Δa| + |Δb|` alone (the LED light) and on `D` and `E =
                // |Δg|` together (saturation, white ratio, green rise); the departure's
                // is on both phases' `D` together (below).
                terms.push([k * m, if lit { f64::from(d_ref) } else { f64::INFINITY }]);
                let led_margin = led - f64::from(filter.min_led);
                let saturation = f64::from(filter.saturation) - r.max(g).max(b);
                let whiteness = white * led - (1.0 - white) * g;
                let rise_margin = if rise >= 0.0 { rise * led } else { -1.0 };
                // `D` takes at most half of each shared margin, `E` what is left.
                let d_budget = least(&[
                    led_margin,
                    saturation / 2.0,
                    whiteness / (2.0 * white.max(f64::MIN_POSITIVE)),
                    rise_margin / (2.0 * rise.max(f64::MIN_POSITIVE)),
                ]);
                let e_budget = least(&[
                    saturation - d_budget,
                    (whiteness - white * d_budget) / (1.0 - white).abs(),
                    rise_margin - rise * d_budget,
                ]);
                let round = |v: f64| (8.0 * v).round().clamp(-32768.0, 32767.0) as i16;
                out.red_minus_green.push(round(a));
                out.blue_minus_green.push(round(bb));
                out.green.push(round(g));
                // Half a count of rounding for each difference.
                out.budget.push(budget(lit, d_budget, 1.0));
                out.green_budget.push(budget(lit, e_budget, 0.5));
            }
            Some((out, terms))
        };
        let (x, x_terms) = phase(ref_dx, &block_refs.dx)?;
        let (y, y_terms) = phase(ref_dy, &block_refs.dy)?;
        // Both phases' `D` together: their departures add up to at most the glance's bar
        // when `D_dx + D_dy ≤ (bar − d_ref,dx − d_ref,dy) / max(K·m)`, less the margin and
        // the references' rounding (a count for each of the four differences).
        let bar = f64::from(GLANCE_SHARE * params.threshold);
        let joint = x_terms
            .iter()
            .zip(&y_terms)
            .map(|([cx, dx], [cy, dy])| {
                let (cost, slack) = (cx.max(*cy), bar - dx - dy);
                let t = if cost > 0.0 {
                    slack / cost
                } else if slack > 0.0 {
                    f64::INFINITY
                } else {
                    -1.0
                };
                budget(true, t, 2.0)
            })
            .collect();
        Some(Self {
            width: bw,
            height: bh,
            filter: *filter,
            threshold: params.threshold,
            phases: [x, y],
            joint,
        })
    }

    /// Share of blocks with a budget (the others are weighed every time).
    pub fn budgeted_share(&self) -> f64 {
        let n = self.phases[0].budget.len().max(1);
        let both = self.phases[0]
            .budget
            .iter()
            .zip(&self.phases[1].budget)
            .filter(|(a, b)| **a >= 0 && **b >= 0)
            .count();
        both as f64 / n as f64
    }

    /// [`contact::glance`] at the pair `dx`, `dy`: [`Verdict::AtRest`] with the same
    /// detection when the skin is at rest, [`Verdict::LookAtEveryRow`] when the glance
    /// would read every row (said as soon as two blocks that count towards contact touch,
    /// without reading further), [`Verdict::CannotTell`] when these budgets are not for
    /// this pair's size, `block_refs`' size, `filter` or `params`, or the CPU cannot sum
    /// the bands in vector lanes (the caller then looks as before).
    pub fn glance(
        &self,
        dx: &RgbImage,
        dy: &RgbImage,
        block_refs: &References,
        filter: &ColourFilter,
        params: &ContactParams,
    ) -> Verdict {
        self.look(dx, dy, block_refs, filter, params)
            .map_or(Verdict::CannotTell, |at_rest| {
                at_rest.map_or(Verdict::LookAtEveryRow, Verdict::AtRest)
            })
    }

    /// [`Self::glance`]: `None` where it cannot tell, `Some(None)` where the glance
    /// would read every row.
    #[allow(unsafe_code)]
    fn look(
        &self,
        dx: &RgbImage,
        dy: &RgbImage,
        block_refs: &References,
        filter: &ColourFilter,
        params: &ContactParams,
    ) -> Option<Option<contact::Detection>> {
        let (w, h) = (dx.width() as usize, dx.height() as usize);
        if (w, h) != (self.width * 4, self.height * 4)
            || dy.dimensions() != dx.dimensions()
            || *filter != self.filter
            || params.threshold != self.threshold
            || params.coarse_step != 4
            || [&block_refs.dx, &block_refs.dy]
                .iter()
                .any(|r| r.width() * r.height() != self.width * self.height)
            || !crate::cpu::avx2()
        {
            return None;
        }
        let bw = self.width;
        let bar = GLANCE_SHARE * params.threshold;
        let mut sums = [smooth::band_scratch(bw), smooth::band_scratch(bw)];
        let mut over = vec![false; bw];
        let mut spent = vec![0.0f32; bw];
        let mut marked: Option<Vec<bool>> = None;
        let mut unlit = [0usize; 2];
        let (ref_dx, ref_dy) = (
            block_refs.dx.planes(0..bw * self.height),
            block_refs.dy.planes(0..bw * self.height),
        );
        for by in 0..self.height {
            let [Some(clip_dx), Some(clip_dy)] = [
                smooth::middle_row_sums(dx, by, &mut sums[0]),
                smooth::middle_row_sums(dy, by, &mut sums[1]),
            ] else {
                return None;
            };
            let blocks = by * bw..(by + 1) * bw;
            let mut newly = false;
            over.iter_mut().for_each(|o| *o = false);
            // SAFETY: the CPU has AVX2 (checked above; elsewhere `avx2()` is false and
            // the glance defers before this).
            #[cfg(target_arch = "x86_64")]
            unsafe {
                mark_band_avx2(
                    &sums,
                    &self.phases,
                    &self.joint,
                    blocks,
                    &mut over,
                    &mut spent,
                )
            };
            if !over.iter().fold(false, |seen, &o| seen | o) {
                continue;
            }
            // Where a value in the band is 255, the weighed blocks are looked at for it.
            let clipped = [clip_dx, clip_dy];
            // The blocks over budget as bits, taken lowest first: a branch a block
            // over budget rather than one a block.
            for (word, chunk) in over.chunks(64).enumerate() {
                let mut bits = chunk
                    .iter()
                    .enumerate()
                    .fold(0u64, |m, (k, &o)| m | (u64::from(o) << k));
                while bits != 0 {
                    let bx = word * 64 + bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let i = by * bw + bx;
                    let [(mean_dx, clip_dx), (mean_dy, clip_dy)] =
                        [(dx, &sums[0], clipped[0]), (dy, &sums[1], clipped[1])]
                            .map(|(image, s, clipped)| block_mean(image, s, clipped, by, bx));
                    let (d_dx, lit_dx) = ref_dx.departure(filter, i, mean_dx);
                    let (d_dy, lit_dy) = ref_dy.departure(filter, i, mean_dy);
                    unlit[0] += usize::from(!lit_dx);
                    unlit[1] += usize::from(!lit_dy);
                    let d = if clip_dx | clip_dy {
                        f32::NAN
                    } else {
                        0.0 + d_dx + d_dy
                    };
                    if d > bar {
                        marked.get_or_insert_with(|| vec![false; bw * self.height])[i] = true;
                        newly = true;
                    }
                }
            }
            // The glance reads every row once two marked blocks touch (or one is
            // marked, where a contact may be one block): more marks cannot change
            // that, so the rest of the frame is not read.
            if let Some(marked) = &marked
                && newly
                && (params.min_cells <= 1 || touches_the_band_above(marked, bw, by))
            {
                return Some(None);
            }
        }
        let n = bw * self.height;
        Some(Some(contact::Detection {
            regions: Vec::new(),
            step: 4,
            blocks_across: bw,
            touched: vec![false; n],
            unlit_fraction: unlit.map(|u| u as f32 / n.max(1) as f32),
        }))
    }
}

/// What the budgets tell of a pair ([`QuietBlocks::glance`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// At rest: the glance's detection (no contact).
    AtRest(contact::Detection),
    /// The glance would read every row: look at the pair in full
    /// ([`contact::look_at_every_row`], which is what it then does).
    LookAtEveryRow,
    /// These budgets cannot tell for this pair: look as before ([`contact::find_regions`]).
    CannotTell,
}

/// Whether a marked block of band `by` (blocks `bw` across) has a marked neighbour in
/// its own band or the one above (8-connected): over every band, the pairs
/// [`contact::has_neighbours`] looks for, each once.
fn touches_the_band_above(marked: &[bool], bw: usize, by: usize) -> bool {
    let row = &marked[by * bw..(by + 1) * bw];
    let beside = row.windows(2).any(|p| p[0] & p[1]);
    beside
        || by > 0 && {
            let above = &marked[(by - 1) * bw..by * bw];
            (0..bw).any(|x| {
                row[x]
                    && above[x.saturating_sub(1)..(x + 2).min(bw)]
                        .iter()
                        .any(|&a| a)
            })
        }
}

/// A budget `t` (in mean units) in counts of the 8 pixels' sums, less [`MARGIN`] and
/// `rounding` counts of the references' rounding; `-1` (never quiet) where there is
/// none or the reference is not `usable` (the filter rejects it).
fn budget(usable: bool, t: f64, rounding: f64) -> i16 {
    let t = if usable && t > 0.0 {
        t * (1.0 - MARGIN) - MARGIN
    } else {
        -1.0
    };
    let count = (8.0 * t - rounding).floor();
    if count >= 0.0 {
        count.min(f64::from(i16::MAX)) as i16
    } else {
        -1
    }
}

/// The least of `bounds`; `-1` (no budget) when one is not a number (a filter's setting
/// that is none), where `f64::min` would pass it over.
fn least(bounds: &[f64]) -> f64 {
    if bounds.iter().any(|b| b.is_nan()) {
        return -1.0;
    }
    bounds.iter().copied().fold(f64::INFINITY, f64::min)
}

/// Sets `over[k]` for the blocks `blocks` (one band) whose sums `sums` (per phase) are
/// further from the references than a budget allows, in vector lanes (eight blocks a
/// step); `spent` is scratch for `D_dx + D_dy`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn mark_band_avx2(
    sums: &[BlockMeans; 2],
    phases: &[Phase; 2],
    joint: &[i16],
    blocks: std::ops::Range<usize>,
    over: &mut [bool],
    spent: &mut [f32],
) {
    let n = over.len();
    spent[..n].iter_mut().for_each(|s| *s = 0.0);
    for (s, p) in sums.iter().zip(phases) {
        mark_phase(s, p, blocks.clone(), over, spent);
    }
    let (joint, spent) = (&joint[blocks][..n], &spent[..n]);
    for k in 0..n {
        over[k] |= spent[k] > f32::from(joint[k]);
    }
}

/// One phase of [`mark_band_avx2`]: its filter's budgets, and its `D` added to `spent`.
#[inline(always)]
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
fn mark_phase(
    s: &BlockMeans,
    p: &Phase,
    blocks: std::ops::Range<usize>,
    over: &mut [bool],
    spent: &mut [f32],
) {
    let n = over.len();
    let (r, g, b) = (&s.red[..n], &s.green[..n], &s.blue[..n]);
    let (ra, rb, rg, t, tg) = (
        &p.red_minus_green[blocks.clone()],
        &p.blue_minus_green[blocks.clone()],
        &p.green[blocks.clone()],
        &p.budget[blocks.clone()],
        &p.green_budget[blocks],
    );
    let (ra, rb, rg, t, tg, spent) = (
        &ra[..n],
        &rb[..n],
        &rg[..n],
        &t[..n],
        &tg[..n],
        &mut spent[..n],
    );
    for k in 0..n {
        let da = (r[k] - g[k] - f32::from(ra[k])).abs();
        let db = (b[k] - g[k] - f32::from(rb[k])).abs();
        let dg = (g[k] - f32::from(rg[k])).abs();
        over[k] |= (da + db > f32::from(t[k])) | (dg > f32::from(tg[k]));
        spent[k] += da + db;
    }
}

/// Block `bx` of band `by`'s mean over its two middle rows, as
/// [`BlockMeans::of_middle_rows`] gives it (the band's sum `s` times 1/8, exact), and
/// whether a value there is 255 (looked for in the bytes where the band has one).
fn block_mean(
    image: &RgbImage,
    s: &BlockMeans,
    band_clipped: bool,
    by: usize,
    bx: usize,
) -> ([f32; 3], bool) {
    let mean = [s.red[bx], s.green[bx], s.blue[bx]].map(|v| v * 0.125);
    if !band_clipped {
        return (mean, false);
    }
    let stride = image.width() as usize * 3;
    let raw = image.as_raw();
    let clipped = [by * 4 + 1, by * 4 + 2].into_iter().any(|row| {
        let start = row * stride + bx * 12;
        raw[start..start + 12].contains(&255)
    });
    (mean, clipped)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use crate::tactile::contact;
    use crate::tactile::crosstalk::Unmix;

    /// A flat-skin frame of one phase: red and blue LED light falling off across the
    /// frame, some green, `noise` counts of noise per channel.
    fn skin(w: u32, h: u32, rng: &mut Rng, noise: f64, flip: bool) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            let (u, v) = (x as f64 / w as f64, y as f64 / h as f64);
            let (s, t) = if flip { (v, u) } else { (u, v) };
            let base = [60.0 + 90.0 * s, 25.0 + 10.0 * t, 150.0 - 80.0 * s];
            image::Rgb(base.map(|c| (c + rng.range(-noise, noise)).round().clamp(0.0, 255.0) as u8))
        })
    }

    /// `frame` with a patch of `[r, g, b]` added over the disk of `radius` px at `(cx, cy)`.
    fn patch(frame: &mut RgbImage, cx: f64, cy: f64, radius: f64, add: [f64; 3]) {
        let (w, h) = frame.dimensions();
        for y in 0..h {
            for x in 0..w {
                if (x as f64 - cx).hypot(y as f64 - cy) <= radius {
                    let p = frame.get_pixel_mut(x, y);
                    for (v, a) in p.0.iter_mut().zip(add) {
                        *v = (f64::from(*v) + a).round().clamp(0.0, 255.0) as u8;
                    }
                }
            }
        }
    }

    /// Flat-skin references of both phases, a filter with `unmix`, a threshold, and the
    /// budgets for them.
    fn setup(
        unmix: Unmix,
        rng: &mut Rng,
    ) -> (References, ColourFilter, ContactParams, QuietBlocks) {
        let (w, h) = (96, 64);
        let (rdx, rdy) = (skin(w, h, rng, 0.0, false), skin(w, h, rng, 0.0, true));
        let refs = contact::block_references(&rdx, &rdy, 4, unmix);
        let filter = ColourFilter {
            unmix,
            ..ColourFilter::default()
        };
        let params = ContactParams {
            threshold: 0.06,
            ..ContactParams::default()
        };
        let quiet = QuietBlocks::new(&rdx, &rdy, &refs, &filter, &params).expect("4×4 blocks");
        (refs, filter, params, quiet)
    }

    /// Over pairs at rest (noise only, lone noisy blocks over the bar among them), faint
    /// and plain presses, bright spots of 255, dark and white-lit patches and a green
    /// rise, with and without an unmixing: the budgets' glance gives what the glance
    /// gives, detection for detection.
    #[test]
    fn the_quiet_glance_answers_as_the_glance() {
        if !crate::cpu::avx2() {
            eprintln!("skipped: this CPU has no AVX2, so the quiet glance always defers");
            return;
        }
        let mut rng = Rng::new(19);
        let mut answered = [0usize; 2];
        for unmix in [
            Unmix::IDENTITY,
            Unmix {
                red: [1.06, -0.09],
                blue: [-0.04, 1.03],
            },
        ] {
            let (refs, filter, params, quiet) = setup(unmix, &mut rng);
            assert!(quiet.budgeted_share() > 0.9, "{}", quiet.budgeted_share());
            for case in 0..120 {
                let noise = [1.0, 3.0, 6.0, 9.0][case % 4];
                let (mut dx, mut dy) = (
                    skin(96, 64, &mut rng, noise, false),
                    skin(96, 64, &mut rng, noise, true),
                );
                let (cx, cy) = (rng.range(0.0, 96.0), rng.range(0.0, 64.0));
                let r = rng.range(2.0, 12.0);
                let k = rng.range(0.5, 8.0);
                match (case / 4) % 6 {
                    0 => {}
                    1 => patch(&mut dx, cx, cy, r, [k, 0.0, -k]),
                    2 => patch(&mut dy, cx, cy, r, [255.0, 255.0, 255.0]),
                    3 => patch(&mut dx, cx, cy, r, [-200.0, -30.0, -200.0]),
                    4 => patch(&mut dy, cx, cy, r, [90.0, 120.0, 10.0]),
                    _ => patch(&mut dx, cx, cy, r, [0.0, 2.0 * k, 0.0]),
                }
                let middle = [&dx, &dy].map(|f| BlockMeans::of_middle_rows(f, 4));
                let want = contact::glance(&middle[0], &middle[1], &refs, &filter, &params);
                let got = match quiet.glance(&dx, &dy, &refs, &filter, &params) {
                    Verdict::AtRest(detection) => Some(detection),
                    Verdict::LookAtEveryRow => None,
                    Verdict::CannotTell => panic!("budgets made for this pair"),
                };
                assert_eq!(got, want, "case {case}, unmix {unmix:?}");
                answered[usize::from(want.is_some())] += 1;
            }
        }
        // Both answers were given, so neither side holds trivially.
        assert!(answered[0] > 20 && answered[1] > 20, "{answered:?}");
    }

    /// Sums anywhere within a block's budgets (at their corners: all of a phase's `D` on
    /// one difference or split, all of `E`, the joint budget shared between the phases,
    /// either sign) give means the filter accepts in both phases and whose departures
    /// add up to at most the glance's bar.
    #[test]
    fn a_block_within_its_budgets_is_lit_and_departs_by_at_most_the_bar() {
        let mut rng = Rng::new(7);
        for unmix in [
            Unmix::IDENTITY,
            Unmix {
                red: [1.1, -0.12],
                blue: [-0.05, 1.04],
            },
        ] {
            let (refs, filter, params, quiet) = setup(unmix, &mut rng);
            let bar = GLANCE_SHARE * params.threshold;
            let planes = [&refs.dx, &refs.dy].map(|r| r.planes(0..quiet.joint.len()));
            let mut checked = 0;
            for i in 0..quiet.joint.len() {
                let [x, y] = [&quiet.phases[0], &quiet.phases[1]];
                let budgets = [
                    x.budget[i],
                    y.budget[i],
                    x.green_budget[i],
                    y.green_budget[i],
                    quiet.joint[i],
                ];
                if budgets.iter().any(|&b| b < 0) {
                    continue;
                }
                let [fx, fy, ex, ey, joint] = budgets.map(i32::from);
                for _ in 0..8 {
                    // The joint budget (or what the phases allow) split between them.
                    let total = joint.min(fx + fy);
                    let low = (total - fy).max(0);
                    let high = total.min(fx);
                    let share = rng.range(f64::from(low), f64::from(high + 1)).floor() as i32;
                    let share = share.clamp(low, high);
                    let shares = [(share, ex), (total - share, ey)];
                    let mut sum = 0.0;
                    for (phase, (d, e)) in shares.into_iter().enumerate() {
                        let p = &quiet.phases[phase];
                        let part = rng.range(0.0, f64::from(d + 1)).floor() as i32;
                        let part = part.clamp(0, d);
                        let sign = |v: i32, rng: &mut Rng| if rng.uniform() < 0.5 { -v } else { v };
                        let (da, db, dg) = (
                            sign(part, &mut rng),
                            sign(d - part, &mut rng),
                            sign(e, &mut rng),
                        );
                        let g = i32::from(p.green[i]) + dg;
                        let r = i32::from(p.red_minus_green[i]) + da + g;
                        let b = i32::from(p.blue_minus_green[i]) + db + g;
                        let mean = [r, g, b].map(|v| v as f32 * 0.125);
                        let (d, lit) = planes[phase].departure(&filter, i, mean);
                        assert!(lit, "block {i} phase {phase}: {mean:?} within {budgets:?}");
                        sum += d;
                    }
                    assert!(sum <= bar, "block {i}: departs {sum} > {bar}");
                    checked += 1;
                }
            }
            assert!(checked > 1000, "{checked}");
        }
    }
}
