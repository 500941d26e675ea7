//! Shared by the CLI test files: run the `stereotac` binary, make a scratch directory.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs `stereotac ARGS`: (success, stdout, stderr).
pub fn stereotac(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_stereotac"))
        .args(args)
        .output()
        .expect("run stereotac");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A fresh, empty directory for one test (`name`) of this test process.
#[allow(dead_code)] // not every test file writes files
pub fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("stereotac-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}

/// Runs `stereotac stereo` on one pair of files with one calibration file, writing to
/// `out_dir`; `extra` adds flags.
#[allow(dead_code)] // used by the stereo test files only
pub fn stereo_from_files(
    calib: &Path,
    left: &Path,
    right: &Path,
    out_dir: &Path,
    extra: &[&str],
) -> (bool, String, String) {
    let path = |p: &Path| p.to_str().expect("UTF-8 path").to_string();
    let mut args = vec![
        "stereo".to_string(),
        "--calib".into(),
        path(calib),
        "--left".into(),
        path(left),
        "--right".into(),
        path(right),
        "--out-dir".into(),
        path(out_dir),
    ];
    args.extend(extra.iter().map(|s| s.to_string()));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    stereotac(&args)
}
