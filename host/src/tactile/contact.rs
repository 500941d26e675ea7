//! Contact detection: where does the colour differ from flat skin, and which small
//! rectangles (regions of interest) must the rest of the pipeline look at?
//!
//! Detection compares the mean colour of `coarse_step × coarse_step` blocks with the
//! references' (a block mean is several times less noisy than a pixel), so a frame with
//! no contact costs one pass of integer sums over the images and nothing else. The
//! threshold is measured by calibration on the frames' own flat skin. Marked blocks are
//! grouped into 8-connected components; components smaller than `min_cells` are noise. Each
//! component's bounding box, padded, becomes a region; overlapping regions merge, and each
//! is grown to a length the FFT solvers handle efficiently (5-smooth) where the frame
//! allows.

use image::RgbImage;
use serde::{Deserialize, Serialize};

use crate::union_find::DisjointSets;

use super::colour::{ColourFilter, Reference};
use super::crosstalk::Unmix;
use super::poisson::SolverKind;
use super::smooth::BlockMeans;

/// Thresholds of contact detection.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactParams {
    /// A block is touched when its mean colour's weighted departure from flat skin
    /// (`Σ w·|normalised colour − 1|` over both images, see [`colours_of`]) exceeds this.
    /// Calibration measures it on the frames' flat skin.
    pub threshold: f32,
    /// Block size of detection (px).
    pub coarse_step: usize,
    /// Smallest component of touched blocks that counts as a contact (blocks).
    pub min_cells: usize,
    /// Flat margin around each contact inside its region (px).
    pub pad_px: usize,
    /// The full-resolution mask is grown by this many pixels (the faint outer slopes).
    pub dilate_px: usize,
}

/// The largest contact threshold that means something: a block whose LED light falls to
/// almost nothing in both phases (just above the filter's floor: darker, it is rejected)
/// departs from flat skin by about 4 (each phase's weights sum to 2), so a threshold above
/// that would see only light more than doubled, never a press.
pub const MAX_THRESHOLD: f32 = 4.0;

impl Default for ContactParams {
    fn default() -> Self {
        Self {
            threshold: 0.25,
            coarse_step: 4,
            min_cells: 3,
            pad_px: 16,
            dilate_px: 6,
        }
    }
}

/// No-contact references of both phases.
#[derive(Debug, Clone, PartialEq)]
pub struct References {
    /// dx phase.
    pub dx: Reference,
    /// dy phase.
    pub dy: Reference,
}

/// A rectangle of the frame, in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Roi {
    /// Left column.
    pub x: usize,
    /// Top row.
    pub y: usize,
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
}

impl Roi {
    fn overlaps(&self, o: &Roi) -> bool {
        self.x < o.x + o.width
            && o.x < self.x + self.width
            && self.y < o.y + o.height
            && o.y < self.y + self.height
    }

    fn union(&self, o: &Roi) -> Roi {
        let (x0, y0) = (self.x.min(o.x), self.y.min(o.y));
        let x1 = (self.x + self.width).max(o.x + o.width);
        let y1 = (self.y + self.height).max(o.y + o.height);
        Roi {
            x: x0,
            y: y0,
            width: x1 - x0,
            height: y1 - y0,
        }
    }

    /// Number of pixels.
    pub fn area(&self) -> usize {
        self.width * self.height
    }
}

/// Normalised colours `[r_dx, b_dx, r_dy, b_dy]` of the (mean) colours `dx` and `dy` at
/// index `i` of `refs` (NaN where the colour filter rejects that phase) and how far they
/// are from flat skin: `Σ w·|colour − 1|` over the accepted phases (a rejected phase
/// counts as flat), each channel weighted by its share of the reference's LED light there
/// ([`Reference::weights`]), so the faint light of a far strip does not turn noise into
/// contact.
#[inline]
pub fn colours_of(
    refs: &References,
    filter: &ColourFilter,
    i: usize,
    dx: [f32; 3],
    dy: [f32; 3],
) -> ([f32; 4], f32) {
    let mut colour = [f32::NAN; 4];
    let mut deviation = 0.0;
    for (phase, (px, reference)) in [(dx, &refs.dx), (dy, &refs.dy)].into_iter().enumerate() {
        if let Some((r, b)) = reference.normalise_mean(filter, i, px) {
            (colour[2 * phase], colour[2 * phase + 1]) = (r, b);
            let (wr, wb) = reference.weights(i);
            deviation += wr * (r - 1.0).abs() + wb * (b - 1.0).abs();
        }
    }
    (colour, deviation)
}

/// [`colours_of`] for pixel `(x, y)` of the images.
#[inline]
pub fn pixel_colours(
    refs: &References,
    filter: &ColourFilter,
    dx: &RgbImage,
    dy: &RgbImage,
    x: usize,
    y: usize,
) -> ([f32; 4], f32) {
    let i = y * refs.dx.width() + x;
    let at = |img: &RgbImage| img.get_pixel(x as u32, y as u32).0.map(f32::from);
    colours_of(refs, filter, i, at(dx), at(dy))
}

/// The deviation from flat skin of every block of a pair's block means (what
/// [`colours_of`] gives); NaN (unknown) where a block has clipped pixels.
pub fn block_deviations(
    dx: &BlockMeans,
    dy: &BlockMeans,
    block_refs: &References,
    filter: &ColourFilter,
) -> Vec<f32> {
    block_departures(dx, dy, block_refs, filter).0
}

/// [`block_deviations`] and, per phase (`[dx, dy]`), the number of blocks where the filter
/// rejected that phase. One branch-free pass (vector lanes); detection and calibration's
/// threshold both use it, so the threshold is measured on the very numbers it is compared
/// with.
#[allow(unsafe_code)]
fn block_departures(
    dx: &BlockMeans,
    dy: &BlockMeans,
    refs: &References,
    filter: &ColourFilter,
) -> (Vec<f32>, [usize; 2]) {
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::avx2() {
        // SAFETY: `block_departures_avx2` only needs AVX2, detected just above.
        return unsafe { block_departures_avx2(dx, dy, refs, filter) };
    }
    block_departures_portable(dx, dy, refs, filter)
}

/// [`block_departures_portable`] in 8-wide lanes. No FMA: the results stay bit-equal to
/// [`colours_of`]'s.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn block_departures_avx2(
    dx: &BlockMeans,
    dy: &BlockMeans,
    refs: &References,
    filter: &ColourFilter,
) -> (Vec<f32>, [usize; 2]) {
    block_departures_portable(dx, dy, refs, filter)
}

#[inline(always)]
fn block_departures_portable(
    dx: &BlockMeans,
    dy: &BlockMeans,
    refs: &References,
    filter: &ColourFilter,
) -> (Vec<f32>, [usize; 2]) {
    let n = dx.len().min(dy.len());
    let (ref_dx, ref_dy) = (refs.dx.planes(0..n), refs.dy.planes(0..n));
    let (rx, gx, bx, cx) = (
        &dx.red[..n],
        &dx.green[..n],
        &dx.blue[..n],
        &dx.clipped[..n],
    );
    let (ry, gy, by, cy) = (
        &dy.red[..n],
        &dy.green[..n],
        &dy.blue[..n],
        &dy.clipped[..n],
    );
    let mut out = vec![0.0f32; n];
    // Per block, bit 0 set when dx is unlit, bit 1 when dy is, counted after the loop:
    // with the counts inside it the loop stayed scalar (detection at rest 235 → 150 µs
    // at 640×480 here).
    let mut unlit = vec![0u8; n];
    for i in 0..n {
        let (d_dx, lit_dx) = ref_dx.departure(filter, i, [rx[i], gx[i], bx[i]]);
        let (d_dy, lit_dy) = ref_dy.departure(filter, i, [ry[i], gy[i], by[i]]);
        unlit[i] = u8::from(!lit_dx) | (u8::from(!lit_dy) << 1);
        let clipped = (cx[i] | cy[i]) != 0;
        out[i] = if clipped { f32::NAN } else { 0.0 + d_dx + d_dy };
    }
    let count = |bit: u8| unlit.iter().map(|&u| u32::from(u & bit != 0)).sum::<u32>() as usize;
    (out, [count(1), count(2)])
}

/// Where contact was found: the regions to integrate, and the blocks (of
/// `ContactParams::coarse_step` px) that belong to a contact.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Regions of interest; empty when nothing touches the skin.
    pub regions: Vec<Roi>,
    /// Block size (px).
    pub step: usize,
    /// Blocks across.
    pub blocks_across: usize,
    /// Per block: part of a contact large enough to count.
    pub touched: Vec<bool>,
    /// Per phase (dx, dy): the fraction of blocks where the colour filter rejected it (no
    /// LED light, saturated, white light). Above a half in either, the pair is not a lit
    /// dx/dy pair: one unlit frame alone makes the other's colours read as slopes.
    pub unlit_fraction: [f32; 2],
}

impl Detection {
    /// The touched flags of the blocks that pixel row `y` crosses (block `x / step` for
    /// pixel column `x`).
    #[inline]
    pub fn touched_row(&self, y: usize) -> &[bool] {
        let start = y / self.step.max(1) * self.blocks_across;
        &self.touched[start..start + self.blocks_across]
    }

    /// The pixels of `roi` (row by row) whose block is touched, grown by `grow` pixels
    /// (square): [`dilate`] of the touched blocks, clipped to the region, built block
    /// row by block row. Every pixel row of a block row is the same, so each block row is
    /// grown across once and a pixel row is the union of the few grown block rows
    /// within `grow` of it.
    pub fn touched_pixels(&self, roi: &Roi, grow: usize) -> Vec<bool> {
        let (w, h) = (roi.width, roi.height);
        let step = self.step.max(1);
        let mut mask = vec![false; w * h];
        if w == 0 || h == 0 {
            return mask;
        }
        let (first, last) = (roi.y / step, (roi.y + h - 1) / step);
        // Each block row's touched pixels across the region, grown by `grow` across.
        let mut grown = vec![false; (last - first + 1) * w];
        let mut plain = vec![false; w];
        for (by, out) in (first..=last).zip(grown.chunks_exact_mut(w)) {
            let touched = self.touched_row(by * step);
            for (x, p) in plain.iter_mut().enumerate() {
                *p = touched[(roi.x + x) / step];
            }
            grow_row(&plain, out, grow);
        }
        for (ry, row) in mask.chunks_exact_mut(w).enumerate() {
            let top = roi.y + ry.saturating_sub(grow);
            let bottom = roi.y + (ry + grow).min(h - 1);
            for by in top / step..=bottom / step {
                let src = &grown[(by - first) * w..(by - first + 1) * w];
                for (m, s) in row.iter_mut().zip(src) {
                    *m |= *s;
                }
            }
        }
        mask
    }
}

/// `out[x]` is set when any of `row[x − r ..= x + r]` is.
fn grow_row(row: &[bool], out: &mut [bool], r: usize) {
    let w = row.len();
    let mut last_set: Option<usize> = None;
    for x in 0..(w + r) {
        if x < w && row[x] {
            last_set = Some(x);
        }
        if x >= r {
            out[x - r] = matches!(last_set, Some(s) if x - s <= 2 * r);
        }
    }
}

/// The first look at a pair: each block's departure from flat skin over its middle rows
/// only ([`BlockMeans::of_middle_rows`]: half the bytes). `Some`, the detection of a skin
/// at rest (no regions), when no two neighbouring blocks (8-connected) depart by more than
/// [`GLANCE_SHARE`] of the threshold (no block at all when `min_cells` lets one block be a
/// contact); `None` when a contact may be there, and the caller reads every row.
///
/// A contact the full look finds is `min_cells` (default 3) neighbouring blocks over the
/// threshold. A skin's imprint changes little over two pixel rows, so their middle rows
/// depart about as much, with √2 times the noise: the glance asks for two blocks over a
/// lower bar. At rest its unlit fraction is that of the middle rows.
pub fn glance(
    mx: &BlockMeans,
    my: &BlockMeans,
    block_refs: &References,
    filter: &ColourFilter,
    params: &ContactParams,
) -> Option<Detection> {
    let (gw, gh) = (mx.width, mx.height);
    let (deviations, unlit) = block_departures(mx, my, block_refs, filter);
    let bar = GLANCE_SHARE * params.threshold;
    let marked: Vec<bool> = deviations.iter().map(|&d| d > bar).collect();
    if marked.iter().fold(false, |seen, &m| seen | m)
        && (params.min_cells <= 1 || has_neighbours(&marked, gw))
    {
        return None;
    }
    Some(Detection {
        regions: Vec::new(),
        step: mx.step,
        blocks_across: gw,
        touched: vec![false; gw * gh],
        unlit_fraction: unlit.map(|u| u as f32 / (gw * gh).max(1) as f32),
    })
}

/// Whether some set cell of `mask` (rows of `w`) has a set 8-neighbour. A pass of vector
/// lanes per row (the cells right of it and the three below it), no labelling: at rest a
/// few lone cells are set in most frames.
pub(crate) fn has_neighbours(mask: &[bool], w: usize) -> bool {
    if w == 0 {
        return false;
    }
    let rows: Vec<&[bool]> = mask.chunks_exact(w).collect();
    let mut found = false;
    for (y, row) in rows.iter().enumerate() {
        let below = rows.get(y + 1).copied();
        // Right neighbour: cells x and x + 1.
        found |= row
            .iter()
            .zip(&row[1..])
            .fold(false, |f, (&a, &b)| f | (a & b));
        if let Some(below) = below {
            // Below, below-right and below-left.
            found |= row.iter().zip(below).fold(false, |f, (&a, &b)| f | (a & b));
            found |= row
                .iter()
                .zip(&below[1..])
                .fold(false, |f, (&a, &b)| f | (a & b));
            found |= row[1..]
                .iter()
                .zip(below)
                .fold(false, |f, (&a, &b)| f | (a & b));
        }
    }
    found
}

/// Share of the contact threshold two neighbouring blocks' middle rows must depart by
/// for [`glance`] to read every row. Measured on skin 1 of every family and on
/// `phys-glossy` skin 2 (each calibrated from its own presses): of 474 faint presses
/// (balls and a disk 0.005–0.1 mm deep, anywhere) that the full look found, the glance
/// passed over none at any share from 0.5 to 1.0. At rest (60 pairs a skin) it read every
/// row for 0–2 pairs at 0.9 but 10 on `phys-glossy` skin 2, whose threshold is held at
/// its bound, below its noise; at 0.8 for 0–5 and 35 there, at 0.7 for up to 52 and 59.
/// A pair the glance passes on costs both looks: 0.9 keeps the median pair at rest on
/// the glance on every skin measured, and a tenth below the threshold for seeing.
pub const GLANCE_SHARE: f32 = 0.9;

/// Finds the regions of interest around contacts from the images' block means, compared
/// with `block_refs` (references at block resolution, [`block_references`]); no regions
/// when nothing touches the skin. Images must have the model's size (checked by the
/// caller). A [`glance`] at half the rows answers for a skin at rest; where it sees
/// something, every row is read ([`look_at_every_row`]).
pub fn find_regions(
    dx: &RgbImage,
    dy: &RgbImage,
    block_refs: &References,
    filter: &ColourFilter,
    params: &ContactParams,
    solver: SolverKind,
) -> Detection {
    let step = params.coarse_step.max(1);
    let middle = [dx, dy].map(|img| BlockMeans::of_middle_rows(img, step));
    if let Some(at_rest) = glance(&middle[0], &middle[1], block_refs, filter, params) {
        return at_rest;
    }
    // The other rows, added to the middle ones: each byte is read once.
    let [mx, my] = [(dx, &middle[0]), (dy, &middle[1])]
        .map(|(img, half)| BlockMeans::of_given_middle_rows(img, half));
    detect(dx, &mx, &my, block_refs, filter, params, solver)
}

/// [`find_regions`] without the glance: the blocks' means over all their rows.
pub fn look_at_every_row(
    dx: &RgbImage,
    dy: &RgbImage,
    block_refs: &References,
    filter: &ColourFilter,
    params: &ContactParams,
    solver: SolverKind,
) -> Detection {
    let step = params.coarse_step.max(1);
    let (mx, my) = (BlockMeans::of(dx, step), BlockMeans::of(dy, step));
    detect(dx, &mx, &my, block_refs, filter, params, solver)
}

/// Detection from the block means of a pair (`frame`: either image, for its size).
fn detect(
    frame: &RgbImage,
    mx: &BlockMeans,
    my: &BlockMeans,
    block_refs: &References,
    filter: &ColourFilter,
    params: &ContactParams,
    solver: SolverKind,
) -> Detection {
    let (w, h) = (frame.width() as usize, frame.height() as usize);
    let step = mx.step;
    let (gw, gh) = (mx.width, mx.height);
    // A block with clipped pixels has a mean that says nothing about the light (a
    // bright spot or overexposure there): its deviation is NaN and it cannot show contact.
    let (deviations, unlit) = block_departures(mx, my, block_refs, filter);
    let marked: Vec<bool> = deviations.iter().map(|&d| d > params.threshold).collect();
    let mut detection = Detection {
        regions: Vec::new(),
        step,
        blocks_across: gw,
        touched: vec![false; gw * gh],
        unlit_fraction: unlit.map(|u| u as f32 / (gw * gh).max(1) as f32),
    };
    // A fold, not `any`: it runs in vector lanes, where `any`'s early exit kept it one
    // block at a time over the whole frame at rest (about 5 µs at 640×480).
    if !marked.iter().fold(false, |seen, &m| seen | m) {
        return detection;
    }
    let (labels, components) = label_components(&marked, gw, gh);
    let keep: Vec<bool> = components
        .iter()
        .map(|c| c.cells >= params.min_cells)
        .collect();
    for (t, l) in detection.touched.iter_mut().zip(&labels) {
        *t = *l > 0 && keep[*l as usize - 1];
    }
    // Blocks clipped in one phase only: a wall overexposed by the strip it faces (a
    // light seen through the skin, such as a ceiling spot, clips both phases).
    let one_phase: Vec<bool> = mx
        .clipped
        .iter()
        .zip(&my.clipped)
        .map(|(&a, &b)| (a != 0) != (b != 0))
        .collect();
    // The regions hold the contacts with the blocks they took in (a joined block can
    // lie past the padding of the contact's own box). With no block clipped in one phase
    // nothing joins, and the contacts are the components kept (most frames: the two
    // passes over the blocks are skipped).
    let contacts = if one_phase.iter().any(|&c| c) {
        join_clipped_neighbours(&mut detection.touched, &one_phase, gw, gh);
        join_enclosing_clipped(&mut detection.touched, &one_phase, params.min_cells, gw, gh);
        label_components(&detection.touched, gw, gh).1
    } else {
        let kept = components.into_iter().zip(&keep).filter(|(_, k)| **k);
        kept.map(|(c, _)| c).collect()
    };
    let mut regions: Vec<Roi> = contacts
        .iter()
        .map(|c| {
            let x0 = (c.x0 * step).saturating_sub(params.pad_px);
            let y0 = (c.y0 * step).saturating_sub(params.pad_px);
            let x1 = ((c.x1 + 1) * step + params.pad_px).min(w);
            let y1 = ((c.y1 + 1) * step + params.pad_px).min(h);
            Roi {
                x: x0,
                y: y0,
                width: x1 - x0,
                height: y1 - y0,
            }
        })
        .collect();
    merge_overlapping(&mut regions);
    for r in &mut regions {
        (r.x, r.width) = fit_length(r.x, r.width, w, solver);
        (r.y, r.height) = fit_length(r.y, r.height, h, solver);
    }
    // Growing may make regions overlap again; merged ones keep their (valid) size.
    merge_overlapping(&mut regions);
    detection.regions = regions;
    detection
}

/// Above this share of a touched block's departure in common (red and blue of a phase
/// moved the same way) to the departure between its two strips, and above
/// [`MIN_COMMON_DEPARTURE`], the touched blocks read as light that changed (see
/// [`departs_as_light_change`]).
const COMMON_TO_DIFFERENTIAL: f32 = 3.0;
/// The least common departure (normalised colour) that reads as light that changed: an
/// exposure 5 % off the references'.
const MIN_COMMON_DEPARTURE: f32 = 0.05;

/// Whether the touched blocks of `detection` depart from flat skin as a change of light
/// does rather than as slopes do. A phase's two strips face each other, so a slope makes
/// one brighter and the other darker (a differential departure, `|r − b| / 2`), and even
/// the steepest makes both darker by much less than it moves them apart; an exposure,
/// gain or LED brightness change moves both the same way (a common departure,
/// `|(r + b) / 2 − 1|`). Light changed when, over the touched blocks, the median common
/// departure is above [`MIN_COMMON_DEPARTURE`] and [`COMMON_TO_DIFFERENTIAL`] times the
/// median differential one. For frames where most of the skin reads as contact (rare: one
/// extra pass over both frames).
pub fn departs_as_light_change(
    dx: &RgbImage,
    dy: &RgbImage,
    block_refs: &References,
    filter: &ColourFilter,
    detection: &Detection,
) -> bool {
    let (mx, my) = (
        BlockMeans::of(dx, detection.step),
        BlockMeans::of(dy, detection.step),
    );
    let (mut common, mut differential) = (Vec::new(), Vec::new());
    let touched = detection.touched.iter().enumerate().filter(|(_, t)| **t);
    for (i, _) in touched.filter(|(i, _)| *i < mx.len().min(my.len())) {
        let (c, _) = colours_of(block_refs, filter, i, mx.mean(i), my.mean(i));
        for (r, b) in [(c[0], c[1]), (c[2], c[3])] {
            if r.is_finite() && b.is_finite() {
                common.push(((r + b) / 2.0 - 1.0).abs());
                differential.push(((r - b) / 2.0).abs());
            }
        }
    }
    if common.is_empty() {
        return false;
    }
    let median = |v: &mut Vec<f32>| {
        let k = v.len() / 2;
        *v.select_nth_unstable_by(k, f32::total_cmp).1
    };
    let (common, differential) = (median(&mut common), median(&mut differential));
    common > MIN_COMMON_DEPARTURE && common > COMMON_TO_DIFFERENTIAL * differential
}

/// How far (blocks) a contact takes in clipped blocks: 3 blocks of the default 4 px are about the
/// width of a 1 mm deep wall of slope 1.3 at 15 px/mm.
const JOIN_REACH_BLOCKS: usize = 3;

/// Blocks clipped in one phase (`clipped`) connected to a contact, directly or through
/// other such blocks (8-neighbours) at most [`JOIN_REACH_BLOCKS`] away, join it. A clipped block says nothing about the
/// light, and one clipped in a single phase next to a contact is the contact's wall
/// facing a strip, which overexposes: left out, a saturated stretch of wall breaks the
/// ring of touched blocks around a flat-bottomed imprint, whose flat middle (it has the
/// colour of skin at rest) then is no longer enclosed and reads 0. Blocks clipped in
/// both phases (light from outside, such as a ceiling spot, shows in both) stay out, and
/// so do those farther away: joined, their slopes would be filled from the contact's and
/// read as depth beside it.
fn join_clipped_neighbours(touched: &mut [bool], clipped: &[bool], w: usize, h: usize) {
    let mut queue: std::collections::VecDeque<(usize, usize)> = (0..touched.len())
        .filter(|&i| touched[i])
        .map(|i| (i, 0))
        .collect();
    while let Some((i, d)) = queue.pop_front() {
        if d >= JOIN_REACH_BLOCKS {
            continue;
        }
        for j in neighbourhood(i, w, h) {
            if !touched[j] && clipped[j] {
                touched[j] = true;
                queue.push_back((j, d + 1));
            }
        }
    }
}

/// At most this many clipped stretches meeting a contact, the largest first, are weighed by
/// [`join_enclosing_clipped`]: each can cost two hole fills of the block grid, and speckled
/// clipping around a large contact could otherwise make many.
const MAX_ENCLOSING_STRETCHES: usize = 8;

/// The rest of a stretch of one-phase clipped blocks ([`join_clipped_neighbours`] took in
/// its first [`JOIN_REACH_BLOCKS`] from the contact) joins when it closes the contact's
/// ring: with it the touched blocks enclose at least `min_cells` more blocks, nine tenths
/// of them inside some contact's bounding box (taken before this join). The stretches
/// meeting a contact (the [`MAX_ENCLOSING_STRETCHES`] largest) are judged together first;
/// when together they fail the box rule, each stretch that on its own encloses a pocket
/// failing it is left out and the others are judged again (so a pocket beside one contact
/// does not keep a ring-closing arc elsewhere out). Then each stretch is left out that the
/// enclosed area does not need. A wall facing a bright strip can clip along a long arc of
/// the ring (15 blocks, 60 px, seen on a skin we did not tune on); reach alone leaves the
/// arc's middle open and the flat middle of the imprint, no longer enclosed, reads 0. A
/// clipped stretch beside a contact that encloses nothing, or encloses a pocket of skin
/// outside the contact's box, stays out (its slopes would be filled from the contact's and
/// read as depth beside it).
fn join_enclosing_clipped(
    touched: &mut [bool],
    clipped: &[bool],
    min_cells: usize,
    w: usize,
    h: usize,
) {
    let rest: Vec<bool> = touched
        .iter()
        .zip(clipped)
        .map(|(&t, &c)| c && !t)
        .collect();
    if !rest.iter().any(|&r| r) {
        return;
    }
    let (labels, components) = label_components(&rest, w, h);
    // The stretches that meet a contact (8-neighbours), the largest first.
    let mut meets = vec![false; components.len()];
    for (i, &l) in labels.iter().enumerate() {
        if l != 0 && neighbourhood(i, w, h).any(|j| touched[j]) {
            meets[l as usize - 1] = true;
        }
    }
    let mut weighed: Vec<usize> = (0..components.len()).filter(|&k| meets[k]).collect();
    if weighed.is_empty() {
        return;
    }
    weighed.sort_by_key(|&k| std::cmp::Reverse(components[k].cells));
    weighed.truncate(MAX_ENCLOSING_STRETCHES);
    let filled = |mask: &[bool]| {
        let mut f = mask.to_vec();
        fill_holes(&mut f, w, h);
        f
    };
    let before = filled(touched);
    // A contact's box: the middle its ring encloses lies inside it; a pocket of skin
    // between a contact and a clipped stretch beside it lies mostly outside.
    let (_, contacts) = label_components(touched, w, h);
    let in_a_box = |i: usize| {
        let (x, y) = (i % w, i / w);
        contacts
            .iter()
            .any(|c| (c.x0..=c.x1).contains(&x) && (c.y0..=c.y1).contains(&y))
    };
    // Skin the `chosen` stretches newly enclose (filled with them, not filled before and
    // not one of their own blocks): (inside a contact's box, outside every box).
    let enclosed = |chosen: &[bool]| {
        let trial = touched_with(touched, &labels, &|k| chosen[k]);
        let (mut inside, mut outside) = (0usize, 0usize);
        for (i, ((&a, &b), &t)) in filled(&trial).iter().zip(&before).zip(&trial).enumerate() {
            if a && !b && !t {
                if in_a_box(i) {
                    inside += 1;
                } else {
                    outside += 1;
                }
            }
        }
        (inside, outside)
    };
    // The box rule: less than a tenth of the newly enclosed skin outside every box.
    let passes = |(inside, outside): (usize, usize)| outside * 10 < inside + outside;
    // The enclosed skin inside the boxes, 0 when the box rule fails.
    let gain = |e: (usize, usize)| if passes(e) { e.0 } else { 0 };
    let mut chosen = vec![false; components.len()];
    for &k in &weighed {
        chosen[k] = true;
    }
    // All of them first (most frames enclose nothing new and stop here; two arcs may close
    // the ring only together).
    let together = enclosed(&chosen);
    if together.0 + together.1 < min_cells {
        return;
    }
    if !passes(together) {
        for &k in &weighed {
            let mut alone = vec![false; components.len()];
            alone[k] = true;
            let e = enclosed(&alone);
            if e.1 > 0 && !passes(e) {
                chosen[k] = false;
            }
        }
    }
    let all = if passes(together) {
        together.0
    } else {
        gain(enclosed(&chosen))
    };
    if all < min_cells {
        return;
    }
    for k in 0..chosen.len() {
        if chosen[k] {
            chosen[k] = false;
            chosen[k] = gain(enclosed(&chosen)) < all;
        }
    }
    let joined = touched_with(touched, &labels, &|k| chosen[k]);
    touched.copy_from_slice(&joined);
}

/// Cell `i` of a `w × h` grid (row-major) and its up to eight neighbours inside the grid.
fn neighbourhood(i: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (x, y) = (i % w, i / w);
    (y.saturating_sub(1)..=(y + 1).min(h - 1))
        .flat_map(move |ny| (x.saturating_sub(1)..=(x + 1).min(w - 1)).map(move |nx| ny * w + nx))
}

/// `touched` with the blocks of the components (`labels`, 1-based) that `pick` takes.
fn touched_with(touched: &[bool], labels: &[u32], pick: &dyn Fn(usize) -> bool) -> Vec<bool> {
    touched
        .iter()
        .zip(labels)
        .map(|(&t, &l)| t || (l > 0 && pick(l as usize - 1)))
        .collect()
}

/// References at block resolution from no-contact frames (LED light `unmix`ed: see
/// [`crate::tactile::crosstalk`]).
pub fn block_references(dx: &RgbImage, dy: &RgbImage, step: usize, unmix: Unmix) -> References {
    let (a, b) = (BlockMeans::of(dx, step), BlockMeans::of(dy, step));
    References {
        dx: Reference::from_means(a.width, a.height, &a.means(), unmix),
        dy: Reference::from_means(b.width, b.height, &b.means(), unmix),
    }
}

/// Grows `[start, start+len)` to an efficient solver length inside `[0, total)`, keeping
/// the original span inside; the whole axis when the efficient length does not fit.
fn fit_length(start: usize, len: usize, total: usize, solver: SolverKind) -> (usize, usize) {
    let good = solver.good_length(len);
    if good >= total {
        return (0, total);
    }
    let grow = good - len;
    let start = start.saturating_sub(grow / 2).min(total - good);
    (start, good)
}

fn merge_overlapping(regions: &mut Vec<Roi>) {
    let mut merged = true;
    while merged {
        merged = false;
        'outer: for i in 0..regions.len() {
            for j in i + 1..regions.len() {
                if regions[i].overlaps(&regions[j]) {
                    regions[i] = regions[i].union(&regions[j]);
                    regions.swap_remove(j);
                    merged = true;
                    break 'outer;
                }
            }
        }
    }
}

pub(crate) struct Component {
    /// Bounding box, inclusive.
    pub x0: usize,
    pub y0: usize,
    pub x1: usize,
    pub y1: usize,
    /// Number of cells.
    pub cells: usize,
}

/// 8-connected components of `mask` (`w × h`): a label per cell (0 = unset, `k + 1` =
/// component `k`) and each component's bounding box and size.
pub(crate) fn label_components(mask: &[bool], w: usize, h: usize) -> (Vec<u32>, Vec<Component>) {
    let mut labels = vec![0u32; mask.len()];
    let mut out = Vec::new();
    let mut stack = Vec::new();
    for start in 0..mask.len() {
        if !mask[start] || labels[start] != 0 {
            continue;
        }
        let id = out.len() as u32 + 1;
        labels[start] = id;
        stack.push(start);
        let mut c = Component {
            x0: usize::MAX,
            y0: usize::MAX,
            x1: 0,
            y1: 0,
            cells: 0,
        };
        while let Some(i) = stack.pop() {
            let (x, y) = (i % w, i / w);
            c.x0 = c.x0.min(x);
            c.x1 = c.x1.max(x);
            c.y0 = c.y0.min(y);
            c.y1 = c.y1.max(y);
            c.cells += 1;
            for j in neighbourhood(i, w, h) {
                if mask[j] && labels[j] == 0 {
                    labels[j] = id;
                    stack.push(j);
                }
            }
        }
        out.push(c);
    }
    (labels, out)
}

/// The runs `[start, end)` of consecutive entries of `row` equal to `value`, left to
/// right.
pub(crate) fn runs(row: &[bool], value: bool) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
    let mut x = 0;
    std::iter::from_fn(move || {
        while x < row.len() && row[x] != value {
            x += 1;
        }
        let start = x;
        while x < row.len() && row[x] == value {
            x += 1;
        }
        (x > start).then_some(start..x)
    })
}

/// Sets every unset pixel not 4-connected to the frame border through unset pixels.
///
/// Works on runs of unset pixels rather than pixels: the runs of each row are joined to
/// the runs they overlap in the row above (union–find), a set of runs touching the border
/// is outside, and the runs of every other set are holes.
pub(crate) fn fill_holes(mask: &mut [bool], w: usize, h: usize) {
    if w == 0 || h == 0 {
        return;
    }
    // Spans `[start, end)` of unset pixels, row by row; `rows[y]..rows[y + 1]` are row y's.
    let mut spans: Vec<(usize, usize)> = Vec::new();
    let mut rows = Vec::with_capacity(h + 1);
    for row in mask.chunks_exact(w) {
        rows.push(spans.len());
        spans.extend(runs(row, false).map(|r| (r.start, r.end)));
    }
    rows.push(spans.len());
    let mut sets = DisjointSets::new(spans.len());
    for y in 1..h {
        let (above, here) = (rows[y - 1]..rows[y], rows[y]..rows[y + 1]);
        let mut a = above.start;
        for i in here {
            let (start, end) = spans[i];
            // Spans above that end before this one starts can touch no later span either.
            while a < above.end && spans[a].1 <= start {
                a += 1;
            }
            let mut j = a;
            while j < above.end && spans[j].0 < end {
                sets.union(i, j);
                j += 1;
            }
        }
    }
    let mut outside = vec![false; spans.len()];
    for y in 0..h {
        let first = rows[y];
        for (i, &(start, end)) in spans[first..rows[y + 1]].iter().enumerate() {
            if y == 0 || y + 1 == h || start == 0 || end == w {
                let r = sets.root(first + i);
                outside[r] = true;
            }
        }
    }
    for y in 0..h {
        for i in rows[y]..rows[y + 1] {
            if !outside[sets.root(i)] {
                let (start, end) = spans[i];
                mask[y * w + start..y * w + end].fill(true);
            }
        }
    }
}

/// Grows a `w × h` mask by `r` pixels (square structuring element), in place.
pub fn dilate(mask: &mut [bool], w: usize, h: usize, r: usize) {
    if r == 0 || w == 0 || h == 0 {
        return;
    }
    let mut tmp = vec![false; mask.len()];
    // Rows: a pixel is set when any pixel within ±r in its row is.
    for (row, out) in mask.chunks_exact(w).zip(tmp.chunks_exact_mut(w)) {
        grow_row(row, out, r);
    }
    // Columns, from tmp back into mask.
    for x in 0..w {
        let mut last_set: Option<usize> = None;
        for y in 0..(h + r) {
            if y < h && tmp[y * w + x] {
                last_set = Some(y);
            }
            if y >= r {
                mask[(y - r) * w + x] = matches!(last_set, Some(s) if y - s <= 2 * r);
            }
        }
    }
}

/// For tests of the glance and of the screen that stands for it: a skin of our renderer
/// with faint presses straddling its contact threshold.
#[cfg(test)]
pub(crate) mod faint_presses {
    use super::*;
    use crate::rng::Rng;
    use crate::tactile::render::{Optics, RenderedPair, Scene, Shape, render};

    /// Skin `seed` of our renderer at 320×240: its flat frames, block references, eight
    /// pairs at rest and the threshold as calibration sets it from them (half as much
    /// again as their largest departure).
    pub(crate) struct FaintSkin {
        pub optics: Optics,
        pub flat: RenderedPair,
        pub refs: References,
        pub filter: ColourFilter,
        pub params: ContactParams,
        pub at_rest: Vec<RenderedPair>,
    }

    impl FaintSkin {
        pub(crate) fn new(seed: u64) -> Self {
            let filter = ColourFilter::default();
            let optics = Optics::random(320, 240, seed);
            let flat = render(&optics, &Scene::default(), 0);
            let refs = block_references(&flat.dx, &flat.dy, 4, Unmix::IDENTITY);
            let at_rest: Vec<_> = (1..=8)
                .map(|k| render(&optics, &Scene::default(), k))
                .collect();
            let largest = at_rest
                .iter()
                .flat_map(|p| {
                    let means = |img| BlockMeans::of(img, 4);
                    block_deviations(&means(&p.dx), &means(&p.dy), &refs, &filter)
                })
                .filter(|d| d.is_finite())
                .fold(0.0f32, f32::max);
            let params = ContactParams {
                threshold: 1.5 * largest,
                ..ContactParams::default()
            };
            Self {
                optics,
                flat,
                refs,
                filter,
                params,
                at_rest,
            }
        }

        /// Press `k`: a 4 mm ball 0.02, 0.04, 0.08 or 0.16 mm deep (by `k`) at a place
        /// drawn from `rng`, and its depth.
        pub(crate) fn press(&self, rng: &mut Rng, k: u64) -> (RenderedPair, f64) {
            let depth = [0.02, 0.04, 0.08, 0.16][k as usize % 4];
            let shape = Shape::Ball {
                cx: rng.range(0.5, 20.8),
                cy: rng.range(0.5, 15.5),
                diameter: 4.0,
                depth,
            };
            let scene = Scene {
                shapes: vec![shape],
            };
            (render(&self.optics, &scene, 100 + k), depth)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The branch-free block pass gives exactly what [`colours_of`] gives block by block,
    /// on images that cross every rule of the colour filter (dark, white, saturated,
    /// clipped, green risen) and at a width that leaves a partial block.
    #[test]
    fn block_departures_equal_colours_of() {
        let mut rng = crate::rng::Rng::new(11);
        let (w, h) = (43u32, 22u32);
        // Columns 0–7 dark, 8–15 white, the rest LED light; strong noise everywhere
        // (saturated pixels included).
        let mut noisy = |base: [f32; 3]| {
            RgbImage::from_fn(w, h, |x, _| {
                let base = match x {
                    0..8 => [8.0, 7.0, 8.0],
                    8..16 => [200.0, 190.0, 195.0],
                    _ => base,
                };
                image::Rgb(base.map(|c| {
                    (c + rng.range(-60.0, 80.0) as f32 * (c / 100.0)).clamp(0.0, 255.0) as u8
                }))
            })
        };
        let (dx, dy) = (noisy([120.0, 30.0, 110.0]), noisy([100.0, 25.0, 130.0]));
        let (rdx, rdy) = (noisy([120.0, 30.0, 110.0]), noisy([100.0, 25.0, 130.0]));
        let filter = ColourFilter::default();
        for step in [4, 3] {
            let refs = block_references(&rdx, &rdy, step, Unmix::IDENTITY);
            let (a, b) = (BlockMeans::of(&dx, step), BlockMeans::of(&dy, step));
            let (fast, unlit) = block_departures(&a, &b, &refs, &filter);
            let mut want_unlit = [0; 2];
            for (i, got) in fast.iter().enumerate() {
                let (colour, d) = colours_of(&refs, &filter, i, a.mean(i), b.mean(i));
                want_unlit[0] += usize::from(colour[0].is_nan());
                want_unlit[1] += usize::from(colour[2].is_nan());
                let want = if a.clipped[i] > 0 || b.clipped[i] > 0 {
                    f32::NAN
                } else {
                    d
                };
                assert!(
                    got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                    "step {step} block {i}: {got} vs {want}"
                );
            }
            assert_eq!(unlit, want_unlit);
            assert!(fast.iter().any(|d| d.is_nan()) && fast.iter().any(|&d| d > 0.0));
            assert!(unlit.iter().all(|&u| u > 0 && u < fast.len()));
        }
    }

    /// Growing the touched blocks block row by block row gives what building the pixel
    /// mask and dilating it gives, for regions at odd offsets and sizes.
    #[test]
    fn touched_pixels_equal_dilated_blocks() {
        let mut rng = crate::rng::Rng::new(3);
        let (bw, bh, step) = (13usize, 9usize, 4usize);
        let detection = Detection {
            regions: Vec::new(),
            step,
            blocks_across: bw,
            touched: (0..bw * bh).map(|_| rng.uniform() < 0.15).collect(),
            unlit_fraction: [0.0; 2],
        };
        for (x, y, width, height, grow) in [
            (0, 0, 52, 36, 6),
            (3, 5, 41, 27, 6),
            (7, 2, 30, 33, 0),
            (1, 1, 50, 34, 9),
            (10, 30, 5, 6, 2),
        ] {
            let roi = Roi {
                x,
                y,
                width,
                height,
            };
            let mut want = vec![false; width * height];
            for ry in 0..height {
                for rx in 0..width {
                    want[ry * width + rx] = detection.touched_row(y + ry)[(x + rx) / step];
                }
            }
            dilate(&mut want, width, height, grow);
            assert_eq!(
                detection.touched_pixels(&roi, grow),
                want,
                "{roi:?} grow {grow}"
            );
        }
    }

    /// The run-based hole filling equals a pixel flood fill from the border on random
    /// masks (rings, spirals of holes and bays of every shape come up at these densities).
    #[test]
    fn fill_holes_equals_a_flood_fill() {
        fn flood(mask: &[bool], w: usize, h: usize) -> Vec<bool> {
            let mut outside = vec![false; mask.len()];
            let mut stack: Vec<usize> = (0..mask.len())
                .filter(|&i| {
                    let (x, y) = (i % w, i / w);
                    (x == 0 || y == 0 || x == w - 1 || y == h - 1) && !mask[i]
                })
                .collect();
            for &i in &stack {
                outside[i] = true;
            }
            while let Some(i) = stack.pop() {
                let (x, y) = (i % w, i / w);
                let mut next = Vec::new();
                if x > 0 {
                    next.push(i - 1);
                }
                if x + 1 < w {
                    next.push(i + 1);
                }
                if y > 0 {
                    next.push(i - w);
                }
                if y + 1 < h {
                    next.push(i + w);
                }
                for j in next {
                    if !mask[j] && !outside[j] {
                        outside[j] = true;
                        stack.push(j);
                    }
                }
            }
            outside.iter().map(|o| !o).collect()
        }
        let mut rng = crate::rng::Rng::new(8);
        let mut holes = 0;
        for (w, h) in [(1, 1), (1, 9), (9, 1), (2, 2), (17, 13), (40, 31), (64, 64)] {
            for density in [0.3, 0.5, 0.6, 0.75] {
                let mask: Vec<bool> = (0..w * h).map(|_| rng.uniform() < density).collect();
                let want = flood(&mask, w, h);
                let mut got = mask.clone();
                fill_holes(&mut got, w, h);
                assert_eq!(got, want, "{w}x{h} density {density}");
                holes += got.iter().zip(&mask).filter(|(g, m)| **g && !**m).count();
            }
        }
        assert!(holes > 50, "the masks had holes to fill: {holes}");
    }

    #[test]
    fn holes_fill_but_border_bays_stay_open() {
        let (w, h) = (7, 5);
        let mut m = vec![false; w * h];
        for y in 1..4 {
            for x in 1..4 {
                m[y * w + x] = !(x == 2 && y == 2);
            }
        }
        fill_holes(&mut m, w, h);
        assert!(m[2 * w + 2]);
        assert!(!m[0] && !m[2 * w + 5]);
    }

    #[test]
    fn clipped_blocks_join_the_contact_they_touch_and_no_other() {
        // 12×6 blocks: a ring of touched blocks whose right side is clipped, a clipped
        // chain running on from it, and a clipped island away from it.
        let (w, h) = (12, 6);
        let mut touched = vec![false; w * h];
        let mut clipped = vec![false; w * h];
        for (x, y) in [
            (0, 0),
            (1, 0),
            (2, 0),
            (0, 1),
            (0, 2),
            (0, 3),
            (1, 3),
            (2, 3),
        ] {
            touched[y * w + x] = true;
        }
        // The wall (x = 3), then a chain along row 1 out to x = 9.
        for (x, y) in [(3, 0), (3, 1), (3, 2), (3, 3), (11, 5)] {
            clipped[y * w + x] = true;
        }
        for x in 4..10 {
            clipped[w + x] = true;
        }
        join_clipped_neighbours(&mut touched, &clipped, w, h);
        for y in 0..4 {
            assert!(touched[y * w + 3], "clipped wall block (3, {y}) joins");
        }
        // (2, 0) is touched: (3, 1) is 1 block away, (4, 1) 2, (5, 1) 3; no farther.
        for x in 4..10 {
            assert_eq!(
                touched[w + x],
                x <= 5,
                "chain block ({x}, 1) at {} blocks",
                x - 2
            );
        }
        assert!(
            !touched[5 * w + 11],
            "a clipped island away from contact stays out"
        );
        assert!(
            !touched[w + 1] && !touched[2 * w + 2],
            "the enclosed middle is not touched"
        );
        // The middle is now enclosed.
        let mut blocks = touched.clone();
        fill_holes(&mut blocks, w, h);
        assert!(blocks[w + 1] && blocks[2 * w + 2]);
    }

    #[test]
    fn a_clipped_arc_longer_than_the_reach_closes_the_ring() {
        // 30×30 blocks: a square ring (5..=20) whose right side (x = 20, 16 blocks) is
        // clipped in one phase, and a clipped chain leaving the top side (x = 12, y 0..5).
        let (w, h) = (30, 30);
        let mut touched = vec![false; w * h];
        let mut clipped = vec![false; w * h];
        for i in 5..20 {
            for (x, y) in [(i, 5), (i, 20), (5, i)] {
                touched[y * w + x] = true;
            }
        }
        for y in 5..=20 {
            clipped[y * w + 20] = true;
        }
        for y in 0..5 {
            clipped[y * w + 12] = true;
        }
        join_clipped_neighbours(&mut touched, &clipped, w, h);
        assert!(
            !touched[12 * w + 20],
            "reach alone leaves the arc's middle open"
        );
        let mut blocks = touched.clone();
        fill_holes(&mut blocks, w, h);
        assert!(!blocks[12 * w + 12], "so the middle is not enclosed");
        join_enclosing_clipped(&mut touched, &clipped, 3, w, h);
        assert!((5..=20).all(|y| touched[y * w + 20]), "the whole arc joins");
        let mut blocks = touched.clone();
        fill_holes(&mut blocks, w, h);
        assert!(blocks[12 * w + 12], "the middle is enclosed");
        assert!(
            touched[2 * w + 12] && !touched[w + 12] && !touched[12],
            "the chain beside the ring joins as far as the reach and no farther"
        );
    }

    #[test]
    fn a_pocket_beside_a_contact_does_not_keep_a_ring_closing_arc_out() {
        // 30×32 blocks: a square ring (x 5..=20, y 10..=25) whose right side is clipped in
        // one phase, and above its top side a clipped loop (x 8..=14, y 1..=9) that with
        // the top side encloses a pocket of skin mostly outside the ring's box.
        let (w, h) = (30, 32);
        let mut touched = vec![false; w * h];
        let mut clipped = vec![false; w * h];
        for i in 5..20 {
            for (x, y) in [(i, 10), (i, 25), (5, i + 5)] {
                touched[y * w + x] = true;
            }
        }
        for y in 10..=25 {
            clipped[y * w + 20] = true;
        }
        for y in 1..=9 {
            clipped[y * w + 8] = true;
            clipped[y * w + 14] = true;
        }
        for x in 8..=14 {
            clipped[w + x] = true;
        }
        // The loop alone (the right side lit normally, touched but for its middle): it
        // stays out.
        let mut alone = touched.clone();
        let mut loop_only = clipped.clone();
        for y in 10..=25 {
            alone[y * w + 20] = !(14..=21).contains(&y);
            loop_only[y * w + 20] = false;
        }
        join_clipped_neighbours(&mut alone, &loop_only, w, h);
        join_enclosing_clipped(&mut alone, &loop_only, 3, w, h);
        assert!(
            !alone[w + 11],
            "a loop enclosing a pocket outside the box stays out"
        );
        join_clipped_neighbours(&mut touched, &clipped, w, h);
        assert!(!touched[17 * w + 20] && !touched[w + 11]);
        join_enclosing_clipped(&mut touched, &clipped, 3, w, h);
        assert!(
            (10..=25).all(|y| touched[y * w + 20]),
            "the whole arc joins"
        );
        assert!(
            !touched[w + 11] && !touched[3 * w + 8] && !touched[3 * w + 14],
            "the loop joins only as far as the reach"
        );
        let mut blocks = touched.clone();
        fill_holes(&mut blocks, w, h);
        assert!(blocks[17 * w + 12], "the ring's middle is enclosed");
        assert!(!blocks[4 * w + 11], "the pocket above it is not");
    }

    #[test]
    fn regions_hold_the_clipped_blocks_a_contact_takes_in() {
        let (w, h) = (160u32, 96u32);
        let flat = RgbImage::from_pixel(w, h, image::Rgb([120, 30, 120]));
        let refs = block_references(&flat, &flat, 4, Unmix::IDENTITY);
        let (mut dx, mut dy) = (flat.clone(), flat.clone());
        // A contact (x 40..56, y 40..56), and its wall clipped in the dx phase for 3
        // blocks beyond it (x 56..68).
        for y in 40..56 {
            for x in 40..56 {
                dx.put_pixel(x, y, image::Rgb([200, 30, 60]));
            }
            for x in 56..68 {
                dx.get_pixel_mut(x, y).0[0] = 255;
            }
        }
        // Lights clipped in both phases: one beyond the wall, one right below the contact.
        let white = image::Rgb([255, 255, 255]);
        for (xs, ys) in [(68..80, 40..56), (40..44, 56..60)] {
            for y in ys {
                for x in xs.clone() {
                    dx.put_pixel(x, y, white);
                    dy.put_pixel(x, y, white);
                }
            }
        }
        let params = ContactParams::default();
        let filter = ColourFilter::default();
        let d = find_regions(&dx, &dy, &refs, &filter, &params, SolverKind::Dct);
        let touched = |bx: usize, by: usize| d.touched[by * d.blocks_across + bx];
        assert!(
            touched(13, 12) && touched(14, 12) && touched(16, 12),
            "wall joins"
        );
        assert!(
            !touched(17, 12) && !touched(10, 14),
            "lights clipped in both phases stay out"
        );
        // Every touched pixel, grown as reconstruction grows it, lies inside a region.
        assert_eq!(d.regions.len(), 1, "{:?}", d.regions);
        let roi = d.regions[0];
        let inside = d.touched_pixels(&roi, params.dilate_px);
        let wanted = {
            let full = Roi {
                x: 0,
                y: 0,
                width: w as usize,
                height: h as usize,
            };
            d.touched_pixels(&full, params.dilate_px)
        };
        assert_eq!(
            inside.iter().filter(|&&t| t).count(),
            wanted.iter().filter(|&&t| t).count(),
            "region {roi:?} cuts the grown contact"
        );
        assert!(roi.x + roi.width >= 68 + params.dilate_px, "{roi:?}");
    }

    /// The glance answers "at rest" only where the full look finds no contact: faint
    /// presses straddling the threshold, at random places on random skins, are found
    /// alike with and without it; on a skin at rest it answers most pairs alone.
    #[test]
    fn the_glance_misses_no_contact_the_full_look_finds() {
        use crate::rng::Rng;
        for seed in [1u64, 2] {
            let skin = faint_presses::FaintSkin::new(seed);
            let (refs, filter, params) = (&skin.refs, &skin.filter, &skin.params);
            let answered = skin
                .at_rest
                .iter()
                .filter(|p| {
                    let [mx, my] = [&p.dx, &p.dy].map(|img| BlockMeans::of_middle_rows(img, 4));
                    glance(&mx, &my, refs, filter, params).is_some()
                })
                .count();
            assert!(
                answered >= 6,
                "skin {seed}: the glance answered {answered} of 8"
            );
            let mut rng = Rng::new(seed);
            let mut found = 0;
            for k in 0..40u64 {
                let (p, depth) = skin.press(&mut rng, k);
                let full = look_at_every_row(&p.dx, &p.dy, refs, filter, params, SolverKind::Dct);
                let seen = find_regions(&p.dx, &p.dy, refs, filter, params, SolverKind::Dct);
                // The same detection, unlit fractions included: where the budgets say the
                // glance would read every row, the reconstructor looks at every row.
                assert_eq!(seen, full, "skin {seed} press {k} ({depth} mm)");
                found += usize::from(!full.regions.is_empty());
            }
            assert!(
                (10..40).contains(&found),
                "skin {seed}: the presses should straddle the threshold, {found} of 40 found"
            );
        }
    }

    #[test]
    fn neighbours_are_the_eight_around_a_cell_within_the_grid() {
        let w = 5;
        let one = |cells: &[usize]| {
            let mut m = vec![false; w * 4];
            for &c in cells {
                m[c] = true;
            }
            has_neighbours(&m, w)
        };
        assert!(!one(&[]));
        assert!(!one(&[7, 9, 17]), "lone cells");
        // Right, below, below-right, below-left.
        for pair in [[7, 8], [7, 12], [7, 13], [7, 11], [19, 18], [14, 19]] {
            assert!(one(&pair), "{pair:?}");
        }
        // The end of a row and the start of the next are not neighbours.
        assert!(!one(&[4, 5]) && !one(&[9, 10]));
        assert!(!has_neighbours(&[], 0) && !has_neighbours(&[true], 1));
    }

    #[test]
    fn dilate_grows_by_exactly_r() {
        let (w, h) = (9, 7);
        let mut m = vec![false; w * h];
        m[3 * w + 4] = true;
        dilate(&mut m, w, h, 2);
        for y in 0..h {
            for x in 0..w {
                let want = (2..=6).contains(&x) && (1..=5).contains(&y);
                assert_eq!(m[y * w + x], want, "({x},{y})");
            }
        }
        let mut corner = vec![false; 4];
        corner[0] = true;
        dilate(&mut corner, 2, 2, 5);
        assert!(corner.iter().all(|&v| v));
    }

    #[test]
    fn lengths_grow_to_smooth_sizes_inside_the_frame() {
        assert_eq!(fit_length(100, 97, 640, SolverKind::Dct), (99, 100));
        assert_eq!(fit_length(0, 97, 640, SolverKind::Dct), (0, 100));
        assert_eq!(fit_length(600, 40, 640, SolverKind::Dct), (600, 40));
        assert_eq!(fit_length(630, 7, 640, SolverKind::Dct), (630, 8));
        assert_eq!(fit_length(0, 470, 479, SolverKind::Dct), (0, 479));
        assert_eq!(fit_length(10, 101, 640, SolverKind::Dst), (7, 108));
    }
}
