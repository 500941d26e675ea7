//! OpenCV's StereoBM and StereoSGBM as references, run by Python on the very images our
//! matchers see (`host/benches/opencv_stereobm.py`, written to a temporary folder and run
//! with `python3`, or the interpreter `STEREOTAC_PYTHON` names): `bench stereo --opencv`
//! times them against ours, `stereo-eval --compare` measures their depth as it measures
//! ours. Nothing here is needed to use the toolkit; when Python or OpenCV is missing the
//! error says so and the caller reports the reference as skipped.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::grid::Grid;
use crate::output::{read_npy, write_grey_png};

/// The script (run with Python).
const SCRIPT: &str = include_str!("../../benches/opencv_stereobm.py");

/// The environment variable that names the Python interpreter (default `python3`).
pub const PYTHON_VAR: &str = "STEREOTAC_PYTHON";

/// What to do when the references cannot run.
pub const SETUP_HINT: &str = "install OpenCV for Python (`pip install opencv-python-headless \
     numpy`), or name an interpreter that has it in STEREOTAC_PYTHON";

/// Which OpenCV matcher runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum OpenCvMatcher {
    /// StereoBM with our block matcher's settings (x-Sobel prefilter capped at 31,
    /// texture 10, uniqueness 15, left–right 1 px, speckles of 100 px within 1 px).
    Bm {
        /// Block side, px.
        block: u32,
    },
    /// StereoSGBM, 3-way (along the row both ways and straight down), P1 = 8·block²,
    /// P2 = 32·block², uniqueness 10, left–right 1 px, speckles as StereoBM's.
    Sgbm {
        /// Block side, px.
        block: u32,
    },
}

impl OpenCvMatcher {
    /// Name in tables, with the block size.
    pub fn label(self) -> String {
        match self {
            Self::Bm { block } => format!("OpenCV StereoBM {block}×{block}"),
            Self::Sgbm { block } => format!("OpenCV StereoSGBM 3-way {block}×{block}"),
        }
    }

    fn mode(self) -> (&'static str, u32) {
        match self {
            Self::Bm { block } => ("bm", block),
            Self::Sgbm { block } => ("sgbm", block),
        }
    }
}

/// What one run of the script gave.
#[derive(Debug, Clone)]
pub struct OpenCvRun {
    /// Median time of one `compute`, over every pair's timed repeats, ms.
    pub median_ms: f64,
    /// OpenCV's version.
    pub version: String,
    /// Each pair's disparity (px, NaN invalid), in the pairs' order.
    pub disparities: Vec<Grid<f32>>,
}

/// Runs `matcher` on every rectified grey pair of `pairs` (one thread, disparities
/// `min_disparity .. min_disparity + num_disparities`, a multiple of 16 as OpenCV
/// wants): each pair once untimed, then `repeats` times timed. The error is why it could
/// not run (no Python, no OpenCV, a script that failed, a reply it could not read).
pub fn run(
    pairs: &[(&Grid<u8>, &Grid<u8>)],
    min_disparity: u32,
    num_disparities: u32,
    matcher: OpenCvMatcher,
    repeats: usize,
) -> Result<OpenCvRun, String> {
    if pairs.is_empty() {
        return Err("no pairs to match".into());
    }
    if num_disparities == 0 || !num_disparities.is_multiple_of(16) {
        return Err(format!(
            "{num_disparities} disparities: OpenCV needs a positive multiple of 16"
        ));
    }
    let io = |path: &Path, e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let scratch = Scratch(std::env::temp_dir().join(format!(
        "stereotac-opencv-{}-{}",
        std::process::id(),
        RUNS.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
    )));
    let dir = scratch.0.as_path();
    std::fs::create_dir_all(dir).map_err(|e| io(dir, &e))?;
    let mut list = String::new();
    let mut outs: Vec<PathBuf> = Vec::with_capacity(pairs.len());
    for (i, (left, right)) in pairs.iter().enumerate() {
        let (l, r, d) = (
            dir.join(format!("left{i}.png")),
            dir.join(format!("right{i}.png")),
            dir.join(format!("disparity{i}.npy")),
        );
        write_grey_png(&l, left).map_err(|e| e.to_string())?;
        write_grey_png(&r, right).map_err(|e| e.to_string())?;
        list.push_str(&format!(
            "{}\t{}\t{}\n",
            l.display(),
            r.display(),
            d.display()
        ));
        outs.push(d);
    }
    let (pairs_file, script) = (dir.join("pairs.txt"), dir.join("opencv_stereobm.py"));
    std::fs::write(&pairs_file, list).map_err(|e| io(&pairs_file, &e))?;
    std::fs::write(&script, SCRIPT).map_err(|e| io(&script, &e))?;
    let python = std::env::var_os(PYTHON_VAR).unwrap_or_else(|| "python3".into());
    let (mode, block) = matcher.mode();
    let out = std::process::Command::new(&python)
        .arg(&script)
        .arg(&pairs_file)
        .args([
            num_disparities.to_string(),
            block.to_string(),
            min_disparity.to_string(),
            repeats.to_string(),
            mode.to_string(),
        ])
        .output()
        .map_err(|e| format!("running {}: {e}", python.to_string_lossy()))?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).trim().to_string());
    }
    let reply: serde_json::Value = serde_json::from_slice(&out.stdout).map_err(|e| {
        format!(
            "reading the script's reply {:?}: {e}",
            String::from_utf8_lossy(&out.stdout)
        )
    })?;
    let median_ms = reply["median_ms"]
        .as_f64()
        .ok_or("no median_ms in the script's reply")?;
    let version = reply["opencv"].as_str().unwrap_or("?").to_string();
    let mut disparities = Vec::with_capacity(outs.len());
    for (d, (left, _)) in outs.iter().zip(pairs) {
        let disparity = read_npy(d).map_err(|e| e.to_string())?;
        if (disparity.width(), disparity.height()) != (left.width(), left.height()) {
            return Err(format!(
                "{}: not a {}×{} array",
                d.display(),
                left.width(),
                left.height()
            ));
        }
        disparities.push(disparity);
    }
    Ok(OpenCvRun {
        median_ms,
        version,
        disparities,
    })
}

/// Distinguishes the temporary folders of runs in one process.
static RUNS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// A temporary folder, removed with what it holds when dropped (on every return).
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_requests_are_refused_before_python_runs() {
        let g = Grid::filled(32, 16, 0u8);
        let bm = OpenCvMatcher::Bm { block: 9 };
        assert!(run(&[], 0, 64, bm, 1).unwrap_err().contains("no pairs"));
        for n in [0, 40] {
            let e = run(&[(&g, &g)], 0, n, bm, 1).unwrap_err();
            assert!(e.contains("multiple of 16"), "{e}");
        }
        assert_eq!(bm.label(), "OpenCV StereoBM 9×9");
        assert_eq!(
            OpenCvMatcher::Sgbm { block: 5 }.label(),
            "OpenCV StereoSGBM 3-way 5×5"
        );
    }
}
