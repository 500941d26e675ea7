//! The options of the commands that talk to a sensor (`--serial`, `--sim`, `--libusb`)
//! and the sensor they open: over USB (nusb, or libusb when built with it), or the
//! built-in simulated sensor in real time.

use std::sync::{Arc, Mutex};

use anyhow::{Context, Result, bail};
use stereotac::clock::{HostClock, MonotonicClock};
use stereotac::device::{Sensor, SensorConfig};
use stereotac::sim::link::{LedTimeline, LoopbackConfig};
use stereotac::transport::{Connector, UsbSensor, usb};

/// Board id of the simulated sensor.
const SIM_BOARD: [u8; 8] = *b"SIMSENSR";

/// Which sensor to talk to.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct DeviceArgs {
    /// Serial number of the sensor (required when several are attached).
    #[arg(long)]
    pub serial: Option<String>,
    /// Talk to the built-in simulated sensor instead of USB hardware.
    #[arg(long)]
    pub sim: bool,
    /// Use libusb instead of the built-in pure-Rust USB stack (needs a build with
    /// `--features libusb`).
    #[arg(long, conflicts_with = "sim")]
    pub libusb: bool,
}

impl DeviceArgs {
    /// The argument ids, as clap knows them.
    pub const IDS: [&str; 3] = ["serial", "sim", "libusb"];

    fn is_set(&self) -> bool {
        self.serial.is_some() || self.sim || self.libusb
    }

    /// Adds the options given before the command word (`stereotac --sim info`).
    pub fn take_before_command(&mut self, before: DeviceArgs) -> Result<()> {
        if before.serial.is_some() && self.serial.is_some() && before.serial != self.serial {
            bail!("--serial is given twice with different values");
        }
        self.serial = self.serial.take().or(before.serial);
        self.sim |= before.sim;
        self.libusb |= before.libusb;
        if self.sim && self.libusb {
            bail!("the argument '--sim' cannot be used with '--libusb'");
        }
        Ok(())
    }

    /// Refuses sensor options before a command that does not talk to a sensor.
    pub fn refuse_before(&self, command: &str) -> Result<()> {
        if self.is_set() {
            bail!(
                "`{command}` does not talk to a sensor: --serial, --sim and --libusb apply to \
                 devices, info, selftest, stream, run, record, set and flash"
            );
        }
        Ok(())
    }
}

/// An open sensor, plus the simulation's LED truth when it is simulated.
pub struct Opened {
    /// The connected sensor.
    pub sensor: Sensor,
    /// What the simulated LEDs showed (with `--sim`), for simulated cameras.
    pub timeline: Option<Arc<Mutex<LedTimeline>>>,
}

/// Connects to the sensor `device` names.
pub fn open(device: &DeviceArgs) -> Result<Opened> {
    let clock: Arc<dyn HostClock> = Arc::new(MonotonicClock::new());
    if device.sim {
        let now = clock.now_us();
        let link = LoopbackConfig {
            drift_ppm: 25.0,
            boot_at_us: now,
            seed: now,
            ..LoopbackConfig::default()
        };
        let rig =
            stereotac::sim::connect(SIM_BOARD, clock, link).context("connecting to the sensor")?;
        return Ok(Opened {
            sensor: rig.sensor,
            timeline: Some(rig.timeline),
        });
    }
    let sensor = Sensor::connect(usb_connector(device)?, clock, SensorConfig::default())
        .context("connecting to the sensor")?;
    Ok(Opened {
        sensor,
        timeline: None,
    })
}

/// The sensors on the bus, through the backend `--libusb` asks for.
pub fn list_sensors(device: &DeviceArgs) -> Result<Vec<UsbSensor>> {
    if device.libusb {
        #[cfg(feature = "libusb")]
        return stereotac::transport::libusb::list().context("listing USB devices (libusb)");
        #[cfg(not(feature = "libusb"))]
        bail!(NO_LIBUSB);
    }
    usb::list().context("listing USB devices")
}

/// The connector `--serial`/`--libusb` ask for.
fn usb_connector(device: &DeviceArgs) -> Result<Connector> {
    if device.libusb {
        return libusb_connector(device.serial.clone());
    }
    Ok(Box::new(usb::UsbConnector::new(device.serial.clone())))
}

#[cfg(feature = "libusb")]
fn libusb_connector(serial: Option<String>) -> Result<Connector> {
    Ok(Box::new(
        stereotac::transport::libusb::LibusbConnector::new(serial),
    ))
}

#[cfg(not(feature = "libusb"))]
fn libusb_connector(_serial: Option<String>) -> Result<Connector> {
    bail!(NO_LIBUSB)
}

#[cfg(not(feature = "libusb"))]
const NO_LIBUSB: &str = "this build has no libusb backend; rebuild with `--features libusb` \
    (needs libusb-1.0-0-dev and pkg-config), or drop --libusb to use the built-in USB stack";
