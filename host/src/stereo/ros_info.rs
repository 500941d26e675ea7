//! Writing a calibration as a pair of ROS `camera_info` YAML files (what
//! `camera_calibration` writes and [`StereoCalibration::load`] reads back): each camera's
//! matrix and distortion, and the rectification that carries the extrinsics, with the
//! baseline in metres (`projection_matrix[0][3] = −fx·B`) as everywhere in ROS.

use nalgebra::{Matrix3, Matrix3x4};

use super::calibration::StereoCalibration;
use super::camera::{Camera, Distortion};
use super::rectify::{Rectification, RectifyError};
use super::yaml::list;

/// The left and right `camera_info` YAML of `calib` (rectified at scale 1).
pub fn camera_info_pair(calib: &StereoCalibration) -> Result<(String, String), RectifyError> {
    let rect = Rectification::bouguet(calib, 1.0)?;
    // Our projection matrices are in mm; ROS's are in metres.
    let metres = |p: &Matrix3x4<f64>| {
        let mut p = *p;
        p[(0, 3)] /= 1000.0;
        p[(1, 3)] /= 1000.0;
        p[(2, 3)] /= 1000.0;
        p
    };
    Ok((
        camera_info("left", &calib.left, &rect.r1, &metres(&rect.p1)),
        camera_info("right", &calib.right, &rect.r2, &metres(&rect.p2)),
    ))
}

/// One camera's `camera_info` YAML.
fn camera_info(name: &str, cam: &Camera, r: &Matrix3<f64>, p: &Matrix3x4<f64>) -> String {
    let coefficients = cam.distortion.coefficients();
    let model = match cam.distortion {
        Distortion::KannalaBrandt(_) => "equidistant",
        Distortion::BrownConrady(_) if coefficients.len() > 5 => "rational_polynomial",
        Distortion::BrownConrady(_) => "plumb_bob",
    };
    // nalgebra stores column-major: the transpose's storage is row-major.
    let rows3 = |m: &Matrix3<f64>| list(m.transpose().as_slice());
    format!(
        "image_width: {}\nimage_height: {}\ncamera_name: {name}\n\
         camera_matrix:\n  rows: 3\n  cols: 3\n  data: {}\n\
         distortion_model: {model}\n\
         distortion_coefficients:\n  rows: 1\n  cols: {}\n  data: {}\n\
         rectification_matrix:\n  rows: 3\n  cols: 3\n  data: {}\n\
         projection_matrix:\n  rows: 3\n  cols: 4\n  data: {}\n",
        cam.width,
        cam.height,
        rows3(&cam.k),
        coefficients.len(),
        list(&coefficients),
        rows3(r),
        list(p.transpose().as_slice()),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::calibration::tests::sensor_pair;

    #[test]
    fn a_calibration_round_trips_through_ros_files_in_metres() {
        for distortion in [
            Distortion::NONE,
            Distortion::BrownConrady([0.1, -0.05, 0.001, 0.002, 0.01, 0.3, -0.1, 0.02]),
            Distortion::KannalaBrandt([0.05, -0.01, 0.002, -0.0003]),
        ] {
            let c = sensor_pair(distortion);
            let (left, right) = camera_info_pair(&c).unwrap();
            let tx: f64 = right
                .lines()
                .skip_while(|l| !l.starts_with("projection_matrix"))
                .find_map(|l| l.trim().strip_prefix("data: ["))
                .and_then(|d| d.split(',').nth(3))
                .and_then(|v| v.trim().parse().ok())
                .unwrap();
            let fx = c.left.k[(0, 0)];
            assert!(
                (-tx / fx - c.baseline() / 1000.0).abs() < 1e-4,
                "Tx = {tx}: the baseline is in metres"
            );
            let read =
                StereoCalibration::from_ros_pair(("l.yaml", &left), ("r.yaml", &right)).unwrap();
            assert_eq!((read.left, read.right), (c.left, c.right));
            assert!((read.r - c.r).abs().max() < 1e-9);
            assert!(
                (read.t - c.t).abs().max() < 1e-6,
                "{:?} vs {:?}",
                read.t,
                c.t
            );
        }
    }

    /// Rigs turned a little, with the right camera a little off the left's axis, read back
    /// within round-off: the turn between what was written and what is read is measured
    /// to about 1e-12°, where the arc cosine of the trace read 1.2e-6° (more than
    /// `stereo-convert`'s 1e-6 allowance, so such rigs were refused).
    #[test]
    fn turned_rigs_round_trip_within_round_off() {
        for (yaw_deg, pitch_deg, t) in [
            (0.3, 0.0, [-14.0, 0.05, 0.1]),
            (0.8, -0.5, [-14.02, 0.15, -0.3]),
            (-2.0, 1.0, [-60.0, 1.0, 2.0]),
        ] {
            let mut c = sensor_pair(Distortion::NONE);
            c.r = *nalgebra::Rotation3::from_euler_angles(
                f64::to_radians(pitch_deg),
                f64::to_radians(yaw_deg),
                0.0,
            )
            .matrix();
            c.t = nalgebra::Vector3::from(t);
            let (left, right) = camera_info_pair(&c).unwrap();
            let read =
                StereoCalibration::from_ros_pair(("l.yaml", &left), ("r.yaml", &right)).unwrap();
            let d = read.difference_from(&c);
            assert!(d.rotation_error_deg < 1e-9, "{d:?}");
            assert!(d.baseline_error_percent < 1e-9, "{d:?}");
        }
    }
}
