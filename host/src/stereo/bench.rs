//! The stereo benchmark (`stereotac bench stereo`): remap against a plain copy, block
//! matching per kernel, the whole vision frame on 1 and 2 threads, and, when asked,
//! OpenCV's StereoBM on the same images in the same run, with matching quality against
//! the true disparity of the scene.

use serde::Serialize;

use super::block_match::{BlockMatchParams, BlockMatcher, Kernel, MatchError};
use super::opencv::{self, OpenCvMatcher};
use super::pipeline::{StereoConfig, StereoError, StereoPipeline};
use super::rectify::{Rectification, RectifyError};
use super::sgm::{Paths, SemiGlobalMatcher, SgmParams};
use super::synthetic::{Membrane, Plane, StereoRig, fisheye_calibration, render_pair};
use crate::grid::Grid;
use crate::timing::median_ms;

/// Why the benchmark could not run.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// A thread pool could not be built.
    #[error("building a thread pool: {0}")]
    Threads(#[from] rayon::ThreadPoolBuildError),
    /// The fisheye rig could not be rectified.
    #[error(transparent)]
    Rectify(#[from] RectifyError),
    /// The matcher refused its parameters.
    #[error(transparent)]
    Match(#[from] MatchError),
    /// The pipeline failed.
    #[error(transparent)]
    Pipeline(#[from] StereoError),
}

/// What to run.
#[derive(Debug, Clone, Copy)]
pub struct BenchOptions {
    /// Repeats per measurement; the median is reported.
    pub repeats: usize,
    /// Also time OpenCV's StereoBM (needs python3 with opencv-python).
    pub opencv: bool,
}

/// One measurement.
#[derive(Debug, Clone, Serialize)]
pub struct BenchRow {
    /// What was timed.
    pub what: String,
    /// Threads it ran on.
    pub threads: usize,
    /// Median time, ms.
    pub median_ms: f64,
    /// Against the row named in `reference` (time / reference time).
    pub ratio: Option<f64>,
    /// The row `ratio` compares with.
    pub reference: Option<String>,
    /// Share of pixels with a disparity more than 1 px off the ground truth, among the
    /// pixels both this matcher and the ground truth cover.
    pub bad_1px_pct: Option<f64>,
    /// Share of pixels with a disparity.
    pub valid_pct: Option<f64>,
}

/// The benchmark's rows, and why the OpenCV reference was skipped when it was asked for
/// and could not run.
#[derive(Debug, Clone)]
pub struct BenchReport {
    /// The measurements, in the order they ran.
    pub rows: Vec<BenchRow>,
    /// Set when `--opencv` was asked for but OpenCV could not run.
    pub opencv_skipped: Option<String>,
}

/// Steps `run` reports through its `step` callback.
pub const STEPS: u64 = 8;

/// Runs the benchmark on a built-in 640×480 capture; `step` is called after each of
/// [`STEPS`] steps.
pub fn run(options: BenchOptions, mut step: impl FnMut()) -> Result<BenchReport, BenchError> {
    let repeats = options.repeats;
    let rig = StereoRig::sensor();
    let plane = Plane {
        z_mm: 120.0,
        tilt_x: 0.3,
        tilt_y: 0.1,
    };
    let (left, right) = render_pair(&rig, &plane, &Membrane::sensor(), 1);
    let truth = rig.true_disparity(&plane);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let two = rayon::ThreadPoolBuilder::new().num_threads(2).build()?;
    let mut rows: Vec<BenchRow> = Vec::new();
    let mut opencv_skipped = None;
    let row = |what: &str, threads, ms, reference: Option<(&str, f64)>| BenchRow {
        what: what.to_string(),
        threads,
        median_ms: ms,
        ratio: reference.map(|(_, r)| ms / r),
        reference: reference.map(|(n, _)| n.to_string()),
        bad_1px_pct: None,
        valid_pct: None,
    };

    // Remap: a fisheye camera's map, against a plain copy of the frame.
    let fisheye_pair = fisheye_calibration();
    let (table, _) = Rectification::bouguet(&fisheye_pair, 0.8)?.maps(&fisheye_pair);
    let mut out = vec![0u8; 640 * 480];
    let copy = one.install(|| {
        median_ms(repeats, || {
            out.copy_from_slice(std::hint::black_box(left.as_slice()))
        })
    });
    rows.push(row("frame copy 640×480 (reference)", 1, copy, None));
    let remap = one.install(|| {
        median_ms(repeats, || {
            table.remap(left.as_slice(), &mut out).expect("sizes match")
        })
    });
    rows.push(row(
        "remap 640×480 (fisheye, 5-bit bilinear)",
        1,
        remap,
        None,
    ));
    step();

    // Matching: 64 disparities, 9×9, one thread, each kernel.
    let params = BlockMatchParams::default();
    let mut portable_ms = None;
    for kernel in [Kernel::Portable, Kernel::Avx2] {
        let Ok(m) = BlockMatcher::new(params)?.with_kernel(kernel) else {
            continue;
        };
        let mut last = None;
        let ms = one.install(|| {
            median_ms(repeats, || {
                last = Some(m.compute(&left, &right).expect("same size"))
            })
        });
        let reference = portable_ms.map(|p| ("match, Portable", p));
        let mut r = row(&format!("match, {kernel:?} (64 d, 9×9)"), 1, ms, reference);
        if let Some(d) = last {
            let (bad, valid) = quality(&d.disparity, &truth);
            r.bad_1px_pct = Some(bad);
            r.valid_pct = Some(valid);
        }
        rows.push(r);
        portable_ms.get_or_insert(ms);
        step();
    }
    let best = BlockMatcher::new(params)?;
    let best_ms = one.install(|| median_ms(repeats, || drop(best.compute(&left, &right))));

    // OpenCV's StereoBM on the same images, same parameters, one thread.
    if options.opencv {
        let reference = OpenCvMatcher::Bm {
            block: params.block_size,
        };
        match run_opencv(&left, &right, &truth, &params, reference, repeats) {
            Ok(cv) => {
                let mut r = row("OpenCV StereoBM (64 d, 9×9)", 1, cv.median_ms, None);
                r.bad_1px_pct = Some(cv.bad_1px_pct);
                r.valid_pct = Some(cv.valid_pct);
                rows.push(r);
                rows.push(row(
                    &format!("match, {:?} vs OpenCV", best.kernel()),
                    1,
                    best_ms,
                    Some(("OpenCV StereoBM", cv.median_ms)),
                ));
            }
            Err(why) => opencv_skipped = Some(why),
        }
    }
    step();

    // Semi-global matching, 64 disparities: 8, 5, 4 and 3 paths on one thread, 8 on
    // two; 3 paths also without the sub-pixel refinement on the images, as OpenCV's
    // StereoSGBM (3-way: the same three paths, 5×5) runs on the same images.
    // StereoSGBM runs before and after them, and the faster of its two medians is the
    // reference: a slow spell of a shared machine that falls on one of its runs does
    // not flatter the ratios.
    let mut sgbm_runs = Vec::new();
    let mut time_sgbm = |opencv_skipped: &mut Option<String>| {
        if options.opencv && opencv_skipped.is_none() {
            let sgbm = OpenCvMatcher::Sgbm { block: 5 };
            match run_opencv(&left, &right, &truth, &params, sgbm, repeats) {
                Ok(cv) => sgbm_runs.push(cv),
                Err(why) => *opencv_skipped = Some(why),
            }
        }
    };
    time_sgbm(&mut opencv_skipped);
    let mut sgm_ms = Vec::new();
    for (paths, refine, threads, pool) in [
        (Paths::Eight, true, 1, &one),
        (Paths::Five, true, 1, &one),
        (Paths::Four, true, 1, &one),
        (Paths::Three, true, 1, &one),
        (Paths::Three, false, 1, &one),
        (Paths::Eight, true, 2, &two),
    ] {
        let m = SemiGlobalMatcher::new(SgmParams {
            min_disparity: params.min_disparity,
            num_disparities: params.num_disparities,
            paths,
            refine,
            ..SgmParams::default()
        })?;
        let mut last = None;
        let ms = pool.install(|| {
            median_ms(repeats, || {
                last = Some(m.compute(&left, &right).expect("same size"))
            })
        });
        let what = format!(
            "match, SGM {} paths{}, {:?}{} (64 d)",
            paths.count(),
            if refine { "" } else { " unrefined" },
            m.kernel(),
            if m.counts_with_vpopcntb() {
                "+VPOPCNTB"
            } else {
                ""
            }
        );
        let mut r = row(&what, threads, ms, None);
        if let Some(d) = last {
            let (bad, valid) = quality(&d.disparity, &truth);
            r.bad_1px_pct = Some(bad);
            r.valid_pct = Some(valid);
        }
        rows.push(r);
        if threads == 1 {
            sgm_ms.push((paths, refine, ms));
        }
    }
    time_sgbm(&mut opencv_skipped);
    let reference = match &sgbm_runs[..] {
        [before, after] => Some((
            if after.median_ms < before.median_ms {
                after
            } else {
                before
            },
            format!(
                "OpenCV StereoSGBM 3-way (64 d, 5×5; {:.1} ms before ours, {:.1} after)",
                before.median_ms, after.median_ms
            ),
        )),
        // The second run failed (`opencv_skipped` says why): the first is the reference.
        [only] => Some((
            only,
            "OpenCV StereoSGBM 3-way (64 d, 5×5; one run, before ours)".to_string(),
        )),
        _ => None,
    };
    if let Some((cv, what)) = reference {
        let mut r = row(&what, 1, cv.median_ms, None);
        r.bad_1px_pct = Some(cv.bad_1px_pct);
        r.valid_pct = Some(cv.valid_pct);
        rows.push(r);
        for (paths, refine, ms) in sgm_ms {
            let what = format!(
                "match, SGM {} paths{} vs OpenCV StereoSGBM",
                paths.count(),
                if refine { "" } else { " unrefined" }
            );
            rows.push(row(&what, 1, ms, Some(("OpenCV StereoSGBM", cv.median_ms))));
        }
    }
    step();
    step();

    // The whole vision frame at the sensor's range (5–60 cm), on 1 and 2 threads.
    for (threads, pool) in [(1, &one), (2, &two)] {
        let config = StereoConfig {
            spatial: None,
            ..StereoConfig::default()
        };
        let mut p = StereoPipeline::new(&fisheye_pair, config)?;
        let ms = pool.install(|| {
            median_ms(repeats, || {
                drop(p.process(&left, &right).expect("sizes match"))
            })
        });
        let n = p.matcher().num_disparities();
        rows.push(row(
            &format!("whole frame: rectify both, match ({n} d), reproject"),
            threads,
            ms,
            None,
        ));
        step();
    }
    Ok(BenchReport {
        rows,
        opencv_skipped,
    })
}

/// The rows as a table, headed by the repeat count.
pub fn format_table(rows: &[BenchRow], repeats: usize) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(s, "stereo bench, 640×480, median of {repeats} runs");
    let _ = writeln!(
        s,
        "{:<52} {:>7} {:>10} {:>8} {:>9} {:>9}",
        "what", "threads", "ms", "ratio", "bad>1px%", "valid%"
    );
    for r in rows {
        let opt = |v: Option<f64>, p: usize| v.map_or("-".into(), |v| format!("{v:.p$}"));
        let _ = writeln!(
            s,
            "{:<52} {:>7} {:>10.3} {:>8} {:>9} {:>9}",
            r.what,
            r.threads,
            r.median_ms,
            opt(r.ratio, 2),
            opt(r.bad_1px_pct, 2),
            opt(r.valid_pct, 1)
        );
    }
    s
}

/// Matching quality against the true disparity of the bench scene: (% of valid pixels
/// more than 1 px off, % of pixels valid).
fn quality(disparity: &Grid<f32>, truth: &Grid<f32>) -> (f64, f64) {
    let (mut valid, mut bad) = (0usize, 0usize);
    for (d, t) in disparity.as_slice().iter().zip(truth.as_slice()) {
        if d.is_finite() {
            valid += 1;
            if (d - t).abs() > 1.0 {
                bad += 1;
            }
        }
    }
    let n = disparity.as_slice().len().max(1);
    (
        100.0 * bad as f64 / valid.max(1) as f64,
        100.0 * valid as f64 / n as f64,
    )
}

struct OpenCvResult {
    median_ms: f64,
    bad_1px_pct: f64,
    valid_pct: f64,
}

/// Times OpenCV's `matcher` on the same images ([`opencv::run`]) and scores its
/// disparity against the same ground truth; the error says why it could not.
fn run_opencv(
    left: &Grid<u8>,
    right: &Grid<u8>,
    truth: &Grid<f32>,
    params: &BlockMatchParams,
    matcher: OpenCvMatcher,
    repeats: usize,
) -> Result<OpenCvResult, String> {
    let run = opencv::run(
        &[(left, right)],
        params.min_disparity,
        params.num_disparities,
        matcher,
        repeats,
    )?;
    let (bad_1px_pct, valid_pct) = quality(&run.disparities[0], truth);
    Ok(OpenCvResult {
        median_ms: run.median_ms,
        bad_1px_pct,
        valid_pct,
    })
}
