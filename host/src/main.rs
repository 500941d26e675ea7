//! The `stereotac` command-line tool.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};

mod calibrate_cli;
mod demo;
mod demo_stereo;
mod demo_tactile;
mod link_cli;
mod progress;
mod stereo_cli;
mod tactile_cli;

/// stereotac: visuotactile sensor toolkit (firmware link, tactile and stereo depth).
#[derive(Debug, Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    #[command(flatten)]
    device: link_cli::DeviceArgs,
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
        /// Where the tactile and stereo parts write their outputs.
        #[arg(long, default_value = "stereotac-demo-out")]
        out: PathBuf,
        /// Skip the tactile part (calibration and reconstruction).
        #[arg(long)]
        no_tactile: bool,
        /// Skip the stereo part (one vision frame through the wide lenses).
        #[arg(long)]
        no_stereo: bool,
    },
    /// List attached sensors (serial number, firmware version, bus path).
    Devices {
        /// Print JSON.
        #[arg(long)]
        json: bool,
        /// Keep watching: print sensors as they are plugged in and devices as they leave
        /// (Ctrl-C stops).
        #[arg(long, conflicts_with = "sim")]
        watch: bool,
    },
    /// Handshake details, configuration, device counters and clock sync of one sensor.
    Info {
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Check that the sensor answers every command as the protocol says (invalid values
    /// refused with typed errors, configuration read back, then restored).
    Selftest {
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Run the lighting sequence and print phase events with host-clock timestamps,
    /// clock-sync uncertainty and drop counters (Ctrl-C stops).
    Stream {
        #[command(flatten)]
        sequence: link_cli::SequenceArgs,
        /// One JSON object per line.
        #[arg(long)]
        json: bool,
    },
    /// Record camera frames as PNG plus an index (index.jsonl) of phase, trigger and
    /// timestamps; Ctrl-C finishes cleanly without losing a captured frame.
    Record(link_cli::RecordArgs),
    /// Change colours, brightness, timing, LED count, power budget or mode.
    Set(link_cli::SetArgs),
    /// Reboot the sensor into its USB bootloader and copy a UF2 file onto the boot drive.
    Flash {
        /// The UF2 file (from `stereotac firmware-image ELF --uf2 OUT`).
        file: PathBuf,
        /// How long to wait for the boot drive, seconds.
        #[arg(long, default_value_t = 15)]
        wait_s: u64,
    },
    /// Calibrate the tactile model from ball presses: DIR holds NAME_dx.png / NAME_dy.png.
    Calibrate(tactile_cli::CalibrateArgs),
    /// Reconstruct the depth of one dx/dy pair into depth.npy, PNGs, PLY and summary.json.
    Reconstruct(tactile_cli::ReconstructArgs),
    /// Stereo depth of one rectifiable pair: disparity and depth (.npy, PNG), point cloud
    /// (PLY) and summary.json. `--synthetic MM` uses a built-in capture instead.
    Stereo(stereo_cli::StereoArgs),
    /// Depth-camera metrics (Z-accuracy, RMS error, temporal noise, fill rate) on built-in
    /// captures of flat targets behind the skin, with and without post-filters.
    StereoEval(stereo_cli::StereoEvalArgs),
    /// Stereo calibration from checkerboard pairs (pinhole or fisheye), written as the
    /// OpenCV YAML `stereo --calib` reads; `--synthetic N` uses built-in views. Needs
    /// the `calibrate` cargo feature.
    StereoCalibrate(calibrate_cli::CalibrateStereoArgs),
    /// Benchmarks on built-in synthetic data.
    Bench {
        #[command(subcommand)]
        what: BenchWhat,
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

#[derive(Debug, Subcommand)]
enum BenchWhat {
    /// Tactile pipeline: time per stage against depth error, per scene, model and solver.
    Tactile {
        /// Print JSON records instead of the table.
        #[arg(long)]
        json: bool,
        /// Also write the JSON report to this file.
        #[arg(long)]
        json_out: Option<PathBuf>,
        /// Frame sizes (default 640x480 and 1280x960).
        #[arg(long = "size", value_parser = tactile_cli::parse_size)]
        sizes: Vec<(usize, usize)>,
        /// Repeats per measurement; the median is reported.
        #[arg(long, default_value_t = 15)]
        repeats: usize,
    },
    /// Stereo: remap, matching (per kernel, against OpenCV with --opencv) and the whole
    /// vision frame on 1 and 2 threads.
    Stereo(stereo_cli::BenchStereoArgs),
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
            out,
            no_tactile,
            no_stereo,
        } => {
            demo::run(
                mode,
                period_ms,
                phases,
                (!no_tactile).then_some(out.as_path()),
            )?;
            if no_stereo {
                Ok(())
            } else {
                demo_stereo::run(&out)
            }
        }
        Command::Devices { json, watch: true } => link_cli::watch_devices(json),
        Command::Devices { json, watch: false } => link_cli::devices(&cli.device, json),
        Command::Info { json } => link_cli::info(&cli.device, json),
        Command::Selftest { json } => link_cli::selftest(&cli.device, json),
        Command::Stream { sequence, json } => link_cli::stream(&cli.device, &sequence, json),
        Command::Record(args) => link_cli::record(&cli.device, &args),
        Command::Set(args) => link_cli::set(&cli.device, &args),
        Command::Flash { file, wait_s } => link_cli::flash(&cli.device, &file, wait_s),
        Command::Calibrate(args) => tactile_cli::calibrate_cmd(args),
        Command::Reconstruct(args) => tactile_cli::reconstruct_cmd(args),
        Command::Bench {
            what:
                BenchWhat::Tactile {
                    json,
                    json_out,
                    sizes,
                    repeats,
                },
        } => tactile_cli::bench_tactile(sizes, repeats, json, json_out.as_deref()),
        Command::Bench {
            what: BenchWhat::Stereo(args),
        } => stereo_cli::bench_stereo(&args),
        Command::Stereo(args) => stereo_cli::stereo_cmd(args),
        Command::StereoEval(args) => stereo_cli::stereo_eval_cmd(args),
        Command::StereoCalibrate(args) => calibrate_cli::calibrate_stereo_cmd(args),
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
