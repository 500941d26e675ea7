//! The live path end to end: `run` with two simulated cameras records an MCAP file that
//! the `mcap` crate reads back, and `process` reproduces its depth maps bit for bit,
//! also from a file cut short as a killed writer leaves it.

mod common;

use std::collections::BTreeMap;
use std::path::Path;

use common::{stereotac, temp_dir};
use foxglove::Decode;

/// Every message of `path` by topic: (log time, bytes), with the channel's schema name.
type Messages = BTreeMap<String, (String, Vec<(u64, Vec<u8>)>)>;

fn read_messages(path: &Path) -> Messages {
    let bytes = std::fs::read(path).unwrap();
    let mut out = Messages::new();
    for m in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
        let m = m.expect("a readable message");
        let schema = m
            .channel
            .schema
            .as_ref()
            .map_or("", |s| &s.name)
            .to_string();
        out.entry(m.channel.topic.clone())
            .or_insert((schema, Vec::new()))
            .1
            .push((m.log_time, m.data.into_owned()));
    }
    out
}

fn path(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

#[test]
fn run_records_two_cameras_and_process_reproduces_every_depth_map_bit_for_bit() {
    let dir = temp_dir("live-run");
    let rec = dir.join("out.mcap");
    let (ok, out, err) = stereotac(&[
        "--sim",
        "run",
        "--camera",
        "sim",
        "--camera",
        "sim",
        "--size",
        "320x240",
        "--mode",
        "interleaved",
        "--period-ms",
        "100",
        "--duration-s",
        "2",
        "--mcap",
        path(&rec),
        "--jsonl",
    ]);
    assert!(ok, "{err}");
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert!(lines.len() >= 4, "{out}\n{err}");
    assert!(lines.iter().all(|l| l["latency_ms"].is_f64()), "{out}");

    // What the reference reader finds: every documented topic, Foxglove's schemas.
    let live = read_messages(&rec);
    for (topic, schema) in [
        ("/stereotac/cam0/image", "foxglove.RawImage"),
        ("/stereotac/cam1/image", "foxglove.RawImage"),
        ("/stereotac/cam0/frame", "stereotac.FrameInfo"),
        ("/stereotac/leds/phase", "stereotac.PhaseInfo"),
        ("/stereotac/tactile/depth", "foxglove.RawImage"),
        ("/stereotac/tactile/contact", "stereotac.TactileRecord"),
        ("/stereotac/stereo/depth", "foxglove.RawImage"),
        ("/stereotac/stereo/points", "foxglove.PointCloud"),
    ] {
        let (s, msgs) = live
            .get(topic)
            .unwrap_or_else(|| panic!("{topic} missing: {:?}", live.keys()));
        assert_eq!(s, schema, "{topic}");
        assert!(!msgs.is_empty(), "{topic}");
    }
    assert_eq!(live["/stereotac/tactile/contact"].1.len(), lines.len());
    let depth =
        foxglove::messages::RawImage::decode(&live["/stereotac/stereo/depth"].1[0].1[..]).unwrap();
    assert_eq!(
        (depth.width, depth.height, depth.encoding.as_str()),
        (320, 240, "32FC1")
    );
    // The simulated board is 150 mm away at the centre (metres in the file).
    let centre = 4 * (120 * 320 + 160);
    let z = f32::from_le_bytes(depth.data[centre..centre + 4].try_into().unwrap());
    assert!(
        (0.14..0.16).contains(&z),
        "stereo depth at the centre {z} m"
    );
    let bytes = std::fs::read(&rec).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let mut names: Vec<String> = summary
        .metadata_indexes
        .iter()
        .map(|m| m.name.clone())
        .collect();
    names.sort();
    assert!(names.contains(&"sensor".to_string()), "{names:?}");
    for index in &summary.metadata_indexes {
        if index.name == "sensor" {
            let m = mcap::read::metadata(&bytes, index).unwrap();
            assert_eq!(m.metadata["serial"].len(), 16, "{:?}", m.metadata);
        }
    }
    let attachments: Vec<&str> = summary
        .attachment_indexes
        .iter()
        .map(|a| a.name.as_str())
        .collect();
    assert!(
        attachments.contains(&"tactile_model.json"),
        "{attachments:?}"
    );
    assert!(
        attachments.contains(&"stereo_calibration.yaml"),
        "{attachments:?}"
    );

    // Offline: the same depth, bit for bit, from the model and calibration inside.
    let processed = dir.join("processed.mcap");
    let (ok, out2, err) =
        stereotac(&["process", path(&rec), "--mcap", path(&processed), "--jsonl"]);
    assert!(ok, "{err}");
    assert_eq!(out2.lines().count(), lines.len(), "{out2}");
    let offline = read_messages(&processed);
    for topic in [
        "/stereotac/tactile/depth",
        "/stereotac/stereo/depth",
        "/stereotac/stereo/points",
        "/stereotac/cam0/image",
    ] {
        assert!(
            live[topic].1 == offline[topic].1,
            "{topic}: processed differs from live"
        );
    }
    // A recording is never overwritten.
    let (ok, _, err) = stereotac(&["process", path(&rec), "--mcap", path(&processed)]);
    assert!(!ok && err.contains("exists already"), "{err}");

    // Cut as a killed writer leaves it: what is complete is processed, with a warning.
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let (ok, out3, err) = stereotac(&["process", path(&cut), "--jsonl"]);
    assert!(ok, "{err}");
    assert!(err.contains("ends inside a record"), "{err}");
    let n = out3.lines().count();
    assert!(
        n >= 1 && n < lines.len(),
        "{n} of {} pairs from 2/3 of the file",
        lines.len()
    );
    for (a, b) in out3.lines().zip(&lines) {
        let a: serde_json::Value = serde_json::from_str(a).unwrap();
        assert_eq!(a["max_depth_mm"], b["max_depth_mm"]);
        assert!(a["latency_ms"].is_null(), "offline: no latency");
    }

    // A damaged chunk in the middle: skipped with a warning, and every pair after it is
    // processed as in the live run (same LED phase, same depth).
    let damaged = dir.join("damaged.mcap");
    let mut flipped = bytes.clone();
    flipped[bytes.len() / 2] ^= 0x10;
    std::fs::write(&damaged, &flipped).unwrap();
    let (ok, out4, err) = stereotac(&["process", path(&damaged), "--jsonl"]);
    assert!(ok, "{err}");
    assert!(err.contains("1 damaged chunk skipped"), "{err}");
    let by_phase = |text: &str| -> Vec<(u64, serde_json::Value)> {
        text.lines()
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(l).unwrap();
                (v["phase"].as_u64().unwrap(), v["max_depth_mm"].clone())
            })
            .collect()
    };
    let (live_pairs, read_pairs) = (by_phase(&out), by_phase(&out4));
    assert!(
        read_pairs.len() <= live_pairs.len() && read_pairs.len() + 3 >= live_pairs.len(),
        "{} of {} pairs",
        read_pairs.len(),
        live_pairs.len()
    );
    assert!(read_pairs.iter().all(|p| live_pairs.contains(p)), "{out4}");
    assert_eq!(read_pairs.last(), live_pairs.last(), "read past the damage");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--no-past-reach`: live, every pair reads with the lookup table alone (none counted
/// past its reach, where the default run counts them on the steep scene), the recording
/// keeps the setting, and `process` does as the run did.
#[test]
fn no_past_reach_is_kept_by_the_recording_and_process_does_as_the_run_did() {
    let dir = temp_dir("live-past-reach");
    let reached = |text: &str| -> Vec<u64> {
        text.lines()
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(l).unwrap();
                v["past_reach_pixels"].as_u64().unwrap()
            })
            .collect()
    };
    let run = |extra: &[&str]| {
        let mut args = vec![
            "--sim",
            "run",
            "--camera",
            "sim",
            "--mode",
            "gradient",
            "--duration-s",
            "3",
            "--jsonl",
        ];
        args.extend_from_slice(extra);
        let (ok, text, err) = stereotac(&args);
        assert!(ok, "{err}");
        // Each record says how much of its slopes the depth leaves unexplained: the
        // simulated sensor's pairs are one surface each, and nothing is warned.
        for l in text.lines() {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            let share = v["unexplained_share"].as_f64().unwrap();
            assert!((0.0..0.15).contains(&share), "{l}");
            assert_eq!(v["no_skin_at_rest"], false, "{l}");
        }
        assert!(
            !err.contains("one surface") && !err.contains("no zero"),
            "{err}"
        );
        text
    };
    // The simulated scenes include a wall steeper than the built-in ball's slopes.
    let default = reached(&run(&[]));
    assert!(default.iter().any(|&n| n > 0), "{default:?}");
    let rec = dir.join("alone.mcap");
    let alone = reached(&run(&["--no-past-reach", "--mcap", path(&rec)]));
    assert!(
        !alone.is_empty() && alone.iter().all(|&n| n == 0),
        "{alone:?}"
    );
    let bytes = std::fs::read(&rec).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let settings = summary
        .metadata_indexes
        .iter()
        .find(|m| m.name == "tactile_settings")
        .expect("tactile settings recorded");
    let m = mcap::read::metadata(&bytes, settings).unwrap();
    assert_eq!(m.metadata["past_reach"], "false", "{:?}", m.metadata);
    let (ok, text, err) = stereotac(&["process", path(&rec), "--jsonl"]);
    assert!(ok, "{err}");
    assert_eq!(reached(&text), alone);
    // Turned back on for that recording: the reading is made again.
    let (ok, text, err) = stereotac(&["process", path(&rec), "--jsonl", "--past-reach"]);
    assert!(ok, "{err}");
    let again = reached(&text);
    assert!(
        again.len() == alone.len() && again.iter().any(|&n| n > 0),
        "{again:?}"
    );
    let (ok, _, err) = stereotac(&["process", path(&rec), "--past-reach", "--no-past-reach"]);
    assert!(!ok && err.contains("--no-past-reach"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn process_refuses_what_is_not_a_recording_naming_the_file() {
    let dir = temp_dir("live-bad");
    let not_mcap = dir.join("frames.mcap");
    std::fs::write(&not_mcap, b"this is not an MCAP file at all").unwrap();
    let (ok, _, err) = stereotac(&["process", path(&not_mcap)]);
    assert!(
        !ok && err.contains("frames.mcap") && err.contains("MCAP"),
        "{err}"
    );
    let (ok, _, err) = stereotac(&["process", path(&dir.join("missing.mcap"))]);
    assert!(!ok && err.contains("missing.mcap"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `stereotac --sim record --camera sim OPTIONS --out OUT` (the simulated sensor and
/// camera 0; `options` add cameras, size, mode, duration), asserted to succeed.
fn record_sim(out: &Path, options: &[&str]) {
    let mut args = vec!["--sim", "record", "--camera", "sim"];
    args.extend_from_slice(options);
    args.extend_from_slice(&["--out", path(out)]);
    let (ok, _, err) = stereotac(&args);
    assert!(ok, "{err}");
}

#[test]
fn export_writes_a_recordings_pairs_as_files_and_calibrate_reads_a_recording() {
    let dir = temp_dir("live-export");
    let rec = dir.join("rec.mcap");
    record_sim(
        &rec,
        &[
            "--camera",
            "sim",
            "--size",
            "320x240",
            "--mode",
            "interleaved",
            "--period-ms",
            "100",
            "--duration-s",
            "1.5",
        ],
    );
    let pairs = dir.join("pairs");
    let (ok, out, err) = stereotac(&["export", path(&rec), "--pairs", path(&pairs)]);
    assert!(ok, "{err}");
    // A recording without a calibration or model: said, the pairs written all the same.
    assert!(
        err.contains("holds no stereo calibration") && err.contains("holds no tactile model"),
        "{err}"
    );
    let names: Vec<String> = std::fs::read_dir(&pairs)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    let count = |suffix: &str| names.iter().filter(|n| n.ends_with(suffix)).count();
    assert!(count("_dx.png") >= 2, "{names:?}");
    assert_eq!(count("_dx.png"), count("_dy.png"));
    assert!(count("_left.png") >= 2 && count("_left.png") == count("_right.png"));
    assert!(
        out.contains(&format!("wrote {} dx/dy pairs", count("_dx.png"))),
        "{out}"
    );
    // The exported pair is the recorded frame, pixel for pixel.
    let dx = image::open(pairs.join(names.iter().find(|n| n.ends_with("_dx.png")).unwrap()))
        .unwrap()
        .to_rgb8();
    assert_eq!(dx.dimensions(), (320, 240));
    // A folder with files in it is refused before anything is written; with --force
    // it is written into, but no file is ever replaced.
    let (ok, _, err) = stereotac(&["export", path(&rec), "--pairs", path(&pairs)]);
    assert!(!ok && err.contains("--force"), "{err}");
    let (ok, _, err) = stereotac(&["export", path(&rec), "--pairs", path(&pairs), "--force"]);
    assert!(!ok && err.contains("never overwritten"), "{err}");
    // Forced into a folder holding only the last pair's dx file, the export writes the
    // pairs before it, stops there, and takes back what it wrote: half an export beside
    // another file would be read as one set with it.
    let last = names
        .iter()
        .filter(|n| n.ends_with("_dx.png"))
        .max()
        .unwrap();
    for n in names.iter().filter(|n| *n != last) {
        std::fs::remove_file(pairs.join(n)).unwrap();
    }
    let (ok, _, err) = stereotac(&["export", path(&rec), "--pairs", path(&pairs), "--force"]);
    assert!(!ok && err.contains(last.as_str()), "{err}");
    let left: Vec<_> = std::fs::read_dir(&pairs).unwrap().collect();
    assert_eq!(left.len(), 1, "{left:?}");

    // calibrate takes the recording itself (its objects are not ball presses: the
    // error names the pair, by phase).
    let (ok, _, err) = stereotac(&[
        "calibrate",
        path(&rec),
        "--ball-diameter-mm",
        "6",
        "--out",
        path(&dir.join("model.json")),
    ]);
    assert!(!ok && err.contains("phase0"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_demo_recordings_calibrate_and_process_end_to_end() {
    let dir = temp_dir("live-demo");
    let out = dir.join("demo-out");
    let (ok, text, err) = stereotac(&["demo", "--no-tactile", "--no-stereo", "--out", path(&out)]);
    assert!(ok, "{err}");
    assert!(
        text.contains("presses.mcap") && text.contains("demo.mcap"),
        "{text}"
    );
    // Into a folder that does not exist yet: made once the calibration succeeded. A
    // file where a folder should be is said before the work.
    let blocked = dir.join("a-file");
    std::fs::write(&blocked, b"x").unwrap();
    let (ok, _, err) = stereotac(&[
        "calibrate",
        path(&out.join("presses.mcap")),
        "--ball-diameter-mm",
        "6",
        "--out",
        path(&blocked.join("model.json")),
    ]);
    assert!(!ok && err.contains("is a file, not a folder"), "{err}");
    let model = dir.join("models").join("model.json");
    let (ok, text, err) = stereotac(&[
        "calibrate",
        path(&out.join("presses.mcap")),
        "--ball-diameter-mm",
        "6",
        "--out",
        path(&model),
    ]);
    assert!(ok && model.is_file(), "{err}");
    // The presses as a folder of pairs, one of them damaged: set aside with the reason
    // (printed and in the report), the others calibrate.
    let folder = dir.join("press-pairs");
    let (ok, _, err) = stereotac(&[
        "export",
        path(&out.join("presses.mcap")),
        "--pairs",
        path(&folder),
    ]);
    assert!(ok, "{err}");
    // Presses for a calibration hold no model (said) and no stereo pairs (no calibration
    // written, nor asked for).
    assert!(err.contains("holds no tactile model"), "{err}");
    assert!(
        !folder.join("stereo_calibration.yaml").exists() && !err.contains("stereo calibration"),
        "{err}"
    );
    std::fs::write(folder.join("broken_dx.png"), b"\x89PNG\r\n\x1a\n cut").unwrap();
    std::fs::copy(folder.join("broken_dx.png"), folder.join("broken_dy.png")).unwrap();
    let report = dir.join("report.json");
    let (ok, folder_text, err) = stereotac(&[
        "calibrate",
        path(&folder),
        "--ball-diameter-mm",
        "6",
        "--out",
        path(&dir.join("from-folder.json")),
        "--report",
        path(&report),
    ]);
    assert!(ok, "{err}");
    assert!(
        folder_text.contains("broken") && folder_text.contains("cannot be read"),
        "{folder_text}"
    );
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(r["unreadable"][0]["name"], "broken", "{}", r["unreadable"]);
    // An override naming no press is a slip, said before the work; a press's circle
    // given twice, or far outside the frame, is refused by its name (read as given, the
    // last one or the faraway circle was used without a word).
    let overrides = dir.join("overrides.json");
    let mut names: Vec<String> = std::fs::read_dir(&folder)
        .unwrap()
        .filter_map(|e| {
            let n = e.unwrap().file_name().to_string_lossy().into_owned();
            n.strip_suffix("_dx.png").map(str::to_owned)
        })
        .filter(|n| n.starts_with("phase"))
        .collect();
    names.sort();
    let name = &names[0];
    for (given, expect) in [
        (
            r#"{"phase9999": {"cx": 10, "cy": 10, "r": 5}}"#.to_string(),
            "no press is named \"phase9999\"".to_string(),
        ),
        (
            format!(
                r#"{{"{name}": {{"cx": 1, "cy": 2, "r": 30}}, "{name}": {{"cx": 4, "cy": 5, "r": 30}}}}"#
            ),
            "given twice".to_string(),
        ),
        (
            format!(r#"{{"{name}": {{"cx": 1e9, "cy": 25, "r": 38}}}}"#),
            format!(
                "the circle given for {name} (cx 1000000000, cy 25, r 38 px) lies outside the frame"
            ),
        ),
    ] {
        std::fs::write(&overrides, given).unwrap();
        let (ok, _, err) = stereotac(&[
            "calibrate",
            path(&folder),
            "--ball-diameter-mm",
            "6",
            "--out",
            path(&dir.join("unused.json")),
            "--overrides",
            path(&overrides),
        ]);
        assert!(!ok && err.contains(&expect), "{expect}: {err}");
    }
    assert!(
        text.contains("16 presses") || text.matches("phase0").count() == 16,
        "{text}"
    );
    // Again into the same file: refused before any work; --force replaces it.
    let presses = out.join("presses.mcap");
    let again = |force: bool| {
        let mut args = vec![
            "calibrate",
            path(&presses),
            "--ball-diameter-mm",
            "6",
            "--out",
            path(&model),
        ];
        if force {
            args.push("--force");
        }
        stereotac(&args)
    };
    let (ok, _, err) = again(false);
    assert!(
        !ok && err.contains("exists") && err.contains("--force"),
        "{err}"
    );
    let (ok, _, err) = again(true);
    assert!(ok, "{err}");
    let demo = out.join("demo.mcap");
    // Its stereo pairs come with the calibration they were taken with, which `stereo`
    // reads as it is.
    let demo_pairs = dir.join("demo-pairs");
    let (ok, text, err) = stereotac(&["export", path(&demo), "--pairs", path(&demo_pairs)]);
    assert!(
        ok && text.contains("with stereo_calibration.yaml"),
        "{text}{err}"
    );
    let (ok, _, err) = stereotac(&[
        "stereo",
        "--calib",
        path(&demo_pairs.join("stereo_calibration.yaml")),
        "--left",
        path(&demo_pairs.join("phase000000_left.png")),
        "--right",
        path(&demo_pairs.join("phase000000_right.png")),
        "--out-dir",
        path(&dir.join("demo-stereo")),
    ]);
    assert!(ok, "{err}");
    let process_demo =
        |model: &Path| stereotac(&["process", path(&demo), "--model", path(model), "--jsonl"]);
    let (ok, text, err) = process_demo(&model);
    assert!(ok, "{err}");
    let records: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    // The skin at rest first, then the six objects, each pressed about 1 mm in.
    assert_eq!(records[0]["contact"], false, "{text}");
    let pressed: Vec<f64> = records[1..7]
        .iter()
        .map(|r| r["max_depth_mm"].as_f64().unwrap())
        .collect();
    assert!(
        pressed.iter().all(|d| (0.6..1.4).contains(d)),
        "max depths {pressed:?}"
    );
    // The dark frames of both cameras gave stereo depth of the board (the calibration
    // is in the recording).
    assert!(
        err.contains("stereo: 8 frame pairs") || err.contains("stereo: 7 frame pairs"),
        "{err}"
    );

    // A skin said to be 0.5 mm thick: presses about 1 mm deep cannot be right. Calibrate
    // sets each aside with that reason; `process` with such a model refuses those pairs
    // with a warning each, keeps the rest, and counts them.
    let (ok, _, err) = stereotac(&[
        "calibrate",
        path(&presses),
        "--ball-diameter-mm",
        "6",
        "--skin-thickness-mm",
        "0.5",
        "--out",
        path(&dir.join("thin.json")),
    ]);
    assert!(!ok && err.contains("deeper than the 0.5 mm skin"), "{err}");
    assert!(!dir.join("thin.json").exists());
    let mut thin: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&model).unwrap()).unwrap();
    thin["skin_thickness_mm"] = 0.5.into();
    let thin_model = dir.join("thin-edited.json");
    std::fs::write(&thin_model, serde_json::to_vec(&thin).unwrap()).unwrap();
    let (ok, text, err) = process_demo(&thin_model);
    assert!(ok, "{err}");
    let kept: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let refused = err.matches("tactile pair refused: depth").count();
    assert_eq!(kept.len() + refused, records.len(), "{err}");
    assert!(refused >= 6, "{err}");
    assert!(
        err.contains(&format!("with contact, {refused} refused")) && err.contains("0.5 mm"),
        "{err}"
    );
    assert!(
        kept.iter()
            .all(|r| r["max_depth_mm"].as_f64().unwrap() <= 0.5),
        "{text}"
    );
    // Live, the same: each such pair is a warning, and the run goes on to its end.
    let (ok, text, err) = stereotac(&[
        "--sim",
        "run",
        "--camera",
        "sim",
        "--model",
        path(&thin_model),
        "--duration-s",
        "3",
        "--jsonl",
    ]);
    assert!(ok, "{err}");
    let refused = err.matches("tactile pair refused: depth").count();
    assert!(refused > 0, "{err}");
    assert!(
        err.contains(&format!("with contact, {refused} refused")),
        "{err}"
    );
    for line in text.lines() {
        let r: serde_json::Value = serde_json::from_str(line).unwrap();
        assert!(r["max_depth_mm"].as_f64().unwrap() <= 0.5, "{line}");
    }

    // A model calibrated with LEDs-off frames (an ambient estimate, here none at all)
    // where the mode takes no dark frames: refused at start, unless --static-ambient.
    let mut dark: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&model).unwrap()).unwrap();
    let (w, h) = (
        dark["width"].as_u64().unwrap(),
        dark["height"].as_u64().unwrap(),
    );
    let (bw, bh) = (w.div_ceil(16), h.div_ceil(16));
    dark["ambient"] = serde_json::json!({
        "step": 16,
        "width": bw,
        "height": bh,
        "means": vec![[0.0f32; 3]; (bw * bh) as usize],
    });
    let dark_model = dir.join("dark.json");
    std::fs::write(&dark_model, serde_json::to_vec(&dark).unwrap()).unwrap();
    let gradient_run = |extra: &[&str]| {
        let mut args = vec![
            "--sim",
            "run",
            "--camera",
            "sim",
            "--mode",
            "gradient",
            "--model",
            path(&dark_model),
            "--duration-s",
            "1.5",
            "--jsonl",
        ];
        args.extend_from_slice(extra);
        stereotac(&args)
    };
    let (ok, _, err) = gradient_run(&[]);
    assert!(
        !ok && err.contains("LEDs-off frames") && err.contains("--static-ambient"),
        "{err}"
    );
    let accepted = dir.join("static.mcap");
    let (ok, text, err) = gradient_run(&["--static-ambient", "--mcap", path(&accepted)]);
    assert!(ok, "{err}");
    assert!(
        !text.is_empty()
            && text
                .lines()
                .all(|l| l.contains(r#""ambient":"calibration""#)),
        "{text}"
    );
    // `process` does as the run did: the recording keeps the acceptance.
    let (ok, text, err) = stereotac(&["process", path(&accepted), "--jsonl"]);
    assert!(ok, "{err}");
    assert!(!text.is_empty(), "{err}");
    // A gradient recording processed with such a model: refused, unless accepted.
    let gradient = dir.join("gradient.mcap");
    record_sim(&gradient, &["--mode", "gradient", "--duration-s", "1"]);
    let process_gradient = |extra: &[&str]| {
        let mut args = vec!["process", path(&gradient), "--model", path(&dark_model)];
        args.extend_from_slice(extra);
        stereotac(&args)
    };
    let (ok, _, err) = process_gradient(&[]);
    assert!(
        !ok && err.contains("gradient mode takes none") && err.contains("--static-ambient"),
        "{err}"
    );
    let (ok, _, err) = process_gradient(&["--static-ambient"]);
    assert!(ok, "{err}");
    // The demo's LEDs-off frames show the scene behind the skin, brighter than the lit
    // frames: not an ambient light to remove. Said once, then counted at the end.
    let (ok, text, err) = process_demo(&dark_model);
    assert!(ok, "{err}");
    let refused = text.matches("calibration-dark-refused").count();
    assert!(refused > 0, "{text}");
    assert_eq!(
        err.matches("cannot be their ambient light").count(),
        1,
        "{err}"
    );
    assert!(
        err.contains(&format!("{refused} pairs' LEDs-off frames were brighter"))
            || (refused == 1 && err.contains("1 pair's LEDs-off frames")),
        "{err}"
    );
    // A model of another frame size: refused at start, with the fix for each command
    // (live: the camera's size can change; a recording's cannot).
    let (ok, _, err) = stereotac(&[
        "--sim",
        "run",
        "--camera",
        "sim",
        "--size",
        "320x240",
        "--model",
        path(&model),
        "--duration-s",
        "1",
    ]);
    assert!(
        !ok && err.contains("calibrated at 640×480") && err.contains("(--size)"),
        "{err}"
    );
    let small = dir.join("small.mcap");
    record_sim(&small, &["--size", "320x240", "--duration-s", "1"]);
    let (ok, _, err) = stereotac(&["process", path(&small), "--model", path(&model)]);
    assert!(
        !ok && err.contains("calibrated at 640×480")
            && err.contains("at the recording's frame size (--model FILE)")
            && !err.contains("--size"),
        "{err}"
    );
    // Without a model, the dx/dy pairs are named as skipped, not silently dropped.
    let (ok, _, err) = stereotac(&["process", path(&out.join("demo.mcap"))]);
    assert!(ok, "{err}");
    assert!(
        err.contains("dx/dy pairs not reconstructed: no tactile model"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Stereo results that warn (here a working range the scene is not in) are said on
/// stderr once and counted in the closing figures, as `stereo` says them; a recording
/// with one camera says that no stereo pair was made.
#[test]
fn live_stereo_warnings_are_said_and_counted() {
    let (ok, _, err) = stereotac(&[
        "--sim",
        "run",
        "--camera",
        "sim",
        "--camera",
        "sim",
        "--size",
        "320x240",
        "--mode",
        "vision",
        "--period-ms",
        "100",
        "--duration-s",
        "1",
        "--near-mm",
        "900",
        "--far-mm",
        "1000",
    ]);
    assert!(ok, "{err}");
    assert_eq!(err.matches("warning: stereo frame").count(), 1, "{err}");
    let counted = err
        .lines()
        .find_map(|l| l.strip_prefix("stereo: "))
        .and_then(|l| {
            let (pairs, rest) = l.split_once(" frame pairs, ")?;
            let warned = rest.split_once(" with warnings")?.0;
            Some((pairs.parse::<u64>().ok()?, warned.parse::<u64>().ok()?))
        });
    assert!(
        matches!(counted, Some((pairs, warned)) if pairs > 0 && warned == pairs),
        "{err}"
    );
    let dir = temp_dir("live-one-camera");
    let one = dir.join("one.mcap");
    record_sim(&one, &["--mode", "vision", "--duration-s", "1"]);
    let calib = dir.join("rig.yaml");
    std::fs::write(
        &calib,
        stereotac::stereo::synthetic::StereoRig::sensor()
            .calibration()
            .to_opencv_yaml(),
    )
    .unwrap();
    let (_, _, err) = stereotac(&["process", path(&one), "--calib", path(&calib)]);
    assert!(err.contains("no stereo frame pair was made"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sigterm_and_sighup_finish_the_recording_with_its_summary_and_index() {
    for signal in ["TERM", "HUP"] {
        let dir = temp_dir(&format!("live-sig{signal}"));
        let rec = dir.join("out.mcap");
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_stereotac"))
            .args([
                "--sim",
                "run",
                "--camera",
                "sim",
                "--size",
                "320x240",
                "--period-ms",
                "100",
                "--mcap",
                path(&rec),
                "--jsonl",
            ])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // Wait for the first JSON line: the run is under way.
        let mut stdout = std::io::BufReader::new(child.stdout.take().unwrap());
        let mut first = String::new();
        std::io::BufRead::read_line(&mut stdout, &mut first).unwrap();
        assert!(first.starts_with('{'), "{first}");
        let killed = std::process::Command::new("kill")
            .args([format!("-{signal}"), child.id().to_string()])
            .status()
            .unwrap();
        assert!(killed.success());
        let mut rest = String::new();
        std::io::Read::read_to_string(&mut stdout, &mut rest).unwrap();
        let status = child.wait().unwrap();
        assert!(
            status.success(),
            "SIG{signal}: a clean stop, exit {status:?}"
        );
        // The file is finished: the summary section is there and every pair printed is in it.
        let bytes = std::fs::read(&rec).unwrap();
        let summary = mcap::Summary::read(&bytes)
            .unwrap()
            .expect("a summary section");
        let printed = 1 + rest.lines().count();
        let contact = summary
            .channels
            .values()
            .find(|c| c.topic == "/stereotac/tactile/contact")
            .expect("the contact channel")
            .id;
        let stats = summary.stats.expect("statistics");
        assert_eq!(
            stats.channel_message_counts.get(&contact).copied(),
            Some(printed as u64),
            "SIG{signal}: every printed pair recorded"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
