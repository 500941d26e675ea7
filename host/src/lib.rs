//! # stereotac (host library)
//!
//! The host side of the stereotac visuotactile sensor.
//!
//! * [`sim`]: a simulated sensor that runs the firmware's own command handling and
//!   sequencer on a virtual clock, behind the real wire framing. It is the device end of
//!   the in-memory link used by the demo and the tests.
//! * [`transport`]: byte pipes to a sensor: USB (nusb), the in-memory loopback with
//!   simulated USB timing and a drifting device clock.
//! * [`client`]: the protocol client over any transport (request/reply matching,
//!   handshake with version check, time-sync pings, event collection).
//! * [`clock`]: host clocks and the device→host clock sync.
//! * [`device`]: a connected sensor: events on the host clock, reconnect with backoff.
//! * [`selftest`]: command conformance of any connected sensor (`stereotac selftest`).
//! * [`matcher`]: which LED phase lit each camera frame.
//! * [`frames`]: frame sources (simulated camera, replay), live capture, recording.
//! * [`tactile`]: photometric-stereo reconstruction.
//! * [`uf2`]: converts the firmware ELF into a UF2 image for drag-and-drop flashing and
//!   reports its flash and RAM footprint.
#![warn(missing_docs)]

pub mod client;
pub mod clock;
pub mod device;
pub mod frames;
pub mod matcher;
pub mod output;
pub mod selftest;
pub mod sim;
pub mod stereo;
pub mod tactile;
pub mod transport;
pub mod uf2;
