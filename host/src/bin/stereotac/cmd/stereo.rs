//! `stereotac stereo`: stereo depth of one rectifiable pair (or a built-in capture):
//! disparity and depth (.npy, PNG), point cloud (PLY) and `summary.json`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use stereotac::out_dir::{OutDir, Replace};
use stereotac::output::{read_grey, write_grey_png};
use stereotac::picture::RangeChoice;
use stereotac::stereo::LengthUnit;
use stereotac::stereo::outliers::OutlierParams;
use stereotac::stereo::output::{OutputOptions, PictureRange, StereoSummary, write_outputs};
use stereotac::stereo::pipeline::{StereoConfig, StereoPipeline};
use stereotac::stereo::postfilter::HoleFill;
use stereotac::stereo::synthetic::{Membrane, Plane, StereoRig, render_pair};

use crate::args::PipelineArgs;

/// `stereotac stereo`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Calibration: one OpenCV stereo YAML, or two ROS camera_info YAML (left, then
    /// right). Not needed with --synthetic.
    #[arg(long, num_args = 1, action = clap::ArgAction::Append)]
    pub calib: Vec<PathBuf>,
    /// Length unit of an OpenCV calibration's `T` (ROS camera_info files are always
    /// metres): mm (default) or m.
    #[arg(long, default_value = "mm")]
    pub units: LengthUnit,
    /// Fail (exit non-zero) when the result has warnings: almost nothing matched, the
    /// scene outside --near-mm/--far-mm (they are printed and in summary.json either way).
    #[arg(long)]
    pub strict: bool,
    /// Left image (8-bit; colour is converted to grey).
    #[arg(long, required_unless_present = "synthetic")]
    pub left: Option<PathBuf>,
    /// Right image.
    #[arg(long, required_unless_present = "synthetic")]
    pub right: Option<PathBuf>,
    /// Use a built-in capture instead: a textured plane this many mm away, tilted, seen
    /// through the skin (its inputs and calibration are written to the output directory
    /// too).
    #[arg(long, allow_negative_numbers = true, conflicts_with_all = ["left", "right", "calib"])]
    pub synthetic: Option<f64>,
    /// Output directory (created; one with files in it is refused unless --force).
    #[arg(long)]
    pub out_dir: PathBuf,
    /// Write into an output directory that already has files in it.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Turn off the edge-preserving spatial filter.
    #[arg(long)]
    pub no_spatial: bool,
    /// Fill holes up to this many pixels wide along rows (0: off).
    #[arg(long, default_value_t = 0)]
    pub fill_holes: usize,
    /// Statistical outlier removal on the point cloud (Open3D's rule, neighbour
    /// distances scaled by depth). Off by default: on a slanted surface the far side is
    /// sparser and loses points (4 % of a plane tilted 17° in the built-in capture).
    #[arg(long)]
    pub outliers: bool,
    /// Range of depth_colour.png and disparity_colour.png: `auto` (the data's 2nd to 98th
    /// percentiles), `searched` (--near-mm to --far-mm, and the disparities searched) or
    /// `LO,HI` in mm (depth; disparity automatic). Stated in each legend and summary.json.
    #[arg(long, allow_hyphen_values = true, value_name = "auto|searched|LO,HI", default_value = "auto", value_parser = parse_picture_range)]
    pub colour_range: PictureRange,
    /// Also write the point cloud as a mesh (mesh.ply: neighbouring pixels joined in
    /// triangles, not across depth steps over 5 %).
    #[arg(long)]
    pub mesh: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: Args) -> Result<()> {
    let out = OutDir::prepare(&a.out_dir, Replace::force_if(a.force))?;
    // The calibration's notes are printed as it is read and carried into summary.json
    // (and `--strict`) with the result's own warnings.
    let mut notes = Vec::new();
    let (calib, left, right) = match a.synthetic {
        Some(z) => {
            if !(z.is_finite() && z > 0.0) {
                bail!("--synthetic takes a distance in mm, found {z}");
            }
            let rig = StereoRig::sensor();
            let plane = Plane {
                z_mm: z,
                tilt_x: 0.3,
                tilt_y: 0.1,
            };
            let (l, r) = render_pair(&rig, &plane, &Membrane::sensor(), 1);
            write_grey_png(&out.path().join("input_left.png"), &l)?;
            write_grey_png(&out.path().join("input_right.png"), &r)?;
            // With the calibration beside them, the inputs can be run again with --calib.
            let calib = rig.calibration();
            let yaml = out.path().join("input_calibration.yaml");
            std::fs::write(&yaml, calib.to_opencv_yaml())
                .with_context(|| format!("writing {}", yaml.display()))?;
            (calib, l, r)
        }
        None => {
            let calib;
            (calib, notes) = crate::stages::load_calibration_noting(&a.calib, a.units)?;
            let left = read_grey(a.left.as_deref().context("--left is required")?)?;
            let right = read_grey(a.right.as_deref().context("--right is required")?)?;
            (calib, left, right)
        }
    };
    let config = StereoConfig {
        spatial: if a.no_spatial {
            None
        } else {
            StereoConfig::default().spatial
        },
        hole_fill: (a.fill_holes > 0).then_some(HoleFill {
            max_width: a.fill_holes,
        }),
        outliers: a.outliers.then(OutlierParams::default),
        ..a.pipeline.config()?
    };
    let mut pipeline = StereoPipeline::new(&calib, config)?;
    let frame = pipeline.process(&left, &right)?;
    let options = OutputOptions {
        colour_range: a.colour_range,
        mesh: a.mesh,
        written_before: if a.synthetic.is_some() {
            &[
                "input_left.png",
                "input_right.png",
                "input_calibration.yaml",
            ]
        } else {
            &[]
        },
        earlier_warnings: &notes,
    };
    let summary = write_outputs(out.path(), &pipeline, &frame, &config, options)?;
    out.keep();
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print_summary(&a.out_dir, &summary);
    }
    for w in summary.warnings.iter().skip(notes.len()) {
        eprintln!("warning: {w}");
    }
    anyhow::ensure!(
        !a.strict || summary.warnings.is_empty(),
        "{} warning(s) under --strict (outputs and summary.json written to {})",
        summary.warnings.len(),
        a.out_dir.display()
    );
    Ok(())
}

fn print_summary(dir: &Path, s: &StereoSummary) {
    println!(
        "rectified {}×{}, f = {:.1} px, baseline {:.2} mm, disparities {}..={} px ({:?} kernel)",
        s.width,
        s.height,
        s.focal_px,
        s.baseline_mm,
        s.disparity_range_px[0],
        s.disparity_range_px[1],
        s.kernel
    );
    let st = &s.stats;
    println!(
        "valid {:.1} % of pixels; rejected: border {}, low texture {}, not unique {}, \
         range edge {}, left-right {}, speckle {}, outside the range {}, outliers {}",
        100.0 * s.fill_rate,
        st.border,
        st.low_texture,
        st.not_unique,
        st.range_edge,
        st.left_right,
        st.speckle,
        st.outside_range,
        s.outliers_removed
    );
    if let Some([lo, mid, hi]) = s.depth_mm {
        println!(
            "depth: min {lo:.1} mm, median {mid:.1} mm, max {hi:.1} mm; {} points",
            s.points
        );
    }
    let t = &s.timings;
    println!(
        "time: rectify {:.2} ms, match {:.2} ms, filters {:.2} ms, reproject {:.2} ms, \
         outliers {:.1} ms, total {:.1} ms",
        t.rectify_ms, t.match_ms, t.filter_ms, t.reproject_ms, t.outliers_ms, t.total_ms
    );
    println!("wrote {} into {}", s.files.join(", "), dir.display());
}

/// `--colour-range`: `auto`, `searched` or `LO,HI` (mm).
fn parse_picture_range(text: &str) -> Result<PictureRange, String> {
    crate::args::not_a_flag(text, "auto, searched or LO,HI")?;
    if text.trim().eq_ignore_ascii_case("searched") {
        return Ok(PictureRange::Searched);
    }
    match RangeChoice::parse(text) {
        Ok(RangeChoice::Fixed { lo, hi }) => Ok(PictureRange::DepthMm(lo, hi)),
        Ok(_) => Ok(PictureRange::Auto),
        Err(e) => Err(format!("{e}, or `searched`")),
    }
}
