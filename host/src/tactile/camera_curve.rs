//! The camera's response curve: measured from flat-skin frames whose light adds up, and
//! undone before anything else reads a frame.
//!
//! Everything after this assumes a linear camera: `R − G` takes the green leak and the
//! room's white light out of the red channel, a LEDs-off frame subtracts the ambient
//! light, and normalising by flat skin takes out each strip's fall-off. A camera that
//! records `v^(1/γ)` (most webcams deliver sRGB, about γ = 2.2) breaks all three: the
//! green and the ambient light no longer cancel, a dim facet reads brighter than its
//! share of the light, and each colour answers the slope less. On our renderer's skins
//! seen by such a camera (tuning family `ours-camera-gamma`) the table read the steep
//! wall 0.88–0.94 mm and set aside genuine presses as "no contact"; with the curve
//! undone, 0.94–1.01 and none.
//!
//! Light adds up where the camera is linear: a flat-skin frame with all four strips lit
//! holds the dx frame's LED light plus the dy frame's, so `all + dark = dx + dy` in every
//! channel (`dark`: the LEDs-off frame, the room's light that each of the four holds
//! once). Recorded through `v^(1/γ)` the values are concave in the light and `all + dark`
//! falls short of `dx + dy`. So `γ` is the power that makes the recorded values, raised to
//! it, add up again: the median over well-lit pixels of `(all^γ + dark^γ − dx^γ − dy^γ) /
//! (dx^γ + dy^γ − 2·dark^γ)` is zero there (it grows with `γ`, and is found by bisection).
//! The exposure's scale cancels (every term scales alike). The curve is undone as
//! `gain · 255 · (v/255)^γ` into 8-bit frames like the camera's: without a gain, flat
//! skin recorded at 110 of 255 through γ = 2.5 would be 30 in linear light, and steps of
//! one count there are 3 % of it (on `ours-camera-gamma` skin 1 that read the gentle disk
//! 1.053 mm instead of 1.016). So the gain puts the references' flat skin at
//! [`FLAT_LINEAR_DN`], where a linear camera's exposure would put it; values that the
//! gain lifts past full scale clip, as a linear camera at that exposure would.

use image::RgbImage;
use serde::{Deserialize, Serialize};

use super::smooth::BlockMeans;
use crate::median::median;

/// Smallest and largest response exponent measured or read from a file: cameras
/// deliver linear (1), sRGB (about 2.2) or something near them.
pub const GAMMA_RANGE: (f32, f32) = (0.5, 4.0);

/// Where the gain puts the references' flat skin (the median of each pixel's brighter LED
/// channel, DN of linear light): our renderer's nominal skin's level.
pub const FLAT_LINEAR_DN: f32 = 110.0;
/// The gain stays within `1..=MAX_GAIN`.
const MAX_GAIN: f32 = 16.0;

/// A measured exponent within this of 1 is a linear camera: nothing is undone.
pub const LINEAR_WITHIN: f32 = 0.05;

/// A pixel's channel counts when each phase brings at least this much LED light to it
/// (DN above the LEDs-off frame), so that the two phases' light is each a good share of
/// the all-lit frame's.
const MIN_PHASE_DN: u8 = 12;
/// ... and when the all-lit frame stays below this (DN): clipped values do not add up.
const MAX_ALL_DN: u8 = 250;
/// At least this share of the frame's pixel channels must count.
const MIN_SHARE: f64 = 0.02;
/// At most this many pixel channels are kept for the bisection (taken evenly).
const MAX_SAMPLES: usize = 60_000;
/// Bisection steps on the exponent (the bracket shrinks below 1e-6).
const STEPS: usize = 40;

/// The camera records linear light `v` (0–255) as `255 · (v/255)^(1/gamma)`; it is
/// undone as `gain · 255 · (v/255)^gamma`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraCurve {
    /// The response exponent `γ` (1: linear).
    pub gamma: f32,
    /// The scale of the linear values ([`FLAT_LINEAR_DN`]).
    pub gain: f32,
}

/// Why the curve could not be measured.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CurveError {
    /// The frames differ in size.
    #[error(
        "the all-lit frame is {all:?}, but the reference frames are {refs:?}: take all four \
         frames with one camera at one size"
    )]
    Size {
        /// All-lit frame `(width, height)`.
        all: (u32, u32),
        /// The references' size.
        refs: (u32, u32),
    },
    /// Too few pixels where both phases bring light and the all-lit frame is not clipped.
    #[error(
        "only {percent:.1}% of the frame is lit by both phases without the all-lit frame \
         clipping (at least {need:.0}% needed): is the all-lit frame taken with all four \
         strips on, the LEDs-off frame with all off, and the exposure low enough that \
         flat skin is not white?"
    )]
    TooFewPixels {
        /// Share of the frame that counts (%).
        percent: f64,
        /// Share needed (%).
        need: f64,
    },
    /// No exponent in [`GAMMA_RANGE`] makes the frames add up.
    #[error(
        "the frames do not add up under any response exponent from {lo} to {hi} (the \
         all-lit frame reads {direction} the dx and dy frames' light together): are they \
         of one exposure and one camera setting, with nothing pressed, and the all-lit \
         frame with all four strips on?"
    )]
    NoExponent {
        /// Lower bound tried.
        lo: f32,
        /// Upper bound tried.
        hi: f32,
        /// "more than" or "less than".
        direction: &'static str,
    },
}

impl CameraCurve {
    /// Measures the curve from flat-skin frames of one exposure (averaged over a few
    /// frames, as references are): `all` with every strip lit, `dx` and `dy` (the
    /// references) and `dark` with the LEDs off. `Ok(None)` for a linear camera (within
    /// [`LINEAR_WITHIN`]).
    pub fn measure(
        all: &RgbImage,
        dx: &RgbImage,
        dy: &RgbImage,
        dark: &RgbImage,
    ) -> Result<Option<CameraCurve>, CurveError> {
        let refs = dx.dimensions();
        for img in [all, dy, dark] {
            if img.dimensions() != refs {
                return Err(CurveError::Size {
                    all: img.dimensions(),
                    refs,
                });
            }
        }
        let mut samples: Vec<[f32; 4]> = Vec::new();
        let values = all
            .as_raw()
            .iter()
            .zip(dx.as_raw())
            .zip(dy.as_raw())
            .zip(dark.as_raw());
        for (((&a, &x), &y), &d) in values {
            if a < MAX_ALL_DN
                && x >= d.saturating_add(MIN_PHASE_DN)
                && y >= d.saturating_add(MIN_PHASE_DN)
            {
                samples.push([a, x, y, d].map(|v| f32::from(v) / 255.0));
            }
        }
        let total = all.as_raw().len().max(1) as f64;
        let share = samples.len() as f64 / total;
        if share < MIN_SHARE {
            return Err(CurveError::TooFewPixels {
                percent: 100.0 * share,
                need: 100.0 * MIN_SHARE,
            });
        }
        // Every bisection step takes a median: an even spread of samples is as good.
        let stride = samples.len().div_ceil(MAX_SAMPLES).max(1);
        let samples: Vec<[f32; 4]> = samples.into_iter().step_by(stride).collect();
        let (lo, hi) = GAMMA_RANGE;
        let (mut below, mut above) = (lo, hi);
        let (at_lo, at_hi) = (misfit(&samples, lo), misfit(&samples, hi));
        if at_lo > 0.0 || at_hi < 0.0 {
            return Err(CurveError::NoExponent {
                lo,
                hi,
                direction: if at_lo > 0.0 {
                    "more than"
                } else {
                    "less than"
                },
            });
        }
        for _ in 0..STEPS {
            let mid = 0.5 * (below + above);
            if misfit(&samples, mid) < 0.0 {
                below = mid;
            } else {
                above = mid;
            }
        }
        let gamma = 0.5 * (below + above);
        if (gamma - 1.0).abs() <= LINEAR_WITHIN {
            return Ok(None);
        }
        // Flat skin's level: each pixel's brighter LED channel in either reference.
        let levels: Vec<f32> = [dx, dy]
            .iter()
            .flat_map(|img| img.pixels().map(|p| f32::from(p.0[0].max(p.0[2]))))
            .collect();
        let flat = median(&levels).unwrap_or(255.0).max(1.0);
        let linear = 255.0 * (flat / 255.0).powf(gamma);
        let gain = (FLAT_LINEAR_DN / linear).clamp(1.0, MAX_GAIN);
        Ok(Some(CameraCurve { gamma, gain }))
    }

    /// Whether the curve is one a file may hold: `Err((field, why))` when not.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        let (lo, hi) = GAMMA_RANGE;
        if !(self.gamma.is_finite() && (lo..=hi).contains(&self.gamma)) {
            let why = format!(
                "{} is no camera's response exponent (expected {lo}–{hi})",
                self.gamma
            );
            return Err(("gamma", why));
        }
        if !(self.gain.is_finite() && (1.0..=MAX_GAIN).contains(&self.gain)) {
            return Err(("gain", format!("{} is outside 1–{MAX_GAIN}", self.gain)));
        }
        Ok(())
    }

    /// The linear value of every recorded one: `gain · 255 · (v/255)^γ`, rounded and
    /// clipped at full scale.
    pub fn table(&self) -> [u8; 256] {
        let (gamma, gain) = (f64::from(self.gamma), f64::from(self.gain));
        std::array::from_fn(|v| {
            (gain * 255.0 * (v as f64 / 255.0).powf(gamma))
                .round()
                .clamp(0.0, 255.0) as u8
        })
    }

    /// The curve undone on block means rather than on pixels ([`MeanTable`]).
    pub fn mean_table(&self) -> MeanTable {
        let (gamma, gain) = (f64::from(self.gamma), f64::from(self.gain));
        let top = 255 * MEAN_STEPS;
        debug_assert_eq!(top + 1, MEAN_ENTRIES);
        MeanTable(Box::new(std::array::from_fn(|k| {
            let v = k as f64 / MEAN_STEPS as f64;
            (gain * 255.0 * (v / 255.0).powf(gamma)).min(255.0) as f32
        })))
    }

    /// `image` with the curve undone, written into `out` (resized to fit).
    pub fn linearise_into(table: &[u8; 256], image: &RgbImage, out: &mut RgbImage) {
        if out.dimensions() != image.dimensions() {
            *out = RgbImage::new(image.width(), image.height());
        }
        for (o, &v) in out.iter_mut().zip(image.as_raw()) {
            *o = table[usize::from(v)];
        }
    }

    /// `image` with the curve undone.
    pub fn linearised(&self, image: &RgbImage) -> RgbImage {
        let mut out = RgbImage::new(0, 0);
        Self::linearise_into(&self.table(), image, &mut out);
        out
    }
}

/// Steps per count of [`MeanTable`]: a mean over the middle rows of a 4 px block is a
/// sum of 8 values over 8, so it lands on a step exactly.
const MEAN_STEPS: usize = 8;

/// The curve undone on a block's mean value, for a first look at a pair before its
/// pixels are undone one by one (`reconstruct`'s glance at the frames as they came). The
/// linear value of a mean is not the mean of the linear values: by `f''·σ²/2` for pixel
/// values that scatter by `σ` (convex for `γ > 1`). On flat skin's noise of a few counts
/// that is hundredths of a count (`γ` 2.2 at the gain that puts flat skin at 110: about
/// 0.012 per count² of variance). Means are taken to the nearest eighth of a count.
#[derive(Debug, Clone, PartialEq)]
pub struct MeanTable(Box<[f32; MEAN_ENTRIES]>);

/// Entries of [`MeanTable`]: every eighth of a count from 0 to 255.
const MEAN_ENTRIES: usize = 255 * MEAN_STEPS + 1;

impl MeanTable {
    /// The linear value of the recorded mean `v` (0–255; outside, the nearest end).
    #[inline(always)]
    pub fn at(&self, v: f32) -> f32 {
        // `as` saturates (NaN to 0), and the clamp lets the index go unchecked.
        let k = ((v * MEAN_STEPS as f32 + 0.5) as i32).clamp(0, MEAN_ENTRIES as i32 - 1);
        self.0[k as usize]
    }

    /// Every mean of `means` undone in place (their clipped counts are the recorded
    /// frame's: values the gain lifts past full scale are not counted there).
    #[allow(unsafe_code)]
    pub fn undo(&self, means: &mut BlockMeans) {
        for plane in [&mut means.red, &mut means.green, &mut means.blue] {
            #[cfg(target_arch = "x86_64")]
            if crate::cpu::avx2() {
                // SAFETY: `undo_avx2` only needs AVX2, detected just above.
                unsafe { self.undo_avx2(plane) };
                continue;
            }
            self.undo_plane(plane);
        }
    }

    /// [`Self::undo_plane`] compiled for AVX2 (its table reads become gathers: a
    /// quarter of the time at 640×480).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn undo_avx2(&self, plane: &mut [f32]) {
        self.undo_plane(plane);
    }

    #[inline(always)]
    fn undo_plane(&self, plane: &mut [f32]) {
        for m in plane.iter_mut() {
            *m = self.at(*m);
        }
    }
}

/// `image` in linear light: with `curve` undone when there is one, as it is otherwise.
pub fn undone(curve: Option<&CameraCurve>, image: RgbImage) -> RgbImage {
    match curve {
        Some(c) => c.linearised(&image),
        None => image,
    }
}

/// The median share by which the frames raised to `gamma` fail to add up: negative
/// while `gamma` is below the camera's (the values still concave in the light).
fn misfit(samples: &[[f32; 4]], gamma: f32) -> f32 {
    let shares: Vec<f32> = samples
        .iter()
        .map(|&[a, x, y, d]| {
            let [a, x, y, d] = [a, x, y, d].map(|v| v.powf(gamma));
            (a + d - x - y) / (x + y - 2.0 * d).max(1e-6)
        })
        .collect();
    median(&shares).unwrap_or(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Flat-skin frames of a skin lit `dx_light`, `dy_light` (DN per channel, linear)
    /// over `ambient`, recorded through `gamma` with a gradient across the frame.
    fn frames(gamma: f64, ambient: f64) -> [RgbImage; 4] {
        let (w, h) = (64u32, 48u32);
        let record = |v: f64| {
            (255.0 * (v / 255.0).powf(1.0 / gamma))
                .round()
                .clamp(0.0, 255.0) as u8
        };
        let image = |dx_on: bool, dy_on: bool| {
            RgbImage::from_fn(w, h, |x, y| {
                let s = 0.5 + x as f64 / w as f64;
                let t = 0.5 + y as f64 / h as f64;
                let red =
                    60.0 * s * f64::from(u8::from(dx_on)) + 50.0 * t * f64::from(u8::from(dy_on));
                let blue =
                    55.0 / s * f64::from(u8::from(dx_on)) + 45.0 / t * f64::from(u8::from(dy_on));
                let green = 0.1 * (red + blue);
                image::Rgb([red, green, blue].map(|c| record(c + ambient)))
            })
        };
        [
            image(true, true),
            image(true, false),
            image(false, true),
            image(false, false),
        ]
    }

    #[test]
    fn the_exponent_is_measured_from_frames_whose_light_adds_up() {
        for (gamma, ambient) in [(2.2, 10.0), (1.8, 4.0), (2.6, 20.0), (1.4, 0.0)] {
            let [all, dx, dy, dark] = frames(gamma, ambient);
            let got = CameraCurve::measure(&all, &dx, &dy, &dark)
                .unwrap()
                .unwrap();
            assert!(
                (f64::from(got.gamma) - gamma).abs() < 0.06,
                "{gamma}: {got:?}"
            );
            // Undone, the frames add up again, and the references' flat skin sits near
            // where a linear camera's exposure would put it.
            let [a, x, y, d] = [&all, &dx, &dy, &dark].map(|i| got.linearised(i));
            let mid = |i: &RgbImage| f64::from(i.get_pixel(32, 24).0[0]);
            assert!((mid(&a) + mid(&d) - mid(&x) - mid(&y)).abs() <= 3.0);
            assert!((80.0..140.0).contains(&mid(&x)), "{gamma}: {}", mid(&x));
        }
        // A linear camera keeps its values.
        let [all, dx, dy, dark] = frames(1.0, 10.0);
        assert_eq!(CameraCurve::measure(&all, &dx, &dy, &dark).unwrap(), None);
    }

    #[test]
    fn frames_that_cannot_add_up_are_refused_with_the_reason() {
        let [all, dx, dy, dark] = frames(2.2, 10.0);
        // The dx frame given as the all-lit one: it holds less than both phases' light.
        let err = CameraCurve::measure(&dx, &dx, &dy, &dark).unwrap_err();
        assert!(matches!(err, CurveError::NoExponent { .. }), "{err}");
        // An all-lit frame that is white everywhere, or references with no LED light.
        let white = RgbImage::from_pixel(64, 48, image::Rgb([255; 3]));
        let err = CameraCurve::measure(&white, &dx, &dy, &dark).unwrap_err();
        assert!(matches!(err, CurveError::TooFewPixels { .. }), "{err}");
        let err = CameraCurve::measure(&all, &dark, &dark, &dark).unwrap_err();
        assert!(matches!(err, CurveError::TooFewPixels { .. }), "{err}");
        // Another size.
        let small = RgbImage::new(32, 24);
        let err = CameraCurve::measure(&small, &dx, &dy, &dark).unwrap_err();
        assert!(err.to_string().contains("one camera at one size"), "{err}");
    }

    #[test]
    fn the_table_undoes_the_curve_and_keeps_both_ends() {
        let curve = CameraCurve {
            gamma: 2.2,
            gain: 1.0,
        };
        let table = curve.table();
        assert_eq!((table[0], table[255]), (0, 255));
        // sRGB mid-grey (about 186 recorded) is half the light.
        assert!((i32::from(table[186]) - 127).abs() <= 1, "{}", table[186]);
        assert!(table.windows(2).all(|w| w[0] <= w[1]));
        // A gain lifts the values and clips at full scale.
        let lifted = CameraCurve { gain: 2.0, ..curve }.table();
        assert_eq!(lifted[0], 0);
        assert!((i32::from(lifted[150]) - 2 * i32::from(table[150])).abs() <= 1);
        assert_eq!(lifted[200], 255);
        for bad in [0.2, 9.0, f32::NAN] {
            assert!(
                CameraCurve {
                    gamma: bad,
                    gain: 1.0
                }
                .check()
                .is_err()
            );
        }
        for bad in [0.5, 20.0, f32::INFINITY] {
            assert!(
                CameraCurve {
                    gamma: 2.2,
                    gain: bad
                }
                .check()
                .is_err()
            );
        }
        assert!(curve.check().is_ok());
    }

    #[test]
    fn a_mean_is_undone_close_to_the_mean_of_its_undone_values() {
        let curve = CameraCurve {
            gamma: 2.2,
            gain: 2.75,
        };
        let (table, means) = (curve.table(), curve.mean_table());
        // On whole counts the two tables agree to the rounding of the 8-bit one.
        for v in 0..=255u8 {
            let exact = f32::from(table[usize::from(v)]);
            assert!((means.at(f32::from(v)) - exact).abs() <= 0.5, "{v}");
        }
        // Outside 0..=255 and NaN: the nearest end, never a panic.
        assert_eq!(means.at(-3.0), 0.0);
        assert_eq!(means.at(f32::NAN), 0.0);
        assert_eq!(means.at(1e9), 255.0);
        // Flat skin with noise: 4x2 blocks of 110 +- 3 counts (a fixed pattern).
        let noise = [-3i16, 2, 0, 3, -1, -2, 1, 0];
        let (w, h) = (16u32, 8u32);
        let img = RgbImage::from_fn(w, h, |x, y| {
            let n = noise[((x + 3 * y) % 8) as usize];
            image::Rgb([(110 + n) as u8, (40 - n) as u8, (90 + n / 2) as u8])
        });
        let mut raw = BlockMeans::of_middle_rows(&img, 4);
        let linear = BlockMeans::of_middle_rows(&curve.linearised(&img), 4);
        means.undo(&mut raw);
        for (a, b) in [
            (&raw.red, &linear.red),
            (&raw.green, &linear.green),
            (&raw.blue, &linear.blue),
        ] {
            for (a, b) in a.iter().zip(b) {
                // The rounding of the 8-bit table (0.5) and f''·σ²/2 (under 0.1 here).
                assert!((a - b).abs() < 0.6, "{a} against {b}");
            }
        }
    }
}
