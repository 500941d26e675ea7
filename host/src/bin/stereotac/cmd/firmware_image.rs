//! `stereotac firmware-image`: a firmware ELF's flash and RAM footprint, and optionally
//! the UF2 image for drag-and-drop flashing.

use std::path::PathBuf;

use anyhow::{Context, Result};
use stereotac::uf2::FirmwareImage;

/// `stereotac firmware-image`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The firmware ELF (e.g. target/thumbv6m-none-eabi/firmware/stereotac-firmware).
    pub elf: PathBuf,
    /// Write a UF2 file here for drag-and-drop flashing.
    #[arg(long)]
    pub uf2: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    let image = FirmwareImage::read(&a.elf)
        .with_context(|| format!("reading firmware {}", a.elf.display()))?;
    println!(
        "firmware {}: flash {} bytes ({:.1} KiB of 2048 KiB), static RAM {} bytes ({:.1} KiB of 264 KiB)",
        a.elf.display(),
        image.flash_bytes,
        image.flash_bytes as f64 / 1024.0,
        image.ram_bytes,
        image.ram_bytes as f64 / 1024.0
    );
    if let Some(out) = a.uf2 {
        let blocks = image.write_uf2(&out)?;
        println!("wrote {} ({blocks} UF2 blocks)", out.display());
    }
    Ok(())
}
