//! What the four strips show in each phase, within the LED current budget.
//!
//! A WS2812 pixel draws about [`MA_PER_CHANNEL`] mA per fully lit colour channel, in
//! proportion to the channel value. [`compose_phase`] is the one place where the
//! budget is enforced: it scales the lit strips of a phase down together (keeping their
//! colour ratio, which photometric stereo depends on) until the phase's total current
//! fits. Each phase is scaled on its own, so the gradient phases keep full brightness
//! when only the all-strips phase would exceed the budget.

use smart_leds::RGB8;
use stereotac_protocol::{Phase, Rgb, Strip, StripSettings};

/// Current of one fully lit colour channel of one pixel, in mA (WS2812B datasheet, 5 V).
pub const MA_PER_CHANNEL: u32 = 20;

/// The colour every strip shows in one phase; the first `leds_per_strip` pixels of a strip
/// show its colour, the rest stay dark.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PhaseFrame {
    /// Colour per strip, in wiring order.
    pub colours: [RGB8; 4],
    /// Pixels lit per strip.
    pub leds_per_strip: u16,
    /// Scale applied for the budget, 255 = none.
    pub power_scale: u8,
}

impl PhaseFrame {
    /// All strips dark.
    pub const DARK: PhaseFrame = PhaseFrame {
        colours: [RGB8 { r: 0, g: 0, b: 0 }; 4],
        leds_per_strip: 0,
        power_scale: 255,
    };

    /// Colour of pixel `pixel` of strip `strip`.
    pub fn pixel(&self, strip: usize, pixel: usize) -> RGB8 {
        if pixel < usize::from(self.leds_per_strip) {
            self.colours[strip]
        } else {
            RGB8::default()
        }
    }

    /// Total current of this frame in µA.
    pub fn current_ua(&self) -> u64 {
        self.colours
            .iter()
            .map(|&c| strip_current_ua(c, self.leds_per_strip))
            .sum()
    }
}

/// Whether `strip` is lit in `phase`.
pub const fn is_lit(phase: Phase, strip: Strip) -> bool {
    match phase {
        Phase::Dark => false,
        Phase::All => true,
        Phase::Dx => matches!(strip, Strip::XMinus | Strip::XPlus),
        Phase::Dy => matches!(strip, Strip::YMinus | Strip::YPlus),
    }
}

/// Current of a strip of `leds` pixels showing `colour`, in µA.
pub fn strip_current_ua(colour: RGB8, leds: u16) -> u64 {
    let channel_sum = u64::from(colour.r) + u64::from(colour.g) + u64::from(colour.b);
    // (sum / 255) * 20 mA * leds, in µA, rounded up so the estimate is never low.
    (channel_sum * u64::from(MA_PER_CHANNEL) * 1000 * u64::from(leds)).div_ceil(255)
}

fn apply_brightness(colour: Rgb, brightness: u8) -> RGB8 {
    let scale = |v: u8| ((u16::from(v) * u16::from(brightness)) / 255) as u8;
    RGB8 {
        r: scale(colour.r),
        g: scale(colour.g),
        b: scale(colour.b),
    }
}

/// The strips' colours for `phase`: each lit strip in its colour at its brightness, then
/// all scaled together so the total current stays within `budget_ma`.
///
/// Guarantee (property-tested): `compose_phase(..).current_ua() <= budget_ma * 1000`,
/// and nothing is dimmed when the phase already fits.
pub fn compose_phase(
    phase: Phase,
    strips: &[StripSettings; 4],
    leds_per_strip: u16,
    budget_ma: u16,
) -> PhaseFrame {
    let mut colours = [RGB8::default(); 4];
    for (slot, settings) in colours.iter_mut().zip(strips) {
        if is_lit(phase, settings.strip) {
            *slot = apply_brightness(settings.colour, settings.brightness);
        }
    }
    let wanted: u64 = colours
        .iter()
        .map(|&c| strip_current_ua(c, leds_per_strip))
        .sum();
    let budget = u64::from(budget_ma) * 1000;
    let mut power_scale = 255;
    if wanted > budget {
        // Scale by budget / wanted, rounding every channel down; then trim single steps
        // until the rounded-up current estimate fits too.
        let scale = |v: u8| ((u64::from(v) * budget) / wanted) as u8;
        for c in &mut colours {
            *c = RGB8 {
                r: scale(c.r),
                g: scale(c.g),
                b: scale(c.b),
            };
        }
        trim_to_budget(&mut colours, leds_per_strip, budget);
        power_scale = ((255 * budget) / wanted) as u8;
    }
    PhaseFrame {
        colours,
        leds_per_strip,
        power_scale,
    }
}

/// Lower the brightest channel one step at a time until the frame fits. Only needed for
/// the rounding of [`strip_current_ua`]; runs at most a few iterations.
fn trim_to_budget(colours: &mut [RGB8; 4], leds: u16, budget_ua: u64) {
    let total = |c: &[RGB8; 4]| c.iter().map(|&x| strip_current_ua(x, leds)).sum::<u64>();
    while total(colours) > budget_ua {
        let Some(channel) = colours
            .iter_mut()
            .flat_map(|c| [&mut c.r, &mut c.g, &mut c.b])
            .max_by_key(|v| **v)
        else {
            return;
        };
        if *channel == 0 {
            return;
        }
        *channel -= 1;
    }
}

/// Default strip settings: strips 1 and 2 blue, strips 3 and 4 red, full brightness.
pub const DEFAULT_STRIPS: [StripSettings; 4] = [
    StripSettings {
        strip: Strip::XMinus,
        colour: Rgb::new(0, 0, 255),
        brightness: 255,
    },
    StripSettings {
        strip: Strip::YMinus,
        colour: Rgb::new(0, 0, 255),
        brightness: 255,
    },
    StripSettings {
        strip: Strip::XPlus,
        colour: Rgb::new(255, 0, 0),
        brightness: 255,
    },
    StripSettings {
        strip: Strip::YPlus,
        colour: Rgb::new(255, 0, 0),
        brightness: 255,
    },
];

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn strips_strategy() -> impl Strategy<Value = [StripSettings; 4]> {
        prop::array::uniform4((any::<[u8; 3]>(), any::<u8>())).prop_map(|s| {
            let mut out = DEFAULT_STRIPS;
            for (o, ([r, g, b], brightness)) in out.iter_mut().zip(s) {
                o.colour = Rgb::new(r, g, b);
                o.brightness = brightness;
            }
            out
        })
    }

    fn phase_strategy() -> impl Strategy<Value = Phase> {
        prop_oneof![
            Just(Phase::Dark),
            Just(Phase::All),
            Just(Phase::Dx),
            Just(Phase::Dy)
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 5000, ..ProptestConfig::default() })]

        #[test]
        fn current_never_exceeds_the_budget(
            phase in phase_strategy(),
            strips in strips_strategy(),
            leds in 0u16..=crate::MAX_LEDS_PER_STRIP,
            budget in 0u16..3000,
        ) {
            let frame = compose_phase(phase, &strips, leds, budget);
            prop_assert!(frame.current_ua() <= u64::from(budget) * 1000,
                "{} µA > {} mA", frame.current_ua(), budget);
        }

        #[test]
        fn phases_that_fit_are_not_dimmed_and_unlit_strips_stay_dark(
            phase in phase_strategy(),
            strips in strips_strategy(),
            leds in 0u16..=crate::MAX_LEDS_PER_STRIP,
        ) {
            let frame = compose_phase(phase, &strips, leds, u16::MAX);
            for (i, s) in strips.iter().enumerate() {
                let expected = if is_lit(phase, s.strip) {
                    apply_brightness(s.colour, s.brightness)
                } else {
                    RGB8::default()
                };
                prop_assert_eq!(frame.colours[i], expected);
            }
            prop_assert_eq!(frame.power_scale, 255);
        }

        #[test]
        fn scaling_keeps_lit_strips_near_their_colour_ratio(
            strips in strips_strategy(),
            budget in 50u16..400,
        ) {
            // Capped channels are all scaled by the same factor (up to rounding by one).
            let full = compose_phase(Phase::All, &strips, 8, u16::MAX);
            let capped = compose_phase(Phase::All, &strips, 8, budget);
            let wanted = full.current_ua();
            for (f, c) in full.colours.iter().zip(capped.colours.iter()) {
                for (fv, cv) in [(f.r, c.r), (f.g, c.g), (f.b, c.b)] {
                    let ideal = if wanted > u64::from(budget) * 1000 {
                        u64::from(fv) * u64::from(budget) * 1000 / wanted
                    } else {
                        u64::from(fv)
                    };
                    prop_assert!(u64::from(cv) <= ideal && ideal - u64::from(cv) <= 2,
                        "channel {} -> {} (ideal {})", fv, cv, ideal);
                }
            }
        }
    }

    #[test]
    fn defaults_give_full_gradient_phases_and_a_capped_all_phase() {
        let dx = compose_phase(Phase::Dx, &DEFAULT_STRIPS, 8, 400);
        assert_eq!(dx.colours[0], RGB8 { r: 0, g: 0, b: 255 });
        assert_eq!(dx.colours[2], RGB8 { r: 255, g: 0, b: 0 });
        assert_eq!(dx.colours[1], RGB8::default());
        assert_eq!(dx.colours[3], RGB8::default());
        assert_eq!(dx.current_ua(), 320_000);
        assert_eq!(dx.power_scale, 255);
        let dy = compose_phase(Phase::Dy, &DEFAULT_STRIPS, 8, 400);
        assert_eq!(dy.colours[1], RGB8 { r: 0, g: 0, b: 255 });
        assert_eq!(dy.colours[3], RGB8 { r: 255, g: 0, b: 0 });
        let all = compose_phase(Phase::All, &DEFAULT_STRIPS, 8, 400);
        assert!(all.current_ua() <= 400_000);
        assert_eq!(all.power_scale, 159); // 255 * 400 / 640
        assert_eq!(all.pixel(0, 7), all.colours[0]);
        assert_eq!(all.pixel(0, 8), RGB8::default());
    }
}
