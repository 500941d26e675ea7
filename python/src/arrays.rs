//! numpy arrays in and out. Inputs are checked (dtype, shape, size) and copied into the
//! library's image types, whatever their strides (a sliced or transposed view is read in
//! its logical order); outputs hand the library's buffers to numpy without a copy.

use image::RgbImage;
use numpy::ndarray::{Array1, Array2, ArrayView2, ArrayView3};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2, PyReadonlyArray3, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use stereotac::grid::Grid;
use stereotac::limits::MAX_FRAME_SIDE;

use crate::errors::bad_input;

/// What `obj` is, for an error message: its dtype and shape when it is an array.
fn describe(obj: &Bound<'_, PyAny>) -> String {
    match (obj.getattr("dtype"), obj.getattr("shape")) {
        (Ok(dtype), Ok(shape)) => format!("a {dtype} array of shape {shape}"),
        _ => match obj.get_type().name() {
            Ok(name) => format!("a {name}"),
            Err(_) => "another object".to_string(),
        },
    }
}

/// Checks a frame's sides.
fn check_sides(name: &str, height: usize, width: usize) -> PyResult<()> {
    if height == 0 || width == 0 || height > MAX_FRAME_SIDE || width > MAX_FRAME_SIDE {
        return Err(bad_input(format!(
            "{name}: a frame of {width}x{height} pixels; frames are 1 to {MAX_FRAME_SIDE} \
             pixels on a side"
        )));
    }
    Ok(())
}

/// The values of `view` in row-major order: one copy when the memory is laid out so,
/// element by element otherwise.
fn row_major<T: Copy, D: numpy::ndarray::Dimension>(
    view: numpy::ndarray::ArrayView<'_, T, D>,
) -> Vec<T> {
    match view.as_slice() {
        Some(s) => s.to_vec(),
        None => view.iter().copied().collect(),
    }
}

/// An RGB frame from a `uint8` array of shape `(H, W, 3)`.
pub fn rgb_image(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<RgbImage> {
    let mut image = RgbImage::default();
    rgb_image_into(name, obj, &mut image)?;
    Ok(image)
}

/// [`rgb_image`] into `image`, reusing its buffer (a stream of frames of one size
/// allocates nothing).
pub fn rgb_image_into(name: &str, obj: &Bound<'_, PyAny>, image: &mut RgbImage) -> PyResult<()> {
    let array: PyReadonlyArray3<'_, u8> = obj.extract().map_err(|_| {
        bad_input(format!(
            "{name}: expected a uint8 array of shape (height, width, 3) (RGB), got {}",
            describe(obj)
        ))
    })?;
    let view: ArrayView3<'_, u8> = array.as_array();
    let (h, w, c) = view.dim();
    if c != 3 {
        return Err(bad_input(format!(
            "{name}: expected a uint8 array of shape (height, width, 3) (RGB), got shape \
             ({h}, {w}, {c})"
        )));
    }
    check_sides(name, h, w)?;
    let mut data = std::mem::take(image).into_raw();
    data.clear();
    match view.as_slice() {
        Some(s) => data.extend_from_slice(s),
        None => data.extend(view.iter().copied()),
    }
    *image = RgbImage::from_raw(w as u32, h as u32, data).expect("h × w × 3 values");
    Ok(())
}

/// A grey frame from a `uint8` array of shape `(H, W)`; `(H, W, 3)` (RGB) is converted
/// as the CLI converts colour files and live frames ([`stereotac::output::grey`]), and
/// `(H, W, 1)` taken as grey.
pub fn grey_grid(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Grid<u8>> {
    let wrong = || {
        bad_input(format!(
            "{name}: expected a uint8 array of shape (height, width) (grey) or (height, \
             width, 3) (RGB), got {}",
            describe(obj)
        ))
    };
    if let Ok(array) = obj.extract::<PyReadonlyArray2<'_, u8>>() {
        let view: ArrayView2<'_, u8> = array.as_array();
        let (h, w) = view.dim();
        check_sides(name, h, w)?;
        return Ok(Grid::from_vec(w, h, row_major(view)).expect("h × w values"));
    }
    let array: PyReadonlyArray3<'_, u8> = obj.extract().map_err(|_| wrong())?;
    match array.shape()[2] {
        3 => Ok(stereotac::output::grey(&rgb_image(name, obj)?)),
        1 => {
            let view = array.as_array();
            let (h, w, _) = view.dim();
            check_sides(name, h, w)?;
            Ok(Grid::from_vec(w, h, row_major(view)).expect("h × w values"))
        }
        _ => Err(wrong()),
    }
}

/// [`grey_grid`] into `grid`, reusing its buffer for `(H, W)` arrays (a stream of grey
/// frames of one size allocates nothing).
pub fn grey_grid_into(name: &str, obj: &Bound<'_, PyAny>, grid: &mut Grid<u8>) -> PyResult<()> {
    if let Ok(array) = obj.extract::<PyReadonlyArray2<'_, u8>>() {
        let view: ArrayView2<'_, u8> = array.as_array();
        let (h, w) = view.dim();
        check_sides(name, h, w)?;
        let mut data = std::mem::replace(grid, Grid::filled(0, 0, 0)).into_vec();
        data.clear();
        match view.as_slice() {
            Some(s) => data.extend_from_slice(s),
            None => data.extend(view.iter().copied()),
        }
        *grid = Grid::from_vec(w, h, data).expect("h × w values");
        return Ok(());
    }
    *grid = grey_grid(name, obj)?;
    Ok(())
}

/// A grid as a 2-D numpy array (rows first), without copying its buffer.
pub fn grid_array<'py, T: numpy::Element + Copy>(
    py: Python<'py>,
    grid: Grid<T>,
) -> Bound<'py, PyArray2<T>> {
    let (w, h) = (grid.width(), grid.height());
    Array2::from_shape_vec((h, w), grid.into_vec())
        .expect("a grid holds width × height values")
        .into_pyarray(py)
}

/// Rows of `N` values as an `(rows, N)` numpy array, without copying.
pub fn rows_array<'py, T, const N: usize>(
    py: Python<'py>,
    rows: Vec<[T; N]>,
) -> Bound<'py, PyArray2<T>>
where
    T: numpy::Element + bytemuck::Pod,
    [T; N]: bytemuck::Pod,
{
    let n = rows.len();
    // Same alignment, N times the length: a cast, not a copy (the fallback copies).
    let flat: Vec<T> = bytemuck::allocation::try_cast_vec(rows)
        .unwrap_or_else(|(_, rows)| rows.into_iter().flatten().collect());
    Array2::from_shape_vec((n, N), flat)
        .expect("rows × N values")
        .into_pyarray(py)
}

/// A vector as a 1-D numpy array, without copying.
pub fn vec_array<T: numpy::Element>(py: Python<'_>, v: Vec<T>) -> Bound<'_, PyArray1<T>> {
    Array1::from_vec(v).into_pyarray(py)
}
