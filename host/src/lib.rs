//! # stereotac (host library)
//!
//! The host side of the stereotac visuotactile sensor.
//!
//! * [`sim`]: a simulated sensor that runs the firmware's own command handling and
//!   sequencer on a virtual clock, behind the real wire framing. It is the device end of
//!   the in-memory link used by the demo and the tests.
//! * [`client`]: a minimal protocol client over any byte link (request/reply matching,
//!   handshake with version check, event collection).
//! * [`uf2`]: converts the firmware ELF into a UF2 image for drag-and-drop flashing and
//!   reports its flash and RAM footprint.
#![warn(missing_docs)]

pub mod client;
pub mod clock;
pub mod device;
pub mod frames;
pub mod matcher;
pub mod sim;
pub mod tactile;
pub mod transport;
pub mod uf2;
