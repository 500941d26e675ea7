//! `stereotac stereo-eval`: depth-camera metrics (Z-accuracy, RMS error, temporal noise,
//! fill rate) on built-in captures of flat targets behind the skin.

use std::path::PathBuf;

use anyhow::{Result, bail};
use stereotac::stereo::MatcherKind;
use stereotac::stereo::eval::{self, SyntheticEval};
use stereotac::stereo::synthetic::Membrane;

use crate::args::PipelineArgs;
use crate::console::json_report;
use crate::progress::bar;

/// `stereotac stereo-eval`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Target distances, mm, separated by commas (`--distances 100,200,300`).
    #[arg(long, value_delimiter = ',', default_values_t = [100.0, 150.0, 200.0, 250.0, 300.0])]
    pub distances: Vec<f64>,
    /// Frames per distance.
    #[arg(long, default_value_t = 10)]
    pub frames: usize,
    /// Region of interest: this share of each side, centred.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.4)]
    pub roi: f64,
    /// Share of light from the skin (0..1).
    #[arg(long, allow_negative_numbers = true, default_value_t = Membrane::sensor().haze)]
    pub haze: f64,
    /// Sensor noise, grey levels.
    #[arg(long, allow_negative_numbers = true, default_value_t = Membrane::sensor().noise)]
    pub noise: f64,
    /// Cameras: an ideal rectified rig, or the sensor's 160° fisheye pair (raw frames
    /// through the lens model, rectified by the pipeline).
    #[arg(long, value_enum, default_value_t = LensArg::Ideal)]
    pub lens: LensArg,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Compare matchers on the same captures, unfiltered, side by side: ours (`bm`, and
    /// `sgm` along `--sgm-paths`) and OpenCV's StereoBM and StereoSGBM 3-way, run by
    /// `python3` (or the interpreter `STEREOTAC_PYTHON` names) with opencv-python;
    /// without them OpenCV's rows are reported as skipped, with the reason.
    #[arg(long, conflicts_with = "matcher")]
    pub compare: bool,
    /// Print JSON instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON report here.
    #[arg(long)]
    pub json_out: Option<PathBuf>,
}

/// `--lens` of `stereo-eval`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LensArg {
    /// An ideal rectified pinhole pair.
    Ideal,
    /// The sensor's wide fisheye pair, raw.
    Wide,
}

pub fn run(a: Args) -> Result<()> {
    if a.frames == 0 || a.distances.is_empty() {
        bail!("need at least one distance and one frame");
    }
    if let Some(bad) = a.distances.iter().find(|d| !(d.is_finite() && **d > 0.0)) {
        bail!("distances must be positive, found {bad}");
    }
    let usable = (0.0..=1.0).contains(&a.haze) && a.roi > 0.0 && a.roi <= 1.0 && a.noise >= 0.0;
    if !usable {
        bail!("--haze must be in 0..1, --roi in (0, 1], --noise not negative");
    }
    let setup = SyntheticEval {
        distances_mm: a.distances.clone(),
        frames: a.frames,
        roi: a.roi,
        membrane: Membrane {
            haze: a.haze,
            noise: a.noise,
            ..Membrane::sensor()
        },
        lens: match a.lens {
            LensArg::Ideal => eval::Lens::Ideal,
            LensArg::Wide => eval::Lens::Wide,
        },
        ..SyntheticEval::default()
    };
    if a.compare {
        return compare(&a, &setup);
    }
    let progress = bar(2 * a.distances.len() as u64, "rendering, matching");
    let config = a.pipeline.config()?;
    let rows = eval::run_synthetic(&setup, config, |_| progress.inc(1))?;
    progress.finish_and_clear();
    let json = json_report(&rows, a.json_out.as_deref())?;
    if a.json {
        println!("{json}");
    } else {
        let matcher = match config.matcher {
            MatcherKind::Sgm => format!("sgm, {} paths", config.sgm_paths.count()),
            kind => kind.name().to_string(),
        };
        let b = config.window();
        println!("matcher {matcher}, window {b}×{b}");
        println!("{}", targets(&a));
        print!("{}", eval::table(&rows));
    }
    Ok(())
}

/// `--compare`: both our matchers and OpenCV's on the same captures.
fn compare(a: &Args, setup: &SyntheticEval) -> Result<()> {
    // `--sgm-paths` is for the semi-global rows (block matching runs too).
    let config = PipelineArgs {
        matcher: MatcherKind::Sgm,
        ..a.pipeline.clone()
    }
    .config()?;
    let progress = bar(4 * a.distances.len() as u64, "rendering, matching");
    let report = eval::run_comparison(setup, config, true, |_| progress.inc(1))?;
    progress.finish_and_clear();
    if let Some(why) = &report.opencv_skipped {
        eprintln!(
            "OpenCV's matchers skipped: {} ({})",
            why.lines().last().unwrap_or(why),
            stereotac::stereo::opencv::SETUP_HINT
        );
    }
    let json = json_report(&report, a.json_out.as_deref())?;
    if a.json {
        println!("{json}");
        return Ok(());
    }
    println!(
        "matchers compared, unfiltered, on {}{}",
        targets(a),
        report
            .opencv
            .as_ref()
            .map(|v| format!("; OpenCV {v}, one thread"))
            .unwrap_or_default()
    );
    print!("{}", eval::comparison_table(&report.rows));
    Ok(())
}

/// The captures, as the tables' headings name them.
fn targets(a: &Args) -> String {
    format!(
        "synthetic flat targets, {} lens, {} frames each, ROI {:.0} % of each side, haze {}, noise {} grey levels",
        match a.lens {
            LensArg::Ideal => "ideal",
            LensArg::Wide => "wide fisheye",
        },
        a.frames,
        100.0 * a.roi,
        a.haze,
        a.noise
    )
}
