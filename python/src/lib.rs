//! `stereotac._stereotac`: the native part of the `stereotac` Python package, a thin
//! layer over the host library (no logic of its own): numpy arrays in and out, library
//! errors as Python exceptions, the GIL released while the library works.

mod arrays;
mod errors;
mod files;
mod json;
mod recording;
mod sensor;
mod stereo;
mod tactile;

use pyo3::prelude::*;

/// The native module; `stereotac/__init__.py` re-exports what users need.
#[pymodule]
fn _stereotac(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<tactile::PyTactileModel>()?;
    m.add_class::<tactile::PyReconstructor>()?;
    m.add_class::<tactile::PyTactileResult>()?;
    m.add_function(wrap_pyfunction!(tactile::calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(files::load_rgb, m)?)?;
    m.add_function(wrap_pyfunction!(files::load_grey, m)?)?;
    m.add_class::<stereo::PyStereoRig>()?;
    m.add_class::<stereo::PyStereoResult>()?;
    m.add_class::<recording::PyRecording>()?;
    m.add_class::<recording::PyRecordingItems>()?;
    m.add_class::<recording::PyFrame>()?;
    m.add_class::<recording::PyMessage>()?;
    m.add_class::<sensor::PySensor>()?;
    m.add_class::<sensor::PyEvents>()?;
    m.add_class::<sensor::PyLiveRun>()?;
    Ok(())
}
