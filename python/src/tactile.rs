//! Tactile depth from Python: `TactileModel` (load, save, reconstruct), `Reconstructor`
//! (a model with its reference frames, for streams), `TactileResult`, `calibrate`.
//! Every number comes from the library ([`Reconstructor`], [`Summary`], [`calibrate`]);
//! the GIL is released while it works.

use std::path::PathBuf;
use std::sync::Arc;

use image::RgbImage;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use stereotac::tactile::ambient::PhaseFrames;
use stereotac::tactile::calibrate::{self as cal, CalibrationPair, CalibrationSettings};
use stereotac::tactile::camera_curve::{self, CameraCurve};
use stereotac::tactile::model::{ModelKind, TactileModel};
use stereotac::tactile::output::Summary;
use stereotac::tactile::poisson::SolverKind;
use stereotac::tactile::reconstruct::{Reconstruction, Reconstructor};

use crate::arrays::{grid_array, rgb_image_into};
use crate::errors::{bad_input, py_result};

/// A tactile model (from `stereotac calibrate`, or [`calibrate`]): colour to slope, at the
/// frame size and scale it was calibrated at.
#[pyclass(module = "stereotac._stereotac", name = "TactileModel")]
pub struct PyTactileModel {
    model: TactileModel,
    /// The reconstructor without references, kept for `reconstruct` (its solver plans
    /// and buffers are reused), with the settings it was made for.
    cached: Option<(Settings, Reconstructor)>,
    /// Input buffers, reused between calls.
    frames: Frames,
}

/// What a reconstructor is made with: gradient model, solver, and whether the light model
/// reads past the calibration's slopes.
type Settings = (ModelKind, SolverKind, bool);

/// A gradient model kind from its name.
fn model_kind(name: &str) -> PyResult<ModelKind> {
    name.parse()
        .map_err(|e| bad_input(format!("kind={name:?}: {e}")))
}

/// A solver from its name.
fn solver_kind(name: &str) -> PyResult<SolverKind> {
    name.parse()
        .map_err(|e| bad_input(format!("solver={name:?}: {e}")))
}

/// Owned phase frames: dx, dy, and the LEDs-off frame.
#[derive(Default)]
struct Frames {
    dx: RgbImage,
    dy: RgbImage,
    dark: Option<RgbImage>,
    /// The LEDs-off buffer while a pair without one is held.
    spare: Option<RgbImage>,
}

impl Frames {
    fn phase_frames(&self) -> PhaseFrames<'_> {
        PhaseFrames {
            dx: &self.dx,
            dy: &self.dy,
            dark: self.dark.as_ref(),
        }
    }

    fn read(
        what: &str,
        dx: &Bound<'_, PyAny>,
        dy: &Bound<'_, PyAny>,
        dark: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let mut frames = Self::default();
        frames.fill(what, dx, dy, dark)?;
        Ok(frames)
    }

    /// Reads the arrays into these buffers (reused: a stream allocates nothing).
    fn fill(
        &mut self,
        what: &str,
        dx: &Bound<'_, PyAny>,
        dy: &Bound<'_, PyAny>,
        dark: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        rgb_image_into(&format!("{what}dx"), dx, &mut self.dx)?;
        rgb_image_into(&format!("{what}dy"), dy, &mut self.dy)?;
        match dark {
            Some(d) => {
                let mut buffer = self.dark.take().or(self.spare.take()).unwrap_or_default();
                rgb_image_into(&format!("{what}dark"), d, &mut buffer)?;
                self.dark = Some(buffer);
            }
            None => {
                if let Some(buffer) = self.dark.take() {
                    self.spare = Some(buffer);
                }
            }
        }
        Ok(())
    }

    /// `(dx, dy)` or `(dx, dy, dark)`.
    fn from_tuple(what: &str, obj: &Bound<'_, PyAny>) -> PyResult<Self> {
        let items: Vec<Bound<'_, PyAny>> = match obj.cast::<PyTuple>() {
            Ok(t) => t.iter().collect(),
            Err(_) => obj.extract().map_err(|_| {
                bad_input(format!(
                    "{what}: expected a tuple (dx, dy) or (dx, dy, dark) of uint8 \
                     (height, width, 3) arrays"
                ))
            })?,
        };
        match items.as_slice() {
            [dx, dy] => Self::read(&format!("{what}: "), dx, dy, None),
            [dx, dy, dark] => Self::read(&format!("{what}: "), dx, dy, Some(dark)),
            _ => Err(bad_input(format!(
                "{what}: expected (dx, dy) or (dx, dy, dark), got {} item(s)",
                items.len()
            ))),
        }
    }
}

/// Reconstructs `frames` with `rec`, the GIL released, into a Python result.
fn run(py: Python<'_>, rec: &mut Reconstructor, frames: &Frames) -> PyResult<PyTactileResult> {
    let px_per_mm = rec.model().px_per_mm;
    let (r, summary) = py
        .detach(|| {
            rec.reconstruct_frames(frames.phase_frames())
                .and_then(Reconstruction::require_lit)
                .map(|r| {
                    let s = Summary::of(&r, px_per_mm);
                    (r, s)
                })
        })
        .map_err(crate::errors::IntoPyErr::into_py_err)?;
    for note in r.warnings() {
        crate::errors::warn(py, &note)?;
    }
    Ok(PyTactileResult::new(py, r, summary))
}

#[pymethods]
impl PyTactileModel {
    /// Reads a model file (JSON, as `stereotac calibrate` writes it).
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        let model = py_result(TactileModel::load(&path))?;
        Ok(Self::from_model(model))
    }

    /// Writes the model to `path` (JSON).
    fn save(&self, path: PathBuf) -> PyResult<()> {
        py_result(self.model.save(&path))
    }

    /// Frame width the model was calibrated at (px).
    #[getter]
    fn width(&self) -> usize {
        self.model.width
    }

    /// Frame height the model was calibrated at (px).
    #[getter]
    fn height(&self) -> usize {
        self.model.height
    }

    /// Scale (px per mm).
    #[getter]
    fn px_per_mm(&self) -> f64 {
        self.model.px_per_mm
    }

    /// Thickness of the skin (mm): no depth beyond it is accepted.
    #[getter]
    fn skin_thickness_mm(&self) -> f64 {
        self.model.skin_thickness_mm
    }

    /// Depth of one dx/dy pair. `ref`: no-contact frames `(dx, dy)` or `(dx, dy, dark)`
    /// to normalise by (otherwise the model's background); `dark`: the LEDs-off frame
    /// taken with the pair. `past_reach=False` keeps the model's slopes (lookup table or
    /// perceptron) where they reach the calibration's limit (by default the model file's
    /// light model reads steeper walls there). For a stream with reference frames, make a `Reconstructor` once instead
    /// (references are prepared once, buffers reused).
    #[pyo3(signature = (dx, dy, r#ref = None, dark = None, kind = "lut", solver = "dct", past_reach = true))]
    #[allow(clippy::too_many_arguments)]
    fn reconstruct(
        &mut self,
        py: Python<'_>,
        dx: &Bound<'_, PyAny>,
        dy: &Bound<'_, PyAny>,
        r#ref: Option<&Bound<'_, PyAny>>,
        dark: Option<&Bound<'_, PyAny>>,
        kind: &str,
        solver: &str,
        past_reach: bool,
    ) -> PyResult<PyTactileResult> {
        let (kind, solver) = (model_kind(kind)?, solver_kind(solver)?);
        let settings = (kind, solver, past_reach);
        let mut frames = std::mem::take(&mut self.frames);
        let read = frames.fill("", dx, dy, dark);
        self.frames = frames;
        read?;
        if let Some(r) = r#ref {
            let mut rec = self.reconstructor_for(py, Some(r), settings)?;
            return run(py, &mut rec, &self.frames);
        }
        let mut rec = match self.cached.take() {
            Some((cached, rec)) if cached == settings => rec,
            _ => self.reconstructor_for(py, None, settings)?,
        };
        let result = run(py, &mut rec, &self.frames);
        self.cached = Some((settings, rec));
        result
    }

    /// A reconstructor for this model: `ref` (no-contact frames `(dx, dy)` or
    /// `(dx, dy, dark)`) prepared once, solver plans and buffers kept between pairs;
    /// `past_reach` as in `reconstruct`.
    #[pyo3(signature = (r#ref = None, kind = "lut", solver = "dct", past_reach = true))]
    fn reconstructor(
        &self,
        py: Python<'_>,
        r#ref: Option<&Bound<'_, PyAny>>,
        kind: &str,
        solver: &str,
        past_reach: bool,
    ) -> PyResult<PyReconstructor> {
        let (kind, solver) = (model_kind(kind)?, solver_kind(solver)?);
        Ok(PyReconstructor {
            inner: self.reconstructor_for(py, r#ref, (kind, solver, past_reach))?,
            frames: Frames::default(),
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "TactileModel({}x{} px, {} px/mm, skin {} mm)",
            self.model.width, self.model.height, self.model.px_per_mm, self.model.skin_thickness_mm
        )
    }
}

impl PyTactileModel {
    /// The model.
    pub fn model(&self) -> &TactileModel {
        &self.model
    }

    /// Wraps a model (from a recording, for instance).
    pub fn from_model(model: TactileModel) -> Self {
        Self {
            model,
            cached: None,
            frames: Frames::default(),
        }
    }

    fn reconstructor_for(
        &self,
        py: Python<'_>,
        r#ref: Option<&Bound<'_, PyAny>>,
        (kind, solver, past_reach): Settings,
    ) -> PyResult<Reconstructor> {
        let refs = r#ref.map(|r| Frames::from_tuple("ref", r)).transpose()?;
        let model = self.model.clone();
        py_result(py.detach(|| {
            Reconstructor::new(model, kind, solver, refs.as_ref().map(Frames::phase_frames)).map(
                |mut rec| {
                    rec.set_past_reach(past_reach);
                    rec
                },
            )
        }))
    }
}

/// A model with its reference frames, ready for a stream of pairs.
#[pyclass(module = "stereotac._stereotac", name = "Reconstructor")]
pub struct PyReconstructor {
    inner: Reconstructor,
    /// Input buffers, reused between calls.
    frames: Frames,
}

#[pymethods]
impl PyReconstructor {
    /// Depth of one dx/dy pair (`dark`: the LEDs-off frame taken with it).
    #[pyo3(signature = (dx, dy, dark = None))]
    fn reconstruct(
        &mut self,
        py: Python<'_>,
        dx: &Bound<'_, PyAny>,
        dy: &Bound<'_, PyAny>,
        dark: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyTactileResult> {
        self.frames.fill("", dx, dy, dark)?;
        run(py, &mut self.inner, &self.frames)
    }

    /// For the overhead benchmark (`python/bench/overhead.py`): the mean milliseconds of
    /// what a Rust caller does per pair (reconstruct, check, summarise) over `repeats`
    /// calls, the frames converted once, outside the timing.
    #[pyo3(signature = (dx, dy, dark = None, repeats = 100))]
    fn _library_ms(
        &mut self,
        py: Python<'_>,
        dx: &Bound<'_, PyAny>,
        dy: &Bound<'_, PyAny>,
        dark: Option<&Bound<'_, PyAny>>,
        repeats: usize,
    ) -> PyResult<f64> {
        let frames = Frames::read("", dx, dy, dark)?;
        let rec = &mut self.inner;
        let px_per_mm = rec.model().px_per_mm;
        let repeats = repeats.max(1);
        py_result(py.detach(|| {
            let start = std::time::Instant::now();
            // The last result is kept while the next is made, as a caller that stores
            // results does (and as a Python loop does).
            let mut last = None;
            for _ in 0..repeats {
                let r = rec
                    .reconstruct_frames(frames.phase_frames())
                    .and_then(Reconstruction::require_lit)?;
                let summary = Summary::of(&r, px_per_mm);
                last = Some(std::hint::black_box((r, summary)));
            }
            drop(last);
            Ok::<_, stereotac::tactile::reconstruct::ReconstructError>(
                start.elapsed().as_secs_f64() * 1e3 / repeats as f64,
            )
        }))
    }
}

/// The depth of one pair and the numbers about it.
#[pyclass(module = "stereotac._stereotac", name = "TactileResult", frozen)]
pub struct PyTactileResult {
    /// Depth (mm, float32, height × width), positive where pressed in, 0 off the imprint.
    #[pyo3(get)]
    depth: Py<numpy::PyArray2<f32>>,
    /// Touched pixels (bool, height × width).
    #[pyo3(get)]
    contact_mask: Py<numpy::PyArray2<bool>>,
    /// Something touches the skin.
    #[pyo3(get)]
    contact: bool,
    /// Imprint area (mm²): pixels deeper than 0.01 mm.
    #[pyo3(get)]
    area_mm2: f64,
    /// Depth-weighted centroid (mm from the top-left corner), `None` without contact.
    #[pyo3(get)]
    centroid_mm: Option<(f64, f64)>,
    /// Deepest point (mm).
    #[pyo3(get)]
    max_depth_mm: f32,
    /// Where it is (x, y in px).
    #[pyo3(get)]
    max_depth_at_px: (usize, usize),
    /// Displaced volume (mm³).
    #[pyo3(get)]
    volume_mm3: f64,
    /// Regions integrated, as (x, y, width, height) in px.
    #[pyo3(get)]
    regions: Vec<(usize, usize, usize, usize)>,
    /// Which ambient light was removed (`colour-filter`, `dark-frame`, `calibration`, …).
    #[pyo3(get)]
    ambient: String,
    /// Slopes the sanitiser replaced or clamped.
    #[pyo3(get)]
    sanitized_slopes: usize,
    /// Touched pixels the light model read past the calibration's slopes.
    #[pyo3(get)]
    past_reach_pixels: usize,
    /// The largest share of a region's slopes its solved surface does not explain; above
    /// `MAX_UNEXPLAINED` (0.15) they are not one surface's and the depth is not reliable.
    #[pyo3(get)]
    unexplained_share: f32,
    /// Live results: when the pair's second (dy) exposure ended, host µs; `None` offline.
    #[pyo3(get)]
    timestamp_us: Option<f64>,
    /// Live results: the record `stereotac run --jsonl` prints for this pair (sequence,
    /// exposure ends, latency, frames dropped, …) as a dict; `None` offline.
    #[pyo3(get)]
    record: Option<Py<PyAny>>,
    summary: Summary,
}

impl PyTactileResult {
    /// A live result: with its record and the time its exposures ended.
    pub fn live(
        py: Python<'_>,
        r: Reconstruction,
        s: Summary,
        record: &stereotac::recording::messages::TactileRecord,
    ) -> PyResult<Self> {
        let mut out = Self::new(py, r, s);
        out.timestamp_us = Some(record.exposure_end_us[1]);
        out.record = Some(crate::json::to_python(py, record)?);
        Ok(out)
    }

    fn new(py: Python<'_>, r: Reconstruction, s: Summary) -> Self {
        Self {
            depth: grid_array(py, Arc::unwrap_or_clone(r.depth_mm)).unbind(),
            contact_mask: grid_array(py, Arc::unwrap_or_clone(r.contact_mask)).unbind(),
            contact: !s.no_contact,
            area_mm2: s.contact_area_mm2,
            centroid_mm: s.centroid_mm.map(|[x, y]| (x, y)),
            max_depth_mm: s.max_depth_mm,
            max_depth_at_px: (s.max_depth_at_px[0], s.max_depth_at_px[1]),
            volume_mm3: s.volume_mm3,
            regions: s
                .regions
                .iter()
                .map(|r| (r.x, r.y, r.width, r.height))
                .collect(),
            ambient: r.ambient.name().to_string(),
            sanitized_slopes: s.sanitized_slopes,
            past_reach_pixels: s.past_reach_pixels,
            unexplained_share: s.unexplained_share,
            timestamp_us: None,
            record: None,
            summary: s,
        }
    }
}

#[pymethods]
impl PyTactileResult {
    /// Milliseconds per stage: detect, colour, model, solve, total.
    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = &self.summary.timings;
        let d = PyDict::new(py);
        for (k, v) in [
            ("detect_ms", t.detect_ms),
            ("colour_ms", t.colour_ms),
            ("model_ms", t.model_ms),
            ("solve_ms", t.solve_ms),
            ("total_ms", t.total_ms),
        ] {
            d.set_item(k, v)?;
        }
        Ok(d)
    }

    /// The summary as JSON text (what `stereotac reconstruct --json` prints).
    fn summary_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.summary).map_err(|e| bad_input(e.to_string()))
    }

    fn __repr__(&self) -> String {
        if self.contact {
            format!(
                "TactileResult(contact, max depth {:.3} mm, area {:.1} mm², volume {:.2} mm³, {:.2} ms)",
                self.max_depth_mm, self.area_mm2, self.volume_mm3, self.summary.timings.total_ms
            )
        } else {
            format!(
                "TactileResult(no contact, {:.2} ms)",
                self.summary.timings.total_ms
            )
        }
    }
}

/// Calibrates a model from ball presses: `presses` a list of `(dx, dy)` or
/// `(dx, dy, dark)` uint8 (height, width, 3) arrays; `ref` the no-contact frames;
/// `press_balls_mm` the ball of each press (mm) when they were made with more than one
/// (presses of a smaller ball teach the steep walls a larger one cannot make), else
/// every press is `ball_diameter_mm`'s; `single_colour_dx` a `(blue_only, red_only)`
/// pair of no-contact dx frames taken like `ref`'s but with only the blue strip (1) lit
/// and only the red strip (3) lit: the camera's colour crosstalk is then measured and
/// undone (needs `ref`); `side_light` measures the strips' side light (strips of finite
/// length light a pixel near their ends from the side too) and teaches and reads the
/// lookup table with it taken out (off by default, as `stereotac calibrate --side-light`);
/// `all_lit` a no-contact frame with all four strips lit, taken like `ref`'s (which must
/// then hold its LEDs-off frame): the camera's response curve is measured (light adds up
/// where the camera is linear) and undone on every frame, as `stereotac calibrate
/// --all-lit`.
/// Returns the model and the report (a dict: presses used, presses set aside with
/// reasons, fit per region, coverage, warnings), as `stereotac calibrate --report` writes.
#[pyfunction]
#[pyo3(signature = (presses, ball_diameter_mm, px_per_mm = 15.0, r#ref = None, skin_thickness_mm = 3.0, min_presses = 5, press_balls_mm = None, single_colour_dx = None, side_light = false, all_lit = None))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments, one per setting
pub fn calibrate<'py>(
    py: Python<'py>,
    presses: &Bound<'py, PyAny>,
    ball_diameter_mm: f64,
    px_per_mm: f64,
    r#ref: Option<&Bound<'py, PyAny>>,
    skin_thickness_mm: f64,
    min_presses: usize,
    press_balls_mm: Option<Vec<f64>>,
    single_colour_dx: Option<(Bound<'py, PyAny>, Bound<'py, PyAny>)>,
    side_light: bool,
    all_lit: Option<Bound<'py, PyAny>>,
) -> PyResult<(PyTactileModel, Bound<'py, PyAny>)> {
    let items: Vec<Bound<'py, PyAny>> = presses.try_iter()?.collect::<PyResult<_>>()?;
    if let Some(balls) = press_balls_mm.as_ref().filter(|b| b.len() != items.len()) {
        return Err(crate::errors::bad_input(format!(
            "press_balls_mm has {} diameters for {} presses: give one per press",
            balls.len(),
            items.len()
        )));
    }
    let pairs = items
        .iter()
        .enumerate()
        .map(|(i, item)| {
            let f = Frames::from_tuple(&format!("presses[{i}]"), item)?;
            Ok(CalibrationPair {
                name: format!("press{i:03}"),
                dx: f.dx,
                dy: f.dy,
                dark: f.dark,
                ball_diameter_mm: press_balls_mm.as_ref().map(|b| b[i]),
            })
        })
        .collect::<PyResult<Vec<_>>>()?;
    let refs = r#ref.map(|r| Frames::from_tuple("ref", r)).transpose()?;
    let mut settings = CalibrationSettings {
        ball_diameter_mm,
        px_per_mm,
        skin_thickness_mm,
        min_presses,
        side_light,
        ..Default::default()
    };
    if let Some(all) = &all_lit {
        let (reference, dark) = match refs.as_ref().map(|r| (r, r.dark.as_ref())) {
            Some((r, Some(dark))) => (r, dark),
            _ => {
                return Err(bad_input(
                    "all_lit is measured beside the no-contact frames and their LEDs-off \
                     frame: give ref as (dx, dy, dark) too"
                        .to_string(),
                ));
            }
        };
        let all = crate::arrays::rgb_image("all_lit", all)?;
        settings.camera_curve = CameraCurve::measure(&all, &reference.dx, &reference.dy, dark)
            .map_err(|e| bad_input(format!("all_lit: {e}")))?;
    }
    // The crosstalk is measured on linear light, as the model reads it.
    let curve = settings.camera_curve;
    let linear = |image| camera_curve::undone(curve.as_ref(), image);
    if let Some((blue, red)) = &single_colour_dx {
        let reference = refs.as_ref().ok_or_else(|| {
            bad_input(
                "single_colour_dx is measured beside the no-contact frames: give ref too"
                    .to_string(),
            )
        })?;
        let (blue, red) = (
            crate::arrays::rgb_image("single_colour_dx[0]", blue)?,
            crate::arrays::rgb_image("single_colour_dx[1]", red)?,
        );
        settings.filter.unmix = stereotac::tactile::crosstalk::measure(
            &linear(reference.dx.clone()),
            &linear(blue),
            &linear(red),
        )
        .map_err(|e| bad_input(format!("single_colour_dx: {e}")))?;
    }
    let result = py.detach(|| {
        cal::calibrate(
            &pairs,
            refs.as_ref().map(Frames::phase_frames),
            &settings,
            |_| {},
        )
    });
    let calibration = py_result(result)?;
    let report = crate::json::value_to_python(py, &calibration.report_json())?.into_bound(py);
    Ok((PyTactileModel::from_model(calibration.model), report))
}
