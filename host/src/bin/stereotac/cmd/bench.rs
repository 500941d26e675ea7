//! `stereotac bench`: benchmarks on built-in synthetic data: `tactile` (time per stage
//! against depth error), `stereo` (remap, matching per kernel, whole frame, OpenCV in
//! the same run), `live` (the live path under load: rates, latency, CPU, memory) and
//! `skins` (the tactile goal table on tuning and evaluation skin families).

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Subcommand;
use stereotac::live::bench::{self as live_bench, LiveBenchOptions, LiveBenchProgress};
use stereotac::stereo::bench::{self as stereo_bench, BenchOptions};
use stereotac::tactile::bench::{self as tactile_bench, BenchConfig};
use stereotac::tactile::model::ModelKind;
use stereotac::tactile::skins::AmbientScale;
use stereotac::tactile::skins::evaluate::{EvalConfig, evaluate, format_report};
use stereotac::tactile::skins::families::{families, family};

use crate::args::parse_size;
use crate::console::json_report;
use crate::progress::{bar, spinner};

/// `stereotac bench`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub what: BenchWhat,
}

/// What to benchmark.
#[derive(Debug, Subcommand)]
pub enum BenchWhat {
    /// Tactile pipeline: time per stage against depth error, per scene, model and solver.
    Tactile(TactileArgs),
    /// Stereo: remap, matching (per kernel, against OpenCV with --opencv) and the whole
    /// vision frame on 1 and 2 threads.
    Stereo(StereoArgs),
    /// The live path under load: the simulated sensor in real time and two simulated
    /// cameras, interleaved mode; each stage alone, then the live loop (frames/s,
    /// latency p50/p99, CPU per frame, memory), against the goals.
    Live(LiveArgs),
    /// Tactile goal table on skin families: each skin calibrated from its own ball
    /// presses, then disks, edge balls, the skin at rest, depth beside contacts, region
    /// size and time per pair. Tuning families first, then the evaluation families
    /// (including an independent renderer) nothing was tuned on.
    Skins(SkinsArgs),
}

/// `stereotac bench skins`.
#[derive(Debug, clap::Args)]
pub struct SkinsArgs {
    /// Families to run (default: all); `--list` names them.
    #[arg(long = "family")]
    pub families: Vec<String>,
    /// List the families and exit.
    #[arg(long)]
    pub list: bool,
    /// Skins drawn per family (seeds 1..=N).
    #[arg(long, default_value_t = 1)]
    pub skins: u64,
    /// Ball presses per calibration.
    #[arg(long, default_value_t = 30)]
    pub presses: usize,
    /// Placements of each disk.
    #[arg(long, default_value_t = 30)]
    pub placements: usize,
    /// Calibrate with a ball of this diameter (mm, 2–20) instead of the family's own
    /// (`--list` gives it).
    #[arg(long, allow_negative_numbers = true, value_parser = parse_ball_mm)]
    pub ball_diameter_mm: Option<f64>,
    /// Make half of the presses with a second ball of this diameter (mm, 2–20): a
    /// smaller ball teaches the steeper slopes a larger one cannot make.
    #[arg(long, allow_negative_numbers = true, value_parser = parse_ball_mm)]
    pub second_ball_mm: Option<f64>,
    /// Frame size.
    #[arg(long, value_parser = parse_size, default_value = "640x480")]
    pub size: (u32, u32),
    /// Gradient model.
    #[arg(long, default_value = "lut")]
    pub model: ModelKind,
    /// Read with the model alone (lookup table or perceptron) where its slopes reach the
    /// calibration's limit (by default the light model reads steeper walls there): to
    /// compare the two.
    #[arg(long)]
    pub no_past_reach: bool,
    /// Interleaved mode: calibrate on LED light (LEDs-off frames subtracted) and remove
    /// each pair's ambient light with its LEDs-off frame.
    #[arg(long)]
    pub dark: bool,
    /// Measure the camera's colour crosstalk from flat-skin frames with only the blue
    /// strip lit and only the red, and calibrate with it undone (as `calibrate
    /// --blue-only-dx F --red-only-dx F` does).
    #[arg(long)]
    pub crosstalk: bool,
    /// Calibrate with the strips' side light measured and taken out of the lookup
    /// table's colours (as `calibrate --side-light` does).
    #[arg(long)]
    pub side_light: bool,
    /// Measure the camera's response curve from a flat-skin frame with all four strips
    /// lit and calibrate with it undone (as `calibrate --all-lit F` does).
    #[arg(long)]
    pub camera_curve: bool,
    /// Ambient light of the measured frames relative to the calibration's, in the dx,
    /// dy and LEDs-off exposures: e.g. 2,2,2 (the room twice as bright), 1.3,0.8,1
    /// (light flickering between exposures).
    #[arg(long, allow_hyphen_values = true, value_parser = parse_ambient, default_value = "1,1,1")]
    pub ambient: AmbientScale,
    /// Print JSON instead of the tables.
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON report here.
    #[arg(long)]
    pub json_out: Option<PathBuf>,
}

/// `stereotac bench live`.
#[derive(Debug, clap::Args)]
pub struct LiveArgs {
    /// Length of the live loop, s (10 minutes shows whether memory stays flat).
    #[arg(long, allow_negative_numbers = true, default_value_t = 600.0)]
    pub duration_s: f64,
    /// Camera frame rate (free-running).
    #[arg(long, allow_negative_numbers = true, default_value_t = 60.0)]
    pub fps: f64,
    /// LED phase period, ms.
    #[arg(long, default_value_t = 250)]
    pub period_ms: u32,
    /// Frame size.
    #[arg(long, value_parser = parse_size, default_value = "640x480")]
    pub size: (u32, u32),
    /// Seconds per stage-alone measurement.
    #[arg(long, allow_negative_numbers = true, default_value_t = 3.0)]
    pub stage_s: f64,
    /// Also record to this MCAP file (the recorder's cost included).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Print JSON instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON report here.
    #[arg(long)]
    pub json_out: Option<PathBuf>,
}

/// `stereotac bench tactile`.
#[derive(Debug, clap::Args)]
pub struct TactileArgs {
    /// Print JSON records instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON report to this file.
    #[arg(long)]
    pub json_out: Option<PathBuf>,
    /// Frame sizes (default 640x480 and 1280x960).
    #[arg(long = "size", value_parser = parse_size)]
    pub sizes: Vec<(u32, u32)>,
    /// Repeats per measurement; the median is reported.
    #[arg(long, default_value_t = 15)]
    pub repeats: usize,
}

/// `stereotac bench stereo`.
#[derive(Debug, clap::Args)]
pub struct StereoArgs {
    /// Repeats per measurement; the median is reported.
    #[arg(long, default_value_t = 15)]
    pub repeats: usize,
    /// Also time OpenCV's StereoBM on the same input (needs python3 with opencv-python).
    #[arg(long)]
    pub opencv: bool,
    /// Print JSON instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON report here.
    #[arg(long)]
    pub json_out: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    match a.what {
        BenchWhat::Tactile(a) => tactile(a),
        BenchWhat::Stereo(a) => stereo(a),
        BenchWhat::Live(a) => live(a),
        BenchWhat::Skins(a) => skins(a),
    }
}

fn skins(a: SkinsArgs) -> Result<()> {
    let all = families();
    if a.list {
        let width = all.iter().map(|f| f.name.len()).max().unwrap_or(0);
        for f in &all {
            println!(
                "{:<width$} {:<10} ball {:>4.1} mm  {}",
                f.name,
                f.role.to_string(),
                f.ball_diameter_mm,
                f.about
            );
        }
        return Ok(());
    }
    let chosen: Vec<_> = if a.families.is_empty() {
        all
    } else {
        a.families
            .iter()
            .map(|name| {
                family(name).with_context(|| {
                    format!(
                        "unknown family {name:?}; known: {}",
                        all.iter().map(|f| f.name).collect::<Vec<_>>().join(", ")
                    )
                })
            })
            .collect::<Result<_>>()?
    };
    anyhow::ensure!(a.skins >= 1, "--skins must be at least 1");
    // Fewer presses than calibration needs, or no placements, would print a table of
    // failures and "n/a" that measured nothing.
    let needed = stereotac::tactile::calibrate::DEFAULT_MIN_PRESSES;
    anyhow::ensure!(
        a.presses >= needed,
        "--presses {} is fewer than calibration needs ({needed}): give at least {needed}",
        a.presses
    );
    anyhow::ensure!(a.placements >= 1, "--placements must be at least 1");
    let total = chosen.len() as u64 * a.skins;
    let progress = bar(total, "skins");
    let mut reports = Vec::new();
    for f in &chosen {
        for seed in 1..=a.skins {
            let config = EvalConfig {
                width: a.size.0 as usize,
                height: a.size.1 as usize,
                skin_seed: seed,
                presses: a.presses,
                placements: a.placements,
                ball_diameter_mm: a.ball_diameter_mm,
                second_ball_mm: a.second_ball_mm,
                model: a.model,
                past_reach: !a.no_past_reach,
                dark: a.dark,
                ambient: a.ambient,
                crosstalk: a.crosstalk,
                side_light: a.side_light,
                camera_curve: a.camera_curve,
                ..Default::default()
            };
            let report = evaluate(f, &config, &mut |step| {
                progress.set_message(format!("{} {seed}: {step}", f.name));
            });
            progress.inc(1);
            if !a.json {
                progress.suspend(|| print!("{}", format_report(&report)));
            }
            reports.push(report);
        }
    }
    progress.finish_and_clear();
    let json = json_report(&reports, a.json_out.as_deref())?;
    if a.json {
        println!("{json}");
    }
    Ok(())
}

/// A calibration ball's diameter: a number of mm between 2 and 20 (the presses are
/// 0.8–1.2 mm deep and must fit in the frame).
fn parse_ball_mm(s: &str) -> Result<f64, String> {
    let d: f64 = s.trim().parse().map_err(|e| format!("{s:?}: {e}"))?;
    if (2.0..=20.0).contains(&d) {
        Ok(d)
    } else {
        Err(format!("expected a diameter between 2 and 20 mm, got {s}"))
    }
}

/// `DX,DY,DARK` ambient scales, each finite and non-negative.
fn parse_ambient(s: &str) -> Result<AmbientScale, String> {
    crate::args::not_a_flag(s, "DX,DY,DARK")?;
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("{p:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [dx, dy, dark] if v.iter().all(|x| x.is_finite() && *x >= 0.0) => {
            Ok(AmbientScale { dx, dy, dark })
        }
        _ => Err(format!(
            "expected three non-negative numbers DX,DY,DARK (e.g. 1.3,0.8,1), got {s:?}"
        )),
    }
}

fn live(a: LiveArgs) -> Result<()> {
    let progress = spinner("bench live");
    let report = live_bench::run(
        &LiveBenchOptions {
            size: a.size,
            fps: a.fps,
            period_ms: a.period_ms,
            duration_s: a.duration_s,
            stage_s: a.stage_s,
            mcap: a.mcap.clone(),
        },
        |p| match p {
            LiveBenchProgress::Calibrating => {
                progress.set_message("calibrating the built-in model")
            }
            LiveBenchProgress::Stages => progress.set_message("each stage alone"),
            LiveBenchProgress::Loop(t, total) => {
                progress.set_message(format!("live loop {t:.0} / {total:.0} s"))
            }
        },
    );
    progress.finish_and_clear();
    let report = report?;
    let json = json_report(&report, a.json_out.as_deref())?;
    if a.json {
        println!("{json}");
    } else {
        print!("{}", live_bench::format_table(&report));
    }
    Ok(())
}

fn tactile(a: TactileArgs) -> Result<()> {
    let mut config = BenchConfig {
        repeats: a.repeats,
        ..Default::default()
    };
    if !a.sizes.is_empty() {
        config.sizes = a
            .sizes
            .iter()
            .map(|&(w, h)| (w as usize, h as usize))
            .collect();
    }
    let progress = bar(1, "bench");
    let report = tactile_bench::run(&config, &mut |what, done, total| {
        progress.set_message(what.to_string());
        progress.set_length(total as u64);
        progress.set_position(done as u64);
    });
    progress.finish_and_clear();
    let json = json_report(&report, a.json_out.as_deref())?;
    if a.json {
        println!("{json}");
    } else {
        print!("{}", tactile_bench::format_table(&report));
    }
    Ok(())
}

fn stereo(a: StereoArgs) -> Result<()> {
    let progress = bar(stereo_bench::STEPS, "benchmarking");
    let report = stereo_bench::run(
        BenchOptions {
            repeats: a.repeats,
            opencv: a.opencv,
        },
        || progress.inc(1),
    );
    progress.finish_and_clear();
    let report = report?;
    if let Some(why) = &report.opencv_skipped {
        eprintln!(
            "OpenCV reference skipped: {} ({})",
            why.lines().last().unwrap_or(why),
            stereotac::stereo::opencv::SETUP_HINT
        );
    }
    let json = json_report(&report.rows, a.json_out.as_deref())?;
    if a.json {
        println!("{json}");
    } else {
        print!("{}", stereo_bench::format_table(&report.rows, a.repeats));
    }
    Ok(())
}
