//! `stereotac flash`: reboots the sensor into its USB bootloader and copies a UF2 file
//! onto the boot drive (RPI-RP2).

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use stereotac::clock::{HostClock, MonotonicClock};
use stereotac_protocol::Request;

use crate::sensor_args::{DeviceArgs, open};

/// `stereotac flash`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The UF2 file (from `stereotac firmware-image ELF --uf2 OUT`).
    pub file: PathBuf,
    /// How long to wait for the boot drive, seconds.
    #[arg(long, default_value_t = 15)]
    pub wait_s: u64,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// Where an RP2040 boot drive (label RPI-RP2) gets mounted.
fn boot_drive() -> Option<PathBuf> {
    let user = std::env::var("USER").unwrap_or_default();
    let candidates = [
        PathBuf::from(format!("/media/{user}/RPI-RP2")),
        PathBuf::from(format!("/run/media/{user}/RPI-RP2")),
        PathBuf::from("/media/RPI-RP2"),
        PathBuf::from("/Volumes/RPI-RP2"),
    ];
    candidates
        .into_iter()
        .find(|p| p.join("INFO_UF2.TXT").exists())
}

pub fn run(a: Args) -> Result<()> {
    let file = &a.file;
    let data = std::fs::read(file).with_context(|| format!("reading {}", file.display()))?;
    if data.len() < 512 || data.len() % 512 != 0 || data[..4] != [0x55, 0x46, 0x32, 0x0A] {
        bail!(
            "{} is not a UF2 file (make one with `stereotac firmware-image ELF --uf2 OUT`)",
            file.display()
        );
    }
    let mut opened = open(&a.device)?;
    opened
        .sensor
        .request(Request::EnterBootloader)
        .context("asking the sensor to enter its USB bootloader")?;
    println!(
        "sensor acknowledged; waiting up to {} s for the RPI-RP2 drive…",
        a.wait_s
    );
    let clock = MonotonicClock::new();
    let until = clock.now_us() + a.wait_s * 1_000_000;
    while clock.now_us() < until {
        if let Some(drive) = boot_drive() {
            let target = drive.join("stereotac-firmware.uf2");
            std::fs::write(&target, &data)
                .with_context(|| format!("writing {}", target.display()))?;
            println!(
                "wrote {} ({} blocks) to {}; the sensor reboots into the new firmware",
                file.display(),
                data.len() / 512,
                drive.display()
            );
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    bail!(
        "the RPI-RP2 drive did not appear (not mounted automatically?). Mount it and copy the file yourself:\n  cp {} /path/to/RPI-RP2/",
        file.display()
    )
}
