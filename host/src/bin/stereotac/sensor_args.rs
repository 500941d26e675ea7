//! The options of the commands that talk to a sensor (`--serial`, `--sim`, `--libusb`)
//! and the sensor they open: over USB (nusb, or libusb when built with it), or the
//! built-in simulated sensor in real time.

use anyhow::{Context, Result, bail};
use stereotac::sensors::{self, SensorChoice};
use stereotac::transport::{UsbSensor, usb};

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
pub use stereotac::sensors::OpenedSensor as Opened;

impl DeviceArgs {
    /// The sensor these options name.
    pub fn choice(&self) -> SensorChoice {
        SensorChoice {
            serial: self.serial.clone(),
            sim: self.sim,
            libusb: self.libusb,
        }
    }
}

/// Connects to the sensor `device` names.
pub fn open(device: &DeviceArgs) -> Result<Opened> {
    Ok(sensors::open(&device.choice())?)
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

#[cfg(not(feature = "libusb"))]
const NO_LIBUSB: &str = "this build has no libusb backend; rebuild with `--features libusb` \
    (needs libusb-1.0-0-dev and pkg-config), or drop --libusb to use the built-in USB stack";
