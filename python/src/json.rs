//! JSON values (reports, records, messages) as Python dicts and lists, through Python's
//! own `json` module: the same values `--json` and `--jsonl` print.

use pyo3::prelude::*;

/// `value` as a Python object.
pub fn value_to_python(py: Python<'_>, value: &serde_json::Value) -> PyResult<Py<PyAny>> {
    Ok(py
        .import("json")?
        .call_method1("loads", (value.to_string(),))?
        .unbind())
}

/// Anything serialisable as a Python object.
pub fn to_python(py: Python<'_>, value: &impl serde::Serialize) -> PyResult<Py<PyAny>> {
    let value = serde_json::to_value(value)
        .map_err(|e| crate::errors::bad_input(format!("not JSON: {e}")))?;
    value_to_python(py, &value)
}
