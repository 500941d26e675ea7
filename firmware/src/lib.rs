//! # stereotac-firmware: pure logic
//!
//! Everything the sensor firmware decides, written without hardware so it builds and is
//! unit-tested on the host with a virtual clock, and is reused by the host's in-memory
//! loopback transport:
//!
//! * [`pins`]: the board's pin map (one table, repeated in the README).
//! * [`leds`]: which strip shows what in each phase, and the LED current budget.
//! * [`sequencer`]: the absolute, drift-free phase schedule and the trigger decision.
//! * [`controller`]: requests in, replies and events out; counters; host-silence timeout.
//! * [`probe`]: the loopback probe's edge times and WS2812 decoding.
//! * [`version`]: firmware version and git hash baked in at build time.
//!
//! The board code (`src/main.rs`, RP2040 only) is a thin layer of embassy tasks around
//! these types.
#![cfg_attr(not(test), no_std)]
#![warn(missing_docs)]

pub mod controller;
pub mod leds;
pub mod pins;
pub mod probe;
pub mod sequencer;
pub mod version;

pub use controller::{Controller, Effect, Identity};
pub use leds::{PhaseFrame, compose_phase};
pub use sequencer::{PhasePlan, Sequencer};

/// Largest number of WS2812 pixels per strip. The board always clocks out this many
/// pixels (unused ones dark), so the LED write time does not depend on the configured
/// strip length.
pub const MAX_LEDS_PER_STRIP: u16 = 32;
