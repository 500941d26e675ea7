//! Recordings from Python: `Recording(path)` reads an MCAP recording (`stereotac run`,
//! `record`, `process`, the demo) and iterates its frames and messages in file order as
//! numpy arrays and dicts. Reading and decoding are the library's
//! ([`stereotac::recording::content::stream`], [`stereotac::recording::decoded`]).

use std::path::PathBuf;
use std::sync::Mutex;

use numpy::ndarray::Array3;
use numpy::{IntoPyArray, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use stereotac::recording::RecordingError;
use stereotac::recording::content::{Content, ContentStream, RecordedFrame, stream};
use stereotac::recording::decoded::{Decoded, decode};
use stereotac::recording::reader::{Record, RecordingHeader, header};
use stereotac::recording::topics;
use stereotac::tactile::model::TactileModel;

use crate::arrays::{grid_array, rows_array};
use crate::errors::{Kind, bad_input, error, py_result};
use crate::tactile::PyTactileModel;

/// Items read ahead of the caller.
const READ_AHEAD: usize = 8;

fn recording_error(e: RecordingError) -> PyErr {
    let kind = match e {
        RecordingError::Io { .. } => Kind::Io,
        _ => Kind::BadInput,
    };
    error(kind, e.to_string())
}

impl crate::errors::IntoPyErr for RecordingError {
    fn into_py_err(self) -> PyErr {
        recording_error(self)
    }
}

/// An MCAP recording.
#[pyclass(module = "stereotac._stereotac", name = "Recording", frozen)]
pub struct PyRecording {
    path: PathBuf,
    header: RecordingHeader,
}

#[pymethods]
impl PyRecording {
    /// Opens `path` and reads its header (metadata records and attachments; the chunks
    /// are skipped undecompressed).
    #[new]
    fn new(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let header = py_result(py.detach(|| header(&path)))?;
        Ok(Self { path, header })
    }

    /// Metadata records by name (`stereotac`: version, clock origin, mode, cameras;
    /// `sensor`: serial, firmware, board id), each a dict of strings.
    #[getter]
    fn metadata<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (name, entries) in &self.header.metadata {
            d.set_item(name, entries.clone())?;
        }
        Ok(d)
    }

    /// Attachments by name (`tactile_model.json`, `stereo_calibration.yaml`), as bytes.
    #[getter]
    fn attachments<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (name, data) in &self.header.attachments {
            d.set_item(name, PyBytes::new(py, data))?;
        }
        Ok(d)
    }

    /// The tactile model the recording holds (what `process` uses), or `None`.
    fn model(&self) -> PyResult<Option<PyTactileModel>> {
        let Some(bytes) = self.header.attachments.get(topics::MODEL_ATTACHMENT) else {
            return Ok(None);
        };
        let name = format!("{} ({})", self.path.display(), topics::MODEL_ATTACHMENT);
        let model = py_result(TactileModel::from_json(&name, bytes))?;
        Ok(Some(PyTactileModel::from_model(model)))
    }

    /// Every frame and message in file order: `Frame` (camera images with their LED phase
    /// label) and `Message` (depth maps and point clouds in mm as numpy arrays, JSON
    /// messages as dicts, log lines as text).
    fn __iter__(&self) -> PyRecordingItems {
        PyRecordingItems::new(&self.path, false)
    }

    /// The camera frames only, in file order.
    fn frames(&self) -> PyRecordingItems {
        PyRecordingItems::new(&self.path, true)
    }

    fn __repr__(&self) -> String {
        format!("Recording({:?})", self.path.display().to_string())
    }
}

/// An iterator over a recording (one pass).
#[pyclass(module = "stereotac._stereotac", name = "RecordingItems")]
pub struct PyRecordingItems {
    stream: Mutex<ContentStream>,
    frames_only: bool,
    path: PathBuf,
}

impl PyRecordingItems {
    fn new(path: &std::path::Path, frames_only: bool) -> Self {
        Self {
            stream: Mutex::new(stream(path, READ_AHEAD)),
            frames_only,
            path: path.to_path_buf(),
        }
    }
}

#[pymethods]
impl PyRecordingItems {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Option<Py<PyAny>>> {
        loop {
            // The lock is taken with the GIL released (another thread on this iterator
            // may hold it while it waits), and given back before the GIL is taken again.
            let stream = &self.stream;
            let (next, truncated) = py.detach(|| {
                let mut stream = stream.lock().unwrap_or_else(|p| p.into_inner());
                let next = stream.next();
                let truncated = stream.truncated().map(str::to_string);
                (next, truncated)
            });
            let content = match next {
                Some(c) => c.map_err(recording_error)?,
                None => {
                    if let Some(why) = truncated {
                        let message = format!(
                            "{}: the recording was not read whole: {why}",
                            self.path.display()
                        );
                        crate::errors::warn(py, &message)?;
                    }
                    return Ok(None);
                }
            };
            match content {
                Content::Frame(f) => {
                    return Ok(Some(Py::new(py, PyFrame::new(py, f))?.into_any()));
                }
                Content::Other(_) if self.frames_only => continue,
                Content::Other(Record::Message {
                    topic,
                    encoding,
                    log_time_ns,
                    data,
                }) => {
                    let value = decode(&topic, &encoding, &data).map_err(|why| {
                        bad_input(format!(
                            "{}: message on {topic} at log time {log_time_ns} ns: {why}",
                            self.path.display()
                        ))
                    })?;
                    let value = decoded_value(py, value)?;
                    let message = PyMessage {
                        topic,
                        log_time_ns,
                        value,
                    };
                    return Ok(Some(Py::new(py, message)?.into_any()));
                }
                // Metadata and attachments: in `Recording.metadata` / `.attachments`.
                Content::Other(_) => continue,
            }
        }
    }
}

/// A decoded message value as a Python object.
fn decoded_value(py: Python<'_>, value: Decoded) -> PyResult<Py<PyAny>> {
    Ok(match value {
        Decoded::DepthMm(grid) => grid_array(py, grid).into_any().unbind(),
        Decoded::PointsMm(points) => rows_array(py, points).into_any().unbind(),
        Decoded::Json(v) => crate::json::value_to_python(py, &v)?,
        Decoded::Log { level, message } => {
            let d = PyDict::new(py);
            d.set_item("level", level)?;
            d.set_item("message", message)?;
            d.into_any().unbind()
        }
        Decoded::Bytes(b) => PyBytes::new(py, &b).into_any().unbind(),
    })
}

/// A recorded camera frame with its LED phase label.
#[pyclass(module = "stereotac._stereotac", name = "Frame", frozen)]
pub struct PyFrame {
    /// Camera number (0: left / tactile, 1: right).
    #[pyo3(get)]
    camera: usize,
    /// The camera's frame sequence number.
    #[pyo3(get)]
    sequence: u64,
    /// Timestamp, host µs (see `stamp_ref`).
    #[pyo3(get)]
    timestamp_us: f64,
    /// What `timestamp_us` marks: `exposure_start` or `exposure_end`.
    #[pyo3(get)]
    stamp_ref: String,
    /// Exposure time, µs.
    #[pyo3(get)]
    exposure_us: f64,
    /// The matcher's verdict: `phase`, `straddles`, `event_missing`, `no_trigger`,
    /// `unresolved`.
    #[pyo3(get)]
    label: String,
    /// What the strips showed (`dark`, `all`, `dx`, `dy`), for label `phase`.
    #[pyo3(get)]
    phase: Option<String>,
    /// LED phase index, for label `phase`.
    #[pyo3(get)]
    index: Option<u32>,
    /// The trigger that started the exposure (triggered cameras).
    #[pyo3(get)]
    trigger: Option<u32>,
    /// Pixels: uint8 (height, width, 3), RGB.
    #[pyo3(get)]
    image: Py<numpy::PyArray3<u8>>,
}

/// A serialised enum's name (`snake_case`, as recordings write it).
fn name_of(value: &impl serde::Serialize) -> String {
    match serde_json::to_value(value) {
        Ok(serde_json::Value::String(s)) => s,
        Ok(other) => other.to_string(),
        Err(e) => e.to_string(),
    }
}

impl PyFrame {
    /// A frame for Python.
    pub fn new(py: Python<'_>, f: RecordedFrame) -> Self {
        let (w, h) = (f.image.width() as usize, f.image.height() as usize);
        let image = Array3::from_shape_vec((h, w, 3), f.image.into_raw())
            .expect("h × w × 3 values")
            .into_pyarray(py)
            .unbind();
        let info = f.info;
        Self {
            camera: f.camera,
            sequence: info.sequence,
            timestamp_us: info.timestamp_us,
            stamp_ref: name_of(&info.stamp_ref),
            exposure_us: info.exposure_us,
            label: name_of(&info.label),
            phase: info.phase,
            index: info.index,
            trigger: info.trigger,
            image,
        }
    }
}

#[pymethods]
impl PyFrame {
    fn __repr__(&self) -> String {
        let image = Python::attach(|py| format!("{:?}", self.image.bind(py).shape()));
        format!(
            "Frame(camera {}, #{}, {} {}, {:.0} µs, image {image})",
            self.camera,
            self.sequence,
            self.label,
            self.phase.as_deref().unwrap_or("-"),
            self.timestamp_us
        )
    }
}

/// A recorded message, decoded.
#[pyclass(module = "stereotac._stereotac", name = "Message", frozen)]
pub struct PyMessage {
    /// Its topic (see the README's topic table).
    #[pyo3(get)]
    topic: String,
    /// Log time, ns since the Unix epoch (the host clock).
    #[pyo3(get)]
    log_time_ns: u64,
    /// The value: depth (float32 H×W, mm) and points (float32 N×3, mm) as numpy arrays,
    /// JSON messages as dicts, log lines as {"level", "message"}, anything else as bytes.
    #[pyo3(get)]
    value: Py<PyAny>,
}

#[pymethods]
impl PyMessage {
    fn __repr__(&self) -> String {
        format!("Message({}, {} ns)", self.topic, self.log_time_ns)
    }
}
