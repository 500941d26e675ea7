//! The loopback probe's arithmetic: what the board's probe state machines report, turned
//! into edge times and decoded WS2812 frames.
//!
//! Two spare inputs take the camera trigger and strip 1's data line, wired back from
//! their outputs (see [`crate::pins::PinMap::probe_trigger`]). A PIO state machine on
//! each times what it sees with its own cycle counter, independently of the code that
//! drives the outputs, so a sensor on the bench can check its own pins:
//!
//! * **Stamping**: when a state machine sees its event (a trigger rising edge, or the
//!   end of a WS2812 frame) it raises an IRQ and counts down from `u32::MAX`, one count
//!   per [`STAMP_LOOP_CYCLES`], until the CPU pushes a token into its TX FIFO. The CPU
//!   pushes that token right after a tick of the 1 MHz timer; the state machine then
//!   pushes its count. The event happened `fixed + 3·count` cycles before the token:
//!   [`StampClock::event_ns`]. Interrupt and executor latency only lengthen the count.
//! * **Decoding**: the strip state machine samples each bit in the middle of its data
//!   part and pushes whole 24-bit GRB pixels, then a bit count, then its stamp:
//!   [`FrameTally`] summarises the pixels.
//!
//! All of it is plain arithmetic, unit-tested on the host; the board code is in
//! `src/board/probe.rs`.

use stereotac_protocol::{DeviceMicros, DeviceNanos, Rgb, StripFrameProbe};

/// PIO cycles per count of the stamp loop (`mov y, status`, `jmp !y`, `jmp x--`).
pub const STAMP_LOOP_CYCLES: u64 = 3;

/// A stamp word is `u32::MAX - count`; counts this large (seconds of CPU latency) are
/// not believed, and pixel words (at most 24 bits) can never look like a stamp.
pub const MAX_STAMP_COUNT: u32 = 1 << 24;

/// How to turn one state machine's stamp count into time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StampClock {
    /// One cycle of the state machine (clock divider included), ps.
    pub cycle_ps: u64,
    /// Cycles from the event to the first status check of the stamp loop.
    pub fixed_cycles: u64,
    /// From the timer tick the CPU waited for to its token being visible to the state
    /// machine, ns.
    pub token_latency_ns: u64,
}

impl StampClock {
    /// When the stamped event happened (device ns), from the timer tick after which the
    /// token was pushed and the word the state machine pushed back. `None` for a word
    /// that is not a believable stamp.
    pub fn event_ns(&self, tick_us: DeviceMicros, word: u32) -> Option<DeviceNanos> {
        let count = u32::MAX - word;
        if count >= MAX_STAMP_COUNT {
            return None;
        }
        let token_ns = tick_us
            .checked_mul(1000)?
            .checked_add(self.token_latency_ns)?;
        let back_ps = (self.fixed_cycles + STAMP_LOOP_CYCLES * u64::from(count)) * self.cycle_ps;
        token_ns.checked_sub(back_ps / 1000)
    }
}

/// Whether a word from the strip decoder is a pixel (24-bit GRB) rather than a bit
/// count or a stamp.
pub const fn is_pixel_word(word: u32) -> bool {
    word <= 0x00FF_FFFF
}

/// The bit count the strip decoder pushes after a frame's pixels (it counts down from
/// `u32::MAX`, one per bit).
pub const fn bits_from_count_word(word: u32) -> u32 {
    u32::MAX - word
}

/// A pixel word (GRB, most significant bit first, as it went down the wire) as RGB.
pub const fn pixel_rgb(word: u32) -> Rgb {
    Rgb::new((word >> 8) as u8, (word >> 16) as u8, word as u8)
}

/// Summary of one decoded frame, built pixel by pixel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FrameTally {
    pixels: u16,
    lit: u16,
    leading_lit: u16,
    first: Option<Rgb>,
    mismatched: u16,
}

impl FrameTally {
    /// Add the next pixel word.
    pub fn push(&mut self, word: u32) {
        let colour = pixel_rgb(word);
        let first = *self.first.get_or_insert(colour);
        let lit = colour != Rgb::new(0, 0, 0);
        if lit {
            self.lit = self.lit.saturating_add(1);
            if self.leading_lit == self.pixels {
                self.leading_lit = self.leading_lit.saturating_add(1);
            }
            if colour != first {
                self.mismatched = self.mismatched.saturating_add(1);
            }
        }
        self.pixels = self.pixels.saturating_add(1);
    }

    /// Pixels so far.
    pub fn pixels(&self) -> u16 {
        self.pixels
    }

    /// The frame's summary: it ended at `end_ns` after `bits` bits in all.
    pub fn finish(self, end_ns: DeviceNanos, bits: u32) -> StripFrameProbe {
        let stray = bits.saturating_sub(u32::from(self.pixels) * 24);
        StripFrameProbe {
            end_ns,
            pixels: self.pixels,
            lit: self.lit,
            leading_lit: self.leading_lit,
            first: self.first.unwrap_or(Rgb::new(0, 0, 0)),
            mismatched: self.mismatched,
            stray_bits: u8::try_from(stray).unwrap_or(u8::MAX),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CLOCK: StampClock = StampClock {
        cycle_ps: 8_000,
        fixed_cycles: 4,
        token_latency_ns: 100,
    };

    #[test]
    fn a_stamp_counts_back_from_the_token() {
        // Token at 1_000_000 µs + 100 ns; 1000 counts of 3 cycles and 4 fixed cycles of
        // 8 ns before it: 24_032 ns.
        let word = u32::MAX - 1000;
        assert_eq!(
            CLOCK.event_ns(1_000_000, word),
            Some(1_000_000_000 + 100 - 24_032)
        );
        // No count at all: only the fixed cycles.
        assert_eq!(CLOCK.event_ns(5, u32::MAX), Some(5_000 + 100 - 32));
    }

    #[test]
    fn unbelievable_stamps_are_refused() {
        // A pixel word, or a count of seconds, is not a stamp.
        assert_eq!(CLOCK.event_ns(1_000_000, 0x00FF_FFFF), None);
        assert_eq!(CLOCK.event_ns(1_000_000, u32::MAX - MAX_STAMP_COUNT), None);
        // An event before boot cannot be.
        assert_eq!(CLOCK.event_ns(0, u32::MAX - 1_000_000), None);
        // Overflowing clocks neither.
        assert_eq!(CLOCK.event_ns(u64::MAX, u32::MAX), None);
    }

    #[test]
    fn pixel_words_are_grb_on_the_wire() {
        assert_eq!(pixel_rgb(0x0000_00FF), Rgb::new(0, 0, 255));
        assert_eq!(pixel_rgb(0x0000_FF00), Rgb::new(255, 0, 0));
        assert_eq!(pixel_rgb(0x00FF_0000), Rgb::new(0, 255, 0));
        assert!(is_pixel_word(0x00FF_FFFF));
        assert!(!is_pixel_word(u32::MAX - 768));
        assert_eq!(bits_from_count_word(u32::MAX - 768), 768);
    }

    #[test]
    fn a_frame_is_summarised() {
        let mut tally = FrameTally::default();
        for _ in 0..8 {
            tally.push(0x0000_00C0); // blue
        }
        for _ in 0..24 {
            tally.push(0);
        }
        let frame = tally.finish(42, 32 * 24);
        assert_eq!(
            frame,
            StripFrameProbe {
                end_ns: 42,
                pixels: 32,
                lit: 8,
                leading_lit: 8,
                first: Rgb::new(0, 0, 0xC0),
                mismatched: 0,
                stray_bits: 0,
            }
        );
    }

    #[test]
    fn broken_frames_show() {
        // A different colour, a gap in the lit run, and bits past the last pixel.
        let mut tally = FrameTally::default();
        for word in [0xFF, 0xFF00, 0, 0xFF] {
            tally.push(word);
        }
        let frame = tally.finish(0, 4 * 24 + 5);
        assert_eq!(frame.pixels, 4);
        assert_eq!(frame.lit, 3);
        assert_eq!(frame.leading_lit, 2);
        assert_eq!(frame.mismatched, 1);
        assert_eq!(frame.stray_bits, 5);
        // An empty frame is dark, with no pixels.
        let empty = FrameTally::default().finish(0, 3);
        assert_eq!((empty.pixels, empty.lit, empty.stray_bits), (0, 0, 3));
    }
}
