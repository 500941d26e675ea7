//! Which sensor to talk to, and opening it: a USB sensor (nusb, or libusb in builds with
//! the `libusb` feature) by serial number, or the built-in simulated sensor in real time
//! (the firmware's own logic behind the real wire frames). One place for the CLI and the
//! Python package.

use std::sync::{Arc, Mutex};

use crate::clock::{HostClock, MonotonicClock};
use crate::device::{Sensor, SensorConfig, SensorError};
use crate::sim::link::{LedTimeline, LoopbackConfig};
use crate::transport::{Connector, usb};

/// Board id of the simulated sensor.
pub const SIM_BOARD: [u8; 8] = *b"SIMSENSR";

/// Which sensor.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SensorChoice {
    /// Serial number (needed when several sensors are attached).
    pub serial: Option<String>,
    /// The built-in simulated sensor instead of USB hardware.
    pub sim: bool,
    /// libusb instead of the built-in pure-Rust USB stack.
    pub libusb: bool,
}

/// A connected sensor, and what the simulated LEDs showed when it is simulated (for
/// simulated cameras).
pub struct OpenedSensor {
    /// The sensor.
    pub sensor: Sensor,
    /// The simulated sensor's LED timeline.
    pub timeline: Option<Arc<Mutex<LedTimeline>>>,
}

impl std::fmt::Debug for OpenedSensor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpenedSensor")
            .field("simulated", &self.timeline.is_some())
            .finish_non_exhaustive()
    }
}

/// Why no sensor could be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenSensorError {
    /// Connecting failed (none attached, no permission, the handshake failed).
    #[error("connecting to the sensor: {0}")]
    Connect(#[from] SensorError),
    /// libusb asked for in a build without it.
    #[error(
        "this build has no libusb backend; rebuild with `--features libusb` (needs \
         libusb-1.0-0-dev and pkg-config), or use the built-in USB stack"
    )]
    NoLibusb,
    /// Both the simulated sensor and libusb asked for.
    #[error("the simulated sensor is not reached through libusb: choose one")]
    SimAndLibusb,
}

/// Opens the sensor `choice` names.
pub fn open(choice: &SensorChoice) -> Result<OpenedSensor, OpenSensorError> {
    let clock: Arc<dyn HostClock> = Arc::new(MonotonicClock::new());
    if choice.sim {
        if choice.libusb {
            return Err(OpenSensorError::SimAndLibusb);
        }
        let now = clock.now_us();
        let link = LoopbackConfig {
            drift_ppm: 25.0,
            boot_at_us: now,
            seed: now,
            ..LoopbackConfig::default()
        };
        let rig = crate::sim::connect(SIM_BOARD, clock, link)?;
        return Ok(OpenedSensor {
            sensor: rig.sensor,
            timeline: Some(rig.timeline),
        });
    }
    let sensor = Sensor::connect(connector(choice)?, clock, SensorConfig::default())?;
    Ok(OpenedSensor {
        sensor,
        timeline: None,
    })
}

/// The connector `choice` asks for.
fn connector(choice: &SensorChoice) -> Result<Connector, OpenSensorError> {
    if choice.libusb {
        #[cfg(feature = "libusb")]
        return Ok(Box::new(crate::transport::libusb::LibusbConnector::new(
            choice.serial.clone(),
        )));
        #[cfg(not(feature = "libusb"))]
        return Err(OpenSensorError::NoLibusb);
    }
    Ok(Box::new(usb::UsbConnector::new(choice.serial.clone())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_simulated_sensor_opens_with_its_timeline() {
        let opened = open(&SensorChoice {
            sim: true,
            ..Default::default()
        })
        .unwrap();
        assert!(opened.timeline.is_some());
        assert_eq!(opened.sensor.info().board_id, SIM_BOARD);
        let e = open(&SensorChoice {
            sim: true,
            libusb: true,
            ..Default::default()
        })
        .unwrap_err();
        assert!(matches!(e, OpenSensorError::SimAndLibusb), "{e}");
    }
}
