//! Stereo depth from Python: `StereoRig` (a calibration and the pipeline built for it)
//! and `StereoResult`. The pipeline is the library's [`StereoPipeline`], configured as
//! `stereotac stereo` configures it; the GIL is released while it works.

use std::path::PathBuf;

use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use stereotac::grid::Grid;
use stereotac::stereo::calibration::{LengthUnit, StereoCalibration};
use stereotac::stereo::matcher::MatcherKind;
use stereotac::stereo::outliers::OutlierParams;
use stereotac::stereo::pipeline::{StereoConfig, StereoFrame, StereoPipeline, StereoTimings};
use stereotac::stereo::postfilter::HoleFill;
use stereotac::stereo::sgm::{Paths, SgmParams};

use crate::arrays::{grey_grid, grey_grid_into, grid_array, rows_array, vec_array};
use crate::errors::{bad_input, py_result};

/// A calibrated camera pair with its rectification maps and matcher.
#[pyclass(module = "stereotac._stereotac", name = "StereoRig")]
pub struct PyStereoRig {
    pipeline: StereoPipeline,
    config: StereoConfig,
    /// Input buffers, reused between calls.
    inputs: (Grid<u8>, Grid<u8>),
}

/// The calibration files `source` names: one path (OpenCV stereo YAML) or a pair of
/// paths (ROS camera_info YAML, left then right).
fn calibration_files(source: &Bound<'_, PyAny>) -> PyResult<Vec<PathBuf>> {
    if let Ok(t) = source.cast::<PyTuple>() {
        return t
            .iter()
            .map(|p| p.extract::<PathBuf>())
            .collect::<PyResult<Vec<_>>>()
            .map_err(|_| bad_input("StereoRig.load: a tuple of paths (left, right) expected"));
    }
    // A list of paths (pyo3 does not take a str for a Vec).
    if let Ok(list) = source.extract::<Vec<PathBuf>>() {
        return Ok(list);
    }
    source.extract::<PathBuf>().map(|p| vec![p]).map_err(|_| {
        bad_input(
            "StereoRig.load: expected a path (OpenCV stereo YAML) or a pair of paths (ROS \
             camera_info YAML, left then right)",
        )
    })
}

#[pymethods]
impl PyStereoRig {
    /// Reads a calibration: one OpenCV stereo YAML (`units`: the unit of its `T`, "mm"
    /// or "m"), or a pair of ROS camera_info YAML files (always metres), and builds the
    /// pipeline: depths searched from `near_mm` to `far_mm`, matcher "bm" (block
    /// matching) or "sgm" (semi-global), the spatial filter on, holes up to `fill_holes`
    /// px filled, outliers removed when `outliers` is true (the defaults of
    /// `stereotac stereo`); `block_size` is the matching window's side (odd: block
    /// matching's blocks, semi-global matching's refinement window; 9 for `bm`, 11 for
    /// `sgm` when not given); `sgm_paths` (3, 4, 5 or 8; 8 when not given) are the paths
    /// semi-global matching aggregates along, refused with block matching (they would be
    /// ignored). Keys of a file that its format does not have are warned about.
    #[staticmethod]
    #[pyo3(signature = (source, units = "mm", matcher = "bm", near_mm = None, far_mm = None, scale = None, block_size = None, spatial = true, fill_holes = 0, outliers = false, sgm_paths = None))]
    #[allow(clippy::too_many_arguments)]
    fn load(
        py: Python<'_>,
        source: &Bound<'_, PyAny>,
        units: &str,
        matcher: &str,
        near_mm: Option<f64>,
        far_mm: Option<f64>,
        scale: Option<f64>,
        block_size: Option<u32>,
        spatial: bool,
        fill_holes: usize,
        outliers: bool,
        sgm_paths: Option<u32>,
    ) -> PyResult<Self> {
        let files = calibration_files(source)?;
        let unit: LengthUnit = units
            .parse()
            .map_err(|e| bad_input(format!("units={units:?}: {e}")))?;
        let matcher: MatcherKind = matcher.parse().map_err(bad_input)?;
        let sgm_paths = match sgm_paths {
            Some(_) if matcher != MatcherKind::Sgm => {
                return Err(bad_input(
                    "sgm_paths sets semi-global matching's paths: add matcher=\"sgm\"",
                ));
            }
            None => SgmParams::default().paths,
            Some(n) => Paths::with_count(n as usize).ok_or_else(|| {
                bad_input(format!(
                    "sgm_paths={n}: 3, 4, 5 or 8 (8: every direction, the default; 3: along the \
                     row both ways and down, the fastest)"
                ))
            })?,
        };
        let (calib, notes) = py_result(StereoCalibration::load_noting(&files, unit))?;
        for note in notes {
            crate::errors::warn(py, &note)?;
        }
        let d = StereoConfig::default();
        let config = StereoConfig {
            near_mm: near_mm.unwrap_or(d.near_mm),
            far_mm: far_mm.unwrap_or(d.far_mm),
            rectify_scale: scale.unwrap_or(d.rectify_scale),
            block_size,
            matcher,
            sgm_paths,
            spatial: if spatial { d.spatial } else { None },
            hole_fill: (fill_holes > 0).then_some(HoleFill {
                max_width: fill_holes,
            }),
            outliers: outliers.then(OutlierParams::default),
            ..d
        };
        let pipeline = py_result(py.detach(|| StereoPipeline::new(&calib, config)))?;
        Ok(Self {
            pipeline,
            config,
            inputs: (Grid::filled(0, 0, 0), Grid::filled(0, 0, 0)),
        })
    }

    /// Depth of one raw (unrectified) pair: uint8 arrays (height, width) grey or
    /// (height, width, 3) RGB, the calibration's size.
    fn compute(
        &mut self,
        py: Python<'_>,
        left: &Bound<'_, PyAny>,
        right: &Bound<'_, PyAny>,
    ) -> PyResult<PyStereoResult> {
        grey_grid_into("left", left, &mut self.inputs.0)?;
        grey_grid_into("right", right, &mut self.inputs.1)?;
        let (pipeline, (left, right)) = (&mut self.pipeline, &self.inputs);
        let frame = py_result(py.detach(|| pipeline.process(left, right)))?;
        let warnings = frame.warnings(&self.config);
        Ok(PyStereoResult::new(py, frame, warnings))
    }

    /// For the overhead benchmark (`python/bench/overhead.py`): the mean milliseconds of
    /// what a Rust caller does per pair (process, warnings) over `repeats` calls, the
    /// frames converted once, outside the timing.
    #[pyo3(signature = (left, right, repeats = 20))]
    fn _library_ms(
        &mut self,
        py: Python<'_>,
        left: &Bound<'_, PyAny>,
        right: &Bound<'_, PyAny>,
        repeats: usize,
    ) -> PyResult<f64> {
        let (left, right) = (grey_grid("left", left)?, grey_grid("right", right)?);
        let (pipeline, config) = (&mut self.pipeline, &self.config);
        let repeats = repeats.max(1);
        py_result(py.detach(|| {
            let start = std::time::Instant::now();
            // The last result is kept while the next is made, as a caller that stores
            // results does (and as a Python loop does).
            let mut last = None;
            for _ in 0..repeats {
                let frame = pipeline.process(&left, &right)?;
                let warnings = frame.warnings(config);
                last = Some(std::hint::black_box((frame, warnings)));
            }
            drop(last);
            Ok::<_, stereotac::stereo::pipeline::StereoError>(
                start.elapsed().as_secs_f64() * 1e3 / repeats as f64,
            )
        }))
    }

    /// Rectified focal length (px).
    #[getter]
    fn focal_px(&self) -> f64 {
        self.pipeline.rectification().focal()
    }

    /// Baseline (mm).
    #[getter]
    fn baseline_mm(&self) -> f64 {
        self.pipeline.rectification().baseline()
    }

    /// Paths semi-global matching aggregates along (None with block matching).
    #[getter]
    fn sgm_paths(&self) -> Option<usize> {
        self.pipeline.matcher().sgm_paths().map(Paths::count)
    }

    /// Side of the matching window (px): block matching's blocks, semi-global matching's
    /// refinement window (`block_size`, or 9 for `bm` and 11 for `sgm`).
    #[getter]
    fn window_px(&self) -> u32 {
        self.pipeline.matcher().window()
    }

    /// Disparities searched (px), first and last.
    #[getter]
    fn disparity_range_px(&self) -> (i64, i64) {
        let (lo, hi) = self.pipeline.matcher().disparity_range();
        (lo as i64, hi as i64)
    }

    fn __repr__(&self) -> String {
        let r = self.pipeline.rectification();
        format!(
            "StereoRig({}x{} rectified, f {:.1} px, baseline {:.2} mm, {:?}, {}..{} mm)",
            r.width,
            r.height,
            r.focal(),
            r.baseline(),
            self.config.matcher,
            self.config.near_mm,
            self.config.far_mm
        )
    }
}

/// The depth of one stereo pair.
#[pyclass(module = "stereotac._stereotac", name = "StereoResult", frozen)]
pub struct PyStereoResult {
    /// Disparity (px, float32, rectified height × width; NaN where none).
    #[pyo3(get)]
    disparity: Py<PyArray2<f32>>,
    /// Depth along the rectified optical axis (mm, float32; NaN where none).
    #[pyo3(get)]
    depth: Py<PyArray2<f32>>,
    /// Points (mm, float32, N × 3) in the rectified left camera's frame: X right, Y down,
    /// Z forward.
    #[pyo3(get)]
    points: Py<PyArray2<f32>>,
    /// Each point's pixel in the rectified views (row-major index, uint32, N).
    #[pyo3(get)]
    pixels: Py<PyArray1<u32>>,
    /// The rectified left view (uint8).
    #[pyo3(get)]
    left_rect: Py<PyArray2<u8>>,
    /// The rectified right view (uint8).
    #[pyo3(get)]
    right_rect: Py<PyArray2<u8>>,
    /// Share of pixels with a depth.
    #[pyo3(get)]
    fill_rate: f64,
    /// What to look at twice (almost nothing matched, a scene outside the range searched).
    #[pyo3(get)]
    warnings: Vec<String>,
    /// Live results: when the left exposure ended, host µs; `None` offline.
    #[pyo3(get)]
    timestamp_us: Option<f64>,
    /// Live results: the frame's summary record (sequence, fill, median depth, latency,
    /// frames dropped, …) as a dict; `None` offline.
    #[pyo3(get)]
    record: Option<Py<PyAny>>,
    timings: StereoTimings,
}

impl PyStereoResult {
    /// A live result: with its record and the time its left exposure ended.
    pub fn live(
        py: Python<'_>,
        frame: StereoFrame,
        record: &stereotac::recording::messages::StereoRecord,
    ) -> PyResult<Self> {
        let mut out = Self::new(py, frame, record.warnings.clone());
        out.timestamp_us = Some(record.exposure_end_us);
        out.record = Some(crate::json::to_python(py, record)?);
        Ok(out)
    }

    fn new(py: Python<'_>, frame: StereoFrame, warnings: Vec<String>) -> Self {
        let StereoFrame {
            left,
            right,
            disparity,
            depth_mm,
            cloud,
            timings,
            ..
        } = frame;
        let pixels_total = (depth_mm.width() * depth_mm.height()).max(1);
        // One point per pixel with a depth.
        let valid = cloud.len();
        Self {
            disparity: grid_array(py, disparity).unbind(),
            depth: grid_array(py, depth_mm).unbind(),
            points: rows_array(py, cloud.points).unbind(),
            pixels: vec_array(py, cloud.pixels).unbind(),
            left_rect: grid_array(py, left).unbind(),
            right_rect: grid_array(py, right).unbind(),
            fill_rate: valid as f64 / pixels_total as f64,
            warnings,
            timestamp_us: None,
            record: None,
            timings,
        }
    }
}

#[pymethods]
impl PyStereoResult {
    /// Each point's grey value in the rectified left view, as RGB (uint8, N × 3); made
    /// when asked for.
    #[getter]
    fn colors<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<u8>>> {
        let left = self.left_rect.bind(py).readonly();
        let left = left.as_slice()?;
        let pixels = self.pixels.bind(py).readonly();
        // `pixels` is a writable array: an index out of the view is refused, not a panic.
        let colors = pixels
            .as_slice()?
            .iter()
            .map(|&i| left.get(i as usize).map(|&g| [g; 3]))
            .collect::<Option<Vec<[u8; 3]>>>()
            .ok_or_else(|| {
                bad_input("StereoResult.pixels was changed: an index lies outside the view")
            })?;
        Ok(rows_array(py, colors))
    }

    /// Milliseconds per stage: rectify, match, filter, reproject, outliers, total.
    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = &self.timings;
        let d = PyDict::new(py);
        for (k, v) in [
            ("rectify_ms", t.rectify_ms),
            ("match_ms", t.match_ms),
            ("filter_ms", t.filter_ms),
            ("reproject_ms", t.reproject_ms),
            ("outliers_ms", t.outliers_ms),
            ("total_ms", t.total_ms),
        ] {
            d.set_item(k, v)?;
        }
        Ok(d)
    }

    fn __repr__(&self) -> String {
        format!(
            "StereoResult({:.1} % filled, {} warning(s), {:.1} ms)",
            100.0 * self.fill_rate,
            self.warnings.len(),
            self.timings.total_ms
        )
    }
}
