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

use super::colour::{ColourFilter, Reference};
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

/// The deviation from flat skin of every block of a pair's block means; NaN (unknown)
/// where a block has clipped pixels.
pub fn block_deviations(
    dx: &BlockMeans,
    dy: &BlockMeans,
    block_refs: &References,
    filter: &ColourFilter,
) -> Vec<f32> {
    dx.means
        .iter()
        .zip(&dy.means)
        .enumerate()
        .map(|(i, (a, b))| {
            if dx.clipped[i] > 0 || dy.clipped[i] > 0 {
                f32::NAN
            } else {
                colours_of(block_refs, filter, i, *a, *b).1
            }
        })
        .collect()
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
    /// Fraction of blocks where the colour filter accepted neither phase (no LED light,
    /// saturated, white light): above a half, the frames are not lit phase images.
    pub unlit_fraction: f32,
}

impl Detection {
    /// The touched flags of the blocks that pixel row `y` crosses (block `x / step` for
    /// pixel column `x`).
    #[inline]
    pub fn touched_row(&self, y: usize) -> &[bool] {
        let start = y / self.step.max(1) * self.blocks_across;
        &self.touched[start..start + self.blocks_across]
    }
}

/// Finds the regions of interest around contacts from the images' block means, compared
/// with `block_refs` (references at block resolution, [`block_references`]); no regions
/// when nothing touches the skin. Images must have the model's size (checked by the
/// caller).
pub fn find_regions(
    dx: &RgbImage,
    dy: &RgbImage,
    block_refs: &References,
    filter: &ColourFilter,
    params: &ContactParams,
    solver: SolverKind,
) -> Detection {
    let (w, h) = (dx.width() as usize, dx.height() as usize);
    let step = params.coarse_step.max(1);
    let (mx, my) = (BlockMeans::of(dx, step), BlockMeans::of(dy, step));
    let (gw, gh) = (mx.width, mx.height);
    let mut unlit = 0usize;
    let marked: Vec<bool> = mx
        .means
        .iter()
        .zip(&my.means)
        .enumerate()
        .map(|(i, (a, b))| {
            let (colour, d) = colours_of(block_refs, filter, i, *a, *b);
            unlit += usize::from(colour[0].is_nan() && colour[2].is_nan());
            // A block with clipped pixels has a mean that says nothing about the light
            // (a bright spot or overexposure there): it cannot show contact.
            d > params.threshold && mx.clipped[i] == 0 && my.clipped[i] == 0
        })
        .collect();
    let mut detection = Detection {
        regions: Vec::new(),
        step,
        blocks_across: gw,
        touched: vec![false; gw * gh],
        unlit_fraction: unlit as f32 / (gw * gh).max(1) as f32,
    };
    if !marked.iter().any(|&m| m) {
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
    let mut regions: Vec<Roi> = components
        .iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(c, _)| {
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

/// References at block resolution from no-contact frames.
pub fn block_references(dx: &RgbImage, dy: &RgbImage, step: usize) -> References {
    let (a, b) = (BlockMeans::of(dx, step), BlockMeans::of(dy, step));
    References {
        dx: Reference::from_means(a.width, a.height, &a.means),
        dy: Reference::from_means(b.width, b.height, &b.means),
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
            for ny in y.saturating_sub(1)..=(y + 1).min(h - 1) {
                for nx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
                    let j = ny * w + nx;
                    if mask[j] && labels[j] == 0 {
                        labels[j] = id;
                        stack.push(j);
                    }
                }
            }
        }
        out.push(c);
    }
    (labels, out)
}

/// Sets every unset pixel not 4-connected to the frame border through unset pixels.
pub(crate) fn fill_holes(mask: &mut [bool], w: usize, h: usize) {
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
        let mut visit = |j: usize| {
            if !mask[j] && !outside[j] {
                outside[j] = true;
                stack.push(j);
            }
        };
        if x > 0 {
            visit(i - 1);
        }
        if x + 1 < w {
            visit(i + 1);
        }
        if y > 0 {
            visit(i - w);
        }
        if y + 1 < h {
            visit(i + w);
        }
    }
    for (m, o) in mask.iter_mut().zip(&outside) {
        *m = !*o;
    }
}

/// Grows a `w × h` mask by `r` pixels (square structuring element), in place.
pub fn dilate(mask: &mut [bool], w: usize, h: usize, r: usize) {
    if r == 0 || w == 0 || h == 0 {
        return;
    }
    let mut tmp = vec![false; mask.len()];
    // Rows: a pixel is set when any pixel within ±r in its row is.
    for y in 0..h {
        let row = &mask[y * w..(y + 1) * w];
        let out = &mut tmp[y * w..(y + 1) * w];
        let mut last_set: Option<usize> = None;
        for x in 0..(w + r) {
            if x < w && row[x] {
                last_set = Some(x);
            }
            if x >= r
                && let Some(s) = last_set
                && x - s <= 2 * r
            {
                out[x - r] = true;
            }
        }
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

#[cfg(test)]
mod tests {
    use super::*;

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
