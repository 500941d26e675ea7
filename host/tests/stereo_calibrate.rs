//! `stereotac stereo-calibrate` end to end (built with the `calibrate` feature): built-in
//! checkerboard views through the sensor's wide lenses saved as files, calibrated from
//! the files, the YAML read back against the true calibration, and depth measured with
//! it; bad inputs refused with the reason. Without the feature the command says how to
//! get it.

mod common;

#[cfg(not(feature = "calibrate"))]
#[test]
fn without_the_feature_the_command_says_how_to_get_it() {
    let (ok, _, err) = common::stereotac(&["stereo-calibrate", "--synthetic", "8"]);
    assert!(!ok);
    assert!(err.contains("--features calibrate"), "{err}");
}

#[cfg(feature = "calibrate")]
mod with_the_feature {
    use super::common::{stereo_from_files, stereotac, temp_dir};
    use serde_json::Value;
    use stereotac::grid::Grid;
    use stereotac::output::read_npy;
    use stereotac::stereo::StereoCalibration;
    use stereotac::stereo::synthetic::{Membrane, RawRig, TexturedPlane, wide_fisheye_calibration};

    fn save(path: &std::path::Path, g: &Grid<u8>) {
        image::GrayImage::from_raw(g.width() as u32, g.height() as u32, g.as_slice().to_vec())
            .unwrap()
            .save(path)
            .unwrap();
    }

    #[test]
    fn board_files_give_a_calibration_that_measures_depth() {
        let dir = temp_dir("calibrate");
        let views = dir.join("views");
        let views_arg = views.to_str().unwrap();
        // 1. Built-in views, saved as files.
        let (ok, _, err) = stereotac(&[
            "stereo-calibrate",
            "--synthetic",
            "10",
            "--save-views",
            views_arg,
            "--out",
            dir.join("synthetic.yaml").to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
        let files = |side: &str| -> Vec<String> {
            (0..10)
                .map(|i| {
                    views
                        .join(format!("{side}_{i:02}.png"))
                        .display()
                        .to_string()
                })
                .collect()
        };
        // 2. The same views from the files, as a user runs it.
        let yaml = dir.join("calib.yaml");
        let mut args = vec!["stereo-calibrate".to_string(), "--left".into()];
        args.extend(files("left"));
        args.push("--right".into());
        args.extend(files("right"));
        args.extend(["--out".into(), yaml.display().to_string(), "--json".into()]);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (ok, out, err) = stereotac(&args);
        assert!(ok, "{err}");
        let report: Value = serde_json::from_str(&out).expect("JSON report");
        assert_eq!(report["pairs_used"], 10, "{report}");
        assert!(report["mean_error_px"].as_f64().unwrap() < 0.2, "{report}");
        // 3. The file reads back and is close to the truth.
        let text = std::fs::read_to_string(&yaml).unwrap();
        let got = StereoCalibration::from_opencv_yaml("calib.yaml", &text).unwrap();
        let truth = wide_fisheye_calibration();
        let d = got.difference_from(&truth);
        assert!(d.focal_error_percent < 0.5, "{d:?}");
        assert!(d.principal_point_error_px < 2.0, "{d:?}");
        assert!(d.baseline_error_percent < 1.0, "{d:?}");
        // 4. Depth of a textured plane 150 mm away, raw through the true lenses,
        //    measured with the calibration we found.
        let raw = RawRig::new(&truth);
        let plane = TexturedPlane {
            point: nalgebra::Point3::new(0.0, 0.0, 150.0),
            normal: nalgebra::Vector3::z(),
        };
        let (l, r) = raw.render(&plane, &Membrane::sensor(), 1);
        save(&dir.join("l.png"), &l);
        save(&dir.join("r.png"), &r);
        let out_dir = dir.join("depth");
        let (ok, _, err) = stereo_from_files(
            &yaml,
            &dir.join("l.png"),
            &dir.join("r.png"),
            &out_dir,
            &["--json"],
        );
        assert!(ok, "{err}");
        let depth = read_npy(&out_dir.join("depth.npy")).unwrap().into_vec();
        let (w, h) = (640, 480);
        let mut centre: Vec<f32> = (h / 3..2 * h / 3)
            .flat_map(|y| (w / 3..2 * w / 3).map(move |x| y * w + x))
            .map(|i| depth[i])
            .filter(|z| z.is_finite())
            .collect();
        assert!(centre.len() > w * h / 9 * 9 / 10, "fill {}", centre.len());
        centre.sort_by(f32::total_cmp);
        let median = centre[centre.len() / 2];
        assert!((median - 150.0).abs() < 1.0, "median depth {median} mm");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn bad_inputs_are_refused_with_a_reason() {
        let dir = temp_dir("calibrate-bad");
        let blank = dir.join("blank.png");
        image::GrayImage::from_pixel(64, 48, image::Luma([128]))
            .save(&blank)
            .unwrap();
        let small = dir.join("small.png");
        image::GrayImage::from_pixel(32, 48, image::Luma([128]))
            .save(&small)
            .unwrap();
        let text = dir.join("not-an-image.png");
        std::fs::write(&text, "hello").unwrap();
        let (b, s, t) = (
            blank.to_str().unwrap(),
            small.to_str().unwrap(),
            text.to_str().unwrap(),
        );
        let out = dir.join("never.yaml");
        let o = out.to_str().unwrap();
        let refused = |args: &[&str], why: &str| {
            let (ok, _, err) = stereotac(args);
            assert!(!ok && err.contains(why), "{args:?}: {err}");
        };
        let cal = "stereo-calibrate";
        refused(
            &[cal, "--left", b, b, "--right", b, "--out", o],
            "2 left images but 1 right",
        );
        refused(
            &[cal, "--left", b, s, "--right", b, b, "--out", o],
            "left image 1 is 32×48",
        );
        refused(
            &[cal, "--left", b, "--right", t, "--out", o],
            "not-an-image.png",
        );
        refused(
            &[cal, "--left", b, "--right", b, "--out", o],
            "only 0 of 1 pairs",
        );
        refused(
            &[cal, "--left", b, "--right", b, "--board", "7x7", "--out", o],
            "ambiguous",
        );
        refused(
            &[
                cal, "--left", b, "--right", b, "--board", "8by6", "--out", o,
            ],
            "COLSxROWS",
        );
        refused(
            &[
                cal,
                "--left",
                b,
                "--right",
                b,
                "--square-mm",
                "0",
                "--out",
                o,
            ],
            "square size",
        );
        refused(&[cal, "--synthetic", "0", "--out", o], "at least 1");
        refused(
            &[cal, "--left", b, "--right", b, "--save-views", "x"],
            "only applies",
        );
        assert!(!out.exists(), "no file is written on failure");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
