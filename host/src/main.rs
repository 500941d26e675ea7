//! The `stereotac` command-line tool.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};

mod demo;

/// stereotac: visuotactile sensor toolkit (firmware link, tactile and stereo depth).
#[derive(Debug, Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run a simulated sensor (the firmware's own logic on a virtual clock, behind the
    /// real wire protocol) and show its handshake, phase timeline and counters.
    Demo {
        /// Lighting mode to run.
        #[arg(long, value_enum, default_value_t = DemoMode::Gradient)]
        mode: DemoMode,
        /// Phase period in milliseconds.
        #[arg(long, default_value_t = 250)]
        period_ms: u32,
        /// Number of phases to run.
        #[arg(long, default_value_t = 12)]
        phases: u32,
    },
    /// Report a firmware ELF's flash and RAM footprint, and optionally write it as UF2.
    FirmwareImage {
        /// The firmware ELF (e.g. target/thumbv6m-none-eabi/firmware/stereotac-firmware).
        elf: PathBuf,
        /// Write a UF2 file here for drag-and-drop flashing.
        #[arg(long)]
        uf2: Option<PathBuf>,
    },
}

/// Lighting modes selectable from the command line.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum DemoMode {
    /// LEDs dark, cameras triggered: stereo vision.
    Vision,
    /// All strips lit: contact shape.
    Contact,
    /// dx/dy alternating: photometric stereo.
    Gradient,
    /// dark, dx, dy: vision and gradients together.
    Interleaved,
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Demo {
            mode,
            period_ms,
            phases,
        } => demo::run(mode, period_ms, phases),
        Command::FirmwareImage { elf, uf2 } => {
            let image = stereotac::uf2::FirmwareImage::read(&elf)
                .with_context(|| format!("reading firmware {}", elf.display()))?;
            println!(
                "firmware {}: flash {} bytes ({:.1} KiB of 2048 KiB), static RAM {} bytes ({:.1} KiB of 264 KiB)",
                elf.display(),
                image.flash_bytes,
                image.flash_bytes as f64 / 1024.0,
                image.ram_bytes,
                image.ram_bytes as f64 / 1024.0
            );
            if let Some(out) = uf2 {
                let blocks = image.write_uf2(&out)?;
                println!("wrote {} ({blocks} UF2 blocks)", out.display());
            }
            Ok(())
        }
    }
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
