//! The simulated sensor, in one place: the firmware's own logic on a virtual clock
//! ([`sensor`]), the USB link and drifting device clock in front of it ([`link`]), and
//! the camera that renders what its LEDs showed ([`camera`]).
//!
//! These are test inputs and the demo's data, never a replacement for the real code
//! path: the host reaches the simulated sensor through the same wire frames,
//! [`Sensor`], clock sync and matcher it uses with hardware. [`connect`] is the one way
//! the CLI (`--sim`), the demo and the tests wire a simulated sensor to a [`Sensor`].

pub mod camera;
pub mod link;
pub mod sensor;

use std::sync::{Arc, Mutex};

use crate::clock::HostClock;
use crate::device::{Sensor, SensorConfig, SensorError};
use crate::transport::connect_once;
use link::{LedTimeline, Loopback, LoopbackConfig, PlugHandle};

/// A simulated sensor behind the simulated USB link, connected like a real one.
#[derive(Debug)]
pub struct SimulatedRig {
    /// The connected sensor (handshake and first clock sync done).
    pub sensor: Sensor,
    /// What the LEDs really showed, on the host clock: the simulated camera renders it.
    pub timeline: Arc<Mutex<LedTimeline>>,
    /// Pulls the simulated cable (tests of unplugging and reconnection).
    pub plug: PlugHandle,
}

/// Connects a simulated sensor with board id `board_id` through a [`Loopback`] link
/// configured by `link`, on `clock` (a virtual clock for deterministic runs, the
/// monotonic clock for real time).
pub fn connect(
    board_id: [u8; 8],
    clock: Arc<dyn HostClock>,
    link: LoopbackConfig,
) -> Result<SimulatedRig, SensorError> {
    let link = Loopback::new(board_id, Arc::clone(&clock), link);
    let timeline = link.timeline();
    let plug = link.plug_handle();
    let sensor = Sensor::connect(connect_once(link), clock, SensorConfig::default())?;
    Ok(SimulatedRig {
        sensor,
        timeline,
        plug,
    })
}
