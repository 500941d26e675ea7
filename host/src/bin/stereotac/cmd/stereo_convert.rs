//! `stereotac stereo-convert`: a stereo calibration read in one format (OpenCV stereo
//! YAML in mm or m, or a ROS `camera_info` pair) and written in the others: OpenCV YAML
//! in millimetres and a ROS `camera_info` pair in metres. What is written is read back
//! and compared with what was read before anything is saved.

use std::path::PathBuf;

use anyhow::{Context, Result, bail, ensure};
use stereotac::output::{Written, check_replace, same_file, write_atomic};
use stereotac::stereo::ros_info::camera_info_pair;
use stereotac::stereo::{LengthUnit, StereoCalibration};

/// `stereotac stereo-convert`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The calibration to read: one OpenCV stereo YAML, or two ROS camera_info YAML
    /// (left, then right).
    #[arg(long, num_args = 1, action = clap::ArgAction::Append, required = true)]
    pub calib: Vec<PathBuf>,
    /// Length unit of an OpenCV file's `T` (ROS files are always metres): mm or m.
    #[arg(long, default_value = "mm")]
    pub units: LengthUnit,
    /// Write it as OpenCV stereo YAML (`T` in mm) here.
    #[arg(long)]
    pub opencv: Option<PathBuf>,
    /// Write it as a ROS camera_info pair (metres, rectified at scale 1): the left file.
    #[arg(long, requires = "ros_right")]
    pub ros_left: Option<PathBuf>,
    /// The right camera_info file.
    #[arg(long, requires = "ros_left")]
    pub ros_right: Option<PathBuf>,
    /// Replace output files that exist.
    #[arg(long)]
    pub force: bool,
}

/// Largest difference allowed between what was read and what a written file reads back
/// as (rotation degrees, translation mm, intrinsics px): round-off only.
const ROUND_TRIP: f64 = 1e-6;

pub fn run(a: Args) -> Result<()> {
    let outputs: Vec<(&PathBuf, &str, &str)> = [
        (&a.opencv, "--opencv", "stereo.yaml"),
        (&a.ros_left, "--ros-left", "left.yaml"),
        (&a.ros_right, "--ros-right", "right.yaml"),
    ]
    .into_iter()
    .filter_map(|(path, flag, example)| path.as_ref().map(|p| (p, flag, example)))
    .collect();
    if outputs.is_empty() {
        bail!("nothing to write: give --opencv FILE and/or --ros-left FILE --ros-right FILE");
    }
    for (i, &(path, flag, example)) in outputs.iter().enumerate() {
        // Not even with --force: a slip naming an image or a recording loses it.
        let written = Written {
            what: "a calibration",
            flag,
            example,
        };
        check_replace(path, a.force, written)?;
        if let Some((other, ..)) = outputs[..i].iter().find(|(o, ..)| same_file(o, path)) {
            bail!(
                "{} and {} name one file: each output needs a file of its own (the second \
                 would replace the first)",
                other.display(),
                path.display()
            );
        }
    }
    let calib = crate::stages::load_calibration(&a.calib, a.units)?;
    let mut written = Vec::new();
    if let Some(path) = &a.opencv {
        let yaml = calib.to_opencv_yaml();
        let name = path.display().to_string();
        let back = StereoCalibration::from_opencv_yaml(&name, &yaml)?;
        check_round_trip(&calib, &back, &name)?;
        written.push((path.clone(), yaml));
    }
    if let (Some(left), Some(right)) = (&a.ros_left, &a.ros_right) {
        let (l, r) =
            camera_info_pair(&calib).context("rectifying for the ROS projection matrices")?;
        let name = format!("{} + {}", left.display(), right.display());
        let back = StereoCalibration::from_ros_pair(
            (&left.display().to_string(), &l),
            (&right.display().to_string(), &r),
        )?;
        check_round_trip(&calib, &back, &name)?;
        written.push((left.clone(), l));
        written.push((right.clone(), r));
    }
    for (path, text) in &written {
        // The folder made when missing, as `stereo --out-dir` makes its own.
        if let Some(folder) = path.parent().filter(|f| !f.as_os_str().is_empty()) {
            std::fs::create_dir_all(folder)
                .with_context(|| format!("making the folder {}", folder.display()))?;
        }
        write_atomic(path, text.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    println!(
        "baseline {:.3} mm, image {}×{}",
        calib.baseline(),
        calib.left.width,
        calib.left.height
    );
    Ok(())
}

fn check_round_trip(read: &StereoCalibration, back: &StereoCalibration, name: &str) -> Result<()> {
    let d = back.difference_from(read);
    let distortion = [(&read.left, &back.left), (&read.right, &back.right)]
        .iter()
        .all(|(a, b)| {
            let (a, b) = (a.distortion.coefficients(), b.distortion.coefficients());
            a.len() == b.len() && a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= ROUND_TRIP)
        });
    let worst = [
        d.focal_error_percent,
        d.principal_point_error_px,
        d.baseline_error_percent,
        d.rotation_error_deg,
    ]
    .into_iter()
    .fold(
        0.0f64,
        |m, v| if v.is_nan() { f64::INFINITY } else { m.max(v) },
    );
    ensure!(
        worst <= ROUND_TRIP && distortion,
        "{name} would not read back as the calibration read (focal lengths {:.2e} % off, \
         principal points {:.2e} px, baseline {:.2e} %, rotation {:.2e}°, distortion {}; \
         {ROUND_TRIP:.0e} allowed): nothing written; please report this with the file read",
        d.focal_error_percent,
        d.principal_point_error_px,
        d.baseline_error_percent,
        d.rotation_error_deg,
        if distortion { "the same" } else { "differs" }
    );
    Ok(())
}
