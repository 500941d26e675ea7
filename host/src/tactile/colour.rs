//! Colour filter: keep only the light of the LEDs and express it relative to flat skin.
//!
//! The strips emit pure red and pure blue; white or greenish light (room light, a
//! ceiling lamp seen through the skin) reaches all three channels. So the green channel
//! measures the non-LED light at each pixel, and `R − G`, `B − G` are the LED light alone.
//! A pixel is rejected (its slope is taken as zero downstream, never "black") when it is
//! saturated, when too little LED light is left, when green is a large part of it, or when
//! green rose above the no-contact reference by more than the pixel's LED light (strong
//! light that was not there at calibration; weaker white light is subtracted exactly). Accepted pixels are divided by the reference's LED light at the same
//! pixel: flat skin reads `(1, 1)` anywhere in the frame, which removes the strips'
//! fall-off and vignetting before any model sees the colour. A camera whose channels see
//! both LEDs (crosstalk) has `(R − G, B − G)` unmixed first, when it was measured
//! ([`ColourFilter::unmix`], [`crate::tactile::crosstalk`]); the rejections above look at
//! the channels as they are.

use image::RgbImage;
use serde::{Deserialize, Serialize};

use super::crosstalk::Unmix;

/// Thresholds of the colour filter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColourFilter {
    /// Minimum LED light `max(R−G, B−G)` for a usable pixel (DN).
    pub min_led: f32,
    /// Maximum `G / max(R, B)`: above it the pixel is mostly white or green light.
    pub max_white_ratio: f32,
    /// Maximum rise of green over the reference, as a fraction of the pixel's LED light
    /// `max(R−G, B−G)`, before the pixel is rejected.
    pub max_green_rise: f32,
    /// Any channel at or above this value is saturated.
    pub saturation: u8,
    /// The LED light from `(R − G, B − G)`, undoing the camera's colour crosstalk
    /// ([`crate::tactile::crosstalk`]); the identity (left out of model files) when none
    /// was measured.
    #[serde(default, skip_serializing_if = "Unmix::is_identity")]
    pub unmix: Unmix,
}

impl Default for ColourFilter {
    fn default() -> Self {
        Self {
            min_led: 6.0,
            max_white_ratio: 0.6,
            max_green_rise: 1.0,
            saturation: 250,
            unmix: Unmix::IDENTITY,
        }
    }
}

/// Flat-skin LED light of one phase image, stored as reciprocals for the hot loop.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    width: usize,
    height: usize,
    inv_red: Vec<f32>,
    inv_blue: Vec<f32>,
    green: Vec<f32>,
    weight_red: Vec<f32>,
    weight_blue: Vec<f32>,
    unmix: Unmix,
}

/// The planes of a [`Reference`] over a run of indices, for loops that run in vector
/// lanes ([`Reference::planes`]).
#[derive(Debug, Clone, Copy)]
pub struct ReferencePlanes<'a> {
    /// `1 / red LED light`.
    pub inv_red: &'a [f32],
    /// `1 / blue LED light`.
    pub inv_blue: &'a [f32],
    /// Green (non-LED) light.
    pub green: &'a [f32],
    /// Weight of the red departure ([`Reference::weights`]).
    pub weight_red: &'a [f32],
    /// Weight of the blue departure.
    pub weight_blue: &'a [f32],
    /// The LED light from `(R − G, B − G)`.
    pub unmix: Unmix,
}

impl ReferencePlanes<'_> {
    /// [`Reference::normalise_mean`] at index `i` of these planes without branches:
    /// the normalised `[red, blue]` and whether the filter accepted the colour (the
    /// values mean nothing when it did not). The same arithmetic, so the same numbers.
    #[inline(always)]
    pub fn normalise(&self, filter: &ColourFilter, i: usize, pixel: [f32; 3]) -> ([f32; 2], bool) {
        let saturation = f32::from(filter.saturation);
        let [r, g, b] = pixel;
        let (led_r, led_b) = (r - g, b - g);
        let led = led_r.max(led_b);
        let accepted = (r < saturation)
            & (g < saturation)
            & (b < saturation)
            & (led >= filter.min_led)
            & (g <= filter.max_white_ratio * r.max(b))
            & (g - self.green[i] <= filter.max_green_rise * led);
        let (led_r, led_b) = self.unmix.apply(led_r, led_b);
        (
            [
                led_r.max(0.0) * self.inv_red[i],
                led_b.max(0.0) * self.inv_blue[i],
            ],
            accepted,
        )
    }

    /// What [`Reference::normalise_mean`] gives for `pixel` at index `i` of these planes,
    /// reduced to its weighted departure from flat skin, `wr·|r − 1| + wb·|b − 1|` (see
    /// [`Reference::weights`]), and whether the filter accepted it (the departure is 0
    /// when not). Branch-free, so loops over many blocks run in vector lanes.
    #[inline(always)]
    pub fn departure(&self, filter: &ColourFilter, i: usize, pixel: [f32; 3]) -> (f32, bool) {
        let ([r, b], accepted) = self.normalise(filter, i, pixel);
        let d = self.weight_red[i] * (r - 1.0).abs() + self.weight_blue[i] * (b - 1.0).abs();
        (if accepted { d } else { 0.0 }, accepted)
    }
}

/// Smallest LED light a reference pixel is assumed to have (keeps ratios bounded).
const REFERENCE_FLOOR: f32 = 4.0;

impl Reference {
    /// Reference from a no-contact frame of the same phase; its LED light and every
    /// pixel's it normalises are `unmix`ed ([`ColourFilter::unmix`]).
    pub fn from_image(image: &RgbImage, unmix: Unmix) -> Self {
        let (w, h) = image.dimensions();
        Self::from_planes(
            w as usize,
            h as usize,
            image.pixels().map(|px| {
                let [red, green, blue] = px.0.map(f32::from);
                [red - green, blue - green, green]
            }),
            unmix,
        )
    }

    /// Reference from mean colours `[R, G, B]` (block or neighbourhood means of a
    /// no-contact frame), `width × height` of them.
    pub fn from_means(width: usize, height: usize, means: &[[f32; 3]], unmix: Unmix) -> Self {
        Self::from_planes(
            width,
            height,
            means
                .iter()
                .map(|&[red, green, blue]| [red - green, blue - green, green]),
            unmix,
        )
    }

    /// Reference from per-pixel planes `[R − G, B − G, G]` (`R`, `B` after ambient
    /// removal when there is a LEDs-off frame).
    pub fn from_planes(
        width: usize,
        height: usize,
        planes: impl Iterator<Item = [f32; 3]>,
        unmix: Unmix,
    ) -> Self {
        let mut r = Self {
            width,
            height,
            inv_red: Vec::with_capacity(width * height),
            inv_blue: Vec::with_capacity(width * height),
            green: Vec::with_capacity(width * height),
            weight_red: Vec::with_capacity(width * height),
            weight_blue: Vec::with_capacity(width * height),
            unmix,
        };
        for [red, blue, green] in planes {
            r.push(red, blue, green);
        }
        assert_eq!(r.green.len(), width * height, "plane length");
        r
    }

    fn push(&mut self, red: f32, blue: f32, green: f32) {
        let (red, blue) = self.unmix.apply(red, blue);
        let (ir, ib) = (
            1.0 / red.max(REFERENCE_FLOOR),
            1.0 / blue.max(REFERENCE_FLOOR),
        );
        self.inv_red.push(ir);
        self.inv_blue.push(ib);
        self.green.push(green);
        let s = 2.0 / (ir + ib);
        self.weight_red.push(ib * s);
        self.weight_blue.push(ir * s);
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Weights `(red, blue)` of the two channels' departures at pixel `i`: each channel's
    /// share of the reference's LED light, times two (flat-skin balance gives `(1, 1)`).
    /// A channel lit weakly at this place counts for little: its ratio to the reference
    /// is mostly noise.
    #[inline]
    pub fn weights(&self, i: usize) -> (f32, f32) {
        (self.weight_red[i], self.weight_blue[i])
    }

    /// The reference's planes over indices `range` (panics outside the reference). Inlined
    /// so that loops over `range` see every plane's length and run without bounds checks
    /// (in vector lanes).
    #[inline(always)]
    pub fn planes(&self, range: std::ops::Range<usize>) -> ReferencePlanes<'_> {
        ReferencePlanes {
            inv_red: &self.inv_red[range.clone()],
            inv_blue: &self.inv_blue[range.clone()],
            green: &self.green[range.clone()],
            weight_red: &self.weight_red[range.clone()],
            weight_blue: &self.weight_blue[range],
            unmix: self.unmix,
        }
    }

    /// Normalised LED colour `(red, blue)` of `pixel` at index `i`, or `None` when the
    /// filter rejects it. Flat skin gives about `(1, 1)`.
    #[inline]
    pub fn normalise(&self, filter: &ColourFilter, i: usize, pixel: [u8; 3]) -> Option<(f32, f32)> {
        self.normalise_mean(filter, i, pixel.map(f32::from))
    }

    /// [`Self::normalise`] for a mean colour (of a block or a neighbourhood); a mean at or
    /// above the saturation level counts as saturated.
    #[inline]
    pub fn normalise_mean(
        &self,
        filter: &ColourFilter,
        i: usize,
        pixel: [f32; 3],
    ) -> Option<(f32, f32)> {
        let saturation = f32::from(filter.saturation);
        if pixel.iter().any(|&c| c >= saturation) {
            return None;
        }
        let [r, g, b] = pixel;
        let (led_r, led_b) = (r - g, b - g);
        if led_r.max(led_b) < filter.min_led
            || g > filter.max_white_ratio * r.max(b)
            || g - self.green[i] > filter.max_green_rise * led_r.max(led_b)
        {
            return None;
        }
        let (led_r, led_b) = self.unmix.apply(led_r, led_b);
        Some((
            led_r.max(0.0) * self.inv_red[i],
            led_b.max(0.0) * self.inv_blue[i],
        ))
    }
}

/// Per-pixel median of several no-contact-ish frames: each pixel's background when
/// contacts sit at different places in each frame (used by calibration when no reference
/// frames are given).
pub fn median_image(images: &[&RgbImage]) -> Option<RgbImage> {
    let first = images.first()?;
    let (w, h) = first.dimensions();
    if images.iter().any(|i| i.dimensions() != (w, h)) {
        return None;
    }
    let mut out = RgbImage::new(w, h);
    let mut values = Vec::with_capacity(images.len());
    for (x, y, px) in out.enumerate_pixels_mut() {
        for c in 0..3 {
            values.clear();
            values.extend(images.iter().map(|i| i.get_pixel(x, y).0[c]));
            values.sort_unstable();
            px.0[c] = values[values.len() / 2];
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reference(pixel: [u8; 3]) -> Reference {
        Reference::from_image(
            &RgbImage::from_pixel(1, 1, image::Rgb(pixel)),
            Unmix::IDENTITY,
        )
    }

    #[test]
    fn ambient_white_light_cancels() {
        let f = ColourFilter::default();
        let reference = reference([106, 6, 86]);
        let (r, b) = reference.normalise(&f, 0, [106, 6, 86]).unwrap();
        assert!((r - 1.0).abs() < 1e-6 && (b - 1.0).abs() < 1e-6);
        // Extra white light of 10 DN on every channel changes nothing.
        let (r, b) = reference.normalise(&f, 0, [116, 16, 96]).unwrap();
        assert!((r - 1.0).abs() < 1e-6 && (b - 1.0).abs() < 1e-6);
    }

    #[test]
    fn rejects_white_spots_saturation_and_darkness() {
        let f = ColourFilter::default();
        let reference = reference([106, 6, 86]);
        assert_eq!(reference.normalise(&f, 0, [200, 180, 190]), None, "white");
        assert_eq!(
            reference.normalise(&f, 0, [150, 140, 120]),
            None,
            "green rose"
        );
        // White light weaker than the LEDs' is subtracted, not rejected.
        assert!(reference.normalise(&f, 0, [150, 50, 130]).is_some());
        // A rise of green beyond the LED light itself is rejected even if not white.
        assert_eq!(
            reference.normalise(&f, 0, [160, 90, 60]),
            None,
            "strong cast"
        );
        assert_eq!(reference.normalise(&f, 0, [255, 6, 20]), None, "saturated");
        assert_eq!(reference.normalise(&f, 0, [9, 6, 10]), None, "dark");
        assert!(
            reference.normalise(&f, 0, [10, 6, 200]).is_some(),
            "one LED dark is fine"
        );
    }

    #[test]
    fn median_needs_equal_sizes() {
        let a = RgbImage::from_pixel(2, 2, image::Rgb([1, 2, 3]));
        let b = RgbImage::from_pixel(2, 2, image::Rgb([9, 9, 9]));
        let c = RgbImage::from_pixel(2, 2, image::Rgb([5, 5, 5]));
        assert_eq!(
            median_image(&[&a, &b, &c]).unwrap().get_pixel(1, 1).0,
            [5, 5, 5]
        );
        let d = RgbImage::new(3, 2);
        assert!(median_image(&[&a, &d]).is_none());
        assert!(median_image(&[]).is_none());
    }
}
