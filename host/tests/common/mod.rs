//! Shared by the CLI test files: run the `stereotac` binary.

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
