//! Depth-camera evaluation of flat targets at known distances, after Intel's depth
//! testing methodology: over a central region of interest (ROI),
//!
//! - **Z-accuracy**: median of `(Z − ground truth)` over all frames' valid ROI pixels,
//!   as a signed percentage of the distance;
//! - **RMS error** (spatial noise): RMS distance of each frame's ROI points from the
//!   plane fitted to them (least squares), as % of the distance, averaged over frames;
//! - **temporal noise**: per pixel, the standard deviation of its depth over the frames
//!   (pixels valid in at least two), averaged over the ROI, as % of the distance;
//! - **fill rate**: share of ROI pixels with a depth, averaged over frames.
//!
//! [`run_synthetic`] produces the captures itself (textured planes behind the hazy skin,
//! [`super::synthetic`]) and measures the pipeline with and without post-filters, either
//! through an ideal rig (rectification is the identity) or through the sensor's wide
//! lenses ([`Lens::Wide`]: raw fisheye frames, rectified by the pipeline as real ones
//! are, with the target facing the rectified left camera). [`run_comparison`] measures
//! both our matchers and OpenCV's StereoBM and StereoSGBM on the same captures,
//! unfiltered, with the time each takes to match a frame.

use nalgebra::{Matrix3, Point3, Vector3};
use serde::Serialize;

use super::matcher::MatcherKind;
use super::opencv::{self, OpenCvMatcher};
use super::pipeline::{StereoConfig, StereoError, StereoPipeline};
use super::postfilter::{SpatialFilter, TemporalParams};
use super::rectify::Rectification;
use super::reproject::depth_from_disparity;
use super::sgm::Paths;
use super::synthetic::{
    Membrane, Plane, RawRig, StereoRig, TexturedPlane, render_pair, wide_fisheye_calibration,
};
use crate::grid::Grid;

/// A rectangle of pixels: columns `x0..x1`, rows `y0..y1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Region {
    /// First column.
    pub x0: usize,
    /// One past the last column.
    pub x1: usize,
    /// First row.
    pub y0: usize,
    /// One past the last row.
    pub y1: usize,
}

impl Region {
    /// The centred rectangle covering `share` of each side of a `width × height` image.
    pub fn central(width: usize, height: usize, share: f64) -> Self {
        let share = share.clamp(0.0, 1.0);
        let (w, h) = (
            (width as f64 * share).round() as usize,
            (height as f64 * share).round() as usize,
        );
        let (x0, y0) = ((width - w) / 2, (height - h) / 2);
        Self {
            x0,
            x1: x0 + w,
            y0,
            y1: y0 + h,
        }
    }

    /// Number of pixels.
    pub fn area(&self) -> usize {
        (self.x1 - self.x0) * (self.y1 - self.y0)
    }

    fn pixels(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (self.y0..self.y1).flat_map(move |y| (self.x0..self.x1).map(move |x| (x, y)))
    }
}

/// The measures of one target distance.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PlaneMetrics {
    /// Ground-truth distance, mm.
    pub distance_mm: f64,
    /// Frames measured.
    pub frames: usize,
    /// Median signed depth error, % of distance.
    pub z_accuracy_pct: f64,
    /// Spatial noise about the fitted plane, % of distance (NaN with < 3 points).
    pub rms_error_pct: f64,
    /// Mean per-pixel standard deviation over frames, % of distance (NaN with < 2 frames).
    pub temporal_noise_pct: f64,
    /// Share of ROI pixels with a depth, %.
    pub fill_rate_pct: f64,
}

/// How depth maps (mm) map to 3-D: focal length and principal point of the rectified
/// left camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Focal length, px.
    pub focal_px: f64,
    /// Principal point, px.
    pub centre: (f64, f64),
}

/// Measures `frames` (depth in mm, NaN invalid) of a facing plane at `distance_mm`.
pub fn plane_metrics(
    frames: &[Grid<f32>],
    distance_mm: f64,
    roi: Region,
    intrinsics: Intrinsics,
) -> PlaneMetrics {
    let pct = |v: f64| 100.0 * v / distance_mm;
    let mut errors = Vec::new();
    let mut rms = Vec::new();
    let mut fill = 0.0;
    for depth in frames {
        let mut points = Vec::new();
        for (x, y) in roi.pixels() {
            let z = f64::from(depth.get(x, y));
            if z.is_finite() {
                errors.push(z - distance_mm);
                let (a, b) = (
                    (x as f64 - intrinsics.centre.0) / intrinsics.focal_px,
                    (y as f64 - intrinsics.centre.1) / intrinsics.focal_px,
                );
                points.push(Vector3::new(a * z, b * z, z));
            }
        }
        fill += points.len() as f64 / roi.area().max(1) as f64;
        if let Some(r) = plane_rms(&points) {
            rms.push(r);
        }
    }
    let mut temporal = Vec::new();
    if frames.len() >= 2 {
        for (x, y) in roi.pixels() {
            let v: Vec<f64> = frames
                .iter()
                .map(|f| f64::from(f.get(x, y)))
                .filter(|z| z.is_finite())
                .collect();
            if v.len() >= 2 {
                let mean = v.iter().sum::<f64>() / v.len() as f64;
                let var = v.iter().map(|z| (z - mean).powi(2)).sum::<f64>() / v.len() as f64;
                temporal.push(var.sqrt());
            }
        }
    }
    let mean = |v: &[f64]| {
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    PlaneMetrics {
        distance_mm,
        frames: frames.len(),
        z_accuracy_pct: pct(median(&mut errors)),
        rms_error_pct: pct(mean(&rms)),
        temporal_noise_pct: pct(mean(&temporal)),
        fill_rate_pct: 100.0 * fill / frames.len().max(1) as f64,
    }
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// RMS distance of `points` from their least-squares plane `Z = a·X + b·Y + c`
/// (`None` with fewer than 3 points or a degenerate spread).
fn plane_rms(points: &[Vector3<f64>]) -> Option<f64> {
    if points.len() < 3 {
        return None;
    }
    let n = points.len() as f64;
    let c: Vector3<f64> = points.iter().sum::<Vector3<f64>>() / n;
    let mut m = Matrix3::zeros();
    let mut rhs = Vector3::zeros();
    for p in points {
        let d = p - c;
        let row = Vector3::new(d.x, d.y, 1.0);
        m += row * row.transpose();
        rhs += row * d.z;
    }
    let sol = m.lu().solve(&rhs)?;
    let (a, b, off) = (sol.x, sol.y, sol.z);
    let norm = (a * a + b * b + 1.0).sqrt();
    let ss: f64 = points
        .iter()
        .map(|p| {
            let d = p - c;
            ((a * d.x + b * d.y + off - d.z) / norm).powi(2)
        })
        .sum();
    Some((ss / n).sqrt())
}

/// Which cameras the synthetic captures come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Lens {
    /// The ideal rectified rig of [`SyntheticEval::rig`].
    Ideal,
    /// The sensor's 160° fisheye pair ([`wide_fisheye_calibration`]), raw frames.
    Wide,
}

/// What the synthetic evaluation runs.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticEval {
    /// The ideal rig (used with [`Lens::Ideal`]).
    pub rig: StereoRig,
    /// Which cameras see the targets.
    pub lens: Lens,
    /// The skin and noise.
    pub membrane: Membrane,
    /// Target distances, mm.
    pub distances_mm: Vec<f64>,
    /// Frames per distance.
    pub frames: usize,
    /// ROI share of each side.
    pub roi: f64,
}

impl Default for SyntheticEval {
    fn default() -> Self {
        Self {
            rig: StereoRig::sensor(),
            lens: Lens::Ideal,
            membrane: Membrane::sensor(),
            distances_mm: vec![100.0, 150.0, 200.0, 250.0, 300.0],
            frames: 10,
            roi: 0.4,
        }
    }
}

/// One row of the evaluation table.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EvalRow {
    /// "raw" (no post-filters) or "filtered" (spatial + temporal).
    pub variant: &'static str,
    /// The matcher that ran.
    pub matcher: MatcherKind,
    /// The paths semi-global matching aggregated along (none with block matching).
    pub sgm_paths: Option<usize>,
    /// Side of the matching window, px ([`super::Matcher::window`]).
    pub window_px: u32,
    /// The measures.
    #[serde(flatten)]
    pub metrics: PlaneMetrics,
    /// Mean whole-frame time, ms.
    pub frame_ms: f64,
}

/// The two pipeline variants compared: no post-filters, and spatial + temporal.
pub fn variants(base: StereoConfig) -> [(&'static str, StereoConfig); 2] {
    [
        (
            "raw",
            StereoConfig {
                spatial: None,
                temporal: None,
                ..base
            },
        ),
        (
            "filtered",
            StereoConfig {
                spatial: Some(SpatialFilter::default()),
                temporal: Some(TemporalParams::default()),
                ..base
            },
        ),
    ]
}

/// The cameras of an evaluation, and where its depth maps are measured.
struct Setup {
    calib: super::StereoCalibration,
    raw: Option<RawRig>,
    rectification: Rectification,
    roi: Region,
    intrinsics: Intrinsics,
}

impl Setup {
    fn new(eval: &SyntheticEval, rectify_scale: f64) -> Result<Self, StereoError> {
        let (calib, raw) = match eval.lens {
            Lens::Ideal => (eval.rig.calibration(), None),
            Lens::Wide => {
                let raw = RawRig::new(&wide_fisheye_calibration());
                (*raw.calibration(), Some(raw))
            }
        };
        // The rectified left camera the depth maps are in (as every pipeline has it).
        let rectification = Rectification::bouguet(&calib, rectify_scale)?;
        let (width, height) = (rectification.width as usize, rectification.height as usize);
        Ok(Self {
            calib,
            raw,
            roi: Region::central(width, height, eval.roi),
            intrinsics: Intrinsics {
                focal_px: rectification.focal(),
                centre: (rectification.p1[(0, 2)], rectification.p1[(1, 2)]),
            },
            rectification,
        })
    }

    /// The `eval.frames` captures of the target at `distance` mm.
    fn captures(&self, eval: &SyntheticEval, distance: f64) -> Vec<(Grid<u8>, Grid<u8>)> {
        // The wide lens's targets face the rectified left camera: Z_rect = distance.
        let to_raw = self.rectification.r1.transpose();
        let target = TexturedPlane {
            point: Point3::from(to_raw * Vector3::new(0.0, 0.0, distance)),
            normal: to_raw * Vector3::z(),
        };
        (0..eval.frames as u64)
            .map(|k| match &self.raw {
                None => render_pair(&eval.rig, &Plane::facing(distance), &eval.membrane, k + 1),
                Some(raw) => raw.render(&target, &eval.membrane, k + 1),
            })
            .collect()
    }
}

/// Runs the evaluation: for every distance and variant, `frames` captures through a
/// fresh pipeline. `progress` is called after each distance and variant.
pub fn run_synthetic(
    eval: &SyntheticEval,
    base: StereoConfig,
    mut progress: impl FnMut(&EvalRow),
) -> Result<Vec<EvalRow>, StereoError> {
    let setup = Setup::new(eval, base.rectify_scale)?;
    let (roi, intrinsics) = (setup.roi, setup.intrinsics);
    let mut rows = Vec::new();
    for &distance in &eval.distances_mm {
        let captures = setup.captures(eval, distance);
        for (variant, config) in variants(base) {
            let mut pipeline = StereoPipeline::new(&setup.calib, config)?;
            let mut depth = Vec::with_capacity(captures.len());
            let mut time = 0.0;
            for (l, r) in &captures {
                let f = pipeline.process(l, r)?;
                time += f.timings.total_ms;
                depth.push(f.depth_mm);
            }
            // The temporal filter needs a few frames to settle, as on a camera: the
            // first quarter of the frames is not measured.
            let settle = if config.temporal.is_some() {
                depth.len() / 4
            } else {
                0
            };
            let row = EvalRow {
                variant,
                matcher: pipeline.matcher().kind(),
                sgm_paths: pipeline.matcher().sgm_paths().map(Paths::count),
                window_px: pipeline.matcher().window(),
                metrics: plane_metrics(&depth[settle..], distance, roi, intrinsics),
                frame_ms: time / captures.len().max(1) as f64,
            };
            progress(&row);
            rows.push(row);
        }
    }
    Ok(rows)
}

/// One matcher at one distance in [`run_comparison`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CompareRow {
    /// `bm`, `sgm, N paths`, or OpenCV's matcher with its block size.
    pub matcher: String,
    /// Side of the matching window (OpenCV: its block), px.
    pub window_px: u32,
    /// The measures (unfiltered depth).
    #[serde(flatten)]
    pub metrics: PlaneMetrics,
    /// Median time to match one frame, ms: our pipeline's matching stage, or one
    /// `compute` of OpenCV's (on one thread, repeated [`OPENCV_REPEATS`] times a frame).
    pub match_ms: f64,
}

/// What [`run_comparison`] measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Comparison {
    /// Per distance: block matching, semi-global matching, then OpenCV's StereoBM and
    /// StereoSGBM when they ran.
    pub rows: Vec<CompareRow>,
    /// OpenCV's version, when its matchers ran.
    pub opencv: Option<String>,
    /// Why OpenCV's matchers did not run (no Python, no OpenCV), when they did not.
    pub opencv_skipped: Option<String>,
}

/// StereoSGBM's block side, as `bench stereo` runs it (OpenCV's usual choice).
pub const SGBM_BLOCK: u32 = 5;
/// Timed repeats of OpenCV's `compute` per frame.
pub const OPENCV_REPEATS: usize = 3;

/// Our two matchers (block matching, and semi-global along `base`'s paths) and, when
/// `with_opencv`, OpenCV's StereoBM (our block matcher's window) and StereoSGBM 3-way
/// ([`SGBM_BLOCK`]) on the same captures, all unfiltered (`base` without its spatial,
/// temporal and hole-filling filters and outlier removal); OpenCV's matchers read the views our pipeline rectified and search
/// block matching's disparities, and their depth keeps the same near–far range. Each
/// matcher's window is its own default unless `base` sets one. `progress` is called
/// after each distance and matcher.
pub fn run_comparison(
    eval: &SyntheticEval,
    base: StereoConfig,
    with_opencv: bool,
    mut progress: impl FnMut(&CompareRow),
) -> Result<Comparison, StereoError> {
    let setup = Setup::new(eval, base.rectify_scale)?;
    let (roi, intrinsics) = (setup.roi, setup.intrinsics);
    let (focal, baseline) = (setup.rectification.focal(), setup.rectification.baseline());
    let mut out = Comparison {
        rows: Vec::new(),
        opencv: None,
        opencv_skipped: None,
    };
    for &distance in &eval.distances_mm {
        let captures = setup.captures(eval, distance);
        // The views block matching rectified, its disparities and window, for OpenCV.
        let mut rectified = Vec::new();
        let (mut range, mut bm_window) = ((0, 0), 0);
        for matcher in [MatcherKind::Bm, MatcherKind::Sgm] {
            let config = StereoConfig {
                matcher,
                spatial: None,
                temporal: None,
                hole_fill: None,
                outliers: None,
                ..base
            };
            let mut pipeline = StereoPipeline::new(&setup.calib, config)?;
            // Once untimed, as OpenCV's are: the first frame allocates the volumes.
            if let Some((l, r)) = captures.first() {
                pipeline.process(l, r)?;
            }
            let mut depth = Vec::with_capacity(captures.len());
            let mut times = Vec::with_capacity(captures.len());
            for (l, r) in &captures {
                let f = pipeline.process(l, r)?;
                times.push(f.timings.match_ms);
                depth.push(f.depth_mm);
                if matcher == MatcherKind::Bm {
                    rectified.push((f.left, f.right));
                }
            }
            let m = pipeline.matcher();
            if matcher == MatcherKind::Bm {
                range = (m.disparity_range().0, m.num_disparities());
                bm_window = m.window();
            }
            let row = CompareRow {
                matcher: match m.sgm_paths() {
                    Some(p) => format!("sgm, {} paths", p.count()),
                    None => m.kind().name().to_string(),
                },
                window_px: m.window(),
                metrics: plane_metrics(&depth, distance, roi, intrinsics),
                match_ms: median(&mut times),
            };
            progress(&row);
            out.rows.push(row);
        }
        if !with_opencv || out.opencv_skipped.is_some() {
            continue;
        }
        let pairs: Vec<_> = rectified.iter().map(|(l, r)| (l, r)).collect();
        for matcher in [
            OpenCvMatcher::Bm { block: bm_window },
            OpenCvMatcher::Sgbm { block: SGBM_BLOCK },
        ] {
            let run = match opencv::run(&pairs, range.0, range.1, matcher, OPENCV_REPEATS) {
                Ok(run) => run,
                Err(why) => {
                    out.opencv_skipped = Some(why);
                    break;
                }
            };
            let depth: Vec<Grid<f32>> = run
                .disparities
                .iter()
                .map(|d| within(depth_from_disparity(d, focal, baseline), &base))
                .collect();
            let row = CompareRow {
                matcher: matcher.label(),
                window_px: match matcher {
                    OpenCvMatcher::Bm { block } | OpenCvMatcher::Sgbm { block } => block,
                },
                metrics: plane_metrics(&depth, distance, roi, intrinsics),
                match_ms: run.median_ms,
            };
            out.opencv = Some(run.version);
            progress(&row);
            out.rows.push(row);
        }
    }
    Ok(out)
}

/// `depth` with the depths outside `config`'s near–far range dropped (NaN), as our
/// pipeline drops them.
fn within(mut depth: Grid<f32>, config: &StereoConfig) -> Grid<f32> {
    let (near, far) = (config.near_mm as f32, config.far_mm as f32);
    for z in depth.as_mut_slice() {
        if !(near..=far).contains(z) {
            *z = f32::NAN;
        }
    }
    depth
}

/// [`run_comparison`]'s rows as text.
pub fn comparison_table(rows: &[CompareRow]) -> String {
    let mut s = String::from(
        "distance  matcher                       window  Z-accuracy  RMS error  temporal  fill rate  match\n\
         (mm)                                    (px)    (%)         (%)        (%)       (%)        (ms)\n",
    );
    for r in rows {
        s.push_str(&format!(
            "{:>8.0}  {:<30}  {:>5}  {}  {:>5.1}\n",
            r.metrics.distance_mm,
            r.matcher,
            r.window_px,
            measures(&r.metrics),
            r.match_ms
        ));
    }
    s
}

/// The measures' columns of a row (Z-accuracy, RMS error, temporal noise, fill rate).
fn measures(m: &PlaneMetrics) -> String {
    format!(
        "{:>+10.3}  {:>9.3}  {:>8.3}  {:>9.1}",
        m.z_accuracy_pct, m.rms_error_pct, m.temporal_noise_pct, m.fill_rate_pct
    )
}

/// The table as text.
pub fn table(rows: &[EvalRow]) -> String {
    let mut s = String::from(
        "distance  variant   Z-accuracy  RMS error  temporal  fill rate  frame\n\
         (mm)                (%)         (%)        (%)       (%)        (ms)\n",
    );
    for r in rows {
        s.push_str(&format!(
            "{:>8.0}  {:<8}  {}  {:>5.1}\n",
            r.metrics.distance_mm,
            r.variant,
            measures(&r.metrics),
            r.frame_ms
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    const K: Intrinsics = Intrinsics {
        focal_px: 100.0,
        centre: (9.5, 9.5),
    };

    #[test]
    fn metrics_match_hand_computed_values() {
        let roi = Region::central(20, 20, 0.5); // 10×10 at (5, 5)
        assert_eq!((roi.x0, roi.x1, roi.area()), (5, 15, 100));
        // Every pixel 101 mm on a 100 mm target: +1 % accuracy, flat, still, full.
        let flat = Grid::filled(20, 20, 101.0f32);
        let m = plane_metrics(&[flat.clone(), flat.clone()], 100.0, roi, K);
        assert!((m.z_accuracy_pct - 1.0).abs() < 1e-9);
        assert!(m.rms_error_pct.abs() < 1e-6 && m.temporal_noise_pct == 0.0);
        assert_eq!(m.fill_rate_pct, 100.0);

        // ±1 mm checkerboard about 100: the fitted plane is Z ≈ 100, RMS ≈ 1 mm = 1 %
        // (the points sit on rays, so X and Y move a little with Z: hence the tolerance).
        let checker = Grid::from_fn(20, 20, |x, y| if (x + y) % 2 == 0 { 101.0 } else { 99.0 });
        let m = plane_metrics(std::slice::from_ref(&checker), 100.0, roi, K);
        assert!((m.rms_error_pct - 1.0).abs() < 0.01, "{}", m.rms_error_pct);
        assert!(m.z_accuracy_pct.abs() < 1e-9); // median of 50 × +1 and 50 × −1
        assert!(m.temporal_noise_pct.is_nan());

        // Frames at 100 and 102 per pixel: std 1 mm = 1 %; half the ROI missing in one.
        let a = Grid::filled(20, 20, 100.0f32);
        let mut b = Grid::filled(20, 20, 102.0f32);
        for y in 5..10 {
            for x in 5..15 {
                b.set(x, y, f32::NAN);
            }
        }
        let m = plane_metrics(&[a, b], 100.0, roi, K);
        assert!(
            (m.temporal_noise_pct - 1.0).abs() < 1e-9,
            "{}",
            m.temporal_noise_pct
        );
        assert!((m.fill_rate_pct - 75.0).abs() < 1e-9);
        // Errors: 100 × 0 and 50 × +2: the median is 0.
        assert_eq!(m.z_accuracy_pct, 0.0);
    }

    #[test]
    fn a_tilted_plane_has_no_rms_error() {
        // Z = 100 + 0.2·X on the rays of the 20×20 camera.
        let depth = Grid::from_fn(20, 20, |x, _| {
            let a = (x as f64 - K.centre.0) / K.focal_px;
            (100.0 / (1.0 - 0.2 * a)) as f32
        });
        let m = plane_metrics(&[depth], 100.0, Region::central(20, 20, 1.0), K);
        assert!(m.rms_error_pct < 1e-4, "{}", m.rms_error_pct);
        assert!(plane_rms(&[Vector3::zeros(); 2]).is_none());
        let empty = plane_metrics(
            &[Grid::filled(4, 4, f32::NAN)],
            100.0,
            Region::central(4, 4, 1.0),
            K,
        );
        assert!(empty.z_accuracy_pct.is_nan() && empty.fill_rate_pct == 0.0);
    }
}
