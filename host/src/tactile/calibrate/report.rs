//! What a calibration tells its user besides the model: how well the model fits in each
//! part of the frame, which slopes and places the presses covered, warnings where they
//! left gaps, and overlay images of each fitted circle.

use image::RgbImage;
use serde::Serialize;

use super::threshold::{FlatSkinNoise, MAX_THRESHOLD};
use super::{Circle, PressFit, RejectedPress};
use crate::tactile::model::{Sample, TactileModel};

/// The frame is judged in this many regions across and down.
pub const REGIONS: usize = 3;
/// Slopes below this never seen: steeper walls are extrapolated.
pub const STEEP_SLOPE: f32 = 0.8;
/// Slopes up to this taught: a note says how walls steeper than the steepest taught
/// read, and how to teach them (the goal table's steep wall is 1.31).
pub const TAUGHT_STEEP_SLOPE: f32 = 1.2;
/// Presses suggested for a good model.
const SUGGESTED_PRESSES: usize = 10;
/// A press counts as near an edge when its centre is within this fraction of the frame.
const EDGE_FRACTION: f64 = 0.15;
/// A press is called saturated when this fraction of its contact is, in either phase. On
/// the tuning skins presses saturated up to 8 % did no measurable harm (our nominal skin's
/// steepest walls facing a strip saturate 5–8 % of a contact, `ours-random` skin 4's 7 %),
/// while with `ours-random` skin 1's (14 %, by the left strip) its edge ball read 7 %
/// short before refused slopes were filled.
pub const SATURATED_FRACTION: f64 = 0.10;

/// The LUT's fit in one region of the frame (both axes together).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RegionFit {
    /// Column (0 = left).
    pub col: usize,
    /// Row (0 = top).
    pub row: usize,
    /// Training and held-out samples in the region.
    pub samples: usize,
    /// RMS slope error of the LUT there.
    pub lut_rms: f32,
}

/// Presses whose centre lies near each edge of the frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct EdgePresses {
    /// Near x = 0.
    pub left: usize,
    /// Near y = 0.
    pub top: usize,
    /// Near x = width.
    pub right: usize,
    /// Near y = height.
    pub bottom: usize,
}

/// The report of one calibration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CalibrationReport {
    /// Presses given.
    pub presses_given: usize,
    /// Presses used.
    pub presses_used: usize,
    /// The contact threshold stored in the model (on detection blocks).
    pub contact_threshold: f32,
    /// The flat skin it was measured on (absent when fixed or not measurable).
    pub flat_skin_noise: Option<FlatSkinNoise>,
    /// The threshold press outlines were found with (on box means around each pixel).
    pub outline_threshold: f32,
    /// LUT fit per region, row by row.
    pub regions: Vec<RegionFit>,
    /// Largest |slope| taught, along x and along y.
    pub max_slope: [f32; 2],
    /// Presses near each edge.
    pub edge_presses: EdgePresses,
    /// Where the presses left gaps or the fit is poor.
    pub warnings: Vec<String>,
}

/// The warning that `count` of `given` presses were set aside.
fn set_aside_warning(count: usize, given: usize) -> String {
    format!("{count} of {given} presses set aside (reasons listed per press)")
}

impl CalibrationReport {
    /// The report of a calibration made again without some of the `given` presses: it
    /// counts them all, and `rejected` set aside.
    pub(super) fn count_all(&mut self, given: usize, rejected: usize) {
        let said = |w: &String| w.ends_with("presses set aside (reasons listed per press)");
        self.warnings.retain(|w| !said(w));
        self.presses_given = given;
        if rejected > 0 {
            self.warnings.push(set_aside_warning(rejected, given));
        }
    }

    /// Builds the report; `samples` are every training and held-out sample per axis.
    pub(super) fn new(
        model: &TactileModel,
        presses: &[PressFit],
        rejected: &[RejectedPress],
        given: usize,
        min_presses: usize,
        (outline_threshold, noise): (f32, Option<FlatSkinNoise>),
        samples: &[Vec<Sample>; 2],
    ) -> Self {
        let mut warnings = Vec::new();
        let used = presses.len();
        if used < SUGGESTED_PRESSES {
            warnings.push(format!(
                "only {used} presses used (minimum {min_presses}): {SUGGESTED_PRESSES}-30 presses spread over the frame give a better model"
            ));
        }
        if !rejected.is_empty() {
            warnings.push(set_aside_warning(rejected.len(), given));
        }
        let threshold = model.contact.threshold;
        if let Some(n) = noise.filter(|n| n.unbounded > MAX_THRESHOLD) {
            let held = if n.p9999 >= MAX_THRESHOLD {
                "a skin at rest will read as contact in places"
            } else {
                "less margin over the noise, and light contact will be missed"
            };
            warnings.push(format!(
                "flat skin departs from the references by up to {:.2} (99.99th percentile), so its contact threshold would be {:.2}, above the {MAX_THRESHOLD} allowed (held there: {held}): are the reference frames from this sensor and these lights, and is the LED light bright enough (dim light makes the colours noisy)?",
                n.p9999, n.unbounded
            ));
        }

        // Fit per region.
        let mut sums = [(0usize, 0.0f64); REGIONS * REGIONS];
        for (axis, set) in samples.iter().enumerate() {
            let axis_model = if axis == 0 { &model.dx } else { &model.dy };
            for s in set {
                let col = ((s.features[2] * REGIONS as f32) as usize).min(REGIONS - 1);
                let row = ((s.features[3] * REGIONS as f32) as usize).min(REGIONS - 1);
                let f = s.features;
                let e = (axis_model.lut.eval(f[0], f[1], f[2], f[3]) - s.target) as f64;
                let cell = &mut sums[row * REGIONS + col];
                cell.0 += 1;
                cell.1 += e * e;
            }
        }
        let regions: Vec<RegionFit> = sums
            .iter()
            .enumerate()
            .map(|(i, &(n, sq))| RegionFit {
                col: i % REGIONS,
                row: i / REGIONS,
                samples: n,
                lut_rms: if n > 0 {
                    (sq / n as f64).sqrt() as f32
                } else {
                    0.0
                },
            })
            .collect();
        let mut rms: Vec<f32> = regions
            .iter()
            .filter(|r| r.samples > 0)
            .map(|r| r.lut_rms)
            .collect();
        rms.sort_by(f32::total_cmp);
        let typical = rms.get(rms.len() / 2).copied().unwrap_or(0.0);
        for r in &regions {
            let name = region_name(r.col, r.row);
            if r.samples == 0 {
                warnings.push(format!(
                    "no press in the {name} region: the model is extrapolated there"
                ));
            } else if r.lut_rms > 2.0 * typical && r.lut_rms > 0.05 {
                warnings.push(format!(
                    "the fit is poor in the {name} region (slope RMS {:.3}, {typical:.3} typical)",
                    r.lut_rms
                ));
            }
        }

        let max_slope = [0, 1].map(|axis| {
            samples[axis]
                .iter()
                .map(|s| s.target.abs())
                .fold(0.0f32, f32::max)
        });
        for (axis, m) in ["x", "y"].iter().zip(max_slope) {
            if m < STEEP_SLOPE {
                warnings.push(format!(
                    "slopes along {axis} above {m:.2} were never seen: steeper walls will read shallow (press deeper, or add presses of a smaller ball with --with-ball; in Python, press_balls_mm)"
                ));
            }
        }
        let (least_axis, least) = if max_slope[1] < max_slope[0] {
            ("y", max_slope[1])
        } else {
            ("x", max_slope[0])
        };
        if (STEEP_SLOPE..TAUGHT_STEEP_SLOPE).contains(&least) {
            let smallest = presses
                .iter()
                .map(|p| p.ball_diameter_mm)
                .fold(f64::INFINITY, f64::min);
            let fix = if smallest < model.ball_diameter_mm {
                format!("press the {smallest} mm ball deeper, or add presses of a smaller one")
            } else {
                "add presses of a smaller ball (--with-ball 4:DIR; in Python, press_balls_mm) to teach steeper slopes".to_string()
            };
            warnings.push(format!(
                "the steepest slope taught along {least_axis} is {least:.2}: walls steeper than that read short, or from the light model's straight lines past the lookup table's reach (on our evaluation skins a 1 mm disk with a wall of 1.31 read 0.79-1.05 mm from an 8 or 6 mm ball alone, 0.84-1.08 mm with half the presses made with a 4 mm ball); {fix}"
            ));
        }
        // Shallow slopes also come from a ball given larger than it is: its circles then
        // mean shallower presses than were made, and every depth reads shallow. Only the
        // user knows how deep they pressed. Judged per ball: the presses of a second,
        // smaller ball teach steep slopes whatever the first one's diameter says.
        warnings.extend(press_depth_warnings(presses, model.px_per_mm));

        warnings.extend(saturation_warning(presses));

        let (w, h) = (model.width as f64, model.height as f64);
        let mut edges = EdgePresses::default();
        for p in presses {
            let c = p.circle;
            edges.left += usize::from(c.cx < EDGE_FRACTION * w);
            edges.right += usize::from(c.cx > (1.0 - EDGE_FRACTION) * w);
            edges.top += usize::from(c.cy < EDGE_FRACTION * h);
            edges.bottom += usize::from(c.cy > (1.0 - EDGE_FRACTION) * h);
        }
        for (name, n) in [
            ("left", edges.left),
            ("top", edges.top),
            ("right", edges.right),
            ("bottom", edges.bottom),
        ] {
            if n == 0 {
                warnings.push(format!(
                    "no press near the {name} edge: depth there relies on the rest of the frame"
                ));
            }
        }
        Self {
            presses_given: given,
            presses_used: used,
            contact_threshold: threshold,
            flat_skin_noise: noise,
            outline_threshold,
            regions,
            max_slope,
            edge_presses: edges,
            warnings,
        }
    }
}

/// How deep the presses' circles say they went, for the user to hold against what they
/// did (a ball given larger than it is fits the same circles with shallower presses):
/// one warning per ball whose presses' steepest rim slope is under [`STEEP_SLOPE`].
fn press_depth_warnings(presses: &[PressFit], px_per_mm: f64) -> Vec<String> {
    let mut balls: Vec<f64> = presses.iter().map(|p| p.ball_diameter_mm).collect();
    balls.sort_by(f64::total_cmp);
    balls.dedup();
    let two = balls.len() > 1;
    balls
        .into_iter()
        .filter_map(|ball| {
            let of_ball = || presses.iter().filter(move |p| p.ball_diameter_mm == ball);
            let radius_px = ball / 2.0 * px_per_mm;
            let steepest = of_ball()
                .map(|p| {
                    let r = p.circle.r.min(radius_px);
                    r / (radius_px * radius_px - r * r).sqrt()
                })
                .filter(|s| s.is_finite())
                .fold(0.0f64, f64::max);
            if steepest >= STEEP_SLOPE as f64 {
                return None;
            }
            let depths = of_ball().map(|p| p.depth_mm).filter(|d| d.is_finite());
            let (lo, hi) = depths.fold((f64::INFINITY, 0.0f64), |(lo, hi), d| {
                (lo.min(d), hi.max(d))
            });
            (lo <= hi).then(|| {
                let (given, flag) = if two {
                    (format!("the {ball} mm ball given"), "its --ball-diameter-mm or --with-ball (in Python, ball_diameter_mm or press_balls_mm)")
                } else {
                    ("the ball diameter given".to_string(), "--ball-diameter-mm (in Python, ball_diameter_mm)")
                };
                format!(
                    "with {given}, the presses' circles mean presses {lo:.2}-{hi:.2} mm deep: if they went deeper, the ball is smaller than {flag} says and every depth will read shallow"
                )
            })
        })
        .collect()
}

/// The warning when presses saturate the camera inside their contact: the user can fix
/// it (exposure, LED brightness), and the pixels cost the model the steepest slopes it
/// would learn there.
fn saturation_warning(presses: &[PressFit]) -> Option<String> {
    let worst_phase = |p: &PressFit| p.saturated[0].max(p.saturated[1]);
    let count = presses
        .iter()
        .filter(|p| worst_phase(p) >= SATURATED_FRACTION)
        .count();
    let worst = presses
        .iter()
        .max_by(|a, b| worst_phase(a).total_cmp(&worst_phase(b)))?;
    if count == 0 {
        return None;
    }
    let phase = if worst.saturated[0] >= worst.saturated[1] {
        "dx"
    } else {
        "dy"
    };
    Some(format!(
        "{count} of {} presses saturate the camera in {:.0}% or more of their contact (worst: {} at ({:.0}, {:.0}) px, {:.0}% in the {phase} frame): the colour there says nothing reliable about the slope, so the model does not learn the steep walls facing a strip there, and such pixels are filled from their neighbours when measuring; lower the camera's exposure or the LEDs' brightness",
        presses.len(),
        100.0 * SATURATED_FRACTION,
        worst.name,
        worst.circle.cx,
        worst.circle.cy,
        100.0 * worst_phase(worst),
    ))
}

fn region_name(col: usize, row: usize) -> String {
    let v = ["top", "middle", "bottom"][row.min(2)];
    let h = ["left", "centre", "right"][col.min(2)];
    if row == 1 && col == 1 {
        "centre".to_string()
    } else {
        format!("{v}-{h}")
    }
}

/// The dx image with the fitted circle drawn on it (solid green when the press was used,
/// dashed white when set aside: magenta, tried first, vanished on the red and blue of a
/// dx frame), each line between black edges so it shows on any colour, and a cross at
/// its centre, to check fits by eye.
pub fn overlay(dx: &RgbImage, circle: Option<&Circle>, used: bool) -> RgbImage {
    let mut out = dx.clone();
    let Some(c) = circle else { return out };
    if !(c.cx.is_finite() && c.cy.is_finite() && c.r.is_finite()) {
        return out;
    }
    let colour = if used {
        image::Rgb([0, 255, 0])
    } else {
        image::Rgb([255, 255, 255])
    };
    let edge = image::Rgb([0, 0, 0]);
    let (w, h) = (out.width() as i64, out.height() as i64);
    let mut put = |x: f64, y: f64, colour| {
        let (x, y) = (x.round() as i64, y.round() as i64);
        if (0..w).contains(&x) && (0..h).contains(&y) {
            out.put_pixel(x as u32, y as u32, colour);
        }
    };
    let steps = ((c.r * 8.0).ceil() as usize).clamp(16, 20_000);
    // A step is about 0.8 px of arc: set aside, dashes and gaps of ten steps (8 px).
    let drawn = |k: usize| used || (k / 10).is_multiple_of(2);
    for pass in [0, 1] {
        for k in (0..steps).filter(|&k| drawn(k)) {
            let a = std::f64::consts::TAU * k as f64 / steps as f64;
            let (cos, sin) = (a.cos(), a.sin());
            if pass == 0 {
                // The black edges first, the line over them.
                for r in [c.r - 1.0, c.r + 1.0] {
                    put(c.cx + r * cos, c.cy + r * sin, edge);
                }
            } else {
                put(c.cx + c.r * cos, c.cy + c.r * sin, colour);
            }
        }
    }
    for d in -4..=4 {
        put(c.cx + d as f64, c.cy, colour);
        put(c.cx, c.cy + d as f64, colour);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overlays_draw_inside_the_frame_only() {
        let img = RgbImage::new(40, 30);
        let c = Circle {
            cx: 35.0,
            cy: 15.0,
            r: 10.0,
        };
        let o = overlay(&img, Some(&c), true);
        assert_eq!(o.get_pixel(25, 15).0, [0, 255, 0]);
        assert_eq!(o.get_pixel(35, 15).0, [0, 255, 0], "centre cross");
        assert_eq!(o.get_pixel(5, 5).0, [0, 0, 0]);
        // Black edges either side of the line.
        assert_eq!(o.get_pixel(24, 15).0, [0, 0, 0]);
        let grey = RgbImage::from_pixel(40, 30, image::Rgb([200, 60, 90]));
        let g = overlay(&grey, Some(&c), true);
        assert_eq!(g.get_pixel(24, 15).0, [0, 0, 0], "edge");
        assert_eq!(g.get_pixel(26, 15).0, [0, 0, 0], "edge");
        // Set aside: white and dashed (some of the circle is drawn, some not).
        let r = overlay(&grey, Some(&c), false);
        assert_eq!(r.get_pixel(25, 15).0, [255, 255, 255]);
        let on_circle: Vec<[u8; 3]> = (0..64)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 64.0;
                let (x, y) = (35.0 + 10.0 * a.cos(), 15.0 + 10.0 * a.sin());
                (x.round() as u32, y.round() as u32)
            })
            .filter(|&(x, y)| x < 40 && y < 30)
            .map(|(x, y)| r.get_pixel(x, y).0)
            .collect();
        assert!(on_circle.contains(&[255, 255, 255]), "{on_circle:?}");
        assert!(on_circle.contains(&[200, 60, 90]), "gaps: {on_circle:?}");
        let nan = Circle { r: f64::NAN, ..c };
        assert_eq!(overlay(&img, Some(&nan), true), img);
        assert_eq!(overlay(&img, None, true), img);
        assert_eq!(region_name(0, 0), "top-left");
        assert_eq!(region_name(1, 1), "centre");
    }

    fn press(name: &str, saturated: [f64; 2]) -> PressFit {
        PressFit {
            name: name.to_string(),
            circle: Circle {
                cx: 40.0,
                cy: 200.0,
                r: 30.0,
            },
            depth_mm: 1.0,
            overridden: false,
            fit_rms_px: 0.5,
            ball_diameter_mm: 6.0,
            saturated,
        }
    }

    #[test]
    fn saturated_presses_are_counted_and_the_worst_named() {
        assert_eq!(saturation_warning(&[]), None);
        let fine = [press("a", [0.0, 0.0]), press("b", [0.09, 0.05])];
        assert_eq!(saturation_warning(&fine), None, "below the line");
        let some = [
            press("a", [0.0, 0.0]),
            press("b", [0.12, 0.0]),
            press("c", [0.0, SATURATED_FRACTION]),
            press("d", [0.05, 0.31]),
        ];
        let w = saturation_warning(&some).expect("three presses at or over the line");
        assert!(w.starts_with("3 of 4 presses"), "{w}");
        assert!(
            w.contains("worst: d at (40, 200) px, 31% in the dy frame"),
            "{w}"
        );
        assert!(w.contains("exposure"), "{w}");
    }

    /// The presses' depths, from the shallowest to the deepest, and the ball named; per
    /// ball, and only for a ball whose presses make no slope of 0.8 at their rim.
    #[test]
    fn press_depths_are_said_with_the_ball_as_a_cause() {
        assert!(press_depth_warnings(&[], 15.0).is_empty());
        let mut presses = [
            press("a", [0.0; 2]),
            press("b", [0.0; 2]),
            press("c", [0.0; 2]),
        ];
        for (p, d) in presses.iter_mut().zip([0.5, 0.36, f64::NAN]) {
            p.depth_mm = d;
        }
        // Circles of 30 px from a 6 mm ball at 30 px/mm: rim slope 0.35.
        let w = press_depth_warnings(&presses, 30.0);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(w[0].contains("presses 0.36-0.50 mm deep"), "{}", w[0]);
        assert!(
            w[0].contains("--ball-diameter-mm") && w[0].contains("Python, ball_diameter_mm"),
            "{}",
            w[0]
        );
        // At 15 px/mm the same circles make slope 0.89: nothing to say.
        assert!(press_depth_warnings(&presses, 15.0).is_empty());
        // A second, smaller ball (rim slope 1.33) is not held against the first.
        let mut two = presses.to_vec();
        let mut small = press("s", [0.0; 2]);
        (small.ball_diameter_mm, small.depth_mm) = (2.5, 0.8);
        two.push(small);
        let w = press_depth_warnings(&two, 30.0);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].contains("the 6 mm ball given")
                && w[0].contains("0.36-0.50")
                && w[0].contains("--with-ball"),
            "{}",
            w[0]
        );
    }
}
