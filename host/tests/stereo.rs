//! The `stereotac` stereo commands end to end: built-in captures in, files out, the same
//! result through a calibration file, typed errors for bad input, and the evaluation's
//! goals on synthetic flat targets.

mod common;
use common::{stereo_from_files, stereotac, temp_dir};

use std::path::Path;

use serde_json::Value;
use stereotac::output::read_npy;
use stereotac::stereo::ros_info::camera_info_pair;
use stereotac::stereo::synthetic::StereoRig;

fn npy_f32(path: &Path) -> Vec<f32> {
    read_npy(path).expect("npy").into_vec()
}

#[test]
fn pictures_state_their_range_and_meshes_stop_at_depth_steps() {
    let dir = temp_dir("stereo-pictures");
    let run = |name: &str, extra: &[&str]| {
        let out = dir.join(name);
        let mut args = vec![
            "stereo",
            "--synthetic",
            "150",
            "--out-dir",
            out.to_str().unwrap(),
            "--json",
        ];
        args.extend_from_slice(extra);
        let (ok, text, err) = stereotac(&args);
        assert!(ok, "{err}");
        let s: Value = serde_json::from_str(&text).expect("JSON summary");
        (out, s)
    };
    // Automatic: the data's percentiles, around the plane at 150 mm.
    let (out, s) = run("auto", &[]);
    let depth = &s["colour_ranges"]["depth"];
    let (lo, hi) = (depth["lo"].as_f64().unwrap(), depth["hi"].as_f64().unwrap());
    assert!(lo > 100.0 && hi < 220.0 && lo < hi, "{depth}");
    assert!(
        depth["from"].as_str().unwrap().contains("percentiles"),
        "{depth}"
    );
    assert_eq!(s["colour_ranges"]["disparity"]["unit"], "px");
    let picture = image::open(out.join("depth_colour.png")).unwrap();
    assert!(picture.width() > 640, "the legend is beside the picture");
    assert!(s.get("mesh_triangles").is_none());
    // Searched and fixed ranges, and a mesh.
    let (_, s) = run("searched", &["--colour-range", "searched"]);
    assert_eq!(s["colour_ranges"]["depth"]["lo"], 50.0);
    assert_eq!(s["colour_ranges"]["depth"]["hi"], 600.0);
    let (out, s) = run("fixed", &["--colour-range", "100,300", "--mesh"]);
    assert_eq!(s["colour_ranges"]["depth"]["from"], "given");
    assert_eq!(s["colour_ranges"]["depth"]["hi"], 300.0);
    let triangles = s["mesh_triangles"].as_u64().unwrap();
    let points = s["points"].as_u64().unwrap();
    // A plane: nearly two triangles per point, none across the frame's gaps.
    assert!(
        triangles > points && triangles < 2 * points,
        "{triangles} for {points} points"
    );
    assert!(
        s["files"]
            .as_array()
            .unwrap()
            .contains(&Value::from("mesh.ply"))
    );
    assert!(out.join("mesh.ply").is_file());
    assert_eq!(
        s["warnings"],
        Value::Array(Vec::new()),
        "the range shows the plane"
    );
    // A range that shows none of the depths is said (the picture is one colour).
    let (_, s) = run("beyond", &["--colour-range", "1000,2000"]);
    let warnings = s["warnings"].to_string();
    assert!(
        warnings.contains("depth_colour.png: none of its") && warnings.contains("1000–2000 mm"),
        "{warnings}"
    );
    // The matcher is chosen on the command line and named in the summary; both put the
    // plane's centre at 150 mm (the built-in capture is tilted: the median is near it).
    let (_, bm) = run("bm", &[]);
    let (_, sgm) = run("sgm", &["--matcher", "sgm"]);
    assert_eq!(
        (bm["matcher"].as_str(), sgm["matcher"].as_str()),
        (Some("bm"), Some("sgm"))
    );
    // Eight paths unless told; OpenCV's three on request, as accurate on this plane.
    assert_eq!(
        (bm.get("sgm_paths"), sgm["sgm_paths"].as_u64()),
        (None, Some(8))
    );
    let median = |s: &Value| s["depth_mm"][1].as_f64().unwrap();
    assert!(
        (median(&sgm) - median(&bm)).abs() < 1.5,
        "{} against {}",
        median(&sgm),
        median(&bm)
    );
    assert!(sgm["fill_rate"].as_f64().unwrap() >= bm["fill_rate"].as_f64().unwrap() - 0.01);
    // Each matcher's own window unless one is given.
    assert_eq!(
        (bm["window_px"].as_u64(), sgm["window_px"].as_u64()),
        (Some(9), Some(11))
    );
    let (_, three) = run(
        "sgm3",
        &["--matcher", "sgm", "--sgm-paths", "3", "--block-size", "7"],
    );
    assert_eq!(three["sgm_paths"].as_u64(), Some(3));
    assert_eq!(three["window_px"].as_u64(), Some(7));
    // Paths without semi-global matching would be ignored: refused.
    let (ok, _, err) = stereotac(&[
        "stereo",
        "--synthetic",
        "150",
        "--out-dir",
        dir.join("bm3").to_str().unwrap(),
        "--sgm-paths",
        "3",
    ]);
    assert!(!ok && err.contains("--matcher sgm"), "{err}");
    assert!(
        (median(&three) - median(&sgm)).abs() < 0.5,
        "{} against {}",
        median(&three),
        median(&sgm)
    );
    let (ok, _, err) = stereotac(&[
        "stereo",
        "--synthetic",
        "150",
        "--out-dir",
        dir.join("bad").to_str().unwrap(),
        "--colour-range",
        "300,100",
    ]);
    assert!(!ok && err.contains("LO,HI"), "{err}");
    // A scene beyond what depth16.png holds (655.35 mm at 0.01 mm a count): said, not
    // silently written as 65535.
    let far = dir.join("far");
    let (ok, out, err) = stereotac(&[
        "stereo",
        "--synthetic",
        "800",
        "--far-mm",
        "1500",
        "--out-dir",
        far.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let s: Value = serde_json::from_str(&out).expect("JSON summary");
    let warned = s["warnings"].as_array().unwrap().iter().any(|w| {
        let w = w.as_str().unwrap();
        w.contains("deeper than 655.35 mm") && w.contains("depth.npy")
    });
    assert!(warned, "{s}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_built_in_capture_and_the_same_images_through_a_calibration_file_agree() {
    let dir = temp_dir("stereo-cli");
    let a = dir.join("a");
    let (ok, out, err) = stereotac(&[
        "stereo",
        "--synthetic",
        "150",
        "--out-dir",
        a.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let s: Value = serde_json::from_str(&out).expect("JSON summary");
    assert!(s["fill_rate"].as_f64().unwrap() > 0.7, "{s}");
    assert_eq!(
        s["warnings"],
        serde_json::json!([]),
        "a clean capture warns of nothing"
    );
    // The plane is at 150 mm on the axis, tilted: the median depth is near it.
    let median = s["depth_mm"][1].as_f64().unwrap();
    assert!((140.0..170.0).contains(&median), "{median}");
    for f in s["files"].as_array().unwrap() {
        assert!(a.join(f.as_str().unwrap()).is_file(), "{f} missing");
    }
    let depth = npy_f32(&a.join("depth.npy"));
    assert_eq!(depth.len(), 640 * 480);

    // The same images with the rig written as an OpenCV file give the same disparity.
    let yaml = dir.join("rig.yaml");
    std::fs::write(&yaml, StereoRig::sensor().calibration().to_opencv_yaml()).unwrap();
    let b = dir.join("b");
    let (ok, _, err) = stereo_from_files(
        &yaml,
        &a.join("input_left.png"),
        &a.join("input_right.png"),
        &b,
        &[],
    );
    assert!(ok, "{err}");
    let (da, db) = (
        npy_f32(&a.join("disparity.npy")),
        npy_f32(&b.join("disparity.npy")),
    );
    let same = da
        .iter()
        .zip(&db)
        .filter(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()))
        .count();
    assert_eq!(same, da.len());

    // The rig as a ROS camera_info pair (metres) and as an OpenCV file in metres with
    // --units m: the same depth. Without --units the metres file is refused, with why.
    let median_depth = |d: &Path| {
        let mut v: Vec<f32> = npy_f32(&d.join("depth.npy"))
            .into_iter()
            .filter(|v| v.is_finite())
            .collect();
        v.sort_by(f32::total_cmp);
        v[v.len() / 2] as f64
    };
    let want = median_depth(&b);
    let rig = StereoRig::sensor().calibration();
    let (ros_left, ros_right) = camera_info_pair(&rig).unwrap();
    let (l, r) = (dir.join("left.yaml"), dir.join("right.yaml"));
    std::fs::write(&l, ros_left).unwrap();
    std::fs::write(&r, ros_right).unwrap();
    let ros = dir.join("ros");
    let (ok, _, err) = stereotac(&[
        "stereo",
        "--calib",
        l.to_str().unwrap(),
        "--calib",
        r.to_str().unwrap(),
        "--left",
        a.join("input_left.png").to_str().unwrap(),
        "--right",
        a.join("input_right.png").to_str().unwrap(),
        "--out-dir",
        ros.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let got = median_depth(&ros);
    assert!(
        (got / want - 1.0).abs() < 0.005,
        "ROS pair: {got} vs {want} mm"
    );
    let mut in_m = rig;
    in_m.t /= 1000.0;
    let yaml_m = dir.join("rig_m.yaml");
    std::fs::write(&yaml_m, in_m.to_opencv_yaml()).unwrap();
    let (left_png, right_png) = (a.join("input_left.png"), a.join("input_right.png"));
    let m = dir.join("m");
    let (ok, _, err) = stereo_from_files(&yaml_m, &left_png, &right_png, &m, &[]);
    assert!(!ok && err.contains("--units m"), "{err}");
    let (ok, _, err) = stereo_from_files(&yaml_m, &left_png, &right_png, &m, &["--units", "m"]);
    assert!(ok, "{err}");
    let got = median_depth(&m);
    assert!(
        (got / want - 1.0).abs() < 1e-6,
        "--units m: {got} vs {want} mm"
    );

    // What the calibration's reading warns of (here a misspelt key) is in summary.json
    // with the result's warnings, and `--strict` fails on it.
    let noted = dir.join("rig_noted.yaml");
    std::fs::write(&noted, rig.to_opencv_yaml() + "k1: 0.5\n").unwrap();
    let n = dir.join("noted");
    let (ok, _, err) = stereo_from_files(&noted, &left_png, &right_png, &n, &[]);
    assert!(
        ok && err.matches("`k1`").count() == 1,
        "printed once: {err}"
    );
    let s: Value =
        serde_json::from_str(&std::fs::read_to_string(n.join("summary.json")).unwrap()).unwrap();
    let warnings = s["warnings"].as_array().unwrap();
    assert!(
        warnings.len() == 1 && warnings[0].as_str().unwrap().contains("`k1`"),
        "{warnings:?}"
    );
    let (ok, _, err) =
        stereo_from_files(&noted, &left_png, &right_png, &n, &["--strict", "--force"]);
    assert!(!ok && err.contains("1 warning(s) under --strict"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Every depth written lies within `--near-mm..--far-mm`: the matcher searches whole
/// blocks of 16 disparities, a little past the range, and what it finds past it is
/// dropped and counted (a plane at 130–175 mm with the range starting at 160 used to
/// keep its depths from 129 mm, under a warning that said they lay at the range's ends).
#[test]
fn depths_outside_the_working_range_are_dropped_and_counted() {
    let dir = temp_dir("stereo-range");
    let (ok, text, err) = stereotac(&[
        "stereo",
        "--synthetic",
        "150",
        "--near-mm",
        "160",
        "--far-mm",
        "400",
        "--out-dir",
        dir.join("out").to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let s: Value = serde_json::from_str(&text).unwrap();
    let dropped = s["stats"]["outside_range"].as_u64().unwrap();
    assert!(dropped > 1000, "{}", s["stats"]);
    let depth = npy_f32(&dir.join("out").join("depth.npy"));
    let valid: Vec<f32> = depth.into_iter().filter(|d| d.is_finite()).collect();
    assert!(!valid.is_empty());
    assert!(
        valid.iter().all(|&d| (159.99..=400.01).contains(&d)),
        "{:?}",
        valid
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &d| (a.min(d), b.max(d)))
    );
    assert_eq!(s["stats"]["valid"].as_u64().unwrap() as usize, valid.len());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A blank pair (a covered lens, the light off) is said to be blank by either matcher:
/// semi-global matching finds its best matches at the range's end there, and used to
/// advise a wider range, which cannot help.
#[test]
fn a_blank_pair_is_said_to_have_no_texture_by_either_matcher() {
    let dir = temp_dir("stereo-blank");
    let (ok, _, err) = stereotac(&[
        "stereo",
        "--synthetic",
        "200",
        "--out-dir",
        dir.join("syn").to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let grey = dir.join("grey.png");
    image::GrayImage::from_pixel(640, 480, image::Luma([128]))
        .save(&grey)
        .unwrap();
    let calib = dir.join("syn").join("input_calibration.yaml");
    for matcher in ["bm", "sgm"] {
        let out = dir.join(matcher);
        let (ok, _, err) = stereo_from_files(&calib, &grey, &grey, &out, &["--matcher", matcher]);
        assert!(ok, "{matcher}: {err}");
        assert!(
            err.contains("almost no texture") && !err.contains("widen"),
            "{matcher}: {err}"
        );
        let (ok, _, err) = stereo_from_files(
            &calib,
            &grey,
            &grey,
            &out,
            &["--matcher", matcher, "--force", "--strict"],
        );
        assert!(!ok && err.contains("almost no texture"), "{matcher}: {err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_inputs_are_refused_with_a_reason() {
    let dir = temp_dir("stereo-bad");
    let out_dir = dir.join("out");
    let out = out_dir.to_str().unwrap();
    let refused = |args: &[&str], why: &str| {
        let (ok, _, err) = stereotac(args);
        assert!(!ok && err.contains(why), "{args:?}: {err}");
    };
    let pair = ["--left", "l.png", "--right", "r.png", "--out-dir", out];
    refused(&[&["stereo"][..], &pair].concat(), "--calib");
    let missing = ["stereo", "--calib", "/nonexistent.yaml"];
    refused(&[&missing[..], &pair].concat(), "/nonexistent.yaml");
    // A calibration for 640×480 and a 20×10 image: the frame size error names the camera.
    let yaml = dir.join("rig.yaml");
    std::fs::write(&yaml, StereoRig::sensor().calibration().to_opencv_yaml()).unwrap();
    let small = dir.join("small.png");
    image::GrayImage::new(20, 10).save(&small).unwrap();
    let (y, sm) = (yaml.to_str().unwrap(), small.to_str().unwrap());
    refused(
        &[
            "stereo",
            "--calib",
            y,
            "--left",
            sm,
            "--right",
            sm,
            "--out-dir",
            out,
        ],
        "left frame",
    );
    refused(
        &[
            "stereo",
            "--synthetic",
            "150",
            "--near-mm",
            "700",
            "--out-dir",
            out,
        ],
        "disparity range",
    );
    refused(&["stereo-eval", "--frames", "0"], "frame");
    // A working range that cuts the scene: a warning, and failure under --strict.
    let cut = dir.join("cut");
    let cut_args = [
        "stereo",
        "--synthetic",
        "150",
        "--far-mm",
        "140",
        "--out-dir",
        cut.to_str().unwrap(),
    ];
    let (ok, _, err) = stereotac(&cut_args);
    assert!(
        ok && err.contains("warning:") && err.contains("--far-mm"),
        "{err}"
    );
    let summary: Value =
        serde_json::from_slice(&std::fs::read(cut.join("summary.json")).unwrap()).unwrap();
    assert!(
        !summary["warnings"].as_array().unwrap().is_empty(),
        "{summary}"
    );
    refused(
        &[&cut_args[..], &["--strict", "--force"]].concat(),
        "--strict",
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `stereo-eval --lens LENS` at 100 and 300 mm, six frames each: the (raw, filtered)
/// rows of each distance.
fn eval_pairs(lens: &str) -> Vec<(Value, Value)> {
    let (ok, out, err) = stereotac(&[
        "stereo-eval",
        "--lens",
        lens,
        "--distances",
        "100,300",
        "--frames",
        "6",
        "--json",
    ]);
    assert!(ok, "{err}");
    let rows: Vec<Value> = serde_json::from_str(&out).expect("JSON rows");
    assert_eq!(rows.len(), 4);
    rows.chunks(2)
        .map(|pair| {
            let (raw, filtered) = (pair[0].clone(), pair[1].clone());
            assert_eq!(
                (raw["variant"].as_str(), filtered["variant"].as_str()),
                (Some("raw"), Some("filtered"))
            );
            // Each row names the matcher that made it (the default: block matching).
            assert_eq!(
                (raw["matcher"].as_str(), raw["sgm_paths"].is_null()),
                (Some("bm"), true)
            );
            (raw, filtered)
        })
        .collect()
}

fn get(row: &Value, key: &str) -> f64 {
    row[key].as_f64().unwrap_or(f64::NAN)
}

#[test]
fn the_evaluation_meets_its_goals_with_the_post_filters() {
    for (raw, filtered) in eval_pairs("ideal") {
        // Issue goals: Z-accuracy and RMS error within 0.3 %, fill ≥ 95 %.
        assert!(get(&filtered, "z_accuracy_pct").abs() <= 0.3, "{filtered}");
        assert!(get(&filtered, "rms_error_pct") <= 0.3, "{filtered}");
        assert!(get(&filtered, "fill_rate_pct") >= 95.0, "{filtered}");
        // And the filters help.
        assert!(
            get(&filtered, "rms_error_pct") < get(&raw, "rms_error_pct"),
            "{raw} {filtered}"
        );
        assert!(get(&filtered, "temporal_noise_pct") < get(&raw, "temporal_noise_pct"));
    }
}

#[test]
fn through_the_wide_lenses_raw_frames_are_rectified_and_measured() {
    // Raw fisheye frames (160° lenses), rectified by the pipeline like real ones.
    let pairs = eval_pairs("wide");
    for (raw, filtered) in &pairs {
        // Rectification through the lens model puts the plane where it is.
        assert!(get(filtered, "z_accuracy_pct").abs() <= 0.1, "{filtered}");
        assert!(get(filtered, "fill_rate_pct") >= 95.0, "{filtered}");
        assert!(get(filtered, "rms_error_pct") < get(raw, "rms_error_pct"));
    }
    // The RMS goal holds at 100 mm; at 300 mm the wide lens's lower focal length (294
    // px against the ideal rig's 336) leaves it at about 0.37 % (see the README).
    let at_100 = &pairs[0].1;
    assert!(get(at_100, "rms_error_pct") <= 0.3, "{at_100}");
}

#[test]
fn the_stereo_bench_reports_every_stage() {
    let (ok, out, err) = stereotac(&["bench", "stereo", "--repeats", "1", "--json"]);
    assert!(ok, "{err}");
    let rows: Vec<Value> = serde_json::from_str(&out).expect("JSON rows");
    let names: Vec<&str> = rows.iter().filter_map(|r| r["what"].as_str()).collect();
    for want in ["remap", "match, Portable", "whole frame"] {
        assert!(
            names.iter().any(|n| n.starts_with(want)),
            "{want} missing: {names:?}"
        );
    }
    for r in &rows {
        assert!(r["median_ms"].as_f64().is_some_and(|t| t >= 0.0), "{r}");
    }
}

/// `stereotac … | head -1`: the reader goes away, the command still finishes its work
/// and exits cleanly (it used to panic on the closed pipe, before writing its outputs).
#[test]
fn a_closed_stdout_is_not_a_crash() {
    let dir = temp_dir("stereo-pipe");
    let out = dir.join("out");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_stereotac"))
        .args([
            "stereo",
            "--synthetic",
            "150",
            "--out-dir",
            out.to_str().unwrap(),
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let done = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&done.stderr);
    assert!(done.status.success() && !err.contains("panicked"), "{err}");
    assert!(out.join("summary.json").is_file(), "outputs written");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `stereo-convert`: an OpenCV file in metres becomes an OpenCV file in mm and a ROS pair,
/// each reading back as the rig; the ROS pair converts back to the same OpenCV file;
/// metres read as mm are refused with the hint; outputs are not replaced without --force.
#[test]
fn calibrations_convert_between_formats_and_read_back() {
    let dir = temp_dir("stereo-convert");
    let rig = StereoRig::sensor().calibration();
    let mut in_m = rig;
    in_m.t /= 1000.0;
    let yaml_m = dir.join("rig_m.yaml");
    std::fs::write(&yaml_m, in_m.to_opencv_yaml()).unwrap();
    let p = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let (ok, _, err) = stereotac(&[
        "stereo-convert",
        "--calib",
        &p("rig_m.yaml"),
        "--opencv",
        &p("mm.yaml"),
    ]);
    assert!(!ok && err.contains("--units m"), "{err}");
    let (ok, out, err) = stereotac(&[
        "stereo-convert",
        "--calib",
        &p("rig_m.yaml"),
        "--units",
        "m",
        "--opencv",
        &p("mm.yaml"),
        "--ros-left",
        &p("ros/left.yaml"),
        "--ros-right",
        &p("ros/right.yaml"),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("baseline 14.000 mm"), "{out}");
    // (`ros/` did not exist: made, as `stereo --out-dir` is.)
    for f in ["left.yaml", "right.yaml"] {
        std::fs::rename(dir.join("ros").join(f), dir.join(f)).unwrap();
    }
    let read = |files: &[&str]| {
        let paths: Vec<_> = files.iter().map(|f| dir.join(f)).collect();
        stereotac::stereo::StereoCalibration::load(&paths).unwrap()
    };
    for files in [&["mm.yaml"][..], &["left.yaml", "right.yaml"]] {
        let d = read(files).difference_from(&rig);
        assert!(
            d.focal_error_percent < 1e-9
                && d.baseline_error_percent < 1e-9
                && d.rotation_error_deg < 1e-6,
            "{files:?}: {d:?}"
        );
    }
    // Back from the ROS pair: the same calibration, to round-off.
    let (ok, _, err) = stereotac(&[
        "stereo-convert",
        "--calib",
        &p("left.yaml"),
        "--calib",
        &p("right.yaml"),
        "--opencv",
        &p("again.yaml"),
    ]);
    assert!(ok, "{err}");
    let d = read(&["again.yaml"]).difference_from(&read(&["mm.yaml"]));
    assert!(d.baseline_error_percent < 1e-9, "{d:?}");
    let (ok, _, err) = stereotac(&[
        "stereo-convert",
        "--calib",
        &p("mm.yaml"),
        "--opencv",
        &p("again.yaml"),
    ]);
    assert!(!ok && err.contains("--force"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A stand-in for Python with OpenCV, for `stereo-eval --compare`'s plumbing: called as
/// the interpreter with our script's path and its arguments, it reads the pairs file and
/// writes, for StereoBM, the true disparity of a facing plane at `FAKE_DISTANCE_MM` as
/// every pixel's (an .npy of the left PNG's size, from the PNG header); for StereoSGBM it
/// fails as a missing module would.
const FAKE_OPENCV: &str = r#"
import json, os, struct, sys
_, _script, pairs, num_disp, block, min_disp, repeats, mode = sys.argv
if mode != "bm":
    sys.exit("ModuleNotFoundError: No module named 'cv2' (fake sgbm)")
d = float(os.environ["FAKE_DISPARITY"])
for line in open(pairs, encoding="utf-8"):
    left, right, out = line.rstrip("\n").split("\t")
    with open(left, "rb") as f:
        w, h = struct.unpack(">II", f.read(24)[16:24])
    header = "{'descr': '<f4', 'fortran_order': False, 'shape': (%d, %d), }" % (h, w)
    header += " " * ((64 - (10 + len(header) + 1) % 64) % 64) + "\n"
    with open(out, "wb") as f:
        f.write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode())
        f.write(struct.pack("<f", d) * (w * h))
print(json.dumps({"median_ms": 1.5, "opencv": "fake"}))
"#;

#[test]
fn compare_runs_both_matchers_and_opencvs_on_the_same_captures() {
    let dir = temp_dir("compare");
    let fake = dir.join("fake_opencv.py");
    std::fs::write(&fake, FAKE_OPENCV).unwrap();
    let python = dir.join("python");
    std::fs::write(
        &python,
        format!("#!/bin/sh\nexec python3 {} \"$@\"\n", fake.display()),
    )
    .unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&python, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    let rig = StereoRig::sensor();
    let truth = rig.focal_px * rig.baseline_mm / 200.0;
    let run = |python: &Path| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_stereotac"))
            .args(["stereo-eval", "--compare", "--distances", "200"])
            .args(["--frames", "2", "--json"])
            .env("STEREOTAC_PYTHON", python)
            .env("FAKE_DISPARITY", truth.to_string())
            .output()
            .expect("run stereotac");
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "{err}");
        let report: Value = serde_json::from_slice(&out.stdout).expect("JSON report");
        (report, err)
    };
    let (report, err) = run(&python);
    let rows = report["rows"].as_array().expect("rows");
    let names: Vec<&str> = rows.iter().filter_map(|r| r["matcher"].as_str()).collect();
    assert_eq!(
        names,
        ["bm", "sgm, 8 paths", "OpenCV StereoBM 9×9"],
        "{report}"
    );
    // Ours measure the plane; the stand-in's exact disparity reads it exactly, with its
    // time; StereoSGBM's failure is reported as skipped, with the reason.
    for row in &rows[..2] {
        assert!(get(row, "z_accuracy_pct").abs() < 0.5, "{row}");
        assert!(get(row, "fill_rate_pct") > 95.0, "{row}");
        assert!(get(row, "match_ms") > 0.0, "{row}");
    }
    let cv = &rows[2];
    assert!(get(cv, "z_accuracy_pct").abs() < 1e-3, "{cv}");
    assert!(get(cv, "rms_error_pct") < 1e-3, "{cv}");
    assert_eq!(
        (get(cv, "fill_rate_pct"), get(cv, "match_ms")),
        (100.0, 1.5)
    );
    assert_eq!(report["opencv"].as_str(), Some("fake"));
    let skipped = report["opencv_skipped"].as_str().unwrap_or("");
    assert!(skipped.contains("fake sgbm"), "{report}");
    assert!(err.contains("OpenCV's matchers skipped"), "{err}");
    // No interpreter at all: our rows, OpenCV's skipped with the reason.
    let (report, err) = run(&dir.join("no-such-python"));
    assert_eq!(report["rows"].as_array().map(Vec::len), Some(2), "{report}");
    assert!(report["opencv"].is_null());
    assert!(
        err.contains("OpenCV's matchers skipped")
            && err.contains("no-such-python")
            && err.contains("STEREOTAC_PYTHON"),
        "{err}"
    );
    // The matchers are its own: --matcher does not go with it.
    let (ok, _, err) = stereotac(&["stereo-eval", "--compare", "--matcher", "sgm"]);
    assert!(!ok && err.contains("--matcher"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
