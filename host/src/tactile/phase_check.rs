//! Do two images look like this sensor's dx and dy phases? Checked on the no-contact
//! references before anything is calibrated or reconstructed against them, so a black,
//! white or unlit frame, or dx and dy given the wrong way round, is refused with the
//! reason instead of turning into plausible-looking depth.
//!
//! In the dx phase strip 1 (x−) is blue and strip 3 (x+) red, so red minus blue grows
//! from the left of the frame to the right; in the dy phase it grows from top to bottom.
//! Both phases show LED light (red or blue above green) over most of the frame.

use image::RgbImage;

use super::colour::ColourFilter;
use super::smooth::BlockMeans;

/// Least fraction of the frame that must show LED light.
pub const MIN_LIT_FRACTION: f32 = 0.5;
/// Least red-minus-blue change across the frame for its direction to count (DN).
const MIN_BALANCE_DN: f32 = 8.0;

/// What is wrong with a pair of phase images.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PhaseImageError {
    /// Too little of the frame shows LED light (black, white, saturated or unlit).
    #[error(
        "{what} {phase}: only {:.0}% of the frame shows LED light (red or blue above green, unsaturated, not mostly white light; at least {:.0}% expected): is it black, white, overexposed, taken with the LEDs off, or is other light stronger than the LEDs'?",
        lit * 100.0,
        MIN_LIT_FRACTION * 100.0
    )]
    Unlit {
        /// Which images ("reference frames", "calibration press NAME").
        what: String,
        /// "dx" or "dy".
        phase: &'static str,
        /// Fraction of the frame lit.
        lit: f32,
    },
    /// dx's red-blue balance runs top to bottom and dy's left to right.
    #[error(
        "{what}: the dx image's colour changes from top to bottom and the dy image's from left to right: dx and dy look swapped (dx has strips 1 and 3, on the left and right, lit)"
    )]
    Swapped {
        /// Which images.
        what: String,
    },
    /// Both images' red-blue balance runs the same way: one image of one phase given
    /// twice, or two frames of the same phase.
    #[error(
        "{what}: the dx and dy images both change colour from {direction}, as {phase} does: \
         they look like two images of the {phase} phase (the same file given twice, or two \
         frames of one phase); give one frame of each phase (dx: strips 1 and 3, left and \
         right, lit; dy: strips 2 and 4, top and bottom)"
    )]
    SamePhase {
        /// Which images.
        what: String,
        /// "left to right" or "top to bottom".
        direction: &'static str,
        /// The phase both look like.
        phase: &'static str,
    },
}

/// Summary of one phase image: lit fraction and how red minus blue changes across it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhaseLook {
    /// Fraction of 8×8 blocks with LED light the colour filter accepts.
    pub lit: f32,
    /// Mean red minus blue of the right third minus the left third (DN).
    pub across: f32,
    /// Mean red minus blue of the bottom third minus the top third (DN).
    pub down: f32,
}

/// Looks at one phase image.
pub fn look(image: &RgbImage, filter: &ColourFilter) -> PhaseLook {
    let b = BlockMeans::of(image, 8);
    let sat = f32::from(filter.saturation);
    let mut lit = 0usize;
    let (mut thirds_x, mut thirds_y) = ([(0.0f32, 0usize); 3], [(0.0f32, 0usize); 3]);
    for (i, [r, g, bl]) in (0..b.len()).map(|i| (i, b.mean(i))) {
        let (x, y) = (i % b.width, i / b.width);
        // The colour filter's rules that need no reference (the green rise is measured
        // against these frames): the same as make a pair's frame unlit in
        // reconstruction, so references that pass here are not refused there.
        if (r - g).max(bl - g) >= filter.min_led
            && r.max(g).max(bl) < sat
            && g <= filter.max_white_ratio * r.max(bl)
        {
            lit += 1;
        }
        let tx = (x * 3 / b.width.max(1)).min(2);
        let ty = (y * 3 / b.height.max(1)).min(2);
        thirds_x[tx].0 += r - bl;
        thirds_x[tx].1 += 1;
        thirds_y[ty].0 += r - bl;
        thirds_y[ty].1 += 1;
    }
    // Across a frame too narrow for three thirds (fewer than three blocks) the balance
    // is unknown: 0, not one third's mean against an empty one's.
    let change = |t: &[(f32, usize); 3]| {
        if t[0].1 > 0 && t[2].1 > 0 {
            t[2].0 / t[2].1 as f32 - t[0].0 / t[0].1 as f32
        } else {
            0.0
        }
    };
    PhaseLook {
        lit: lit as f32 / b.len().max(1) as f32,
        across: change(&thirds_x),
        down: change(&thirds_y),
    }
}

/// Checks that `dx` and `dy` look like the two phases; `what` names them in errors.
pub fn check_pair(
    dx: &RgbImage,
    dy: &RgbImage,
    filter: &ColourFilter,
    what: &str,
) -> Result<(), PhaseImageError> {
    let (a, b) = (look(dx, filter), look(dy, filter));
    for (phase, l) in [("dx", a), ("dy", b)] {
        if l.lit < MIN_LIT_FRACTION {
            return Err(PhaseImageError::Unlit {
                what: what.to_string(),
                phase,
                lit: l.lit,
            });
        }
    }
    let strong = |l: PhaseLook| l.across.abs().max(l.down.abs()) >= MIN_BALANCE_DN;
    let dx_vertical = strong(a) && a.down.abs() > a.across.abs();
    let dy_horizontal = strong(b) && b.across.abs() > b.down.abs();
    if dx_vertical && dy_horizontal {
        return Err(PhaseImageError::Swapped {
            what: what.to_string(),
        });
    }
    let (dx_horizontal, dy_vertical) = (strong(a) && !dx_vertical, strong(b) && !dy_horizontal);
    let same = match (dx_horizontal && dy_horizontal, dx_vertical && dy_vertical) {
        (true, _) => Some(("left to right", "dx")),
        (_, true) => Some(("top to bottom", "dy")),
        _ => None,
    };
    if let Some((direction, phase)) = same {
        return Err(PhaseImageError::SamePhase {
            what: what.to_string(),
            direction,
            phase,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tactile::render::{Optics, Scene, render};

    #[test]
    fn real_phases_pass_and_bad_ones_are_named() {
        let o = Optics::sized(160, 120);
        let p = render(&o, &Scene::default(), 1);
        let f = ColourFilter::default();
        check_pair(&p.dx, &p.dy, &f, "refs").unwrap();
        let l = look(&p.dx, &f);
        assert!(
            l.across > 10.0 && l.down.abs() < 2.0 && l.lit > 0.9,
            "{l:?}"
        );
        assert!(matches!(
            check_pair(&p.dy, &p.dx, &f, "refs"),
            Err(PhaseImageError::Swapped { .. })
        ));
        // One phase given twice, either one.
        for (img, phase) in [(&p.dx, "dx"), (&p.dy, "dy")] {
            let e = check_pair(img, img, &f, "refs").unwrap_err();
            assert!(
                matches!(e, PhaseImageError::SamePhase { phase: p, .. } if p == phase),
                "{e}"
            );
        }
        let black = RgbImage::new(160, 120);
        let white = RgbImage::from_pixel(160, 120, image::Rgb([255, 255, 255]));
        let grey = RgbImage::from_pixel(160, 120, image::Rgb([90, 90, 90]));
        // LED light above green, but green as bright as it: white light the colour
        // filter rejects (reconstruction would call every pair unlit).
        let whitish = RgbImage::from_pixel(160, 120, image::Rgb([200, 125, 100]));
        assert!(
            200.0 - 125.0 >= f.min_led && 125.0 > f.max_white_ratio * 200.0,
            "the test's colour must pass the LED rule and fail the white one"
        );
        for bad in [&black, &white, &grey, &whitish] {
            let e = check_pair(&p.dx, bad, &f, "refs").unwrap_err();
            assert!(
                matches!(e, PhaseImageError::Unlit { phase: "dy", .. }),
                "{e}"
            );
        }
        assert!(
            check_pair(&black, &p.dy, &f, "refs")
                .unwrap_err()
                .to_string()
                .contains("refs dx")
        );
    }
}
