//! `stereotac stereo-calibrate`: checkerboard pairs (files, or built-in views through the
//! sensor's wide lenses) in, an OpenCV stereo YAML that `stereo --calib` reads out, with
//! a report of how well it fits.
//!
//! The solver lives behind the `calibrate` cargo feature (it brings about 300 crates);
//! without it the command explains how to get it.

use std::path::PathBuf;

/// Lens model to fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ModelArg {
    /// Kannala–Brandt equidistant fisheye (OpenCV's fisheye model), for the 160° lenses.
    Fisheye,
    /// Pinhole with Brown–Conrady distortion (k1 k2 p1 p2).
    Pinhole,
}

/// `stereotac stereo-calibrate`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Left images of the board (as many as --right, in the same order).
    #[arg(long, num_args = 1.., required_unless_present = "synthetic")]
    pub left: Vec<PathBuf>,
    /// Right images of the board, taken at the same moments as --left.
    #[arg(long, num_args = 1.., required_unless_present = "synthetic")]
    pub right: Vec<PathBuf>,
    /// Use N built-in pairs of the board seen through the sensor's wide lenses instead
    /// (the report then compares the result with the true calibration).
    #[arg(long, value_name = "N", conflicts_with_all = ["left", "right"])]
    pub synthetic: Option<usize>,
    /// Board size as inner corners, COLSxROWS.
    #[arg(long, default_value = "8x6")]
    pub board: String,
    /// Side of one square, mm.
    #[arg(long, allow_negative_numbers = true, default_value_t = 17.0)]
    pub square_mm: f64,
    /// Lens model of both cameras.
    #[arg(long, value_enum, default_value_t = ModelArg::Fisheye)]
    pub model: ModelArg,
    /// Fewest pairs that must show the whole board in both views.
    #[arg(long, default_value_t = 6)]
    pub min_pairs: usize,
    /// Where to write the calibration (OpenCV stereo YAML, as `stereo --calib` reads); an
    /// existing file is kept unless --force.
    #[arg(long, default_value = "stereotac-calib.yaml")]
    pub out: PathBuf,
    /// Replace an existing --out file (and write into a --save-views folder with files).
    #[arg(long)]
    pub force: bool,
    /// With --synthetic: also save the built-in views here as left_NN.png/right_NN.png.
    #[arg(long)]
    pub save_views: Option<PathBuf>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

#[cfg(not(feature = "calibrate"))]
pub fn run(_: Args) -> anyhow::Result<()> {
    anyhow::bail!(
        "this stereotac was built without stereo calibration; rebuild with the `calibrate` \
         feature: `cargo run --release -p stereotac --features calibrate -- stereo-calibrate …` \
         (or `cargo install --path host --features calibrate`)"
    )
}

#[cfg(feature = "calibrate")]
pub use with_solver::run;

#[cfg(feature = "calibrate")]
mod with_solver {
    use anyhow::{Context, Result, bail};
    use serde::Serialize;
    use stereotac::grid::Grid;
    use stereotac::out_dir::{OutDir, Replace};
    use stereotac::output::{read_grey, write_grey_png};
    use stereotac::stereo::board::{Checkerboard, render_board_capture};
    use stereotac::stereo::board_calibration::{
        CalibrateOptions, CalibrationResult, LensModel, calibrate_stereo,
    };
    use stereotac::stereo::calibration::CalibrationDifference;
    use stereotac::stereo::scene::Membrane;
    use stereotac::stereo::synthetic::wide_fisheye_calibration;
    use stereotac::stereo::{Camera, Distortion, StereoCalibration};

    use super::{Args, ModelArg};
    use crate::progress::bar;

    #[derive(Serialize)]
    struct CameraReport {
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        model: &'static str,
        distortion: Vec<f64>,
        error_px: f64,
    }

    #[derive(Serialize)]
    struct Skipped {
        pair: usize,
        reason: String,
    }

    #[derive(Serialize)]
    struct Report {
        out: String,
        pairs: usize,
        pairs_used: usize,
        mean_error_px: f64,
        baseline_mm: f64,
        t_mm: [f64; 3],
        left: CameraReport,
        right: CameraReport,
        skipped: Vec<Skipped>,
        truth: Option<CalibrationDifference>,
    }

    fn camera_report(c: &Camera, error_px: f64) -> CameraReport {
        CameraReport {
            fx: c.k[(0, 0)],
            fy: c.k[(1, 1)],
            cx: c.k[(0, 2)],
            cy: c.k[(1, 2)],
            model: match c.distortion {
                Distortion::BrownConrady(_) => "plumb_bob",
                Distortion::KannalaBrandt(_) => "fisheye",
            },
            distortion: c.distortion.coefficients(),
            error_px,
        }
    }

    /// The pairs to calibrate from, and the true calibration when they are built in.
    struct Inputs {
        left: Vec<Grid<u8>>,
        right: Vec<Grid<u8>>,
        truth: Option<StereoCalibration>,
    }

    fn inputs(a: &Args, board: &Checkerboard) -> Result<Inputs> {
        if let Some(n) = a.synthetic {
            if n == 0 {
                bail!("--synthetic takes a number of pairs (at least 1)");
            }
            let truth = wide_fisheye_calibration();
            let capture = render_board_capture(&truth, board, &Membrane::sensor(), n, 1);
            if capture.poses.len() < n {
                bail!(
                    "the built-in rig could only place the {}×{} board whole in both views {} times",
                    board.cols,
                    board.rows,
                    capture.poses.len()
                );
            }
            if let Some(dir) = &a.save_views {
                let dir = OutDir::prepare(dir, Replace::force_if(a.force))?;
                for (i, (l, r)) in capture.left.iter().zip(&capture.right).enumerate() {
                    write_grey_png(&dir.path().join(format!("left_{i:02}.png")), l)?;
                    write_grey_png(&dir.path().join(format!("right_{i:02}.png")), r)?;
                }
                dir.keep();
            }
            return Ok(Inputs {
                left: capture.left,
                right: capture.right,
                truth: Some(truth),
            });
        }
        if a.save_views.is_some() {
            bail!("--save-views only applies to --synthetic");
        }
        let load = |files: &[std::path::PathBuf]| -> Result<Vec<Grid<u8>>> {
            files.iter().map(|f| Ok(read_grey(f)?)).collect()
        };
        Ok(Inputs {
            left: load(&a.left)?,
            right: load(&a.right)?,
            truth: None,
        })
    }

    pub fn run(a: Args) -> Result<()> {
        // Before the work, not after: a calibration is never replaced by accident, and
        // never written over an image or a recording (the board images are PNGs).
        let written = stereotac::output::Written {
            what: "a calibration",
            flag: "--out",
            example: "stereo.yaml",
        };
        stereotac::output::check_replace(&a.out, a.force, written)?;
        let board = Checkerboard::parse(&a.board, a.square_mm)?;
        let Inputs { left, right, truth } = inputs(&a, &board)?;
        let options = CalibrateOptions {
            board,
            model: match a.model {
                ModelArg::Fisheye => LensModel::Fisheye,
                ModelArg::Pinhole => LensModel::Pinhole,
            },
            min_pairs: a.min_pairs,
        };
        let progress = bar(left.len() as u64, "finding the board");
        let result = calibrate_stereo(&left, &right, &options, |n| progress.set_position(n as u64));
        progress.finish_and_clear();
        let result = result?;
        let yaml = result.calibration.to_opencv_yaml();
        // What we write must read back as what we found.
        let name = a.out.display().to_string();
        StereoCalibration::from_opencv_yaml(&name, &yaml)
            .context("the calibration does not read back")?;
        stereotac::output::write_atomic(&a.out, yaml.as_bytes())
            .with_context(|| format!("writing {name}"))?;
        let report = report(&result, &name, truth.as_ref());
        if a.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            print_report(&report);
        }
        Ok(())
    }

    fn report(result: &CalibrationResult, out: &str, truth: Option<&StereoCalibration>) -> Report {
        let c = &result.calibration;
        Report {
            out: out.to_string(),
            pairs: result.pairs.len(),
            pairs_used: result.pairs_used(),
            mean_error_px: result.mean_error_px,
            baseline_mm: c.baseline(),
            t_mm: [c.t.x, c.t.y, c.t.z],
            left: camera_report(&c.left, result.camera_error_px[0]),
            right: camera_report(&c.right, result.camera_error_px[1]),
            skipped: result
                .pairs
                .iter()
                .enumerate()
                .filter_map(|(pair, p)| p.note.clone().map(|reason| Skipped { pair, reason }))
                .collect(),
            truth: truth.map(|t| c.difference_from(t)),
        }
    }

    fn print_report(r: &Report) {
        println!(
            "stereo calibration from {} of {} pairs: mean reprojection error {:.3} px",
            r.pairs_used, r.pairs, r.mean_error_px
        );
        for (name, c) in [("left ", &r.left), ("right", &r.right)] {
            println!(
                "  {name}: fx {:.2} fy {:.2} cx {:.2} cy {:.2} px, {} {:?}, error {:.3} px",
                c.fx, c.fy, c.cx, c.cy, c.model, c.distortion, c.error_px
            );
        }
        println!(
            "  baseline {:.3} mm, T = [{:.3}, {:.3}, {:.3}] mm",
            r.baseline_mm, r.t_mm[0], r.t_mm[1], r.t_mm[2]
        );
        for s in &r.skipped {
            println!("  pair {} not used: {}", s.pair, s.reason);
        }
        if let Some(t) = &r.truth {
            println!(
                "  against the built-in rig's truth: focal {:.3} %, principal point {:.2} px, baseline {:.3} %, rotation {:.4}°",
                t.focal_error_percent,
                t.principal_point_error_px,
                t.baseline_error_percent,
                t.rotation_error_deg
            );
        }
        println!("wrote {}", r.out);
    }
}
