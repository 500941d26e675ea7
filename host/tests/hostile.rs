//! Hostile input, by category: files written by someone else, given to the CLI as a user
//! would. Each case must end in a clear error that names the file and the problem (or a
//! warning and a sane result), never a panic, an abort, a hang or an allocation beyond the
//! documented bounds (`stereotac::limits`).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::temp_dir;
use image::{DynamicImage, ImageBuffer, RgbImage};
use stereotac::stereo::synthetic::StereoRig;

/// Runs `stereotac ARGS` and asserts that it was refused cleanly: exit code 1 or 2 (not
/// a panic's 101 or an abort's 134), no panic message, and every one of `expect` in
/// stderr. Returns stderr.
fn refused(args: &[&str], expect: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_stereotac"))
        .args(args)
        .output()
        .expect("run stereotac");
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    let code = out.status.code();
    assert!(
        matches!(code, Some(1 | 2)) && !err.contains("panicked"),
        "{args:?}: exit {code:?}\n{err}"
    );
    for e in expect {
        assert!(err.contains(e), "{args:?}: {e:?} not in\n{err}");
    }
    err
}

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

/// A left/right pair of plain RGB frames and the sensor's calibration, in `dir`.
fn stereo_inputs(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let (calib, left, right) = (dir.join("c.yaml"), dir.join("l.png"), dir.join("r.png"));
    std::fs::write(&calib, StereoRig::sensor().calibration().to_opencv_yaml()).unwrap();
    let img = RgbImage::from_fn(640, 480, |x, y| image::Rgb([(x ^ y) as u8, 90, 40]));
    img.save(&left).unwrap();
    img.save(&right).unwrap();
    (calib, left, right)
}

fn stereo_args<'a>(
    calib: &'a Path,
    left: &'a Path,
    right: &'a Path,
    out: &'a Path,
) -> Vec<&'a str> {
    vec![
        "stereo",
        "--calib",
        s(calib),
        "--left",
        s(left),
        "--right",
        s(right),
        "--out-dir",
        s(out),
    ]
}

/// Calibration YAML: repeated keys, impossible sizes, overflowing matrix sizes, huge
/// and unterminated lists, bytes that are not text.
#[test]
fn calibration_files() {
    let dir = temp_dir("hostile-calib");
    let (calib, left, right) = stereo_inputs(&dir);
    let out = dir.join("out");
    let good = std::fs::read_to_string(&calib).unwrap();
    let bad = dir.join("bad.yaml");
    let args = stereo_args(&bad, &left, &right, &out);
    let t_lines: Vec<&str> = good
        .lines()
        .skip_while(|l| !l.starts_with("T:"))
        .take(5)
        .collect();
    let cases: Vec<(String, Vec<&str>)> = vec![
        (
            format!("{good}{}\n", t_lines.join("\n")),
            vec!["bad.yaml", "`T` is given twice"],
        ),
        (
            good.replace("image_width: 640", "image_width: 4294967295"),
            vec!["bad.yaml", "`image_width`", "8192"],
        ),
        (
            good.replacen("rows: 3", "rows: 18446744073709551615", 1),
            vec!["bad.yaml", "but 9 values"],
        ),
        (
            format!("K1: [{}\n", "1.5, ".repeat(700_000)),
            vec!["bad.yaml", "larger than"],
        ),
        (
            format!("K1: [{}\n", "1.5, ".repeat(200_000)),
            vec!["bad.yaml", "line"],
        ),
        (
            format!("{good}a: &x [1]\nb: *x\n"),
            vec!["bad.yaml", "aliases"],
        ),
    ];
    for (text, expect) in &cases {
        std::fs::write(&bad, text).unwrap();
        refused(&args, expect);
        assert!(!out.exists(), "a refused run leaves no output folder");
    }
    std::fs::write(&bad, [0xff, 0xfe, 0x00, 0x41]).unwrap();
    refused(&args, &["bad.yaml"]);
    // A key the format does not have is not refused (newer tools add keys) but said, so
    // a misspelt one is seen.
    std::fs::write(&bad, format!("{good}k1: [1]\n")).unwrap();
    let run = Command::new(env!("CARGO_BIN_EXE_stereotac"))
        .args(&args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{err}");
    assert!(
        err.contains("warning: ") && err.contains("bad.yaml: key `k1`") && err.contains("`K1`"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Image files: colour types and bit depths a command cannot use, and sizes no sensor
/// produces (refused from the header, before decoding).
#[test]
fn image_files() {
    let dir = temp_dir("hostile-images");
    let (calib, left, right) = stereo_inputs(&dir);
    let out = dir.join("out");
    // Stereo: 8-bit grey is fine; 16-bit is refused with the fix.
    let deep = dir.join("deep.png");
    DynamicImage::ImageRgb16(ImageBuffer::from_pixel(
        640,
        480,
        image::Rgb([9000u16, 0, 0]),
    ))
    .save(&deep)
    .unwrap();
    refused(
        &stereo_args(&calib, &deep, &right, &out),
        &["deep.png", "16-bit RGB", "8 bits"],
    );
    // A PNG header declaring 100000×100000 px (a few hundred bytes of file).
    let big = dir.join("big.png");
    let mut bytes = std::fs::read(&left).unwrap();
    bytes[16..24].copy_from_slice(&[0, 1, 0x86, 0xa0, 0, 1, 0x86, 0xa0]);
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&bytes[12..29]);
    bytes[29..33].copy_from_slice(&crc.to_be_bytes());
    std::fs::write(&big, &bytes).unwrap();
    refused(
        &stereo_args(&calib, &left, &big, &out),
        &["big.png", "100000×100000", "8192"],
    );
    // Tactile calibration: a grey or a 16-bit press is refused by name before any work.
    let presses = dir.join("presses");
    std::fs::create_dir_all(&presses).unwrap();
    let rgb = RgbImage::from_pixel(64, 48, image::Rgb([200, 40, 90]));
    rgb.save(presses.join("a_dx.png")).unwrap();
    DynamicImage::ImageRgb8(rgb.clone())
        .into_luma8()
        .save(presses.join("a_dy.png"))
        .unwrap();
    let model = dir.join("model.json");
    let calibrate = [
        "calibrate",
        s(&presses),
        "--ball-diameter-mm",
        "8",
        "--out",
        s(&model),
    ];
    refused(&calibrate, &["a_dy.png", "8-bit grey", "colour"]);
    DynamicImage::ImageRgb16(ImageBuffer::from_pixel(
        64,
        48,
        image::Rgb([60000u16, 0, 0]),
    ))
    .save(presses.join("a_dy.png"))
    .unwrap();
    refused(&calibrate, &["a_dy.png", "16-bit RGB"]);
    // Not an image at all.
    std::fs::write(presses.join("a_dy.png"), b"GIF89a, or so it says").unwrap();
    refused(&calibrate, &["a_dy.png"]);
    // Nothing in it.
    std::fs::write(presses.join("a_dy.png"), b"").unwrap();
    refused(&calibrate, &["a_dy.png", "empty file"]);
    // Its colours reduced to a palette: the decoder would expand it to RGB without a
    // word, and the shading read from 256 colours is wrong.
    let mut quantised = Vec::new();
    {
        use image::ImageEncoder;
        let indices: Vec<u8> = (0..64 * 48).map(|i| (i % 7) as u8).collect();
        let palette: Vec<u8> = (0..7u8).flat_map(|k| [200, 40 + k, 90]).collect();
        let png = image::codecs::png::PngEncoder::new(&mut quantised);
        // The `image` encoder writes no palettes: the indices as grey, then the header's
        // colour type and a palette chunk patched in by hand.
        png.write_image(&indices, 64, 48, image::ExtendedColorType::L8)
            .unwrap();
        let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
        quantised[25] = 3;
        let sum = crc.checksum(&quantised[12..29]);
        quantised[29..33].copy_from_slice(&sum.to_be_bytes());
        let mut plte = (palette.len() as u32).to_be_bytes().to_vec();
        plte.extend_from_slice(b"PLTE");
        plte.extend_from_slice(&palette);
        let sum = crc.checksum(&plte[4..]);
        plte.extend_from_slice(&sum.to_be_bytes());
        quantised.splice(33..33, plte);
    }
    std::fs::write(presses.join("a_dy.png"), &quantised).unwrap();
    refused(
        &calibrate,
        &["a_dy.png", "indexed (palette) PNG", "save it as RGB"],
    );
    // Readable frames, too few of them: the error names the folder (a script calibrating
    // many read "1 pair(s)" without knowing whose).
    rgb.save(presses.join("a_dy.png")).unwrap();
    let folder = format!("calibrating from {}", s(&presses));
    refused(&calibrate, &[&folder, "1 pair(s) and no reference frames"]);
    assert!(!model.exists(), "no model written from refused input");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Numbers on the command line outside what the sensor or the pipelines can mean.
#[test]
fn arguments() {
    refused(
        &["--sim", "stream", "--duration-s", "1e15"],
        &["--duration-s"],
    );
    // A goal table from too few presses to calibrate, or from no placements, measures
    // nothing: refused before any skin is drawn.
    refused(
        &["bench", "skins", "--presses", "1"],
        &["--presses 1", "give at least 5"],
    );
    refused(
        &["bench", "skins", "--placements", "0"],
        &["--placements must be at least 1"],
    );
    refused(
        &["--sim", "stream", "--duration-s", "NaN"],
        &["--duration-s"],
    );
    // An exposure that cannot fit in one LED phase: no frame could ever be labelled.
    for (flag, value) in [("--period-ms", "5"), ("--exposure-us", "1e30")] {
        refused(
            &[
                "--sim",
                "run",
                "--camera",
                "sim",
                "--duration-s",
                "1",
                flag,
                value,
            ],
            &["does not fit in one phase", "--exposure-us"],
        );
    }
    let dir = temp_dir("hostile-args");
    // A working range whose disparities reach past the image: refused with the nearest
    // depth that fits, rather than a run that matches nothing and blames the texture.
    let scaled = dir.join("scaled");
    refused(
        &[
            "stereo",
            "--synthetic",
            "150",
            "--scale",
            "10",
            "--out-dir",
            s(&scaled),
        ],
        &["px wide", "--near-mm to about"],
    );
    assert!(!scaled.exists(), "a refused run leaves no folder");
    // A negative number is read as the flag's value and refused by its own check (it
    // was "unexpected argument '-10'", which suggested writing `--near-mm=-10`).
    refused(
        &[
            "stereo",
            "--synthetic",
            "150",
            "--near-mm",
            "-10",
            "--out-dir",
            s(&scaled),
        ],
        &["--near-mm -10", "positive and finite"],
    );
    // Options whose values may start with '-' do not take the next flag as their value
    // without saying so.
    refused(
        &[
            "stereo",
            "--synthetic",
            "150",
            "--colour-range",
            "--mesh",
            "--out-dir",
            s(&scaled),
        ],
        &["--mesh", "another flag"],
    );
    refused(
        &["bench", "live", "--stage-s", "-1"],
        &["--stage-s must be"],
    );
    // A model or report is never written over a recording or an image, even with
    // --force (the input recording, given as --out by a slip, became a model file).
    let recording = dir.join("presses.mcap");
    let frame = dir.join("p_dx.png");
    std::fs::write(&recording, b"\x89MCAP0\r\nrecorded frames").unwrap();
    RgbImage::new(4, 4).save(&frame).unwrap();
    for (flag, target) in [("--out", &recording), ("--report", &frame)] {
        let mut args = vec!["calibrate", s(&dir), "--ball-diameter-mm", "8", "--force"];
        if flag == "--report" {
            args.extend(["--out", "unused-model.json"]);
        }
        args.extend([flag, s(target)]);
        refused(&args, &["never written over it, even with --force"]);
    }
    assert_eq!(
        std::fs::read(&recording).unwrap(),
        b"\x89MCAP0\r\nrecorded frames"
    );
    assert!(image::open(&frame).is_ok());
    // A sequence the sensor refuses leaves no recording behind (a header-only file was
    // left, and refused as existing on the next try).
    let refused_rec = dir.join("refused.mcap");
    refused(
        &[
            "--sim",
            "record",
            "--out",
            s(&refused_rec),
            "--period-ms",
            "4294967295",
        ],
        &["--period-ms 4294967295", "1 to 60000"],
    );
    assert!(!refused_rec.exists(), "a refused start left its recording");
    // Nor a PNG recording's folders (made two levels deep here), nor, in a folder that
    // was there, its empty index.
    let png_rec = dir.join("new").join("frames");
    let kept = dir.join("kept");
    std::fs::create_dir(&kept).unwrap();
    for out in [&png_rec, &kept] {
        refused(
            &[
                "--sim",
                "record",
                "--png",
                "--out",
                s(out),
                "--period-ms",
                "4294967295",
            ],
            &["--period-ms 4294967295", "1 to 60000"],
        );
    }
    assert!(
        !dir.join("new").exists(),
        "a refused start left its folders"
    );
    assert_eq!(std::fs::read_dir(&kept).unwrap().count(), 0, "left files");
    // `run` refuses a recording that exists before it calibrates a built-in model.
    refused(
        &[
            "--sim",
            "run",
            "--camera",
            "sim",
            "--duration-s",
            "1",
            "--mcap",
            s(&recording),
        ],
        &["exists already"],
    );
    // Refused before the (empty) directory is even read.
    for (flag, value, says) in [
        ("--px-per-mm", "1e9", "px/mm"),
        ("--px-per-mm", "1e-30", "above 0.5"),
        ("--ball-diameter-mm", "inf", "ball diameter"),
    ] {
        let model = dir.join("m.json");
        let mut args = vec!["calibrate", s(&dir), "--out", s(&model), flag, value];
        if flag != "--ball-diameter-mm" {
            args.extend(["--ball-diameter-mm", "8"]);
        }
        refused(&args, &[says]);
    }
    // A second ball's presses: DIAMETER_MM:PATH, refused at parsing when it is not.
    for (value, says) in [
        ("presses-4mm", "expected DIAMETER_MM:PATH"),
        ("four:presses-4mm", "not a ball diameter in mm"),
        ("0:presses-4mm", "ball diameter 0 mm"),
        ("-3:presses-4mm", "ball diameter -3 mm"),
        ("nan:presses-4mm", "ball diameter NaN mm"),
        ("4:", "no PATH after the diameter"),
    ] {
        let model = dir.join("m.json");
        let args = [
            "calibrate",
            s(&dir),
            "--out",
            s(&model),
            "--ball-diameter-mm",
            "8",
            "--with-ball",
            value,
        ];
        refused(&args, &["--with-ball", says]);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Output folders: files already there are never replaced without --force, and a run that
/// fails leaves no folder behind.
#[test]
fn output_folders() {
    let dir = temp_dir("hostile-out");
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("notes.txt"), b"the user's").unwrap();
    let args = ["stereo", "--synthetic", "150", "--out-dir", s(&out)];
    refused(&args, &["notes.txt", "--force"]);
    assert!(!out.join("summary.json").exists());
    // A file where the folder, or one of its parents, should be.
    let file = out.join("notes.txt");
    for place in [file.clone(), file.join("deeper")] {
        refused(
            &["stereo", "--synthetic", "150", "--out-dir", s(&place)],
            &["notes.txt is a file, not a folder"],
        );
    }
    let forced = Command::new(env!("CARGO_BIN_EXE_stereotac"))
        .args(args)
        .arg("--force")
        .output()
        .unwrap();
    assert!(forced.status.success());
    assert!(out.join("summary.json").exists());
    assert_eq!(std::fs::read(out.join("notes.txt")).unwrap(), b"the user's");
    // Forced into a folder holding a link named as an output, the run would write
    // through it, over the file it points to: refused, the file untouched.
    #[cfg(unix)]
    {
        let victim = dir.join("victim.png");
        std::fs::write(&victim, b"an input image").unwrap();
        std::fs::remove_file(out.join("depth16.png")).unwrap();
        std::os::unix::fs::symlink(&victim, out.join("depth16.png")).unwrap();
        let mut forced = args.to_vec();
        forced.push("--force");
        refused(&forced, &["depth16.png", "victim.png", "remove the link"]);
        assert_eq!(std::fs::read(&victim).unwrap(), b"an input image");
        std::fs::remove_file(out.join("depth16.png")).unwrap();
    }
    // A PNG recording never writes into a folder with files (no --force there).
    refused(
        &[
            "--sim",
            "record",
            "--png",
            "--camera",
            "sim",
            "--duration-s",
            "1",
            "--out",
            s(&out),
        ],
        &["exists and holds", "nothing is ever written over"],
    );
    // A calibration's report never replaces a file without --force, and never the model
    // it comes with (refused before the presses are read: the folder is empty).
    let (model, report) = (dir.join("model.json"), dir.join("report.json"));
    std::fs::write(&model, b"the user's model").unwrap();
    let calibrate = |out: &Path, report: &Path| {
        [
            "calibrate",
            s(&out_empty(&dir)),
            "--ball-diameter-mm",
            "8",
            "--out",
            s(out),
            "--report",
            s(report),
        ]
        .map(str::to_owned)
    };
    let args = calibrate(&dir.join("new.json"), &model);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    refused(&args, &["model.json exists", "--force", "--report"]);
    let args = calibrate(&report, &dir.join(".").join("report.json"));
    let mut args: Vec<&str> = args.iter().map(String::as_str).collect();
    args.push("--force");
    refused(&args, &["the model file --out names"]);
    assert_eq!(std::fs::read(&model).unwrap(), b"the user's model");
    // Two outputs of stereo-convert naming one file: refused, nothing written.
    let (calib, _, _) = stereo_inputs(&dir);
    let ros = dir.join("ros.yaml");
    refused(
        &[
            "stereo-convert",
            "--calib",
            s(&calib),
            "--ros-left",
            s(&ros),
            "--ros-right",
            s(&dir.join(".").join("ros.yaml")),
        ],
        &["ros.yaml", "name one file"],
    );
    assert!(!ros.exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// An empty folder in `dir` (made once).
fn out_empty(dir: &Path) -> PathBuf {
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    empty
}

/// Model files: not JSON, not a model, another version, bytes that are not text. (Damaged
/// fields of a real model are refused by name in tests/tactile.rs.)
#[test]
fn model_files() {
    let dir = temp_dir("hostile-model");
    let (_, left, _) = stereo_inputs(&dir);
    let model = dir.join("model.json");
    let out = dir.join("out");
    let args = [
        "reconstruct",
        "--model",
        s(&model),
        "--dx",
        s(&left),
        "--dy",
        s(&left),
        "--out-dir",
        s(&out),
    ];
    for (text, expect) in [
        (&b""[..], "model.json"),
        (b"{ not json", "not a stereotac model file"),
        (b"[1, 2, 3]", "not a stereotac model file"),
        (
            br#"{"format": "stereotac-tactile-model", "version": 99}"#,
            "version",
        ),
        (&[0xff, 0xfe, 0xfd][..], "model.json"),
    ] {
        std::fs::write(&model, text).unwrap();
        refused(&args, &[expect]);
        assert!(!out.exists(), "a refused run leaves no output folder");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
