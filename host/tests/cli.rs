//! The `stereotac` binary's link commands, end to end against the simulated sensor.

mod common;
use common::stereotac;

#[test]
fn help_documents_every_subcommand() {
    let (ok, help, _) = stereotac(&["--help"]);
    assert!(ok);
    for sub in [
        "devices",
        "info",
        "stream",
        "record",
        "set",
        "flash",
        "demo",
        "calibrate",
        "reconstruct",
        "stereo",
        "stereo-eval",
        "stereo-convert",
        "bench",
        "firmware-image",
        "run",
        "process",
        "export",
    ] {
        assert!(
            help.contains(&format!("  {sub} ")),
            "{sub} missing from:\n{help}"
        );
        let (ok, text, _) = stereotac(&[sub, "--help"]);
        assert!(ok && text.contains("Usage:"), "{sub} --help");
    }
}

#[test]
fn info_stream_set_and_record_against_the_simulated_sensor() {
    let (ok, info, err) = stereotac(&["--sim", "info"]);
    assert!(ok, "{err}");
    assert!(
        info.contains(&format!(
            "protocol v{}",
            stereotac_protocol::PROTOCOL_VERSION
        )) && info.contains("clock sync"),
        "{info}"
    );

    let (ok, lines, err) = stereotac(&["--sim", "stream", "--duration-s", "1.1", "--json"]);
    assert!(ok, "{err}");
    let phases: Vec<serde_json::Value> = lines
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .filter(|v: &serde_json::Value| v["event"] == "phase")
        .collect();
    assert!(phases.len() >= 4, "{lines}");
    assert_eq!(phases[0]["phase"], "dx");
    assert_eq!(phases[1]["phase"], "dy");
    assert!(err.contains("0 lost"), "{err}");

    let (ok, _, err) = stereotac(&["--sim", "set", "--strip", "2", "--colour", "zz0000"]);
    assert!(!ok && err.contains("RRGGBB"), "{err}");
    let (ok, _, err) = stereotac(&["--sim", "set", "--leds", "0"]);
    assert!(!ok && err.contains("invalid value for LED count"), "{err}");
    // One bad value among good ones: one request, refused whole.
    let (ok, out, err) = stereotac(&["--sim", "set", "--period-ms", "100", "--leds", "0"]);
    assert!(
        !ok && err.contains("LED count") && err.contains("nothing was changed"),
        "{err}"
    );
    assert!(!out.contains("ok:"), "{out}");
    let (ok, out, err) = stereotac(&["--sim", "set", "--period-ms", "100", "--mode", "vision"]);
    assert!(ok, "{err}");
    assert!(
        out.contains("ok: set mode vision") && out.contains("period 100000 µs"),
        "{out}"
    );
    assert!(
        !out.contains("SetMode") && !out.contains('{'),
        "debug text: {out}"
    );

    let dir = std::env::temp_dir().join(format!("stereotac-cli-rec-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let rec = dir.join("rec.mcap");
    let r = rec.to_str().unwrap();
    let (ok, _, err) = stereotac(&["--sim", "record", "--out", r, "--duration-s", "1.6"]);
    assert!(ok, "{err}");
    assert!(err.contains("0 dropped, 0 straddling"), "{err}");
    let bytes = std::fs::read(&rec).unwrap();
    let images = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .filter(|m| m.channel.topic == "/stereotac/cam0/image")
        .count();
    assert!(images >= 5, "{images} frames in 1.6 s at 4 Hz\n{err}");
    assert!(
        err.contains(&format!("{images} frames")),
        "the summary counts what the file holds: {err}"
    );
    let (ok, _, err) = stereotac(&["--sim", "record", "--out", r, "--duration-s", "1"]);
    assert!(
        !ok && err.contains("exists already"),
        "never overwrites: {err}"
    );
    // --png: the PNG-and-index directory.
    let png = dir.join("png");
    let d = png.to_str().unwrap();
    let (ok, out, err) = stereotac(&[
        "--sim",
        "record",
        "--png",
        "--out",
        d,
        "--duration-s",
        "1.6",
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("0 frames dropped"), "{out}");
    let index = std::fs::read_to_string(png.join("index.jsonl")).unwrap();
    let n = index.lines().count();
    assert!(n >= 5, "{index}");
    assert_eq!(
        std::fs::read_dir(&png).unwrap().count(),
        n + 1,
        "one PNG per index line"
    );
    let (ok, _, err) = stereotac(&["--sim", "record", "--png", "--out", d, "--duration-s", "1"]);
    assert!(
        !ok && err.contains("frame_00000000.png") && err.contains("nothing is ever written over"),
        "never overwrites: {err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn flash_refuses_a_file_that_is_not_uf2() {
    let path = std::env::temp_dir().join(format!("not-uf2-{}.bin", std::process::id()));
    std::fs::write(&path, [0u8; 1024]).unwrap();
    let (ok, _, err) = stereotac(&["--sim", "flash", path.to_str().unwrap()]);
    assert!(!ok && err.contains("not a UF2 image"), "{err}");
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn record_takes_several_cameras_into_one_directory_each() {
    let dir = std::env::temp_dir().join(format!("stereotac-cli-two-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = dir.to_str().unwrap();
    let args = [
        "--sim",
        "record",
        "--png",
        "--out",
        d,
        "--camera",
        "sim",
        "--camera",
        "sim",
        "--duration-s",
        "1.3",
    ];
    let (ok, out, err) = stereotac(&args);
    assert!(ok, "{err}");
    assert_eq!(out.matches("0 frames dropped").count(), 2, "{out}");
    let lines = |cam: &str| {
        std::fs::read_to_string(dir.join(cam).join("index.jsonl"))
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
            .collect::<Vec<_>>()
    };
    let (a, b) = (lines("cam0"), lines("cam1"));
    assert!(a.len() >= 4, "{a:?}");
    // Frames labelled with a phase carry its trigger. (A frame exposed across an LED
    // change is labelled "straddles" instead, which a loaded machine can make happen to
    // either camera's first frame.)
    let phases = |v: &[serde_json::Value]| -> std::collections::BTreeMap<u64, String> {
        v.iter()
            .filter(|l| l["label"] == "phase")
            .map(|l| {
                assert!(l["phase"].is_string() && l["trigger"].is_u64(), "{l}");
                (
                    l["trigger"].as_u64().unwrap(),
                    l["phase"].as_str().unwrap().to_string(),
                )
            })
            .collect()
    };
    let (pa, pb) = (phases(&a), phases(&b));
    assert!(pa.len() >= 3 && pb.len() >= 3, "{a:?}\n{b:?}");
    // Both cameras answer the same triggers, so they label them with the same phases.
    let common: Vec<_> = pa.keys().filter(|t| pb.contains_key(t)).collect();
    assert!(common.len() >= 3, "{pa:?} {pb:?}");
    for t in common {
        assert_eq!(pa[t], pb[t], "trigger {t}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn cameras_and_backends_this_build_lacks_are_refused_with_the_fix() {
    if !cfg!(feature = "v4l2") {
        let (ok, _, err) = stereotac(&[
            "record",
            "--out",
            "/nonexistent/x",
            "--camera",
            "/dev/video0",
        ]);
        assert!(!ok && err.contains("`v4l2` feature"), "{err}");
    } else if cfg!(target_os = "linux") {
        // In the default Linux build: a camera that is not there is named, and no
        // recording is left behind.
        let out = std::env::temp_dir().join(format!("no-camera-{}.mcap", std::process::id()));
        let (ok, _, err) = stereotac(&[
            "--sim",
            "record",
            "--out",
            out.to_str().unwrap(),
            "--camera",
            "/dev/video-stereotac-none",
        ]);
        assert!(!ok && err.contains("/dev/video-stereotac-none"), "{err}");
        assert!(!out.exists(), "no file for a run that never started");
    }
    if !cfg!(feature = "libusb") {
        let (ok, _, err) = stereotac(&["--libusb", "devices"]);
        assert!(!ok && err.contains("--features libusb"), "{err}");
    }
    let (ok, _, err) = stereotac(&["--sim", "--libusb", "info"]);
    assert!(!ok && err.contains("cannot be used with"), "{err}");
    let (ok, _, err) = stereotac(&["--sim", "record", "--out", "/tmp/x", "--size", "64"]);
    assert!(!ok && err.contains("640x480"), "{err}");
}

#[test]
fn sensor_options_belong_to_the_sensor_commands_and_json_is_json() {
    // Before the command word, accepted for sensor commands and refused for the others.
    let (ok, _, err) = stereotac(&[
        "--sim",
        "calibrate",
        "--ball-diameter-mm",
        "6",
        "--out",
        "/nonexistent/model.json",
        "/nonexistent",
    ]);
    assert!(!ok && err.contains("does not talk to a sensor"), "{err}");
    // After it, only the sensor commands know them.
    let (ok, _, err) = stereotac(&["stereo-eval", "--sim"]);
    assert!(!ok && err.contains("unexpected argument '--sim'"), "{err}");
    let (ok, help, _) = stereotac(&["reconstruct", "--help"]);
    assert!(ok && !help.contains("--sim"), "{help}");
    let (ok, help, _) = stereotac(&["stream", "--help"]);
    assert!(
        ok && help.contains("--sim") && help.contains("--serial"),
        "{help}"
    );

    let (ok, out, err) = stereotac(&["info", "--sim", "--json"]);
    assert!(ok, "{err}");
    let info: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(info["config"]["mode"], "off", "{out}");
    assert_eq!(info["config"]["strips"][0]["strip"], 1, "{out}");
    assert_eq!(info["config"]["strips"][0]["side"], "x−", "{out}");
    assert!(info["status"]["phases"].is_u64(), "{out}");
    assert!(
        !out.contains("Config {") && !out.contains("XMinus"),
        "{out}"
    );

    let (ok, out, err) = stereotac(&["--sim", "selftest", "--json"]);
    assert!(ok, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    let names: Vec<&str> = report["checks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["name"].as_str().unwrap())
        .collect();
    assert!(names.contains(&"set strip 4 (y+): colour #c80000, brightness 90 acknowledged"));
    assert!(
        names.iter().all(|n| !n.contains('{') && !n.contains("Set")),
        "{names:?}"
    );
}

#[test]
fn run_reconstructs_live_pairs_from_the_simulated_sensor_as_json_lines() {
    let args = [
        "--sim",
        "run",
        "--camera",
        "sim",
        "--period-ms",
        "100",
        "--duration-s",
        "2",
        "--jsonl",
    ];
    let (ok, out, err) = stereotac(&args);
    assert!(ok, "{err}");
    let records: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    // 2 s of 100 ms phases: about ten dx/dy pairs.
    assert!(records.len() >= 6, "{out}\n{err}");
    for (k, r) in records.iter().enumerate() {
        assert_eq!(r["sequence"], k as u64, "{r}");
        let [dx, dy] = [&r["exposure_end_us"][0], &r["exposure_end_us"][1]]
            .map(|v| v.as_f64().expect("exposure end"));
        assert!(dy > dx && (dy - dx - 100_000.0).abs() < 1_000.0, "{r}");
        let latency = r["latency_ms"].as_f64().unwrap();
        assert!((0.0..1_000.0).contains(&latency), "{r}");
        assert!(r["stage_ms"]["total_ms"].as_f64().unwrap() > 0.0, "{r}");
        assert!(r["frames_dropped"].is_u64(), "{r}");
    }
    // The simulated camera shows the built-in objects in turn, a second each: the first
    // is a sphere 1 mm deep.
    let first = &records[0];
    assert_eq!(first["contact"], true, "{first}");
    let depth = first["max_depth_mm"].as_f64().unwrap();
    assert!((0.9..1.1).contains(&depth), "{first}");
    assert!(first["centroid_mm"].is_array() && first["area_mm2"].as_f64().unwrap() > 1.0);
    assert!(err.contains("pairs reconstructed"), "{err}");

    let (ok, _, err) = stereotac(&["run", "--camera", "sim"]);
    assert!(!ok && err.contains("--model"), "{err}");
    let (ok, _, err) = stereotac(&["--sim", "run", "--mode", "vision"]);
    assert!(!ok && err.contains("--mode gradient"), "{err}");
}
