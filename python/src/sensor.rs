//! The sensor from Python: `Sensor(sim=..., serial=...)` as a context manager, its
//! identity and settings, its LED phase events on the host clock, and `run`: the live
//! pipeline of `stereotac run` (the library's [`runner::run`]: cameras labelled by LED
//! phase, tactile and stereo stages on their threads) yielding frames and results as
//! they come. The loop runs on its own thread; the Python iterator takes its items
//! from a bounded queue with the GIL released.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use pyo3::prelude::*;

use stereotac::describe;
use stereotac::device::{SensorError, SensorEvent};
use stereotac::frames::capture::{CaptureError, LabelledFrame};
use stereotac::live::cameras::CameraSetup;
use stereotac::live::runner::{self, Hooks, Stopped, Until};
use stereotac::live::session::Session;
use stereotac::live::{
    Output, Pipeline, PipelineError, StereoStage, TactileStage, check_ambient, stages_of,
};
use stereotac::matcher::{MatcherConfig, StampRef};
use stereotac::recording::content::RecordedFrame;
use stereotac::recording::messages::{FrameInfo, StereoRecord, TactileRecord};
use stereotac::recording::writer::{Recorder, RecorderOptions, clock_origin_unix_ns};
use stereotac::sensors::{self, OpenedSensor, SensorChoice};
use stereotac::stereo::calibration::{LengthUnit, StereoCalibration};
use stereotac::stereo::pipeline::{StereoConfig, StereoFrame, StereoPipeline};
use stereotac::tactile::model::{ModelKind, TactileModel};
use stereotac::tactile::output::Summary;
use stereotac::tactile::poisson::SolverKind;
use stereotac::tactile::reconstruct::{Reconstruction, Reconstructor};
use stereotac::tactile::synthetic::{BUILTIN_PRESSES, builtin_calibration};
use stereotac_protocol::{Mode, Request};

use crate::errors::{Kind, bad_input, error, py_result};
use crate::recording::PyFrame;
use crate::stereo::PyStereoResult;
use crate::tactile::{PyTactileModel, PyTactileResult};

/// Items the live loop hands on before the caller takes them.
const QUEUE: usize = 16;
/// How long one poll for events waits (s).
const POLL: Duration = Duration::from_millis(20);

fn device_error(e: impl std::fmt::Display) -> PyErr {
    error(Kind::Device, e.to_string())
}

/// A sensor: USB hardware by serial number, or the built-in simulated sensor.
#[pyclass(module = "stereotac._stereotac", name = "Sensor")]
pub struct PySensor {
    /// `None` while a run holds it, and once closed.
    opened: Arc<Mutex<Option<OpenedSensor>>>,
    running: Arc<AtomicBool>,
    /// The stop flag of the last live session.
    run_stop: Mutex<Option<Arc<AtomicBool>>>,
}

impl PySensor {
    /// `true` when no live session holds the sensor. A session told to stop (closed, or
    /// its iterator dropped) ends within a few polls and gives the sensor back: this
    /// waits for that (up to 10 s); a running one gives `false`.
    fn settle(&self, py: Python<'_>) -> bool {
        if !self.running.load(Ordering::SeqCst) {
            return true;
        }
        let stopping = self
            .run_stop
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .as_ref()
            .is_some_and(|f| f.load(Ordering::SeqCst));
        let running = Arc::clone(&self.running);
        stopping
            && py.detach(move || {
                let start = std::time::Instant::now();
                while running.load(Ordering::SeqCst) {
                    if start.elapsed() > Duration::from_secs(10) {
                        return false;
                    }
                    std::thread::sleep(Duration::from_millis(5));
                }
                true
            })
    }

    /// The open sensor, or why it cannot be used now.
    fn with<T>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut OpenedSensor) -> Result<T, SensorError> + Send,
    ) -> PyResult<T>
    where
        T: Send,
    {
        if !self.settle(py) {
            return Err(device_error(
                "the sensor is running a live session (Sensor.run): finish or close it first",
            ));
        }
        let opened = Arc::clone(&self.opened);
        py.detach(move || {
            let mut guard = opened.lock().unwrap_or_else(|p| p.into_inner());
            match guard.as_mut() {
                Some(o) => f(o).map_err(|e| e.to_string()),
                None => Err("the sensor is closed".to_string()),
            }
        })
        .map_err(device_error)
    }
}

/// A sequence mode from its name.
fn mode_named(name: &str) -> PyResult<Mode> {
    describe::mode_named(name).ok_or_else(|| {
        bad_input(format!(
            "mode={name:?}: one of \"gradient\", \"interleaved\", \"vision\", \"contact\", \"off\""
        ))
    })
}

/// A period in ms as µs, checked.
fn period_us(period_ms: u32) -> PyResult<u32> {
    if period_ms == 0 {
        return Err(bad_input("period_ms must be at least 1"));
    }
    Ok(period_ms.saturating_mul(1000))
}

/// A duration in s as µs from `now_us`, checked.
fn deadline(now_us: u64, duration_s: Option<f64>) -> PyResult<Option<u64>> {
    match duration_s {
        None => Ok(None),
        Some(s) if s.is_finite() && s > 0.0 && s <= 1e7 => {
            Ok(Some(now_us.saturating_add((s * 1e6) as u64)))
        }
        Some(s) => Err(bad_input(format!(
            "duration_s={s}: a number of seconds above 0 (at most 1e7), or None for no end"
        ))),
    }
}

#[pymethods]
impl PySensor {
    /// Connects: the simulated sensor (`sim=True`: the firmware's logic behind the real
    /// wire frames, in real time), or a USB sensor (`serial` when several are attached).
    #[new]
    #[pyo3(signature = (sim = false, serial = None))]
    fn new(py: Python<'_>, sim: bool, serial: Option<String>) -> PyResult<Self> {
        if sim && serial.is_some() {
            return Err(bad_input(
                "serial= names a USB sensor: it does not go with sim=True",
            ));
        }
        let choice = SensorChoice {
            serial,
            sim,
            libusb: false,
        };
        let opened = py.detach(|| sensors::open(&choice)).map_err(device_error)?;
        Ok(Self {
            opened: Arc::new(Mutex::new(Some(opened))),
            running: Arc::new(AtomicBool::new(false)),
            run_stop: Mutex::new(None),
        })
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(&self, py: Python<'_>, _args: &Bound<'_, pyo3::types::PyTuple>) -> PyResult<bool> {
        self.close(py)?;
        Ok(false)
    }

    /// Stops a live session and the LED sequence, and disconnects (also at the end of a
    /// `with` block).
    fn close(&self, py: Python<'_>) -> PyResult<()> {
        if let Some(stop) = self
            .run_stop
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .as_ref()
        {
            stop.store(true, Ordering::SeqCst);
        }
        if !self.settle(py) {
            return Err(device_error(
                "the live session did not stop within 10 s; the sensor is left to it",
            ));
        }
        let opened = Arc::clone(&self.opened);
        py.detach(move || {
            let taken = opened.lock().unwrap_or_else(|p| p.into_inner()).take();
            if let Some(mut o) = taken {
                // Best effort: the sensor may already be gone.
                let _ = o.sensor.request(Request::Stop);
            }
        });
        Ok(())
    }

    /// Identity, configuration, counters and clock sync (what `stereotac info --json`
    /// prints), as a dict.
    fn info(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let value = self.with(py, |o| describe::sensor_json(&mut o.sensor))?;
        crate::json::value_to_python(py, &value)
    }

    /// Changes the sequence timing (`stereotac set`): phase period (ms), trigger pulse
    /// (µs), LED settle time (µs). The sensor checks every value before applying any.
    #[pyo3(signature = (period_ms = None, pulse_us = None, settle_us = None))]
    fn set(
        &self,
        py: Python<'_>,
        period_ms: Option<u32>,
        pulse_us: Option<u32>,
        settle_us: Option<u32>,
    ) -> PyResult<()> {
        if period_ms.is_none() && pulse_us.is_none() && settle_us.is_none() {
            return Err(bad_input(
                "nothing to set: give period_ms, pulse_us or settle_us",
            ));
        }
        let period = period_ms.map(period_us).transpose()?;
        self.with(py, move |o| {
            let mut settings = o.sensor.config()?.settings();
            let t = &mut settings.timing;
            t.phase_period_us = period.unwrap_or(t.phase_period_us);
            t.trigger_pulse_us = pulse_us.unwrap_or(t.trigger_pulse_us);
            t.led_settle_us = settle_us.unwrap_or(t.led_settle_us);
            o.sensor.request(Request::Configure(settings)).map(|_| ())
        })
    }

    /// Runs the LED sequence (`mode`, `period_ms`) and yields its events as dicts on the
    /// host clock (what `stereotac stream --json` prints: each phase with its trigger
    /// time, heartbeats, faults), for `duration_s` seconds or until the iterator is
    /// closed; the sequence stops at the end.
    #[pyo3(signature = (mode = "gradient", period_ms = 250, duration_s = None))]
    fn events(
        slf: PyRef<'_, Self>,
        py: Python<'_>,
        mode: &str,
        period_ms: u32,
        duration_s: Option<f64>,
    ) -> PyResult<PyEvents> {
        let (mode, period) = (mode_named(mode)?, period_us(period_ms)?);
        let now = slf.with(py, |o| Ok(o.sensor.clock().now_us()))?;
        let end_us = deadline(now, duration_s)?;
        slf.with(py, move |o| o.sensor.start_sequence(mode, period))?;
        Ok(PyEvents {
            opened: Arc::clone(&slf.opened),
            sensor: slf.into(),
            end_us,
            pending: std::collections::VecDeque::new(),
            done: false,
        })
    }

    /// The live pipeline of `stereotac run`: `cameras` ("sim" or V4L2 paths; camera 0's
    /// dx/dy pairs give tactile depth with `model`, dark frames of cameras 0 and 1
    /// stereo depth with `calib`), in `mode` ("gradient", "interleaved", "vision").
    /// Yields `TactileResult` and `StereoResult` (with `timestamp_us` and `record`) as
    /// they are ready, and each camera `Frame` too with `frames=True`, for `duration_s`
    /// seconds or until the iterator is closed. With the simulated sensor and cameras,
    /// a built-in model (calibrated first, a few seconds) and calibration are used when
    /// none is given. `model`: a path or a `TactileModel`; `calib`: a path or a pair of
    /// paths (ROS), `units` the unit of an OpenCV file's `T`. A model calibrated with
    /// LEDs-off frames is refused in a mode without dark phases unless `static_ambient`
    /// (the ambient light measured at calibration is removed instead). `past_reach=False`
    /// keeps the model's slopes (lookup table or perceptron) where they reach the
    /// calibration's limit (as `TactileModel.reconstruct`).
    #[pyo3(signature = (cameras = vec!["sim".to_string()], mode = "gradient", model = None, calib = None, units = "mm", duration_s = None, period_ms = 250, frames = false, kind = "lut", static_ambient = false, past_reach = true))]
    #[allow(clippy::too_many_arguments)]
    fn run(
        slf: PyRef<'_, Self>,
        py: Python<'_>,
        cameras: Vec<String>,
        mode: &str,
        model: Option<&Bound<'_, PyAny>>,
        calib: Option<&Bound<'_, PyAny>>,
        units: &str,
        duration_s: Option<f64>,
        period_ms: u32,
        frames: bool,
        kind: &str,
        static_ambient: bool,
        past_reach: bool,
    ) -> PyResult<PyLiveRun> {
        let mode = mode_named(mode)?;
        let period = period_us(period_ms)?;
        deadline(0, duration_s)?;
        if !slf.settle(py) {
            return Err(device_error(
                "the sensor is already running a live session: close it first",
            ));
        }
        if slf
            .opened
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .is_none()
        {
            return Err(device_error("the sensor is closed"));
        }
        let kind: ModelKind = kind
            .parse()
            .map_err(|e| bad_input(format!("kind={kind:?}: {e}")))?;
        let setup = CameraSetup {
            cameras,
            ..CameraSetup::default()
        };
        setup.check().map_err(|e| bad_input(e.to_string()))?;
        if setup.cameras.len() > 4 {
            return Err(bad_input(format!(
                "at most 4 cameras ({} given)",
                setup.cameras.len()
            )));
        }
        let (gradients, dark) = stages_of(mode);
        let simulated = setup.cameras.iter().all(|c| c == "sim");
        let sim_sensor = {
            let opened = slf.opened.lock().unwrap_or_else(|p| p.into_inner());
            opened.as_ref().is_some_and(|o| o.timeline.is_some())
        };
        // The stages' inputs, checked before anything runs.
        let tactile = if gradients {
            let (model, references) = match model {
                Some(m) => (model_of(m)?, None),
                None if simulated && sim_sensor => {
                    let optics = setup.sim_optics();
                    let (calibration, refs) = py_result(
                        py.detach(|| builtin_calibration(&optics, BUILTIN_PRESSES, |_| {})),
                    )?;
                    (calibration.model, Some(refs))
                }
                None => {
                    return Err(bad_input(
                        "this mode reconstructs tactile depth: give model= (a path or a \
                         TactileModel); only the simulated sensor and cameras have a \
                         built-in one",
                    ));
                }
            };
            check_ambient(&model, mode, static_ambient).map_err(|e| {
                bad_input(format!(
                    "{e}: use mode=\"interleaved\", a model calibrated without LEDs-off \
                     frames, or static_ambient=True to remove the ambient light measured at \
                     calibration instead (wrong once the room's light changes)"
                ))
            })?;
            Some((model, references))
        } else {
            None
        };
        let stereo = if dark && setup.cameras.len() >= 2 {
            let calib = match calib {
                Some(c) => {
                    let unit: LengthUnit = units
                        .parse()
                        .map_err(|e| bad_input(format!("units={units:?}: {e}")))?;
                    let files = calib_files(c)?;
                    let (calib, notes) = py_result(StereoCalibration::load_noting(&files, unit))?;
                    for note in notes {
                        crate::errors::warn(py, &note)?;
                    }
                    calib
                }
                None => match (sim_sensor, setup.sim_stereo()) {
                    (true, Some(sim)) => sim.calibration(),
                    _ => {
                        return Err(bad_input(
                            "two cameras in this mode give stereo depth: give calib= (an \
                             OpenCV stereo YAML, or a pair of ROS camera_info YAML files)",
                        ));
                    }
                },
            };
            Some(calib)
        } else {
            None
        };
        if tactile.is_none() && stereo.is_none() {
            return Err(bad_input(
                "nothing to do: gradient or interleaved mode gives tactile depth, two \
                 cameras in vision or interleaved mode stereo depth",
            ));
        }
        if slf.running.swap(true, Ordering::SeqCst) {
            return Err(device_error("the sensor is already running a live session"));
        }
        let opened = slf.opened.lock().unwrap_or_else(|p| p.into_inner()).take();
        let Some(opened) = opened else {
            slf.running.store(false, Ordering::SeqCst);
            return Err(device_error("the sensor is closed"));
        };
        let (tx, rx) = sync_channel(QUEUE);
        let stop = Arc::new(AtomicBool::new(false));
        *slf.run_stop.lock().unwrap_or_else(|p| p.into_inner()) = Some(Arc::clone(&stop));
        let job = LiveJob {
            opened,
            settings: LiveSettings {
                setup,
                mode,
                period,
                duration_s,
                tactile: tactile.map(|(m, r)| (m, r, kind, past_reach)),
                stereo,
                frames,
            },
            stop: Arc::clone(&stop),
            home: Arc::clone(&slf.opened),
            running: Arc::clone(&slf.running),
        };
        let thread = std::thread::spawn(move || job.run(tx));
        // Setup errors (a camera that does not open, a model of another size) are raised
        // here, not at the first item.
        let run = PyLiveRun {
            rx: Mutex::new(rx),
            thread: Mutex::new(Some(thread)),
            stop,
        };
        loop {
            let rx = &run.rx;
            let first = py.detach(|| {
                let rx = rx.lock().unwrap_or_else(|p| p.into_inner());
                rx.recv_timeout(Duration::from_millis(100))
            });
            return match first {
                Ok(LiveItem::Ready) => Ok(run),
                Ok(LiveItem::SetupFailed(kind, why)) => {
                    run.finish(py)?;
                    Err(error(kind, why))
                }
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                    // Ctrl-C reaches Python while the cameras open.
                    if let Err(e) = py.check_signals() {
                        run.finish(py)?;
                        return Err(e);
                    }
                    continue;
                }
                _ => {
                    run.finish(py)?;
                    Err(device_error("the live session ended before it started"))
                }
            };
        }
    }

    fn __repr__(&self) -> String {
        let opened = self.opened.lock().unwrap_or_else(|p| p.into_inner());
        match opened.as_ref() {
            Some(o) => format!(
                "Sensor({}{})",
                stereotac::device::serial_number(&o.sensor.info().board_id),
                if o.timeline.is_some() {
                    ", simulated"
                } else {
                    ""
                }
            ),
            None if self.running.load(Ordering::SeqCst) => "Sensor(running)".into(),
            None => "Sensor(closed)".into(),
        }
    }
}

/// A model argument: a path or a `TactileModel`.
fn model_of(obj: &Bound<'_, PyAny>) -> PyResult<TactileModel> {
    if let Ok(m) = obj.cast::<PyTactileModel>() {
        return Ok(m.borrow().model().clone());
    }
    let path: PathBuf = obj
        .extract()
        .map_err(|_| bad_input("model=: a path to a model file, or a TactileModel"))?;
    py_result(TactileModel::load(&path))
}

/// A calibration argument: a path, or a pair of paths.
fn calib_files(obj: &Bound<'_, PyAny>) -> PyResult<Vec<PathBuf>> {
    if let Ok(p) = obj.extract::<PathBuf>() {
        return Ok(vec![p]);
    }
    obj.extract::<Vec<PathBuf>>()
        .map_err(|_| bad_input("calib=: a path (OpenCV stereo YAML) or a pair of paths (ROS)"))
}

/// The events of a running sequence.
#[pyclass(module = "stereotac._stereotac", name = "Events")]
pub struct PyEvents {
    /// The sensor, for stopping the sequence when the iterator is dropped.
    opened: Arc<Mutex<Option<OpenedSensor>>>,
    sensor: Py<PySensor>,
    end_us: Option<u64>,
    pending: std::collections::VecDeque<serde_json::Value>,
    done: bool,
}

#[pymethods]
impl PyEvents {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&mut self, py: Python<'_>) -> PyResult<Option<Py<PyAny>>> {
        loop {
            if let Some(v) = self.pending.pop_front() {
                return crate::json::value_to_python(py, &v).map(Some);
            }
            if self.done {
                return Ok(None);
            }
            let end_us = self.end_us;
            let sensor = self.sensor.borrow(py);
            let (events, ended) = sensor.with(py, move |o| {
                if end_us.is_some_and(|e| o.sensor.clock().now_us() >= e) {
                    o.sensor.request(Request::Stop)?;
                    return Ok((Vec::new(), true));
                }
                let events = o.sensor.poll(POLL)?;
                let lost = o.sensor.counters().link.lost_events;
                Ok((
                    events
                        .iter()
                        .filter_map(|e: &SensorEvent| describe::event_json(e, lost))
                        .collect::<Vec<_>>(),
                    false,
                ))
            })?;
            drop(sensor);
            self.pending.extend(events);
            self.done = ended;
            // Ctrl-C reaches Python between polls.
            py.check_signals()?;
        }
    }

    /// Stops the sequence (also when the events run out, at the end of a `with` block,
    /// and when the iterator is dropped).
    fn close(&mut self, py: Python<'_>) -> PyResult<()> {
        if !self.done {
            self.done = true;
            self.sensor
                .borrow(py)
                .with(py, |o| o.sensor.request(Request::Stop).map(|_| ()))?;
        }
        Ok(())
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(
        &mut self,
        py: Python<'_>,
        _args: &Bound<'_, pyo3::types::PyTuple>,
    ) -> PyResult<bool> {
        self.close(py)?;
        Ok(false)
    }
}

impl Drop for PyEvents {
    fn drop(&mut self) {
        // Left mid-way (a `break`, an exception): the LEDs stop all the same.
        if !self.done
            && let Some(o) = self
                .opened
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .as_mut()
        {
            let _ = o.sensor.request(Request::Stop);
        }
    }
}

/// A tactile model, the no-contact frames it normalises by, the gradient model, and
/// whether the light model reads past the calibration's slopes.
type TactileInputs = (
    TactileModel,
    Option<(image::RgbImage, image::RgbImage)>,
    ModelKind,
    bool,
);

/// What the live thread hands on.
enum LiveItem {
    Ready,
    SetupFailed(Kind, String),
    Frame(Box<RecordedFrame>),
    Tactile(Box<(Reconstruction, Summary, TactileRecord)>),
    Stereo(Box<(StereoFrame, StereoRecord)>),
    Warning(String),
    End(Stopped),
}

/// What the live loop runs.
struct LiveSettings {
    setup: CameraSetup,
    mode: Mode,
    period: u32,
    duration_s: Option<f64>,
    tactile: Option<TactileInputs>,
    stereo: Option<StereoCalibration>,
    frames: bool,
}

/// Everything the live thread needs.
struct LiveJob {
    opened: OpenedSensor,
    settings: LiveSettings,
    stop: Arc<AtomicBool>,
    /// Where the sensor goes back when the loop ends (however it ends), and the flag
    /// that says it is away.
    home: Arc<Mutex<Option<OpenedSensor>>>,
    running: Arc<AtomicBool>,
}

/// The error the hooks report (as text: it ends the run).
#[derive(Debug)]
struct HookError(String);

impl std::fmt::Display for HookError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl From<CaptureError> for HookError {
    fn from(e: CaptureError) -> Self {
        Self(e.to_string())
    }
}

impl From<PipelineError> for HookError {
    fn from(e: PipelineError) -> Self {
        Self(e.to_string())
    }
}

impl From<SensorError> for HookError {
    fn from(e: SensorError) -> Self {
        Self(e.to_string())
    }
}

/// The loop's outputs into the queue; `false` (stop) once the caller is gone.
struct QueueHooks {
    tx: SyncSender<LiveItem>,
    frames: bool,
    stamp_refs: Vec<StampRef>,
    px_per_mm: f64,
    stop: Arc<AtomicBool>,
}

impl QueueHooks {
    /// Queues `item`, waiting while the queue is full unless the session is told to
    /// stop; `false` when it was not queued (stopping, or the caller gone).
    fn put(&self, mut item: LiveItem) -> bool {
        loop {
            match self.tx.try_send(item) {
                Ok(()) => return true,
                Err(std::sync::mpsc::TrySendError::Full(back)) => {
                    if self.stop.load(Ordering::SeqCst) {
                        return false;
                    }
                    item = back;
                    std::thread::sleep(Duration::from_millis(2));
                }
                Err(std::sync::mpsc::TrySendError::Disconnected(_)) => return false,
            }
        }
    }
}

impl Hooks for QueueHooks {
    type Error = HookError;

    fn frame(&mut self, camera: usize, frame: &LabelledFrame) -> Result<(), HookError> {
        if self.frames {
            let stamp_ref = self.stamp_refs[camera];
            let item = RecordedFrame {
                camera,
                info: FrameInfo::new(frame.frame.stamp, stamp_ref, frame.label),
                label: frame.label,
                image: frame.frame.image.clone(),
            };
            // A frame the caller has no room for is dropped (results are not): capture
            // never waits on a slow caller for frames.
            let _ = self.tx.try_send(LiveItem::Frame(Box::new(item)));
        }
        Ok(())
    }

    fn output(&mut self, output: &Output) -> Result<bool, HookError> {
        let item = match output {
            Output::Tactile {
                reconstruction,
                record,
            } => LiveItem::Tactile(Box::new((
                reconstruction.clone(),
                Summary::of(reconstruction, self.px_per_mm),
                record.clone(),
            ))),
            Output::Stereo { frame, record } => {
                LiveItem::Stereo(Box::new(((**frame).clone(), record.clone())))
            }
        };
        Ok(self.put(item))
    }

    fn warning(&mut self, message: String) {
        let _ = self.put(LiveItem::Warning(message));
    }
}

impl LiveJob {
    /// Sets up and runs the loop, then puts the sensor back.
    fn run(self, tx: SyncSender<LiveItem>) {
        let LiveJob {
            mut opened,
            settings,
            stop,
            home,
            running,
        } = self;
        // However this thread ends (a panic included), the sensor is no longer away.
        struct Back(Arc<AtomicBool>);
        impl Drop for Back {
            fn drop(&mut self) {
                self.0.store(false, Ordering::SeqCst);
            }
        }
        let _back = Back(running);
        run_loop(&mut opened, settings, &stop, &tx);
        *home.lock().unwrap_or_else(|p| p.into_inner()) = Some(opened);
    }
}

/// The loop of [`LiveJob::run`]: what it hands on goes to `tx`, the last item
/// [`LiveItem::End`] (or [`LiveItem::SetupFailed`]).
fn run_loop(
    opened: &mut OpenedSensor,
    settings: LiveSettings,
    stop: &Arc<AtomicBool>,
    tx: &SyncSender<LiveItem>,
) {
    let LiveSettings {
        setup,
        mode,
        period,
        duration_s,
        tactile,
        stereo,
        frames,
    } = settings;
    let Prepared {
        mut session,
        mut pipeline,
        recorder,
        stamp_refs,
        px_per_mm,
    } = match prepare(opened, &setup, tactile, stereo) {
        Ok(p) => p,
        Err((kind, why)) => {
            let _ = tx.send(LiveItem::SetupFailed(kind, why));
            return;
        }
    };
    let sensor = &mut opened.sensor;
    if let Err(e) = sensor.start_sequence(mode, period) {
        let _ = tx.send(LiveItem::SetupFailed(
            Kind::Device,
            format!("starting the sequence: {e}"),
        ));
        return;
    }
    let end_us = duration_s.map(|s| sensor.clock().now_us().saturating_add((s * 1e6) as u64));
    if tx.send(LiveItem::Ready).is_err() {
        let _ = sensor.request(Request::Stop);
        return;
    }
    let mut hooks = QueueHooks {
        tx: tx.clone(),
        frames,
        stamp_refs,
        px_per_mm,
        stop: Arc::clone(stop),
    };
    let stopped = runner::run(
        &mut session,
        sensor,
        &recorder,
        &mut pipeline,
        Until { flag: stop, end_us },
        &mut hooks,
    );
    // Through the queue like the results: a caller that stopped reading and closed the
    // session does not keep this thread waiting.
    hooks.put(LiveItem::End(stopped));
}

/// What the loop runs with.
struct Prepared {
    session: Session,
    pipeline: Pipeline,
    recorder: Recorder,
    stamp_refs: Vec<StampRef>,
    px_per_mm: f64,
}

/// Cameras, session, stages and an inactive recorder for the loop.
fn prepare(
    opened: &OpenedSensor,
    setup: &CameraSetup,
    tactile: Option<TactileInputs>,
    stereo: Option<StereoCalibration>,
) -> Result<Prepared, (Kind, String)> {
    let bad = |why: String| (Kind::BadInput, why);
    let sources = setup.open_all(opened).map_err(|e| {
        let kind = match e {
            stereotac::live::cameras::CameraSetupError::Open(_) => Kind::Device,
            _ => Kind::BadInput,
        };
        (kind, e.to_string())
    })?;
    let size_of = |i: usize| sources.get(i).and_then(|s| s.frame_size());
    if let (Some((model, ..)), Some(size)) = (&tactile, size_of(0)) {
        let m = (model.width as u32, model.height as u32);
        if m != size {
            return Err(bad(format!(
                "the tactile model was calibrated at {}×{} but camera 0 gives {}×{} frames",
                m.0, m.1, size.0, size.1
            )));
        }
    }
    if let Some(c) = &stereo {
        for (i, cam) in [&c.left, &c.right].into_iter().enumerate() {
            if let Some(size) = size_of(i).filter(|s| *s != (cam.width, cam.height)) {
                return Err(bad(format!(
                    "the stereo calibration's camera {i} is {}×{} but camera {i} gives {}×{} frames",
                    cam.width, cam.height, size.0, size.1
                )));
            }
        }
    }
    let session = Session::new(
        sources,
        MatcherConfig {
            sync: setup.sync(),
            ..MatcherConfig::default()
        },
    );
    let stamp_refs: Vec<StampRef> = session.captures().iter().map(|c| c.stamp_ref()).collect();
    let mut px_per_mm = 15.0;
    let tactile_stage = match tactile {
        Some((model, references, kind, past_reach)) => {
            px_per_mm = model.px_per_mm;
            let mut rec = Reconstructor::new(
                model,
                kind,
                SolverKind::Dct,
                references.as_ref().map(|(dx, dy)| (dx, dy).into()),
            )
            .map_err(|e| bad(e.to_string()))?;
            rec.set_past_reach(past_reach);
            Some(TactileStage::new(rec, px_per_mm, stamp_refs[0]))
        }
        None => None,
    };
    let stereo_stage = match stereo {
        Some(calib) => {
            let pipeline = StereoPipeline::new(&calib, StereoConfig::default())
                .map_err(|e| bad(format!("setting up the stereo pipeline: {e}")))?;
            Some(StereoStage::new(pipeline, [stamp_refs[0], stamp_refs[1]]))
        }
        None => None,
    };
    let recorder = Recorder::start(RecorderOptions {
        mcap: None,
        live_view: None,
        queue: 64,
        wait_when_full: false,
        clock_origin_unix_ns: clock_origin_unix_ns(opened.sensor.clock().now_us()),
    })
    .map_err(|e| (Kind::Io, e.to_string()))?;
    Ok(Prepared {
        session,
        pipeline: Pipeline::new(tactile_stage, stereo_stage),
        recorder,
        stamp_refs,
        px_per_mm,
    })
}

/// A live session's results, as they come.
#[pyclass(module = "stereotac._stereotac", name = "LiveRun")]
pub struct PyLiveRun {
    rx: Mutex<Receiver<LiveItem>>,
    thread: Mutex<Option<JoinHandle<()>>>,
    stop: Arc<AtomicBool>,
}

impl PyLiveRun {
    /// Stops the loop (if running), waits for it and gives the sensor back.
    fn finish(&self, py: Python<'_>) -> PyResult<()> {
        self.stop.store(true, Ordering::SeqCst);
        let thread = self.thread.lock().unwrap_or_else(|p| p.into_inner()).take();
        let Some(thread) = thread else {
            return Ok(());
        };
        // Drain while waiting: the loop may be blocked on a full queue.
        let rx = &self.rx;
        let joined = py.detach(move || {
            let rx = rx.lock().unwrap_or_else(|p| p.into_inner());
            while !thread.is_finished() {
                let _ = rx.recv_timeout(Duration::from_millis(10));
            }
            thread.join()
        });
        joined.map_err(|_| {
            device_error(
                "the live session's thread failed (a bug: please report it); the sensor is closed",
            )
        })
    }
}

#[pymethods]
impl PyLiveRun {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Option<Py<PyAny>>> {
        loop {
            let rx = &self.rx;
            let item = py.detach(|| {
                let rx = rx.lock().unwrap_or_else(|p| p.into_inner());
                rx.recv_timeout(Duration::from_millis(100))
            });
            let item = match item {
                Ok(item) => item,
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                    // Ctrl-C reaches Python while waiting.
                    if let Err(e) = py.check_signals() {
                        self.finish(py)?;
                        return Err(e);
                    }
                    continue;
                }
                Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                    self.finish(py)?;
                    return Ok(None);
                }
            };
            return match item {
                LiveItem::Frame(f) => Ok(Some(Py::new(py, PyFrame::new(py, *f))?.into_any())),
                LiveItem::Tactile(t) => {
                    let (r, s, record) = *t;
                    let result = PyTactileResult::live(py, r, s, &record)?;
                    Ok(Some(Py::new(py, result)?.into_any()))
                }
                LiveItem::Stereo(s) => {
                    let (frame, record) = *s;
                    let result = PyStereoResult::live(py, frame, &record)?;
                    Ok(Some(Py::new(py, result)?.into_any()))
                }
                LiveItem::Warning(message) => {
                    crate::errors::warn(py, &message)?;
                    continue;
                }
                LiveItem::End(stopped) => {
                    self.finish(py)?;
                    match stopped {
                        Stopped::Failed(why) | Stopped::Recorder(why) => Err(device_error(why)),
                        _ => Ok(None),
                    }
                }
                LiveItem::Ready | LiveItem::SetupFailed(..) => continue,
            };
        }
    }

    /// Stops the live session and gives the sensor back (also when the results run out).
    fn close(&self, py: Python<'_>) -> PyResult<()> {
        self.finish(py)
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(&self, py: Python<'_>, _args: &Bound<'_, pyo3::types::PyTuple>) -> PyResult<bool> {
        self.finish(py)?;
        Ok(false)
    }
}

impl Drop for PyLiveRun {
    fn drop(&mut self) {
        // A run dropped without close: stop the loop; its thread ends on its own and puts
        // the sensor back.
        self.stop.store(true, Ordering::SeqCst);
    }
}
