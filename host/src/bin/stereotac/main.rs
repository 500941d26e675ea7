//! The `stereotac` command-line tool: the command list and dispatch. Each command is one
//! file in `cmd/` (its arguments and `run`); the work itself is the `stereotac` library's.

use std::process::ExitCode;

use anyhow::Result;
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

/// `println!` for this binary: a closed stdout (`stereotac calibrate … | head -1`) drops
/// the rest of the output instead of panicking, so the command still finishes its work (a
/// model is still saved, outputs still written). Commands that stream use
/// [`console::emit`] directly and stop when it fails.
macro_rules! println {
    () => {{
        let _ = $crate::console::emit(format_args!(""));
    }};
    ($($arg:tt)*) => {{
        let _ = $crate::console::emit(format_args!($($arg)*));
    }};
}

/// `print!` with the same rule as [`println!`].
macro_rules! print {
    ($($arg:tt)*) => {{
        let _ = $crate::console::emit_raw(format_args!($($arg)*));
    }};
}

mod allocator;
mod args;
mod cameras;
mod cmd;
mod console;
mod live_report;
mod live_session;
mod progress;
mod sensor_args;
mod stages;

use sensor_args::DeviceArgs;

/// stereotac: visuotactile sensor toolkit (firmware link, tactile and stereo depth).
#[derive(Debug, Parser)]
#[command(
    version,
    about,
    long_about = None,
    after_help = "The commands that talk to a sensor (devices, info, selftest, stream, run, record, \
                  set, flash) take --sim, --serial and --libusb, after the command or before it."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// The sensor options may also stand before the command (`stereotac --sim info`);
    /// they are hidden here and shown on the commands that talk to a sensor.
    #[command(flatten)]
    device: DeviceArgs,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run a simulated sensor (the firmware's own logic on a virtual clock, behind the
    /// real wire protocol) and show its handshake, phase timeline and counters.
    Demo(cmd::demo::Args),
    /// List attached sensors (serial number, firmware version, bus path).
    Devices(cmd::devices::Args),
    /// Handshake details, configuration, device counters and clock sync of one sensor.
    Info(cmd::info::Args),
    /// Check that the sensor answers every command as the protocol says (invalid values
    /// refused with typed errors, configuration read back, then restored).
    Selftest(cmd::selftest::Args),
    /// Run the lighting sequence and print phase events with host-clock timestamps,
    /// clock-sync uncertainty and drop counters (Ctrl-C stops).
    Stream(cmd::stream::Args),
    /// Sensor and cameras in, depth out, live: tactile depth from dx/dy pairs, stereo
    /// depth from two cameras' dark frames (`--jsonl` for a control loop, `--mcap` to
    /// record, `--foxglove` for a live view).
    Run(cmd::run::Args),
    /// The live pipeline offline, on a recording (MCAP): the same depth, bit for bit.
    Process(cmd::process::Args),
    /// A recording's dx/dy and stereo pairs as PNG files (`--pairs DIR`).
    Export(cmd::export::Args),
    /// Record camera frames, LED phases, clock sync and the sensor's identity to an MCAP
    /// file (`--png` for PNG frames plus an index.jsonl); Ctrl-C finishes cleanly without
    /// losing a captured frame.
    Record(cmd::record::Args),
    /// Change colours, brightness, timing, LED count, power budget or mode.
    Set(cmd::set::Args),
    /// Reboot the sensor into its USB bootloader and copy a UF2 file onto the boot drive.
    Flash(cmd::flash::Args),
    /// Calibrate the tactile model from ball presses: a recording (MCAP) or a folder of
    /// NAME_dx.png / NAME_dy.png pairs.
    Calibrate(cmd::calibrate::Args),
    /// Reconstruct the depth of one dx/dy pair into depth.npy, PNGs, PLY and summary.json.
    Reconstruct(cmd::reconstruct::Args),
    /// Stereo depth of one rectifiable pair: disparity and depth (.npy, PNG), point cloud
    /// (PLY) and summary.json. `--synthetic MM` uses a built-in capture instead.
    Stereo(cmd::stereo::Args),
    /// Depth-camera metrics (Z-accuracy, RMS error, temporal noise, fill rate) on built-in
    /// captures of flat targets behind the skin, with and without post-filters.
    StereoEval(cmd::stereo_eval::Args),
    /// Stereo calibration from checkerboard pairs (pinhole or fisheye), written as the
    /// OpenCV YAML `stereo --calib` reads; `--synthetic N` uses built-in views. Needs
    /// the `calibrate` cargo feature.
    StereoCalibrate(cmd::stereo_calibrate::Args),
    /// A stereo calibration in the other formats: OpenCV YAML (mm) and a ROS camera_info
    /// pair (metres), each checked to read back as what was read.
    StereoConvert(cmd::stereo_convert::Args),
    /// Benchmarks on built-in synthetic data.
    Bench(cmd::bench::Args),
    /// Report a firmware ELF's flash and RAM footprint, and optionally write it as UF2.
    FirmwareImage(cmd::firmware_image::Args),
}

impl Command {
    /// The sensor options of a command that talks to a sensor.
    fn device_mut(&mut self) -> Option<&mut DeviceArgs> {
        match self {
            Command::Devices(a) => Some(&mut a.device),
            Command::Info(a) => Some(&mut a.device),
            Command::Selftest(a) => Some(&mut a.device),
            Command::Stream(a) => Some(&mut a.device),
            Command::Record(a) => Some(&mut a.device),
            Command::Run(a) => Some(&mut a.device),
            Command::Set(a) => Some(&mut a.device),
            Command::Flash(a) => Some(&mut a.device),
            _ => None,
        }
    }
}

fn run(cli: Cli, name: &str) -> Result<()> {
    let mut command = cli.command;
    match command.device_mut() {
        Some(device) => device.take_before_command(cli.device)?,
        None => cli.device.refuse_before(name)?,
    }
    match command {
        Command::Demo(a) => cmd::demo::run(a),
        Command::Devices(a) => cmd::devices::run(a),
        Command::Info(a) => cmd::info::run(a),
        Command::Selftest(a) => cmd::selftest::run(a),
        Command::Stream(a) => cmd::stream::run(a),
        Command::Record(a) => cmd::record::run(a),
        Command::Run(a) => cmd::run::run(a),
        Command::Process(a) => cmd::process::run(a),
        Command::Export(a) => cmd::export::run(a),
        Command::Set(a) => cmd::set::run(a),
        Command::Flash(a) => cmd::flash::run(a),
        Command::Calibrate(a) => cmd::calibrate::run(a),
        Command::Reconstruct(a) => cmd::reconstruct::run(a),
        Command::Stereo(a) => cmd::stereo::run(a),
        Command::StereoEval(a) => cmd::stereo_eval::run(a),
        Command::StereoCalibrate(a) => cmd::stereo_calibrate::run(a),
        Command::StereoConvert(a) => cmd::stereo_convert::run(a),
        Command::Bench(a) => cmd::bench::run(a),
        Command::FirmwareImage(a) => cmd::firmware_image::run(a),
    }
}

/// The parser: the sensor options before the command are accepted but not listed in
/// the top-level help (each sensor command lists them).
fn parser() -> clap::Command {
    let mut top = Cli::command();
    for id in DeviceArgs::IDS {
        top = top.mut_arg(id, |a| a.hide(true));
    }
    top
}

fn main() -> ExitCode {
    allocator::keep_frame_buffers();
    console::write_errors_not_signals();
    let matches = parser().get_matches();
    let name = matches.subcommand_name().unwrap_or_default().to_string();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    match run(cli, &name) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", message(&e));
            ExitCode::FAILURE
        }
    }
}

/// An error and its causes on one line, each cause once: library errors often show their
/// source in their own message already, and anyhow's chain would repeat it.
fn message(e: &anyhow::Error) -> String {
    let mut text = e.to_string();
    for cause in e.chain().skip(1) {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            text.push_str(": ");
            text.push_str(&cause);
        }
    }
    text
}
