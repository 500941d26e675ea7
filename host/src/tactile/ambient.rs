//! Ambient light removal with the LEDs-off frame.
//!
//! The skin is see-through: besides the LEDs' light, every phase image holds the scene's
//! light leaking through it, which changes with the room and with whatever touches the
//! skin. In interleaved mode the sensor also exposes with the LEDs off; that frame shows
//! the ambient light alone, and subtracting it leaves the LEDs' light ([`subtract_into`]).
//!
//! A model calibrated on presses with LEDs-off frames works on LED light only and keeps
//! the calibration's mean ambient light ([`AmbientEstimate`]) for frames that come
//! without one (gradient mode); a model calibrated without them works on the raw frames,
//! where the colour filter's green-channel subtraction stands in for the ambient light.

use image::RgbImage;
use serde::{Deserialize, Serialize};

use super::smooth::{BlockMeans, bilinear};

/// The two phase images of one LED cycle and, when there is one, its LEDs-off frame.
#[derive(Debug, Clone, Copy)]
pub struct PhaseFrames<'a> {
    /// Strips 1 and 3 lit.
    pub dx: &'a RgbImage,
    /// Strips 2 and 4 lit.
    pub dy: &'a RgbImage,
    /// LEDs off, exposed next to them.
    pub dark: Option<&'a RgbImage>,
}

impl<'a> From<(&'a RgbImage, &'a RgbImage)> for PhaseFrames<'a> {
    fn from((dx, dy): (&'a RgbImage, &'a RgbImage)) -> Self {
        Self { dx, dy, dark: None }
    }
}

/// Which ambient light a reconstruction removed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AmbientSource {
    /// None: the model works on raw frames (calibrated without LEDs-off frames); the
    /// colour filter alone rejects ambient light.
    ColourFilter,
    /// The pair's own LEDs-off frame.
    DarkFrame,
    /// The calibration's mean ambient light (no LEDs-off frame came with the pair).
    Calibration,
    /// The calibration's mean ambient light, because the pair's LEDs-off frame was
    /// brighter than its lit frames (see [`MAX_BRIGHTER_FRACTION`]) and was not used.
    CalibrationDarkRefused,
}

impl AmbientSource {
    /// Name as in records and JSON.
    pub fn name(self) -> &'static str {
        match self {
            AmbientSource::ColourFilter => "colour-filter",
            AmbientSource::DarkFrame => "dark-frame",
            AmbientSource::Calibration => "calibration",
            AmbientSource::CalibrationDarkRefused => "calibration-dark-refused",
        }
    }
}

/// How far (DN) a LEDs-off value may exceed the lit one before it counts as brighter
/// (noise and compression make small excesses normal).
const EXCESS_DN: u8 = 12;

/// Largest fraction of values where a LEDs-off frame may be brighter than the lit frame
/// it goes with: the LEDs only add light, so beyond this the frame does not show the
/// same scene light (another exposure, another camera's view, a stale frame).
pub const MAX_BRIGHTER_FRACTION: f64 = 0.05;

/// Whether a LEDs-off value `d` exceeds the lit value `l` by more than noise allows.
#[inline]
fn is_brighter(l: u8, d: u8) -> bool {
    d.saturating_sub(l) > EXCESS_DN
}

/// `out = lit − dark` per channel, clamped at 0; a saturated `lit` value (255) stays 255
/// so the colour filter still sees it as saturated. Returns the fraction of values where
/// `dark` was brighter than `lit` by more than the noise allows (see
/// [`MAX_BRIGHTER_FRACTION`]).
pub fn subtract_into(lit: &RgbImage, dark: &RgbImage, out: &mut RgbImage) -> f64 {
    debug_assert_eq!(lit.dimensions(), dark.dimensions());
    if out.dimensions() != lit.dimensions() {
        *out = RgbImage::new(lit.width(), lit.height());
    }
    let mut brighter = 0u64;
    // Chunks of 32 Ki values keep each chunk's count in a u16, which vectorises.
    const CHUNK: usize = 1 << 15;
    for ((o, l), d) in out
        .chunks_mut(CHUNK)
        .zip(lit.as_raw().chunks(CHUNK))
        .zip(dark.as_raw().chunks(CHUNK))
    {
        let n = o.len().min(l.len()).min(d.len());
        let (o, l, d) = (&mut o[..n], &l[..n], &d[..n]);
        let mut count = 0u16;
        for i in 0..n {
            let (l, d) = (l[i], d[i]);
            // Saturated stays saturated: l | 0xff when l == 255.
            o[i] = l.saturating_sub(d) | (u8::from(l == u8::MAX).wrapping_neg());
            count = count.wrapping_add(u16::from(is_brighter(l, d)));
        }
        brighter += u64::from(count);
    }
    brighter as f64 / lit.as_raw().len().max(1) as f64
}

/// The fraction of values where `dark` is brighter than `lit` beyond noise (see
/// [`MAX_BRIGHTER_FRACTION`]); frames of different sizes count as entirely brighter.
pub fn brighter_fraction(lit: &RgbImage, dark: &RgbImage) -> f64 {
    if lit.dimensions() != dark.dimensions() {
        return 1.0;
    }
    let n = lit
        .as_raw()
        .iter()
        .zip(dark.as_raw())
        .filter(|(l, d)| is_brighter(**l, **d))
        .count();
    n as f64 / lit.as_raw().len().max(1) as f64
}

/// `lit − dark` as a new image (see [`subtract_into`]).
pub fn subtracted(lit: &RgbImage, dark: &RgbImage) -> RgbImage {
    let mut out = RgbImage::new(lit.width(), lit.height());
    subtract_into(lit, dark, &mut out);
    out
}

/// [`brighter_fraction`] on block means: the fraction of blocks' channels where the
/// `dark` frame's mean exceeds the `lit` one's beyond noise. A mean is less noisy than a
/// value, so a dark frame of the same scene counts fewer here; a frame of another
/// exposure or with a light switched on counts as many (`reconstruct`'s glance at a pair
/// at rest uses it). Means of different sizes count as entirely brighter.
pub fn brighter_fraction_of_means(lit: &BlockMeans, dark: &BlockMeans) -> f64 {
    if lit.len() != dark.len() {
        return 1.0;
    }
    let excess = f32::from(EXCESS_DN);
    let count: usize = [
        (&lit.red, &dark.red),
        (&lit.green, &dark.green),
        (&lit.blue, &dark.blue),
    ]
    .into_iter()
    // Counted in u32 lanes (a usize count is two lanes a step).
    .map(|(l, d)| {
        l.iter()
            .zip(d)
            .map(|(l, d)| u32::from(*d - *l > excess))
            .sum::<u32>() as usize
    })
    .sum();
    count as f64 / (3 * lit.len()).max(1) as f64
}

/// [`subtract_into`] on block means: `lit − ambient` per channel, clamped at 0. The
/// blocks' clipped counts stay the lit frame's (a saturated value stays saturated).
/// Clamped per block, not per pixel: the two differ only in blocks where some pixel of
/// the ambient light is brighter than the lit one (unlit skin, noise in the dark).
pub fn subtract_means(lit: &mut BlockMeans, ambient: &BlockMeans) {
    for (l, a) in [
        (&mut lit.red, &ambient.red),
        (&mut lit.green, &ambient.green),
        (&mut lit.blue, &ambient.blue),
    ] {
        for (l, a) in l.iter_mut().zip(a) {
            *l = (*l - *a).max(0.0);
        }
    }
}

/// Mean ambient light of a calibration's LEDs-off frames, as block means: what a model
/// calibrated on LED light subtracts from frames that come without a LEDs-off frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AmbientEstimate {
    /// Block size (px).
    pub step: usize,
    /// Blocks across.
    pub width: usize,
    /// Blocks down.
    pub height: usize,
    /// Mean `[R, G, B]` per block, row by row.
    pub means: Vec<[f32; 3]>,
}

impl AmbientEstimate {
    /// Block size of the stored estimate (px).
    pub const STEP: usize = 16;

    /// The mean of `darks`' block means (all the same size); `None` without frames.
    pub fn of(darks: &[&RgbImage]) -> Option<Self> {
        let first = BlockMeans::of(darks.first()?, Self::STEP);
        let mut sum = first.means();
        for d in &darks[1..] {
            for (s, m) in sum.iter_mut().zip(BlockMeans::of(d, Self::STEP).means()) {
                for c in 0..3 {
                    s[c] += m[c];
                }
            }
        }
        let inv = 1.0 / darks.len() as f32;
        Some(Self {
            step: first.step,
            width: first.width,
            height: first.height,
            means: sum.into_iter().map(|m| m.map(|v| v * inv)).collect(),
        })
    }

    /// `true` when the blocks cover a `width × height` frame exactly as [`Self::of`]
    /// made them (a model file could say otherwise).
    pub fn fits(&self, width: usize, height: usize) -> bool {
        self.step > 0
            && self.width == width.div_ceil(self.step)
            && self.height == height.div_ceil(self.step)
            && self.means.len() == self.width * self.height
    }

    /// The estimate as a `width × height` image, bilinear between block centres.
    pub fn image(&self, width: u32, height: u32) -> RgbImage {
        RgbImage::from_fn(width, height, |x, y| {
            let v = bilinear(
                &self.means,
                self.width,
                self.height,
                self.step,
                x as f32 + 0.5,
                y as f32 + 0.5,
            );
            image::Rgb(v.map(|c| c.round().clamp(0.0, 255.0) as u8))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subtraction_clamps_at_zero_and_keeps_saturation() {
        let lit = RgbImage::from_raw(2, 1, vec![100, 255, 5, 40, 41, 254]).unwrap();
        let dark = RgbImage::from_raw(2, 1, vec![30, 60, 9, 40, 0, 255]).unwrap();
        assert_eq!(
            subtracted(&lit, &dark).into_raw(),
            vec![70, 255, 0, 0, 41, 0]
        );
        let mut out = RgbImage::new(0, 0);
        // 5 -> 9 and 41 -> 0 are within noise; 254 -> 255 too.
        assert_eq!(subtract_into(&lit, &dark, &mut out), 0.0);
        let bright = RgbImage::from_raw(2, 1, vec![100, 255, 30, 40, 41, 254]).unwrap();
        assert_eq!(subtract_into(&lit, &bright, &mut out), 1.0 / 6.0);
        assert_eq!(brighter_fraction(&lit, &bright), 1.0 / 6.0);
        assert_eq!(brighter_fraction(&lit, &RgbImage::new(1, 1)), 1.0);
        // Long images cross the per-chunk count.
        let big = RgbImage::from_pixel(300, 200, image::Rgb([10, 10, 10]));
        let brighter = RgbImage::from_pixel(300, 200, image::Rgb([30, 10, 10]));
        assert!((subtract_into(&big, &brighter, &mut out) - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn block_means_are_subtracted_and_judged_as_the_values_are() {
        let lit = RgbImage::from_fn(8, 4, |x, _| {
            image::Rgb([100, if x < 4 { 20 } else { 5 }, 255])
        });
        let dark = RgbImage::from_fn(8, 4, |x, _| {
            image::Rgb([30, if x < 4 { 10 } else { 40 }, 20])
        });
        let (mut l, d) = (
            BlockMeans::of_middle_rows(&lit, 4),
            BlockMeans::of_middle_rows(&dark, 4),
        );
        // The second block's green: 40 over 5, beyond the noise; one of six channels.
        assert!((brighter_fraction_of_means(&l, &d) - 1.0 / 6.0).abs() < 1e-12);
        assert_eq!(
            brighter_fraction_of_means(&l, &BlockMeans::of_middle_rows(&lit, 2)),
            1.0
        );
        let clipped = l.clipped.clone();
        subtract_means(&mut l, &d);
        assert_eq!(l.red, vec![70.0, 70.0]);
        assert_eq!(l.green, vec![10.0, 0.0]);
        assert_eq!(l.blue, vec![235.0, 235.0]);
        // A saturated lit value stays counted as clipped.
        assert_eq!(l.clipped, clipped);
        assert!(l.clipped.iter().all(|&c| c > 0));
    }

    #[test]
    fn estimate_is_the_mean_of_the_frames_and_reproduces_smooth_light() {
        let (w, h) = (70u32, 50u32);
        // Ambient light that varies linearly: bilinear blocks reproduce it inside.
        let ramp = |k: f32| {
            RgbImage::from_fn(w, h, move |x, _| {
                image::Rgb([(20.0 + k + x as f32 * 0.5) as u8, 30, 40])
            })
        };
        let (a, b) = (ramp(0.0), ramp(10.0));
        let e = AmbientEstimate::of(&[&a, &b]).unwrap();
        assert!(e.fits(w as usize, h as usize));
        assert!(!e.fits(w as usize + 16, h as usize));
        let img = e.image(w, h);
        for x in 8..(w - 24) {
            let want = 25.0 + (x as f32 * 0.5).floor();
            let got = img.get_pixel(x, 20).0[0] as f32;
            assert!((got - want).abs() <= 1.0, "x {x}: {got} vs {want}");
        }
        assert_eq!(img.get_pixel(3, 3).0[1..], [30, 40]);
        assert!(AmbientEstimate::of(&[]).is_none());
    }
}
