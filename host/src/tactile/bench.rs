//! `stereotac bench tactile`: run time per stage against depth error on the built-in
//! scenes, for every gradient model and solver, plus the references the goals are
//! measured against (one real 2-D FFT of the frame size, full-frame solves) and the
//! 13 mm disk pressed at 30 random places.
//!
//! Every size images the same skin (42.7 × 32 mm at 640×480 and 15 px/mm, 30 px/mm at
//! 1280×960), so a scene covers 4× the pixels at the larger size.
//!
//! Times are medians over repeats on one thread; the machine is shared, so compare the
//! ratios within one run rather than absolute numbers across runs.

use realfft::RealFftPlanner;
use realfft::num_complex::Complex;
use serde::Serialize;

use super::model::{ModelKind, TactileModel};
use super::poisson::{PoissonSolver, SolverKind};
use super::reconstruct::{Reconstructor, StageTimings};
use super::render::{Optics, Scene, builtin_scenes, disk, render};
use super::synthetic::builtin_calibration;
use crate::grid::{Grid, transpose};
use crate::rng::Rng;
use crate::timing::{median, median_ms};

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchConfig {
    /// Frame sizes.
    pub sizes: Vec<(usize, usize)>,
    /// Repeats per measurement (the median is reported).
    pub repeats: usize,
    /// Ball presses rendered for calibration at each size.
    pub calibration_presses: usize,
    /// Random placements of the 13 mm disk for the accuracy statistic.
    pub disk_placements: usize,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            sizes: vec![(640, 480), (1280, 960)],
            repeats: 15,
            calibration_presses: 20,
            disk_placements: 30,
        }
    }
}

/// Depth errors of one reconstruction against the truth (mm).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct DepthErrors {
    /// RMS over pixels where either truth or result is non-zero.
    pub rms_mm: f64,
    /// Largest absolute error.
    pub max_mm: f64,
    /// True deepest point.
    pub true_peak_mm: f64,
    /// Reconstructed deepest point.
    pub peak_mm: f64,
    /// Median reconstructed depth where the truth is ≥ 95 % of its peak: what the sensor
    /// "reads" for the object (0 without contact).
    pub reading_mm: f64,
}

/// The gradient models measured: every kind, and the lookup table and the perceptron a
/// second time alone (without the light model reading past the calibration's slopes,
/// [`super::past_reach`]) to compare.
const VARIANTS: [(ModelKind, bool); 6] = [
    (ModelKind::Lut, true),
    (ModelKind::Lut, false),
    (ModelKind::Mlp, true),
    (ModelKind::Mlp, false),
    (ModelKind::Light, false),
    (ModelKind::Photometric, false),
];

/// A reconstructor of `variant` (see [`VARIANTS`]) and whether it reads past the table's
/// reach.
fn reconstructor(
    model: &TactileModel,
    (kind, past_reach): (ModelKind, bool),
    solver: SolverKind,
    refs: &(image::RgbImage, image::RgbImage),
) -> (Reconstructor, bool) {
    let mut rec = Reconstructor::new(model.clone(), kind, solver, Some((&refs.0, &refs.1).into()))
        .expect("the built-in model takes its own reference frames");
    let on = rec.set_past_reach(past_reach);
    (rec, on)
}

/// The model's name in the tables: `lut` and `mlp` read past the calibration's slopes,
/// `lut-alone` and `mlp-alone` do not.
fn model_label(kind: ModelKind, past_reach: bool) -> String {
    match kind {
        ModelKind::Lut | ModelKind::Mlp if !past_reach => format!("{kind}-alone"),
        _ => kind.to_string(),
    }
}

/// One scene × size × model × solver.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchRecord {
    /// Scene name.
    pub scene: String,
    /// Frame width.
    pub width: usize,
    /// Frame height.
    pub height: usize,
    /// Gradient model.
    pub model: ModelKind,
    /// The light model read slopes steeper than the calibration's.
    pub past_reach: bool,
    /// Solver.
    pub solver: SolverKind,
    /// Median milliseconds per stage.
    pub median_ms: StageTimings,
    /// Errors versus ground truth.
    pub errors: DepthErrors,
    /// Regions integrated.
    pub regions: usize,
}

/// Reference timings at one frame size.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SizeReference {
    /// Frame width.
    pub width: usize,
    /// Frame height.
    pub height: usize,
    /// One forward real 2-D FFT of the frame (ms, median).
    pub fft2d_ms: f64,
    /// Full-frame Poisson solves (ms, median), per solver.
    pub solve_ms: Vec<(SolverKind, f64)>,
    /// Calibration fit (slope RMS) at this size.
    pub calibration: super::model::FitReport,
}

/// The disk-at-random-places statistic for one model and solver.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DiskStatistic {
    /// Gradient model.
    pub model: ModelKind,
    /// The light model read slopes steeper than the calibration's.
    pub past_reach: bool,
    /// Solver.
    pub solver: SolverKind,
    /// Placements.
    pub placements: usize,
    /// Mean reading (mm); truth 1.0.
    pub mean_mm: f64,
    /// Standard deviation of the readings (mm).
    pub std_mm: f64,
}

/// Everything the benchmark measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchReport {
    /// Per size references.
    pub references: Vec<SizeReference>,
    /// One record per scene, size, model and solver.
    pub records: Vec<BenchRecord>,
    /// The 13 mm disk at random places (first size only).
    pub disk: Vec<DiskStatistic>,
}

/// Progress messages for a progress bar.
pub type Progress<'a> = &'a mut dyn FnMut(&str, usize, usize);

/// Runs the benchmark.
pub fn run(config: &BenchConfig, progress: Progress<'_>) -> BenchReport {
    let mut report = BenchReport {
        references: Vec::new(),
        records: Vec::new(),
        disk: Vec::new(),
    };
    for (size_index, &(w, h)) in config.sizes.iter().enumerate() {
        let optics = Optics::resolution(w, h);
        let label = format!("{w}x{h}");
        progress(&format!("{label}: calibrating"), 0, 1);
        let (model, refs) = calibrated(&optics, config.calibration_presses);
        report.references.push(SizeReference {
            width: w,
            height: h,
            fft2d_ms: median_ms(config.repeats, fft2d_timer(w, h)),
            solve_ms: SolverKind::ALL
                .into_iter()
                .map(|k| (k, median_ms(config.repeats, full_solve_timer(k, w, h))))
                .collect(),
            calibration: model.fit,
        });
        let scenes = builtin_scenes(&optics);
        let total = scenes.len() * VARIANTS.len() * SolverKind::ALL.len();
        let mut done = 0;
        for (name, scene) in &scenes {
            let pair = render(&optics, scene, 7);
            let truth = scene.truth(w, h, optics.px_per_mm).depth;
            for variant in VARIANTS {
                for solver in SolverKind::ALL {
                    let (mut rec, past_reach) = reconstructor(&model, variant, solver, &refs);
                    let mut runs = Vec::with_capacity(config.repeats);
                    let mut last = None;
                    for _ in 0..config.repeats.max(1) {
                        let r = rec.reconstruct(&pair.dx, &pair.dy).expect("valid input");
                        runs.push(r.timings);
                        last = Some(r);
                    }
                    let last = last.expect("at least one run");
                    report.records.push(BenchRecord {
                        scene: name.to_string(),
                        width: w,
                        height: h,
                        model: variant.0,
                        past_reach,
                        solver,
                        median_ms: median_timings(&runs),
                        errors: errors(&last.depth_mm, &truth),
                        regions: last.regions.len(),
                    });
                    done += 1;
                    progress(&label, done, total);
                }
            }
        }
        // The disk with its rim is 18 mm across: it needs a frame of at least 20 mm.
        let fits_disk = (w.min(h) as f64) / optics.px_per_mm >= 20.0;
        if size_index == 0 && config.disk_placements > 0 && fits_disk {
            report.disk = disk_statistics(&optics, &model, &refs, config.disk_placements, progress);
        }
    }
    report
}

fn calibrated(
    optics: &Optics,
    presses: usize,
) -> (TactileModel, (image::RgbImage, image::RgbImage)) {
    let (cal, refs) =
        builtin_calibration(optics, presses, |_| {}).expect("built-in presses calibrate");
    (cal.model, refs)
}

fn disk_statistics(
    optics: &Optics,
    model: &TactileModel,
    refs: &(image::RgbImage, image::RgbImage),
    placements: usize,
    progress: Progress<'_>,
) -> Vec<DiskStatistic> {
    let mut rng = Rng::new(2024);
    let (wmm, hmm) = (
        optics.width as f64 / optics.px_per_mm,
        optics.height as f64 / optics.px_per_mm,
    );
    // The disk and its rim (9 mm radius) stay inside the frame.
    let scenes: Vec<(Scene, Grid<f32>)> = (0..placements)
        .map(|_| {
            let scene = Scene {
                shapes: vec![disk(
                    rng.range(9.5, wmm - 9.5),
                    rng.range(9.5, hmm - 9.5),
                    false,
                )],
            };
            let truth = scene
                .truth(optics.width, optics.height, optics.px_per_mm)
                .depth;
            (scene, truth)
        })
        .collect();
    let mut out = Vec::new();
    let total = placements * VARIANTS.len() * SolverKind::ALL.len();
    let mut done = 0;
    for variant in VARIANTS {
        for solver in SolverKind::ALL {
            let (mut rec, past_reach) = reconstructor(model, variant, solver, refs);
            let mut readings = Vec::with_capacity(placements);
            for (i, (scene, truth)) in scenes.iter().enumerate() {
                let pair = render(optics, scene, 100 + i as u64);
                let r = rec.reconstruct(&pair.dx, &pair.dy).expect("valid input");
                readings.push(errors(&r.depth_mm, truth).reading_mm);
                done += 1;
                progress("disk at 30 places", done, total);
            }
            let n = readings.len() as f64;
            let mean = readings.iter().sum::<f64>() / n;
            let var = readings.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
            out.push(DiskStatistic {
                model: variant.0,
                past_reach,
                solver,
                placements,
                mean_mm: mean,
                std_mm: var.sqrt(),
            });
        }
    }
    out
}

/// Errors of `depth` against `truth` (both mm).
pub fn errors(depth: &Grid<f32>, truth: &Grid<f32>) -> DepthErrors {
    let true_peak = truth.as_slice().iter().copied().fold(0.0f32, f32::max) as f64;
    let peak = depth.as_slice().iter().copied().fold(0.0f32, f32::max) as f64;
    let (mut sq, mut n, mut max) = (0.0f64, 0usize, 0.0f64);
    let mut top = Vec::new();
    for (&d, &t) in depth.as_slice().iter().zip(truth.as_slice()) {
        if d != 0.0 || t != 0.0 {
            let e = (d - t) as f64;
            sq += e * e;
            n += 1;
            max = max.max(e.abs());
        }
        if true_peak > 0.0 && t as f64 >= 0.95 * true_peak {
            top.push(d as f64);
        }
    }
    top.sort_by(f64::total_cmp);
    DepthErrors {
        rms_mm: if n > 0 { (sq / n as f64).sqrt() } else { 0.0 },
        max_mm: max,
        true_peak_mm: true_peak,
        peak_mm: peak,
        reading_mm: top.get(top.len() / 2).copied().unwrap_or(0.0),
    }
}

fn median_timings(runs: &[StageTimings]) -> StageTimings {
    let m = |f: fn(&StageTimings) -> f64| median(runs.iter().map(f).collect());
    StageTimings {
        detect_ms: m(|t| t.detect_ms),
        colour_ms: m(|t| t.colour_ms),
        model_ms: m(|t| t.model_ms),
        solve_ms: m(|t| t.solve_ms),
        total_ms: m(|t| t.total_ms),
    }
}

/// Smooth slope fields `(p, q)` of a `w × h` frame (the solver benchmarks' input).
pub fn smooth_slopes(w: usize, h: usize) -> (Grid<f32>, Grid<f32>) {
    (
        Grid::from_fn(w, h, |x, y| {
            ((x as f32 * 0.05).sin() * (y as f32 * 0.03).cos()) * 0.3
        }),
        Grid::from_fn(w, h, |x, y| {
            ((x as f32 * 0.02).cos() * (y as f32 * 0.07).sin()) * 0.3
        }),
    )
}

/// A full-frame solve of smooth slopes, for the solver-versus-FFT ratio.
fn full_solve_timer(kind: SolverKind, w: usize, h: usize) -> impl FnMut() {
    let (p, q) = smooth_slopes(w, h);
    let mut solver = PoissonSolver::<f32>::new();
    move || {
        let z = solver.integrate(kind, &p, &q).expect("finite input");
        std::hint::black_box(z);
    }
}

/// The solvers' speed reference: one forward real 2-D FFT of a `w × h` f32 frame (real
/// FFT of each row, then complex FFTs down the `w/2 + 1` columns through a transpose),
/// plans and buffers made once.
pub struct Fft2d {
    width: usize,
    rows: std::sync::Arc<dyn realfft::RealToComplex<f32>>,
    cols: std::sync::Arc<dyn rustfft::Fft<f32>>,
    input: Vec<f32>,
    spectrum: Vec<Complex<f32>>,
    transposed: Vec<Complex<f32>>,
    scratch_rows: Vec<Complex<f32>>,
    scratch_cols: Vec<Complex<f32>>,
}

impl Fft2d {
    /// Plans the transform of a `w × h` frame.
    pub fn new(w: usize, h: usize) -> Self {
        let rows = RealFftPlanner::<f32>::new().plan_fft_forward(w);
        let cols = rustfft::FftPlanner::<f32>::new().plan_fft_forward(h);
        let half = w / 2 + 1;
        Self {
            width: w,
            scratch_rows: rows.make_scratch_vec(),
            scratch_cols: vec![Complex::default(); cols.get_inplace_scratch_len()],
            rows,
            cols,
            input: vec![0.0; w * h],
            spectrum: vec![Complex::default(); half * h],
            transposed: vec![Complex::default(); half * h],
        }
    }

    /// Transforms `frame` (row-major, `w × h`); the spectrum is column-major.
    pub fn run(&mut self, frame: &[f32]) -> &[Complex<f32>] {
        let (w, half) = (self.width, self.width / 2 + 1);
        self.input.copy_from_slice(frame);
        for (row, out) in self
            .input
            .chunks_exact_mut(w)
            .zip(self.spectrum.chunks_exact_mut(half))
        {
            self.rows
                .process_with_scratch(row, out, &mut self.scratch_rows)
                .expect("plan lengths");
        }
        transpose(&self.spectrum, &mut self.transposed, half, frame.len() / w);
        self.cols
            .process_with_scratch(&mut self.transposed, &mut self.scratch_cols);
        &self.transposed
    }
}

fn fft2d_timer(w: usize, h: usize) -> impl FnMut() {
    let (frame, _) = smooth_slopes(w, h);
    let mut fft = Fft2d::new(w, h);
    move || {
        std::hint::black_box(fft.run(frame.as_slice()));
    }
}

/// The report as a plain-text table.
pub fn format_table(report: &BenchReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    for r in &report.references {
        let _ = writeln!(
            s,
            "{}x{}: one real 2-D FFT {:.2} ms; full-frame solve {}; calibration slope RMS lut {:.3}/{:.3} mlp {:.3}/{:.3} light {:.3}/{:.3} (train/held-out)",
            r.width,
            r.height,
            r.fft2d_ms,
            r.solve_ms
                .iter()
                .map(|(k, ms)| format!("{k} {ms:.2} ms ({:.2}x FFT)", ms / r.fft2d_ms))
                .collect::<Vec<_>>()
                .join(", "),
            r.calibration.lut_train_rms,
            r.calibration.lut_validation_rms,
            r.calibration.mlp_train_rms,
            r.calibration.mlp_validation_rms,
            r.calibration.light_train_rms,
            r.calibration.light_validation_rms,
        );
    }
    let _ = writeln!(
        s,
        "\n{:<11} {:>9} {:<11} {:<4} | {:>6} {:>6} {:>6} {:>6} {:>7} | {:>7} {:>7} {:>6} {:>6} {:>7}",
        "scene",
        "size",
        "mdl",
        "slv",
        "detect",
        "colour",
        "model",
        "solve",
        "total",
        "rms",
        "max",
        "peak",
        "true",
        "reading"
    );
    for r in &report.records {
        let t = &r.median_ms;
        let e = &r.errors;
        let _ = writeln!(
            s,
            "{:<11} {:>9} {:<11} {:<4} | {:>6.2} {:>6.2} {:>6.2} {:>6.2} {:>7.2} | {:>7.4} {:>7.3} {:>6.3} {:>6.3} {:>7.3}",
            r.scene,
            format!("{}x{}", r.width, r.height),
            model_label(r.model, r.past_reach),
            r.solver,
            t.detect_ms,
            t.colour_ms,
            t.model_ms,
            t.solve_ms,
            t.total_ms,
            e.rms_mm,
            e.max_mm,
            e.peak_mm,
            e.true_peak_mm,
            e.reading_mm
        );
    }
    if !report.disk.is_empty() {
        let _ = writeln!(
            s,
            "\n13 mm disk pressed 1.000 mm at random places (reading = median depth over the plateau):"
        );
        for d in &report.disk {
            let _ = writeln!(
                s,
                "  {} + {}: {} places, mean {:.3} mm, std {:.3} mm",
                model_label(d.model, d.past_reach),
                d.solver,
                d.placements,
                d.mean_mm,
                d.std_mm
            );
        }
    }
    s
}
