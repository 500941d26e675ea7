//! Stereo calibration from checkerboard views, the library's side (built with the
//! `calibrate` feature): corners found through the sensor's wide lenses, known rigs
//! (fisheye and pinhole) recovered from their rendered board views, bad inputs refused
//! with the reason. `stereo_calibrate.rs` runs the command end to end.

#[cfg(feature = "calibrate")]
mod with_the_feature {
    use nalgebra::{Matrix3, Rotation3, Vector3};
    use stereotac::grid::Grid;
    use stereotac::stereo::board::{BoardError, Checkerboard, render_board_capture, true_corners};
    use stereotac::stereo::board_calibration::{
        CalibrateError, CalibrateOptions, Detection, LensModel, calibrate_stereo, detect_board,
    };
    use stereotac::stereo::scene::Membrane;
    use stereotac::stereo::synthetic;
    use stereotac::stereo::{Camera, Distortion, StereoCalibration};

    /// A pinhole pair like the sensor's: 14 mm baseline, slightly rotated and offset.
    fn pinhole_sensor_pair(distortion: Distortion) -> StereoCalibration {
        let camera = |k| Camera {
            width: 640,
            height: 480,
            k,
            distortion,
        };
        StereoCalibration {
            left: camera(Matrix3::new(
                420.0, 0.0, 322.5, 0.0, 421.0, 238.0, 0.0, 0.0, 1.0,
            )),
            right: camera(Matrix3::new(
                425.0, 0.0, 318.0, 0.0, 424.0, 243.5, 0.0, 0.0, 1.0,
            )),
            r: *Rotation3::from_euler_angles(0.01, -0.02, 0.005).matrix(),
            t: Vector3::new(-14.0, 0.2, 0.1),
        }
    }

    #[test]
    fn corners_are_found_within_a_tenth_of_a_pixel_through_the_wide_lens() {
        let calib = synthetic::wide_fisheye_calibration();
        let board = Checkerboard::default();
        let capture = render_board_capture(&calib, &board, &Membrane::sensor(), 4, 3);
        let mut errors = Vec::new();
        for (n, pose) in capture.poses.iter().enumerate() {
            let (truth, _) = true_corners(&calib, &board, pose);
            let found = detect_board(&capture.left[n], &board).unwrap();
            let found = found.corners().expect("whole board");
            for (a, b) in found.iter().zip(&truth) {
                errors.push((a[0] - b[0]).hypot(a[1] - b[1]));
            }
        }
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let worst = errors.iter().copied().fold(0.0, f64::max);
        assert!(
            mean < 0.1 && worst < 0.5,
            "mean {mean:.3} px, worst {worst:.3} px"
        );
    }

    #[test]
    fn a_blank_image_has_no_board_and_a_cropped_one_is_partial() {
        let board = Checkerboard::default();
        let blank = Grid::from_vec(64, 48, vec![128u8; 64 * 48]).unwrap();
        assert_eq!(detect_board(&blank, &board).unwrap(), Detection::Missing);
        let calib = synthetic::wide_fisheye_calibration();
        let capture = render_board_capture(&calib, &board, &Membrane::clear(), 1, 5);
        // Paint the right third grey: a board cut by the image edge.
        let image = &capture.left[0];
        let (l, _) = true_corners(&calib, &board, &capture.poses[0]);
        let cut = (l[board.cols / 2][0]) as usize;
        let cropped = Grid::from_fn(image.width(), image.height(), |x, y| {
            if x > cut { 128 } else { image.get(x, y) }
        });
        match detect_board(&cropped, &board).unwrap() {
            Detection::Partial { found } => assert!(found < 48),
            Detection::Missing => {}
            whole => panic!("a cropped board must not count as whole: {whole:?}"),
        }
    }

    fn check_recovers(calib: &StereoCalibration, model: LensModel, seed: u64) {
        let board = Checkerboard::default();
        let capture = render_board_capture(calib, &board, &Membrane::sensor(), 14, seed);
        let options = CalibrateOptions {
            board,
            model,
            min_pairs: 6,
        };
        let mut calls = 0;
        let result =
            calibrate_stereo(&capture.left, &capture.right, &options, |_| calls += 1).unwrap();
        assert_eq!(calls, 14);
        assert!(result.pairs_used() >= 12, "{:?}", result.pairs);
        // Focal lengths within 0.5 %, principal points within 2 px, baseline within 1 %,
        // rotation within 0.1°.
        let d = result.calibration.difference_from(calib);
        assert!(d.focal_error_percent < 0.5, "{d:?}");
        assert!(d.principal_point_error_px < 2.0, "{d:?}");
        assert!(d.baseline_error_percent < 1.0, "{d:?}");
        assert!(d.rotation_error_deg < 0.1, "{d:?}");
        assert!(result.mean_error_px < 0.2, "{} px", result.mean_error_px);
    }

    #[test]
    fn a_wide_fisheye_pair_is_recovered_from_its_board_views() {
        check_recovers(
            &synthetic::wide_fisheye_calibration(),
            LensModel::Fisheye,
            11,
        );
    }

    #[test]
    fn a_pinhole_pair_is_recovered_from_its_board_views() {
        let calib = pinhole_sensor_pair(Distortion::BrownConrady([
            -0.12, 0.05, 0.0005, -0.0003, 0.0, 0.0, 0.0, 0.0,
        ]));
        check_recovers(&calib, LensModel::Pinhole, 12);
    }

    #[test]
    fn bad_inputs_are_refused_with_the_reason() {
        let board = Checkerboard::default();
        let image = |w: usize| Grid::from_vec(w, 48, vec![128u8; w * 48]).unwrap();
        let options = CalibrateOptions::default();
        let err = calibrate_stereo(&[image(64)], &[], &options, |_| {}).unwrap_err();
        assert!(matches!(
            err,
            CalibrateError::PairCount { left: 1, right: 0 }
        ));
        let err = calibrate_stereo(
            &[image(64), image(60)],
            &[image(64), image(64)],
            &options,
            |_| {},
        )
        .unwrap_err();
        assert!(
            matches!(
                err,
                CalibrateError::ImageSize {
                    camera: "left",
                    index: 1,
                    ..
                }
            ),
            "{err}"
        );
        let err = calibrate_stereo(&[image(64)], &[image(64)], &options, |_| {}).unwrap_err();
        assert!(matches!(
            err,
            CalibrateError::TooFewPairs {
                usable: 0,
                total: 1,
                ..
            }
        ));
        assert!(err.to_string().contains("8×6"));
        let square = CalibrateOptions {
            board: Checkerboard { cols: 6, ..board },
            ..options
        };
        let err = calibrate_stereo(&[image(64)], &[image(64)], &square, |_| {}).unwrap_err();
        assert!(matches!(err, CalibrateError::Board(BoardError::Square(6))));
    }
}
