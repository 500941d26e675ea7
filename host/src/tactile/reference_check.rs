//! Whether reference frames given at reconstruction show a press the calibration's own
//! references did not.
//!
//! Reference frames (flat skin, taken now) replace the model's stored background so that
//! light that drifted since calibration does not read as contact. Taken while something
//! touched the skin, they turn that press into a phantom imprint in every frame read
//! against them (0.14–0.46 mm at rest). So they are compared with the model's background
//! by the contact detection itself, with the model's own threshold: where they depart
//! over less than half the frame, and as slopes do ([`Departure`]: a phase's two strips
//! moved opposite ways, and both ways), they show a press and are refused. Light that
//! changed since calibration (exposure, gain, a dimmer LED, the room's light through the
//! skin, dust that darkens it) is what they are for, and passes, as does a departure
//! over most of the frame (another lighting altogether: the frames are read against
//! these references, not the background).

use image::RgbImage;

use super::colour::ColourFilter;
use super::contact::{self, Detection, References, Roi};
use super::model::TactileModel;
use super::poisson::SolverKind;
use super::smooth::BlockMeans;

/// A contact over more than this share of the frame is not taken for a press.
const MAX_PRESS_SHARE: f64 = 0.5;
/// Least share of the departure where a phase's two strips moved opposite ways for a
/// press (see [`Departure`]). Chosen on the tuning families (`bench skins`' `ours-*`):
/// presses 0.94–1.00, the room's light twice as bright 0.00–0.67 (a warm light adds to
/// the red strip's colour and takes from the blue's, as a slope does); the evaluation
/// families' presses read 0.84–1.00.
const MIN_SLOPE_SHARE: f32 = 0.8;
/// Least balance of the two ways of a phase for a press. Chosen on the tuning families:
/// presses 0.72–1.00, the warm light above 0.00; the evaluation families' presses read
/// 0.73–1.00.
const MIN_BALANCE: f32 = 0.35;

/// Where reference frames show a press.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PressSeen {
    /// Centre of its touched blocks, pixels `(x, y)`.
    pub centre: (usize, usize),
    /// Its region of interest (with the detection's margin).
    pub region: Roi,
    /// How the touched blocks depart from the background.
    pub departure: Departure,
}

/// How touched blocks depart from flat skin, in the colours each phase's two strips give
/// (`r`, `b`: 1 on flat skin).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Departure {
    /// Share of the departure (`|r − 1| + |b − 1|`) found where the two strips moved
    /// opposite ways, one brighter and the other darker, as a slope moves them; light
    /// added or taken away (exposure, gain, ambient light) mostly moves both one way.
    pub slope_share: f32,
    /// In the better balanced phase, the smaller of `Σ (r − b)⁺` and `Σ (b − r)⁺` over
    /// the larger: a press slopes both ways (its depth is 0 all round it), tinted light
    /// moves one way only.
    pub balance: f32,
}

impl Departure {
    /// Whether this reads as a press.
    pub fn is_press(&self) -> bool {
        self.slope_share >= MIN_SLOPE_SHARE && self.balance >= MIN_BALANCE
    }
}

/// The region of the references (after ambient removal) that departs from the model's
/// background as a press does, if any: the largest region, when the touched blocks
/// together read as a press.
pub fn press_in_references(
    dx: &RgbImage,
    dy: &RgbImage,
    model: &TactileModel,
    solver: SolverKind,
) -> Option<PressSeen> {
    let (w, h) = (dx.width() as usize, dx.height() as usize);
    let step = model.contact.coarse_step.max(1);
    let background = model
        .background
        .references_at(w, h, step, model.filter.unmix);
    let seen = contact::find_regions(dx, dy, &background, &model.filter, &model.contact, solver);
    if seen.regions.is_empty() {
        return None;
    }
    let touched = seen.touched.iter().filter(|&&t| t).count();
    if touched as f64 > MAX_PRESS_SHARE * seen.touched.len() as f64 {
        return None;
    }
    let departure = departure(dx, dy, &background, &model.filter, &seen);
    if !departure.is_press() {
        return None;
    }
    let region = seen.regions.iter().copied().max_by_key(Roi::area)?;
    // The centre of the touched blocks inside it (the region's margin and its growth to
    // a size the solver takes need not be even on both sides).
    let (mut sx, mut sy, mut n) = (0usize, 0usize, 0usize);
    for (i, _) in seen.touched.iter().enumerate().filter(|(_, t)| **t) {
        let x = (i % seen.blocks_across) * step + step / 2;
        let y = (i / seen.blocks_across) * step + step / 2;
        let inside = (region.x..region.x + region.width).contains(&x)
            && (region.y..region.y + region.height).contains(&y);
        if inside {
            (sx, sy, n) = (sx + x, sy + y, n + 1);
        }
    }
    let centre = sx
        .checked_div(n)
        .zip(sy.checked_div(n))
        .unwrap_or((region.x + region.width / 2, region.y + region.height / 2));
    Some(PressSeen {
        centre,
        region,
        departure,
    })
}

/// [`Departure`] of the touched blocks of `seen`.
fn departure(
    dx: &RgbImage,
    dy: &RgbImage,
    background: &References,
    filter: &ColourFilter,
    seen: &Detection,
) -> Departure {
    let (mx, my) = (BlockMeans::of(dx, seen.step), BlockMeans::of(dy, seen.step));
    let (mut opposite, mut total) = (0.0f32, 0.0f32);
    // Per phase, Σ (r − b)⁺ and Σ (b − r)⁺.
    let mut ways = [[0.0f32; 2]; 2];
    let n = mx.len().min(my.len());
    for (i, _) in seen
        .touched
        .iter()
        .enumerate()
        .filter(|(i, t)| **t && *i < n)
    {
        let (c, _) = contact::colours_of(background, filter, i, mx.mean(i), my.mean(i));
        for (phase, (r, b)) in [(c[0], c[1]), (c[2], c[3])].into_iter().enumerate() {
            if r.is_finite() && b.is_finite() {
                let d = (r - 1.0).abs() + (b - 1.0).abs();
                total += d;
                if (r - 1.0) * (b - 1.0) < 0.0 {
                    opposite += d;
                }
                ways[phase][0] += (r - b).max(0.0);
                ways[phase][1] += (b - r).max(0.0);
            }
        }
    }
    let balance = |[a, b]: [f32; 2]| {
        let most = a.max(b);
        if most > 0.0 { a.min(b) / most } else { 0.0 }
    };
    Departure {
        slope_share: if total > 0.0 { opposite / total } else { 0.0 },
        balance: balance(ways[0]).max(balance(ways[1])),
    }
}
