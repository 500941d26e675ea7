//! Shared by the CLI test files: run the `stereotac` binary, make a scratch directory.

use std::path::PathBuf;
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
