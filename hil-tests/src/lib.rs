//! Hardware-in-loop tests of the stereotac firmware.
//!
//! The release firmware ELF runs in an emulated RP2040 ([`emulator`]: rp2040js driven
//! in lock-step from Rust, see `emulator/harness.mjs`), and the host library talks to
//! it through [`emulator::EmulatedTransport`], a [`stereotac::transport::Transport`]
//! like USB: the tests use the same host code as a real sensor. The emulator also
//! traces the LED and trigger pins with simulated timestamps ([`trace`]), which
//! [`ws2812`] decodes into the colours each strip latched. [`events`] checks what the
//! sensor's own phase events promise, for the emulator and a real sensor alike;
//! [`probe`] checks what the firmware's loopback probe saw on its own pins, which is
//! how a real sensor gets the pin checks; [`scenarios`] holds the runs both kinds of
//! test drive.
//!
//! `cargo test -p stereotac-hil-tests` runs the emulated tests; they build the firmware
//! (`cargo fw`) and install the emulator (`npm ci`) on first use. See the README for
//! running them against a real sensor (`STEREOTAC_HIL=device`).

pub mod emulator;
pub mod events;
pub mod probe;
pub mod scenarios;
pub mod setup;
pub mod trace;
pub mod ws2812;
