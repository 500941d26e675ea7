//! Image files as numpy arrays, read by the library's bounded reader (the CLI's: same
//! decoder, same checks), so Python code and the CLI see the same pixels.

use std::path::PathBuf;

use numpy::PyArray3;
use numpy::ndarray::Array3;
use numpy::{IntoPyArray, PyArray2};
use pyo3::prelude::*;

use stereotac::image_file::ImageFileError;
use stereotac::output::read_grey;

use crate::arrays::grid_array;
use crate::errors::{Kind, error};

fn file_error(e: ImageFileError) -> PyErr {
    let kind = match e {
        ImageFileError::Io { .. } => Kind::Io,
        _ => Kind::BadInput,
    };
    error(kind, e.to_string())
}

/// Reads an 8-bit image file as RGB: uint8 (height, width, 3). Grey, 16-bit and
/// oversized images are refused (as `stereotac reconstruct` refuses them).
#[pyfunction]
pub fn load_rgb(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyArray3<u8>>> {
    let img = py
        .detach(|| stereotac::image_file::read_rgb(&path))
        .map_err(file_error)?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    Ok(Array3::from_shape_vec((h, w, 3), img.into_raw())
        .expect("h × w × 3 values")
        .into_pyarray(py))
}

/// Reads an 8-bit image file as grey: uint8 (height, width); colour is converted with
/// Rec. 709 weights (as `stereotac stereo` converts it).
#[pyfunction]
pub fn load_grey(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyArray2<u8>>> {
    let grid = py.detach(|| read_grey(&path)).map_err(|e| match e {
        stereotac::output::OutputError::Read(e) => file_error(e),
        e => error(Kind::BadInput, e.to_string()),
    })?;
    Ok(grid_array(py, grid))
}
