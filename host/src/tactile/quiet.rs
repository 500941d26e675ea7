//! Blocks sure to be at rest, from whole-number sums: the glance at a pair
//! ([`contact::glance`]) without its floating-point pass over every block.
//!
//! A pair at rest is mostly memory traffic: the glance reads the middle rows of every
//! block of both frames, writes their means, reads them back with five `f32` reference
//! planes per phase and weighs each block's departure. Here each block gets budgets
//! instead: how far the sums of one of its rows ([`SCREEN_ROW`], the first of its two
//! middle rows) may move from the reference's (`D = |Δ(R − G)| + |Δ(B − G)|` and `E =
//! |ΔG|` per phase, and `D_dx + D_dy` together) and still be sure to be lit in both
//! phases (the colour filter accepts it) and to depart by no more than the glance's bar.
//! The budgets are the least the filter's and the departure's bounds allow (see
//! [`QuietBlocks::new`]; each a triangle inequality on sums of absolute values, so a row
//! within them is quiet whatever the noise did). Each band's row is summed and compared
//! with the budgets while it is in the cache, against eleven 16-bit planes in all.
//!
//! Only blocks over budget can count towards contact, so only those with a neighbour
//! over budget too are weighed where a contact is at least two blocks (`min_cells`):
//! their other middle row is read (block by block, asked for a band ahead; a band with
//! [`DENSE_BAND`] of them or more reads it whole), the two rows' sums are held against
//! the same budgets counted for eight pixels, and what is over those is weighed as the
//! glance weighs it. Blocks not weighed are taken as lit: the unlit fraction at rest
//! counts the weighed blocks only (a frame without LED light departs everywhere, and is
//! weighed everywhere).
//!
//! Why one row: a pair's bytes come from memory, and a 4 KB page holds about two rows of
//! a 640 px frame, so reading two rows of every four brings in nearly every page (the
//! CPU's prefetcher fetches the rest of a page it sees read in order) while one row of
//! every four skips about half of them. The screen differs from the glance only in the
//! blocks it does not weigh: a block the glance would count passes as quiet when its
//! screened row is within the budgets and its other middle row departs by more (noise,
//! or the edge of an imprint running between the two rows). Every block it counts the
//! glance counts too, so at rest it never looks at every row where the glance would not.
//! A test holds the verdicts to that rule; another, on faint presses straddling the
//! threshold, holds that what the screen calls at rest the full look finds no contact
//! in; a third holds both sets of budgets to their promise. Where the screened row is
//! over budget on a few blocks in every band (skins whose noise is near the threshold),
//! the other rows are read anyway and nothing is saved.
//!
//! A contact is told as early: once two touching blocks count towards it, the glance
//! would read every row, so the budgets stop there and say so ([`Verdict`]), and the
//! reconstructor reads every row at once ([`contact::look_at_every_row`]) instead of
//! reading the middle rows a second time for the glance first.

use image::RgbImage;

use super::colour::ColourFilter;
use super::contact::{self, ContactParams, GLANCE_SHARE, References};
use super::smooth::{self, BlockMeans};

/// The row of each block of four (its first middle row) whose sums the budgets screen.
const SCREEN_ROW: usize = 1;
/// The block's other middle row, read where the screened row is over budget.
const OTHER_MIDDLE_ROW: usize = 3 - SCREEN_ROW;
/// Pixels of a block in its screened row: the screen's budgets are in counts of their
/// sums.
const SCREEN_PX: f64 = 4.0;
/// Pixels of a block in its two middle rows: the budgets a block over the screen's is
/// held to once its other middle row is read, before it is weighed.
const MIDDLE_PX: f64 = 8.0;

/// Share of each budget kept as a margin for the rounding of `f32` arithmetic in the
/// exact departure and the filter's rules: the departure's slack it leaves is at least
/// `1.25 · MARGIN` times a block's cost (`K·m ≥ 2/500`), about 5e-5, against at most
/// 1–2e-6 of rounding.
const MARGIN: f64 = 1e-2;

/// One phase's reference at block resolution in sums of a block's pixels (those of its
/// screened row, or of its two middle rows; rounded), and each block's budget in counts
/// of those sums (`-1` where none: never quiet).
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

/// Both phases' budgets of every block in counts of the sums of one set of its pixels.
#[derive(Debug, Clone, PartialEq)]
struct Budgets {
    phases: [Phase; 2],
    /// Per block, the budget of `D_dx + D_dy` that keeps the two departures' sum under
    /// the glance's bar (`-1`: never quiet).
    joint: Vec<i16>,
}

/// What [`QuietBlocks::new`] finds of one block of one phase, in mean units: the
/// reference's `R − G`, `B − G` and `G`, the budgets of `D` and `E`, and whether the
/// filter accepts the reference.
#[derive(Debug, Clone, Copy)]
struct BlockBudget {
    a: f64,
    b: f64,
    g: f64,
    d: f64,
    e: f64,
    lit: bool,
}

impl Budgets {
    /// Whether block `i` with red, green and blue sums `sums` (per phase) is within its
    /// budgets: [`mark_phase`]'s and [`mark_band_avx2`]'s rule for one block.
    fn within(&self, i: usize, sums: [[f32; 3]; 2]) -> bool {
        let mut spent = 0.0;
        for (p, [r, g, b]) in self.phases.iter().zip(sums) {
            let da = (r - g - f32::from(p.red_minus_green[i])).abs();
            let db = (b - g - f32::from(p.blue_minus_green[i])).abs();
            let dg = (g - f32::from(p.green[i])).abs();
            if da + db > f32::from(p.budget[i]) || dg > f32::from(p.green_budget[i]) {
                return false;
            }
            spent += da + db;
        }
        spent <= f32::from(self.joint[i])
    }
}

impl Phase {
    /// The budgets `blocks` in counts of sums of `px` pixels.
    fn counted(blocks: &[BlockBudget], px: f64) -> Self {
        let round = |v: f64| (px * v).round().clamp(-32768.0, 32767.0) as i16;
        Self {
            red_minus_green: blocks.iter().map(|k| round(k.a)).collect(),
            blue_minus_green: blocks.iter().map(|k| round(k.b)).collect(),
            green: blocks.iter().map(|k| round(k.g)).collect(),
            // Half a count of rounding for each difference.
            budget: blocks.iter().map(|k| budget(k.lit, k.d, 1.0, px)).collect(),
            green_budget: blocks.iter().map(|k| budget(k.lit, k.e, 0.5, px)).collect(),
        }
    }
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
    /// In counts of the screened row's sums.
    screen: Budgets,
    /// In counts of the two middle rows' sums.
    middle: Budgets,
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
    /// of what they leave; each budget less [`MARGIN`], in counts of the sums of the 4
    /// pixels of a block's screened row ([`SCREEN_ROW`]), and again of the 8 pixels of its
    /// two middle rows, less the references' rounding.
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
         -> Option<(Vec<BlockBudget>, Vec<[f64; 2]>)> {
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
            let mut out = Vec::with_capacity(bw * bh);
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
                out.push(BlockBudget {
                    a,
                    b: bb,
                    g,
                    d: d_budget,
                    e: e_budget,
                    lit,
                });
            }
            Some((out, terms))
        };
        let (x, x_terms) = phase(ref_dx, &block_refs.dx)?;
        let (y, y_terms) = phase(ref_dy, &block_refs.dy)?;
        // Both phases' `D` together: their departures add up to at most the glance's bar
        // when `D_dx + D_dy ≤ (bar − d_ref,dx − d_ref,dy) / max(K·m)`, less the margin and
        // the references' rounding (a count for each of the four differences).
        let bar = f64::from(GLANCE_SHARE * params.threshold);
        let joint: Vec<f64> = x_terms
            .iter()
            .zip(&y_terms)
            .map(|([cx, dx], [cy, dy])| {
                let (cost, slack) = (cx.max(*cy), bar - dx - dy);
                if cost > 0.0 {
                    slack / cost
                } else if slack > 0.0 {
                    f64::INFINITY
                } else {
                    -1.0
                }
            })
            .collect();
        let counted = |px: f64| Budgets {
            phases: [Phase::counted(&x, px), Phase::counted(&y, px)],
            joint: joint.iter().map(|&t| budget(true, t, 2.0, px)).collect(),
        };
        Some(Self {
            width: bw,
            height: bh,
            filter: *filter,
            threshold: params.threshold,
            screen: counted(SCREEN_PX),
            middle: counted(MIDDLE_PX),
        })
    }

    /// Share of blocks with a budget (the others are weighed every time).
    pub fn budgeted_share(&self) -> f64 {
        let phases = &self.screen.phases;
        let n = phases[0].budget.len().max(1);
        let both = phases[0]
            .budget
            .iter()
            .zip(&phases[1].budget)
            .filter(|(a, b)| **a >= 0 && **b >= 0)
            .count();
        both as f64 / n as f64
    }

    /// [`contact::glance`] at the pair `dx`, `dy`, with the blocks whose screened row is
    /// within their budgets taken as quiet (module doc): [`Verdict::AtRest`] with the
    /// glance's detection of the other blocks when the skin is at rest,
    /// [`Verdict::LookAtEveryRow`] when two blocks that count towards contact touch
    /// (said as soon as they do, without reading further), [`Verdict::CannotTell`] when
    /// these budgets are not for this pair's size, `block_refs`' size, `filter` or
    /// `params`, or the CPU cannot sum the bands in vector lanes (the caller then looks as
    /// before).
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
        // A band's blocks over budget are known as bits once it is screened; once the
        // band below is too, so are those among them with a neighbour over budget (the
        // only ones weighed where a contact is at least two blocks: a block counts only
        // where over budget, so one with no neighbour over budget cannot be one of two
        // touching blocks that count). Their other middle row is asked for then and read
        // a band later, so those scattered reads come in while the CPU sums.
        let mut bands = [(); RING].map(|()| Band::new(bw));
        let mut spent = vec![0.0f32; bw];
        let mut marked: Option<Vec<bool>> = None;
        let mut unlit = [0usize; 2];
        let refs = [
            block_refs.dx.planes(0..bw * self.height),
            block_refs.dy.planes(0..bw * self.height),
        ];
        let lone_blocks_count = params.min_cells <= 1;
        // A dense band's other middle rows, summed with the screened ones.
        let mut other = [smooth::band_scratch(bw), smooth::band_scratch(bw)];
        let mut middle_over = vec![false; bw];
        for by in 0..self.height + 2 {
            if by < self.height {
                let band = &mut bands[by % RING];
                let [Some(clip_dx), Some(clip_dy)] = [
                    smooth::row_sums(dx, by, SCREEN_ROW, &mut band.sums[0]),
                    smooth::row_sums(dy, by, SCREEN_ROW, &mut band.sums[1]),
                ] else {
                    return None;
                };
                band.clipped = [clip_dx, clip_dy];
                band.over.iter_mut().for_each(|o| *o = false);
                // SAFETY: the CPU has AVX2 (checked above; elsewhere `avx2()` is false
                // and the glance defers before this).
                #[cfg(target_arch = "x86_64")]
                unsafe {
                    mark_band_avx2(
                        &band.sums,
                        &self.screen,
                        by * bw..(by + 1) * bw,
                        &mut band.over,
                        &mut spent,
                    )
                };
                band.set_bits();
            }
            // The band above: which of its blocks are weighed, their other middle row
            // asked for.
            if let Some(above) = by.checked_sub(1).filter(|&b| b < self.height) {
                let weighed = if lone_blocks_count {
                    bands[above % RING].over_bits.clone()
                } else {
                    let around = |b: Option<usize>| {
                        b.filter(|&b| b < self.height)
                            .map(|b| bands[b % RING].over_bits.as_slice())
                    };
                    with_neighbour_over(
                        around(above.checked_sub(1)),
                        &bands[above % RING].over_bits,
                        around(Some(above + 1)),
                    )
                };
                let count = weighed
                    .iter()
                    .map(|w| w.count_ones() as usize)
                    .sum::<usize>();
                let dense = count >= DENSE_BAND;
                if !dense {
                    for bx in set_bits(&weighed) {
                        for image in [dx, dy] {
                            let at = other_row_start(image, above, bx);
                            crate::cpu::prefetch(image.as_raw(), at);
                            crate::cpu::prefetch(image.as_raw(), at + 11);
                        }
                    }
                }
                let band = &mut bands[above % RING];
                (band.weighed, band.dense) = (weighed, dense);
            }
            // Two bands above: its weighed blocks weighed as the glance weighs them.
            let Some(by) = by.checked_sub(2) else {
                continue;
            };
            let band = &bands[by % RING];
            // A band with many blocks to weigh has its other middle row read whole, in
            // vector lanes, and held against the middle rows' budgets there (where
            // nothing in either row is 255); the others read block by block.
            let mut in_lanes = false;
            if band.dense && !(band.clipped[0] | band.clipped[1]) {
                let [Some(clip_dx), Some(clip_dy)] = [0, 1]
                    .map(|p| smooth::row_sums([dx, dy][p], by, OTHER_MIDDLE_ROW, &mut other[p]))
                else {
                    return None;
                };
                if !(clip_dx | clip_dy) {
                    for (both, screened) in other.iter_mut().zip(&band.sums) {
                        for (b, s) in [
                            (&mut both.red, &screened.red),
                            (&mut both.green, &screened.green),
                            (&mut both.blue, &screened.blue),
                        ] {
                            b.iter_mut().zip(s).for_each(|(b, s)| *b += s);
                        }
                    }
                    middle_over.iter_mut().for_each(|o| *o = false);
                    // SAFETY: as above.
                    #[cfg(target_arch = "x86_64")]
                    unsafe {
                        mark_band_avx2(
                            &other,
                            &self.middle,
                            by * bw..(by + 1) * bw,
                            &mut middle_over,
                            &mut spent,
                        )
                    };
                    in_lanes = true;
                }
            }
            let mut newly = false;
            for bx in set_bits(&band.weighed) {
                let i = by * bw + bx;
                let (sums_dx, sums_dy, clip_dx, clip_dy) = if in_lanes {
                    // Within the middle rows' budgets: quiet, as the glance would find it.
                    if !middle_over[bx] {
                        continue;
                    }
                    let [sx, sy] =
                        [&other[0], &other[1]].map(|s| [s.red[bx], s.green[bx], s.blue[bx]]);
                    (sx, sy, false, false)
                } else {
                    let [(sx, cx), (sy, cy)] = [0, 1]
                        .map(|p| middle_sums([dx, dy][p], &band.sums[p], band.clipped[p], by, bx));
                    // Within the middle rows' budgets: quiet, as the glance would find it.
                    if !(cx | cy) && self.middle.within(i, [sx, sy]) {
                        continue;
                    }
                    (sx, sy, cx, cy)
                };
                let [mean_dx, mean_dy] = [sums_dx, sums_dy].map(|s| s.map(|v| v * 0.125));
                let (d_dx, lit_dx) = refs[0].departure(filter, i, mean_dx);
                let (d_dy, lit_dy) = refs[1].departure(filter, i, mean_dy);
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

/// Bands of blocks held at a time by [`QuietBlocks::look`]: the one just screened, the
/// one above it (whose weighed blocks are chosen, with both its neighbours known, and
/// asked for) and the one above that (weighed).
const RING: usize = 3;

/// Blocks to weigh in a band from which its other middle row is read whole rather than
/// block by block: a block read alone waits for memory (about 0.15 µs here, asked for a
/// band ahead), a row of both frames streams in about as fast as four.
const DENSE_BAND: usize = 4;

/// One band of blocks as the screen leaves it: its screened row's sums per phase,
/// whether a value there is 255, which blocks are over budget (as flags and as bits,
/// 64 blocks a word), and which of them are weighed.
struct Band {
    sums: [BlockMeans; 2],
    clipped: [bool; 2],
    over: Vec<bool>,
    over_bits: Vec<u64>,
    weighed: Vec<u64>,
    /// Whether at least [`DENSE_BAND`] blocks are weighed.
    dense: bool,
}

impl Band {
    fn new(blocks: usize) -> Self {
        let words = blocks.div_ceil(64);
        Self {
            sums: [smooth::band_scratch(blocks), smooth::band_scratch(blocks)],
            clipped: [false; 2],
            over: vec![false; blocks],
            over_bits: vec![0; words],
            weighed: vec![0; words],
            dense: false,
        }
    }

    /// `over_bits` from `over`.
    fn set_bits(&mut self) {
        for (word, chunk) in self.over_bits.iter_mut().zip(self.over.chunks(64)) {
            *word = chunk
                .iter()
                .enumerate()
                .fold(0u64, |m, (k, &o)| m | (u64::from(o) << k));
        }
    }
}

/// The blocks set in `bits` (64 a word), lowest first: a branch a block set rather than
/// one a block.
fn set_bits(bits: &[u64]) -> impl Iterator<Item = usize> + '_ {
    bits.iter().enumerate().flat_map(|(word, &bits)| {
        let mut bits = bits;
        std::iter::from_fn(move || {
            (bits != 0).then(|| {
                let k = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                word * 64 + k
            })
        })
    })
}

/// The blocks of `own` (bits, 64 a word) with a neighbour set: beside them in `own`, or
/// in the three blocks above or below them in `above` and `below` (bands that exist).
fn with_neighbour_over(above: Option<&[u64]>, own: &[u64], below: Option<&[u64]>) -> Vec<u64> {
    // Each block's bit and those of the blocks beside it, carried across words.
    let spread = |bits: &[u64], k: usize, keep_own: bool| {
        let left = bits[k] << 1 | k.checked_sub(1).map_or(0, |j| bits[j] >> 63);
        let right = bits[k] >> 1 | bits.get(k + 1).map_or(0, |w| w << 63);
        left | right | if keep_own { bits[k] } else { 0 }
    };
    (0..own.len())
        .map(|k| {
            let near = spread(own, k, false)
                | above.map_or(0, |a| spread(a, k, true))
                | below.map_or(0, |b| spread(b, k, true));
            own[k] & near
        })
        .collect()
}

/// Where block `bx` of band `by` starts in `image`'s bytes in its other middle row.
fn other_row_start(image: &RgbImage, by: usize, bx: usize) -> usize {
    (by * 4 + OTHER_MIDDLE_ROW) * image.width() as usize * 3 + bx * 12
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

/// A budget `t` (in mean units) in counts of sums of `px` pixels, less [`MARGIN`] and
/// `rounding` counts of the references' rounding; `-1` (never quiet) where there is
/// none or the reference is not `usable` (the filter rejects it).
fn budget(usable: bool, t: f64, rounding: f64, px: f64) -> i16 {
    let t = if usable && t > 0.0 {
        t * (1.0 - MARGIN) - MARGIN
    } else {
        -1.0
    };
    let count = (px * t - rounding).floor();
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
    budgets: &Budgets,
    blocks: std::ops::Range<usize>,
    over: &mut [bool],
    spent: &mut [f32],
) {
    let n = over.len();
    spent[..n].iter_mut().for_each(|s| *s = 0.0);
    for (s, p) in sums.iter().zip(&budgets.phases) {
        mark_phase(s, p, blocks.clone(), over, spent);
    }
    let (joint, spent) = (&budgets.joint[blocks][..n], &spent[..n]);
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

/// Block `bx` of band `by`'s red, green and blue sums over its two middle rows: the
/// screened row's sums `s` plus the other middle row's, read here (whole numbers, so
/// times 1/8 they are [`BlockMeans::of_middle_rows`]' means bit for bit), and whether a
/// value of either row is 255 (looked for in the screened row only where its band has
/// one).
fn middle_sums(
    image: &RgbImage,
    s: &BlockMeans,
    band_clipped: bool,
    by: usize,
    bx: usize,
) -> ([f32; 3], bool) {
    let stride = image.width() as usize * 3;
    let raw = image.as_raw();
    let bytes = |start: usize| &raw[start..start + 12];
    let other = bytes(other_row_start(image, by, bx));
    let mut add = [0u32; 3];
    for px in other.chunks_exact(3) {
        for (a, &v) in add.iter_mut().zip(px) {
            *a += u32::from(v);
        }
    }
    let sums = [s.red[bx], s.green[bx], s.blue[bx]];
    let sums = [0, 1, 2].map(|c| sums[c] + add[c] as f32);
    let screened = (by * 4 + SCREEN_ROW) * stride + bx * 12;
    let clipped = other.contains(&255) || band_clipped && bytes(screened).contains(&255);
    (sums, clipped)
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

    /// Sums of row `row` of every block of `image` (4 px wide), band `by`, straight from
    /// its pixels.
    fn direct_row_sums(image: &RgbImage, by: usize, row: usize) -> BlockMeans {
        let mut out = smooth::band_scratch(image.width() as usize / 4);
        for bx in 0..image.width() / 4 {
            let mut s = [0u32; 3];
            for x in 0..4 {
                let px = image.get_pixel(bx * 4 + x, by as u32 * 4 + row as u32);
                for c in 0..3 {
                    s[c] += u32::from(px[c]);
                }
            }
            out.red.push(s[0] as f32);
            out.green.push(s[1] as f32);
            out.blue.push(s[2] as f32);
        }
        out
    }

    /// The screen's rule, from floating-point means: [`contact::glance`]'s weighing of
    /// the two middle rows for every block whose screened row is over its budgets and,
    /// where a contact is at least two blocks, so is a neighbour's; the others quiet
    /// (lit, not counted).
    #[allow(unsafe_code)]
    fn screened_glance(
        quiet: &QuietBlocks,
        dx: &RgbImage,
        dy: &RgbImage,
        refs: &References,
        filter: &ColourFilter,
        params: &ContactParams,
    ) -> Option<contact::Detection> {
        let (bw, bh) = (quiet.width, quiet.height);
        let middle = [dx, dy].map(|f| BlockMeans::of_middle_rows(f, 4));
        let planes = [&refs.dx, &refs.dy].map(|r| r.planes(0..bw * bh));
        let bar = GLANCE_SHARE * params.threshold;
        let mut over_all = vec![false; bw * bh];
        for by in 0..bh {
            let sums = [dx, dy].map(|f| direct_row_sums(f, by, SCREEN_ROW));
            let (over, mut spent) = (&mut over_all[by * bw..(by + 1) * bw], vec![0.0f32; bw]);
            // SAFETY: the callers run only where the CPU has AVX2.
            #[cfg(target_arch = "x86_64")]
            unsafe {
                mark_band_avx2(
                    &sums,
                    &quiet.screen,
                    by * bw..(by + 1) * bw,
                    over,
                    &mut spent,
                )
            };
        }
        let over = |x: isize, y: isize| {
            (0..bw as isize).contains(&x)
                && (0..bh as isize).contains(&y)
                && over_all[y as usize * bw + x as usize]
        };
        let mut marked = vec![false; bw * bh];
        let mut unlit = [0usize; 2];
        for (i, mark) in marked.iter_mut().enumerate() {
            let (x, y) = ((i % bw) as isize, (i / bw) as isize);
            let neighbour = (-1..=1)
                .flat_map(|v| (-1..=1).map(move |u| (u, v)))
                .any(|(u, v)| (u, v) != (0, 0) && over(x + u, y + v));
            if over(x, y) && (params.min_cells <= 1 || neighbour) {
                let mut d = 0.0;
                for phase in 0..2 {
                    let (dep, lit) = planes[phase].departure(filter, i, middle[phase].mean(i));
                    unlit[phase] += usize::from(!lit);
                    d += dep;
                }
                let clipped = middle[0].clipped[i] > 0 || middle[1].clipped[i] > 0;
                *mark = !clipped && d > bar;
            }
        }
        if marked.iter().any(|&m| m)
            && (params.min_cells <= 1 || contact::has_neighbours(&marked, bw))
        {
            return None;
        }
        Some(contact::Detection {
            regions: Vec::new(),
            step: 4,
            blocks_across: bw,
            touched: vec![false; bw * bh],
            unlit_fraction: unlit.map(|u| u as f32 / (bw * bh) as f32),
        })
    }

    /// Over pairs at rest (noise only, lone noisy blocks over the bar among them), faint
    /// and plain presses, bright spots of 255, dark and white-lit patches and a green
    /// rise, with and without an unmixing: the budgets' glance gives what the screen's
    /// rule gives, detection for detection; it reads every row only where the glance
    /// would too, and it differs from the glance on few pairs.
    #[test]
    fn the_quiet_glance_answers_as_the_screened_glance() {
        if !crate::cpu::avx2() {
            eprintln!("skipped: this CPU has no AVX2, so the quiet glance always defers");
            return;
        }
        let mut rng = Rng::new(19);
        let mut answered = [0usize; 2];
        let mut unlike_the_glance = 0;
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
                let want = screened_glance(&quiet, &dx, &dy, &refs, &filter, &params);
                let got = match quiet.glance(&dx, &dy, &refs, &filter, &params) {
                    Verdict::AtRest(detection) => Some(detection),
                    Verdict::LookAtEveryRow => None,
                    Verdict::CannotTell => panic!("budgets made for this pair"),
                };
                assert_eq!(got, want, "case {case}, unmix {unmix:?}");
                answered[usize::from(want.is_some())] += 1;
                let middle = [&dx, &dy].map(|f| BlockMeans::of_middle_rows(f, 4));
                let glance = contact::glance(&middle[0], &middle[1], &refs, &filter, &params);
                assert!(
                    got.is_some() || glance.is_none(),
                    "case {case}: every row read where the glance would not"
                );
                unlike_the_glance += usize::from(got.is_some() != glance.is_some());
            }
        }
        // Both answers were given, so neither side holds trivially.
        assert!(answered[0] > 20 && answered[1] > 20, "{answered:?}");
        assert!(
            unlike_the_glance <= 6,
            "{unlike_the_glance} of 240 unlike the glance"
        );
    }

    /// The screen answers "at rest" only where the full look finds no contact: faint
    /// presses straddling the threshold at random places on random skins of our renderer
    /// (the threshold as calibration sets it), and on a skin at rest it answers most
    /// pairs alone.
    #[test]
    fn the_screen_misses_no_contact_the_full_look_finds() {
        use crate::tactile::contact::{faint_presses::FaintSkin, look_at_every_row};
        use crate::tactile::poisson::SolverKind;
        if !crate::cpu::avx2() {
            eprintln!("skipped: this CPU has no AVX2, so the quiet glance always defers");
            return;
        }
        for seed in [1u64, 2] {
            let skin = FaintSkin::new(seed);
            let (refs, filter, params) = (&skin.refs, &skin.filter, &skin.params);
            let quiet = QuietBlocks::new(&skin.flat.dx, &skin.flat.dy, refs, filter, params)
                .expect("4×4 blocks");
            let answered = skin
                .at_rest
                .iter()
                .filter(|p| {
                    matches!(
                        quiet.glance(&p.dx, &p.dy, refs, filter, params),
                        Verdict::AtRest(_)
                    )
                })
                .count();
            assert!(
                answered >= 6,
                "skin {seed}: the screen answered {answered} of 8"
            );
            let mut rng = Rng::new(seed);
            let (mut found, mut screened) = (0, 0);
            for k in 0..60u64 {
                let (p, depth) = skin.press(&mut rng, k);
                let full = look_at_every_row(&p.dx, &p.dy, refs, filter, params, SolverKind::Dct);
                let verdict = quiet.glance(&p.dx, &p.dy, refs, filter, params);
                if !full.regions.is_empty() {
                    found += 1;
                    assert_eq!(
                        verdict,
                        Verdict::LookAtEveryRow,
                        "skin {seed} press {k} ({depth} mm): found by the full look"
                    );
                } else {
                    screened += usize::from(matches!(verdict, Verdict::AtRest(_)));
                }
            }
            assert!(
                (15..60).contains(&found),
                "skin {seed}: the presses should straddle the threshold, {found} of 60 found"
            );
            assert!(screened > 0, "skin {seed}: no faint press answered at rest");
        }
    }

    /// Sums anywhere within a block's budgets (at their corners: all of a phase's `D` on
    /// one difference or split, all of `E`, the joint budget shared between the phases,
    /// either sign), of the screened row or of the two middle rows, give means the filter
    /// accepts in both phases and whose departures add up to at most the glance's bar;
    /// [`Budgets::within`] says so of them.
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
            let n = quiet.width * quiet.height;
            let planes = [&refs.dx, &refs.dy].map(|r| r.planes(0..n));
            let mut checked = 0;
            for ((set, px), i) in [(&quiet.screen, SCREEN_PX), (&quiet.middle, MIDDLE_PX)]
                .into_iter()
                .flat_map(|set| (0..n).map(move |i| (set, i)))
            {
                let [x, y] = [&set.phases[0], &set.phases[1]];
                let budgets = [
                    x.budget[i],
                    y.budget[i],
                    x.green_budget[i],
                    y.green_budget[i],
                    set.joint[i],
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
                    let (mut sum, mut sums) = (0.0, [[0.0f32; 3]; 2]);
                    for (phase, (d, e)) in shares.into_iter().enumerate() {
                        let p = &set.phases[phase];
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
                        sums[phase] = [r, g, b].map(|v| v as f32);
                        let mean = sums[phase].map(|v| v / px as f32);
                        let (d, lit) = planes[phase].departure(&filter, i, mean);
                        assert!(lit, "block {i} phase {phase}: {mean:?} within {budgets:?}");
                        sum += d;
                    }
                    assert!(sum <= bar, "block {i}: departs {sum} > {bar}");
                    assert!(
                        set.within(i, sums),
                        "block {i}: {sums:?} within {budgets:?}"
                    );
                    checked += 1;
                }
            }
            assert!(checked > 2000, "{checked}");
        }
    }
}
