//! The contact threshold from the data: how far flat skin's colour strays from the
//! reference in these very frames (noise, compression, light that drifts), rather than a
//! constant tuned on one renderer.
//!
//! Every calibration frame is mostly flat skin. Two thresholds are measured, each on the
//! quantity it judges: one for press outlines, on the mean colour of a small box around
//! each pixel ([`outline_map`]), and the one stored in the model for detection, on the
//! mean colour of detection blocks ([`block_map`]). For each, a provisional threshold
//! ([`provisional`]: a multiple of the frames' 90th-percentile deviation) finds the
//! presses, and the final one ([`from_flat_skin`]) is a margin above the 99.99th
//! percentile of the deviation over flat skin well away from every fitted press, so a
//! skin at rest stays below it almost everywhere, and detection (which needs several
//! neighbouring blocks) never fires on noise.

use crate::tactile::colour::ColourFilter;
use crate::tactile::contact::{self, References};
use crate::tactile::smooth::{BlockMeans, box_means};

use super::{CalibrationPair, Circle};

/// Lowest threshold ever used (normalised-colour units): below it, quantisation alone
/// (1 DN in 100) would mark pixels.
pub const MIN_THRESHOLD: f32 = 0.04;
/// Highest threshold: above it only the steepest slopes would be seen at all; a skin
/// this noisy is reported rather than silently accepted.
pub const MAX_THRESHOLD: f32 = 0.6;
/// Margin over the flat skin's 99.99th percentile.
const MARGIN: f32 = 1.5;
/// Pixels this far outside a fitted press count as flat (px, beyond its radius).
pub const FLAT_CLEARANCE_PX: f64 = 20.0;

/// Radius of the box around each pixel whose mean colour outlines a press (px).
pub const OUTLINE_BOX_RADIUS: usize = 2;

/// The deviation from flat skin of the mean colour around every pixel of a pair (see
/// [`contact::colours_of`]); NaN where the colour filter rejects either phase (the
/// pixel's state is unknown).
pub fn outline_map(pair: &CalibrationPair, refs: &References, filter: &ColourFilter) -> Vec<f32> {
    let dx = box_means(&pair.dx, OUTLINE_BOX_RADIUS);
    let dy = box_means(&pair.dy, OUTLINE_BOX_RADIUS);
    dx.iter()
        .zip(&dy)
        .enumerate()
        .map(|(i, (a, b))| {
            let (colour, d) = contact::colours_of(refs, filter, i, *a, *b);
            if colour.iter().any(|c| c.is_nan()) {
                f32::NAN
            } else {
                d
            }
        })
        .collect()
}

/// The deviation of every detection block of a pair (see [`contact::block_deviations`]).
pub fn block_map(
    pair: &CalibrationPair,
    block_refs: &References,
    filter: &ColourFilter,
    step: usize,
) -> Vec<f32> {
    contact::block_deviations(
        &BlockMeans::of(&pair.dx, step),
        &BlockMeans::of(&pair.dy, step),
        block_refs,
        filter,
    )
}

/// A circle in pixels as seen on a grid of `step`-pixel blocks.
pub fn in_blocks(c: &Circle, step: usize) -> Circle {
    let s = step.max(1) as f64;
    Circle {
        cx: (c.cx + 0.5) / s - 0.5,
        cy: (c.cy + 0.5) / s - 0.5,
        r: c.r / s,
    }
}

/// A first threshold to find the presses with: 4× the 90th percentile of all frames'
/// deviation (contacts cover well under a tenth of a frame), within the bounds.
pub fn provisional(maps: &[Vec<f32>]) -> f32 {
    let sample: Vec<f32> = maps
        .iter()
        .flat_map(|m| m.iter().step_by(7).copied())
        .collect();
    (4.0 * quantile(sample, 0.9)).clamp(MIN_THRESHOLD, MAX_THRESHOLD)
}

/// The statistics behind the final threshold.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct FlatSkinNoise {
    /// Pixels of flat skin sampled.
    pub pixels: usize,
    /// Median deviation of flat skin.
    pub median: f32,
    /// 99.99th percentile.
    pub p9999: f32,
    /// The threshold chosen (before the bounds are applied).
    pub unbounded: f32,
    /// The threshold used.
    pub threshold: f32,
}

/// The final threshold from the cells of `maps` (`w × h` each) farther than `clearance`
/// beyond every circle of their own pair (`circles[k]` for `maps[k]`, in the maps' cells;
/// `None`: the pair's press was not found and the pair is not used). `None` when there
/// is too little flat skin to measure.
pub fn from_flat_skin(
    maps: &[Vec<f32>],
    circles: &[Option<Circle>],
    w: usize,
    h: usize,
    clearance: f64,
) -> Option<FlatSkinNoise> {
    let mut flat = Vec::new();
    for (map, circle) in maps.iter().zip(circles) {
        let Some(c) = circle else { continue };
        let clear = (c.r + clearance).powi(2);
        for (i, &d) in map.iter().enumerate() {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            if (x - c.cx).powi(2) + (y - c.cy).powi(2) > clear && i / w < h {
                flat.push(d);
            }
        }
    }
    if flat.len() < 500 {
        return None;
    }
    let pixels = flat.len();
    let median = quantile(flat.clone(), 0.5);
    let p9999 = quantile(flat, 0.9999);
    let unbounded = MARGIN * p9999;
    Some(FlatSkinNoise {
        pixels,
        median,
        p9999,
        unbounded,
        threshold: unbounded.clamp(MIN_THRESHOLD, MAX_THRESHOLD),
    })
}

/// The `q` quantile (nearest rank) of `v`; 0 for an empty set; NaN values count as 0.
fn quantile(mut v: Vec<f32>, q: f64) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    for x in &mut v {
        if x.is_nan() {
            *x = 0.0;
        }
    }
    let k = ((v.len() - 1) as f64 * q).round() as usize;
    let (_, value, _) = v.select_nth_unstable_by(k, f32::total_cmp);
    *value
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_skin_sets_the_threshold_and_presses_are_left_out() {
        let (w, h) = (100, 100);
        // Flat skin deviates 0.01..0.05; a press of radius 10 at (30, 30) deviates 2.
        let map: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                if (x - 30.0).powi(2) + (y - 30.0).powi(2) < 100.0 {
                    2.0
                } else {
                    0.01 + 0.04 * ((i * 7919) % 1000) as f32 / 1000.0
                }
            })
            .collect();
        let circle = Circle {
            cx: 30.0,
            cy: 30.0,
            r: 10.0,
        };
        let noise =
            from_flat_skin(std::slice::from_ref(&map), &[Some(circle)], w, h, 20.0).unwrap();
        assert!(noise.p9999 <= 0.05 && noise.p9999 > 0.049, "{noise:?}");
        assert!((noise.threshold - 1.5 * noise.p9999).abs() < 1e-6);
        // Without the press's circle there is no flat skin to measure.
        assert!(from_flat_skin(std::slice::from_ref(&map), &[None], w, h, 20.0).is_none());
        let p = provisional(&[map]);
        assert!((MIN_THRESHOLD..=0.25).contains(&p), "{p}");
        assert_eq!(quantile(vec![], 0.5), 0.0);
        assert_eq!(quantile(vec![f32::NAN, 1.0, 2.0], 0.0), 0.0);
    }
}
