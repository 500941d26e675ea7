//! `stereotac flash`: reboots the sensor into its USB bootloader and copies a UF2 file
//! onto the boot drive (RPI-RP2).

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use stereotac::clock::{HostClock, MonotonicClock};
use stereotac::uf2::{MAX_UF2_BYTES, check_uf2};
use stereotac_protocol::Request;

use crate::sensor_args::{DeviceArgs, open};

/// `stereotac flash`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The UF2 file (from `stereotac firmware-image ELF --uf2 OUT`).
    pub file: PathBuf,
    /// How long to wait for the boot drive, seconds (1 to 600).
    #[arg(long, default_value_t = 15, value_parser = clap::value_parser!(u64).range(1..=600))]
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

/// The file's bytes, refused unread past [`MAX_UF2_BYTES`].
fn read_bounded(file: &Path) -> Result<Vec<u8>> {
    use std::io::Read;
    let mut data = Vec::new();
    std::fs::File::open(file)
        .and_then(|f| f.take(MAX_UF2_BYTES + 1).read_to_end(&mut data))
        .with_context(|| format!("reading {}", file.display()))?;
    anyhow::ensure!(
        data.len() as u64 <= MAX_UF2_BYTES,
        "{}: larger than any RP2040 image ({MAX_UF2_BYTES} bytes)",
        file.display()
    );
    Ok(data)
}

pub fn run(a: Args) -> Result<()> {
    let file = &a.file;
    let data = read_bounded(file)?;
    let blocks = check_uf2(&data).with_context(|| {
        format!(
            "{} is not a UF2 image for this sensor (make one with `stereotac firmware-image ELF --uf2 OUT`)",
            file.display()
        )
    })?;
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
                blocks,
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
