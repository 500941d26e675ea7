//! Rust errors as Python exceptions. The classes live in `stereotac/_errors.py` so each
//! can also be a built-in kind (`BadInputError` is a `ValueError`, `IoError` an
//! `OSError`): `except ValueError` catches bad input as Python code expects.

use pyo3::prelude::*;
use pyo3::types::PyType;

use stereotac::stereo::calibration::CalibError;
use stereotac::stereo::pipeline::StereoError;
use stereotac::tactile::calibrate::CalibrationError;
use stereotac::tactile::model::ModelError;
use stereotac::tactile::reconstruct::ReconstructError;

/// Which exception class an error becomes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Inputs that cannot be right (`stereotac.BadInputError`, a `ValueError`).
    BadInput,
    /// Files that could not be read or written (`stereotac.IoError`, an `OSError`).
    Io,
    /// The sensor could not be reached, or answered wrongly (`stereotac.DeviceError`).
    Device,
}

impl Kind {
    fn class_name(self) -> &'static str {
        match self {
            Kind::BadInput => "BadInputError",
            Kind::Io => "IoError",
            Kind::Device => "DeviceError",
        }
    }
}

/// A Python exception of `kind` with `message`.
pub fn error(kind: Kind, message: impl Into<String>) -> PyErr {
    let message = message.into();
    Python::attach(|py| {
        let class = py
            .import("stereotac._errors")
            .and_then(|m| m.getattr(kind.class_name()))
            .and_then(|c| c.cast_into::<PyType>().map_err(PyErr::from));
        match class {
            Ok(class) => PyErr::from_type(class, message),
            // The package's own module is missing: say so, with the message.
            Err(e) => pyo3::exceptions::PyRuntimeError::new_err(format!(
                "{message} (and stereotac._errors could not be imported: {e})"
            )),
        }
    })
}

/// `BadInputError(message)`.
pub fn bad_input(message: impl Into<String>) -> PyErr {
    error(Kind::BadInput, message)
}

/// Library errors with their kind.
pub trait IntoPyErr {
    /// The Python exception for this error.
    fn into_py_err(self) -> PyErr;
}

impl IntoPyErr for ModelError {
    fn into_py_err(self) -> PyErr {
        let kind = match self {
            ModelError::Io { .. } => Kind::Io,
            _ => Kind::BadInput,
        };
        error(kind, self.to_string())
    }
}

impl IntoPyErr for ReconstructError {
    fn into_py_err(self) -> PyErr {
        bad_input(self.to_string())
    }
}

impl IntoPyErr for CalibrationError {
    fn into_py_err(self) -> PyErr {
        bad_input(self.to_string())
    }
}

impl IntoPyErr for StereoError {
    fn into_py_err(self) -> PyErr {
        bad_input(self.to_string())
    }
}

impl IntoPyErr for CalibError {
    fn into_py_err(self) -> PyErr {
        let kind = match self {
            CalibError::Read { .. } => Kind::Io,
            _ => Kind::BadInput,
        };
        error(kind, self.to_string())
    }
}

/// `result` with its error as the Python exception of its kind.
pub fn py_result<T, E: IntoPyErr>(result: Result<T, E>) -> PyResult<T> {
    result.map_err(IntoPyErr::into_py_err)
}

/// A `UserWarning` with `message` (what the CLI prints as `warning: …`).
pub fn warn(py: Python<'_>, message: &str) -> PyResult<()> {
    let text = std::ffi::CString::new(message.replace('\0', " ")).unwrap_or_default();
    PyErr::warn(
        py,
        &py.get_type::<pyo3::exceptions::PyUserWarning>(),
        &text,
        1,
    )
}
