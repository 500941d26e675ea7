//! Getting a test its sensor: the release firmware ELF (built with `cargo fw` when
//! missing), the emulator's npm packages (`npm ci` when missing), and one booted
//! emulator with the host library's [`Sensor`] connected through it.
//!
//! `STEREOTAC_HIL` chooses the target: unset or `emulator` (default), `device` (an
//! attached sensor over USB; see the README), or `off` (skip, with a message).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, Mutex, OnceLock};

use stereotac::device::{Sensor, SensorConfig, SensorError};
use stereotac::transport::connect_once;

use crate::emulator::{EmulatedClock, EmulatedTransport, Emulator, SharedEmulator, harness_dir};

/// Where the tests run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    /// The firmware ELF in the emulated RP2040.
    Emulator,
    /// A sensor attached over USB.
    Device,
    /// Skip.
    Off,
}

/// The target `STEREOTAC_HIL` asks for.
pub fn target() -> Target {
    match std::env::var("STEREOTAC_HIL").as_deref() {
        Ok("device") => Target::Device,
        Ok("off") => Target::Off,
        _ => Target::Emulator,
    }
}

/// The workspace root.
fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("hil-tests sits in the workspace")
        .to_path_buf()
}

fn run(command: &mut Command, what: &str) -> Result<(), String> {
    let status = command
        .status()
        .map_err(|e| format!("{what}: could not start: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("{what} failed ({status})"))
    }
}

/// The firmware ELF: `STEREOTAC_FIRMWARE_ELF`, or the `cargo fw` output (built once
/// per test run when missing).
pub fn firmware_elf() -> Result<PathBuf, String> {
    static ELF: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    ELF.get_or_init(|| {
        if let Ok(path) = std::env::var("STEREOTAC_FIRMWARE_ELF") {
            return Ok(PathBuf::from(path));
        }
        let root = workspace();
        let elf = root.join("target/thumbv6m-none-eabi/firmware/stereotac-firmware");
        if !elf.exists() {
            let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
            run(
                Command::new(cargo).arg("fw").current_dir(&root),
                "building the firmware (cargo fw)",
            )?;
        }
        Ok(elf)
    })
    .clone()
}

/// Install the emulator's npm packages once when missing.
pub fn emulator_packages() -> Result<(), String> {
    static NPM: OnceLock<Result<(), String>> = OnceLock::new();
    NPM.get_or_init(|| {
        let dir = harness_dir();
        if dir.join("node_modules/rp2040js").exists() {
            return Ok(());
        }
        run(
            Command::new("npm")
                .args(["ci", "--no-audit", "--no-fund"])
                .current_dir(&dir),
            "installing the emulator (npm ci in hil-tests/emulator)",
        )
    })
    .clone()
}

/// A booted emulator and the host clock of the test.
#[derive(Debug, Clone)]
pub struct Rig {
    /// The emulator, shared with the transport.
    pub emulator: SharedEmulator,
    /// The host clock: simulated time + 1000 s, 30 ppm fast.
    pub clock: EmulatedClock,
}

/// Host clock offset from simulated time, µs.
pub const HOST_OFFSET_US: u64 = 1_000_000_000;
/// Host clock rate error against the device's crystal, ppm.
pub const HOST_PPM: f64 = 30.0;

impl Rig {
    /// Boot the firmware in the emulator.
    pub fn boot() -> Result<Self, String> {
        emulator_packages()?;
        let elf = firmware_elf()?;
        let emulator = Emulator::start(&elf).map_err(|e| e.to_string())?;
        let emulator = Arc::new(Mutex::new(emulator));
        let clock = EmulatedClock::new(Arc::clone(&emulator), HOST_OFFSET_US, HOST_PPM);
        Ok(Self { emulator, clock })
    }

    /// A transport to the emulated sensor.
    pub fn transport(&self) -> EmulatedTransport {
        EmulatedTransport::new(Arc::clone(&self.emulator), self.clock.clone())
    }

    /// The host library's [`Sensor`] on the emulated one (connects once; a reconnect
    /// after the emulator stops fails as an unplugged sensor would).
    pub fn sensor(&self, config: SensorConfig) -> Result<Sensor, SensorError> {
        Sensor::connect(
            connect_once(self.transport()),
            Arc::new(self.clock.clone()),
            config,
        )
    }
}
