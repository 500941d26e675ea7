//! Colour crosstalk between the strips' LEDs and the camera's channels: measured from
//! two single-colour frames, and undone before any colour is normalised.
//!
//! The colour filter ([`super::colour`]) takes `R − G` as the red LED's light and `B − G`
//! as the blue one's: right when each LED reaches only its own channel. A camera's
//! filters overlap: the blue LED also reaches R and G, the red one G and B, so `R − G`
//! holds a share of the blue light (negative when the blue LED's green exceeds its red)
//! and `B − G` a share of the red. Normalised by flat skin, the red colour then answers
//! the blue light too, in proportion to how blue the flat skin is at that pixel: near the
//! blue strip the colours answer a slope more strongly than in the middle of the frame,
//! and a model fitted over the whole frame reads the slopes there too steep. On the
//! independent renderer (`phys-matte` skin 1, blue light 17 % into `R − G`) the slopes
//! within 0.5–1.6 mm of the top border read 1.5–1.8 times too steep and a ball centred
//! on that edge 1.26 of its depth.
//!
//! Measured from two extra flat-skin frames of one phase, taken beside the reference
//! frame with both strips lit: one with only the blue strip lit, one with only the red.
//! The reference minus the red-only frame is the blue LED's light alone (steady ambient
//! light cancels, no LEDs-off frame needed), the reference minus the blue-only frame the
//! red one's. Each LED's share in the other's channel is the median over the frame's
//! well-lit pixels, and [`Unmix`] is the inverse of that 2×2 mixing on `(R − G, B − G)`,
//! scaled so that each LED keeps its own channel's light: the identity for a camera
//! without crosstalk.

use image::RgbImage;
use serde::{Deserialize, Serialize};

use crate::median::median;

/// A pixel counts when each LED alone brings at least this much light to its own
/// channel (`R − G` for red, `B − G` for blue; DN): dimmer pixels' ratios are mostly
/// noise.
const MIN_LED_DN: f32 = 20.0;
/// At least this share of the frame's pixels must count.
const MIN_SHARE: f64 = 0.05;
/// A share of one LED in the other's channel beyond this is no camera's crosstalk: the
/// frames are not single-colour (or are swapped).
const MAX_SHARE: f32 = 0.5;

/// The LED light `(red, blue)` from a pixel's `(R − G, B − G)`: `red = red_row · (R − G,
/// B − G)`, `blue = blue_row · (R − G, B − G)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Unmix {
    /// Coefficients of `R − G` and `B − G` giving the red LED's light.
    pub red: [f32; 2],
    /// Coefficients of `R − G` and `B − G` giving the blue LED's light.
    pub blue: [f32; 2],
}

impl Default for Unmix {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Unmix {
    /// No crosstalk: `R − G` is red, `B − G` is blue.
    pub const IDENTITY: Unmix = Unmix {
        red: [1.0, 0.0],
        blue: [0.0, 1.0],
    };

    /// Whether this is [`Self::IDENTITY`] (a model file leaves it out then).
    pub fn is_identity(&self) -> bool {
        *self == Self::IDENTITY
    }

    /// The unmix of LEDs whose light reaches the other's channel by these shares:
    /// `blue_in_red` of the blue LED's `B − G` appears in `R − G`, `red_in_blue` of the
    /// red LED's `R − G` in `B − G`. `None` when the mixing cannot be undone.
    pub fn from_shares(blue_in_red: f32, red_in_blue: f32) -> Option<Unmix> {
        let det = 1.0 - blue_in_red * red_in_blue;
        if !det.is_finite() || det.abs() < 0.25 {
            return None;
        }
        Some(Unmix {
            red: [1.0 / det, -blue_in_red / det],
            blue: [-red_in_blue / det, 1.0 / det],
        })
    }

    /// The LED light `(red, blue)` of `(R − G, B − G)`.
    #[inline(always)]
    pub fn apply(&self, red_minus_green: f32, blue_minus_green: f32) -> (f32, f32) {
        (
            self.red[0] * red_minus_green + self.red[1] * blue_minus_green,
            self.blue[0] * red_minus_green + self.blue[1] * blue_minus_green,
        )
    }

    /// The shares it undoes `(blue in red, red in blue)`, as [`Self::from_shares`] takes
    /// them: the off-diagonal terms over the diagonal.
    pub fn shares(&self) -> (f32, f32) {
        (-self.red[1] / self.blue[1], -self.blue[0] / self.red[0])
    }

    /// Whether every coefficient is finite and the shares are within what a camera has
    /// (the model file's check).
    pub fn check(&self) -> Result<(), String> {
        let all = [self.red[0], self.red[1], self.blue[0], self.blue[1]];
        if all.iter().any(|v| !v.is_finite()) {
            return Err("a coefficient is not a finite number".into());
        }
        let det = self.red[0] * self.blue[1] - self.red[1] * self.blue[0];
        if det.abs() < 1e-3 {
            return Err("the matrix cannot be inverted".into());
        }
        let (blue_in_red, red_in_blue) = self.shares();
        if !(blue_in_red.abs() <= MAX_SHARE && red_in_blue.abs() <= MAX_SHARE) {
            return Err(format!(
                "it undoes {:.0} % of blue light in red and {:.0} % of red in blue; a camera's \
                 crosstalk is below {:.0} %",
                100.0 * blue_in_red,
                100.0 * red_in_blue,
                100.0 * MAX_SHARE
            ));
        }
        Ok(())
    }
}

/// Why the crosstalk could not be measured.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CrosstalkError {
    /// The frames differ in size.
    #[error(
        "the {what} frame is {got:?} but the reference frame is {want:?}: take all three \
         of the same camera at the same resolution"
    )]
    Size {
        /// Which frame.
        what: &'static str,
        /// Its size.
        got: (u32, u32),
        /// The reference's.
        want: (u32, u32),
    },
    /// Too few pixels where each LED alone is bright enough.
    #[error(
        "only {percent:.1}% of the frame shows each LED's light alone (the reference minus \
         the other single-colour frame) at {MIN_LED_DN} DN or more, {need:.0}% needed: give \
         flat-skin frames of the same phase as the reference, one with only its blue strip \
         lit and one with only its red strip lit, at the reference's exposure"
    )]
    TooDim {
        /// Share of the frame that counts (%).
        percent: f64,
        /// Share needed (%).
        need: f64,
    },
    /// One LED's light shows too much of the other colour.
    #[error(
        "the {led} LED's light alone (the reference minus the {other}-only frame) is {share:.0}% \
         {other} (`{channel}`): no camera's crosstalk is above {max:.0}%; the {other}-only \
         frame is not single-colour, or the two frames are swapped"
    )]
    Implausible {
        /// Which LED.
        led: &'static str,
        /// The other colour.
        other: &'static str,
        /// Its channel difference.
        channel: &'static str,
        /// The share (%).
        share: f32,
        /// The bound (%).
        max: f32,
    },
}

/// Measures the crosstalk from flat-skin frames of one phase: `reference` with both of
/// its strips lit, `blue_only` with only the blue strip, `red_only` with only the red
/// (same exposure). See the module documentation.
pub fn measure(
    reference: &RgbImage,
    blue_only: &RgbImage,
    red_only: &RgbImage,
) -> Result<Unmix, CrosstalkError> {
    let want = reference.dimensions();
    for (what, img) in [("blue-only", blue_only), ("red-only", red_only)] {
        if img.dimensions() != want {
            return Err(CrosstalkError::Size {
                what,
                got: img.dimensions(),
                want,
            });
        }
    }
    let (mut blue_in_red, mut red_in_blue) = (Vec::new(), Vec::new());
    let light = |both: &[u8], without: &[u8]| {
        let c = |k: usize| f32::from(both[k]) - f32::from(without[k]);
        // (R − G, B − G) of the light the frame without this LED lacks.
        (c(0) - c(1), c(2) - c(1))
    };
    let pixels = reference
        .as_raw()
        .chunks_exact(3)
        .zip(blue_only.as_raw().chunks_exact(3))
        .zip(red_only.as_raw().chunks_exact(3));
    for ((both, blue_px), red_px) in pixels {
        // A clipped reference channel does not hold the LEDs' sum.
        if both.iter().any(|&v| v >= 250) {
            continue;
        }
        // The reference minus the frame without the red LED (the blue-only frame) is the
        // red LED's light, and the other way round.
        let (blue_r, blue_b) = light(both, red_px);
        let (red_r, red_b) = light(both, blue_px);
        if blue_b >= MIN_LED_DN && red_r >= MIN_LED_DN {
            blue_in_red.push(blue_r / blue_b);
            red_in_blue.push(red_b / red_r);
        }
    }
    let total = (want.0 as usize * want.1 as usize).max(1);
    if (blue_in_red.len() as f64) < MIN_SHARE * total as f64 {
        return Err(CrosstalkError::TooDim {
            percent: 100.0 * blue_in_red.len() as f64 / total as f64,
            need: 100.0 * MIN_SHARE,
        });
    }
    let upper = |v: &[f32]| median(v).expect("at least 5% of a frame's pixels counted");
    let (blue_in_red, red_in_blue) = (upper(&blue_in_red), upper(&red_in_blue));
    for (led, other, channel, share) in [
        ("blue", "red", "R - G over B - G", blue_in_red),
        ("red", "blue", "B - G over R - G", red_in_blue),
    ] {
        if share.abs() > MAX_SHARE {
            return Err(CrosstalkError::Implausible {
                led,
                other,
                channel,
                share: 100.0 * share,
                max: 100.0 * MAX_SHARE,
            });
        }
    }
    Ok(Unmix::from_shares(blue_in_red, red_in_blue).expect("shares within ±0.5 invert"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 64×48 frame whose blue and red LED light vary across it (as strips on opposite
    /// sides do), mixed into the camera's channels by `blue_rgb` and `red_rgb` per unit
    /// of light, over grey ambient light of 12 DN.
    fn frame(blue_rgb: [f32; 3], red_rgb: [f32; 3], blue_on: bool, red_on: bool) -> RgbImage {
        let (w, h) = (64u32, 48u32);
        RgbImage::from_fn(w, h, |x, _| {
            let t = x as f32 / (w - 1) as f32;
            let (b, r) = (
                if blue_on {
                    60.0 + 120.0 * (1.0 - t)
                } else {
                    0.0
                },
                if red_on { 60.0 + 120.0 * t } else { 0.0 },
            );
            image::Rgb(std::array::from_fn(|c| {
                (12.0 + b * blue_rgb[c] + r * red_rgb[c]).round().min(255.0) as u8
            }))
        })
    }

    #[test]
    fn recovers_a_known_mixing_and_undoes_it() {
        // Blue LED: 5 % into R, 19 % into G; red LED: 8 % into G, 4.5 % into B.
        let (blue, red) = ([0.05, 0.19, 1.0], [1.0, 0.08, 0.045]);
        let both = frame(blue, red, true, true);
        let unmix = measure(
            &both,
            &frame(blue, red, true, false),
            &frame(blue, red, false, true),
        )
        .unwrap();
        // Analytic shares on (R − G, B − G): blue (0.05 − 0.19) / (1 − 0.19), red
        // (0.045 − 0.08) / (1 − 0.08).
        let (sb, sr) = ((0.05 - 0.19) / 0.81f32, (0.045 - 0.08) / 0.92f32);
        let want = Unmix::from_shares(sb, sr).unwrap();
        for (a, b) in [(unmix.red, want.red), (unmix.blue, want.blue)] {
            for k in 0..2 {
                assert!((a[k] - b[k]).abs() < 0.01, "{unmix:?} against {want:?}");
            }
        }
        // Pure blue light unmixes to no red, pure red to no blue (up to rounding).
        let (r, b) = unmix.apply(80.0 * (0.05 - 0.19), 80.0 * (1.0 - 0.19));
        assert!(r.abs() < 1.5 && (b - 80.0 * 0.81).abs() < 1.5, "{r} {b}");
        let (r, b) = unmix.apply(80.0 * 0.92, 80.0 * (0.045 - 0.08));
        assert!(b.abs() < 1.5 && (r - 80.0 * 0.92).abs() < 1.5, "{r} {b}");
        assert!(unmix.check().is_ok());
    }

    #[test]
    fn a_camera_without_crosstalk_gives_the_identity() {
        let (blue, red) = ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]);
        let unmix = measure(
            &frame(blue, red, true, true),
            &frame(blue, red, true, false),
            &frame(blue, red, false, true),
        )
        .unwrap();
        for (a, b) in [
            (unmix.red, Unmix::IDENTITY.red),
            (unmix.blue, Unmix::IDENTITY.blue),
        ] {
            assert!((a[0] - b[0]).abs() < 1e-3 && (a[1] - b[1]).abs() < 1e-3);
        }
    }

    #[test]
    fn swapped_dark_or_odd_frames_are_refused_with_the_reason() {
        let (blue, red) = ([0.05, 0.19, 1.0], [1.0, 0.08, 0.045]);
        let both = frame(blue, red, true, true);
        let (blue_only, red_only) = (frame(blue, red, true, false), frame(blue, red, false, true));
        // Swapped: each "LED alone" is the other colour, negative in its own channel.
        let e = measure(&both, &red_only, &blue_only).unwrap_err();
        assert!(matches!(e, CrosstalkError::TooDim { .. }), "{e}");
        // The reference itself as a single-colour frame: no LED light is left.
        let e = measure(&both, &both, &red_only).unwrap_err();
        assert!(e.to_string().contains("only its blue strip lit"), "{e}");
        // Both LEDs on in the "blue-only" frame but half as bright: the red LED's light
        // alone is then half red, half blue.
        let half = RgbImage::from_fn(64, 48, |x, y| {
            let p = both.get_pixel(x, y).0;
            let q = red_only.get_pixel(x, y).0;
            image::Rgb(std::array::from_fn(|c| {
                ((u16::from(p[c]) + u16::from(q[c]) - 12) / 2) as u8
            }))
        });
        assert!(measure(&both, &half, &red_only).is_err());
        let small = RgbImage::new(8, 8);
        let e = measure(&both, &small, &red_only).unwrap_err();
        assert!(
            matches!(
                e,
                CrosstalkError::Size {
                    what: "blue-only",
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn check_refuses_what_no_camera_has() {
        assert!(Unmix::IDENTITY.check().is_ok());
        let nan = Unmix {
            red: [f32::NAN, 0.0],
            blue: [0.0, 1.0],
        };
        assert!(nan.check().is_err());
        let much = Unmix {
            red: [1.0, -0.9],
            blue: [0.0, 1.0],
        };
        assert!(much.check().is_err());
        assert!(Unmix::from_shares(0.9, 0.9).is_none());
    }
}
