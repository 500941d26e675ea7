//! What several commands do at the terminal: print lines that notice a closed stdout,
//! stop on Ctrl-C (and SIGTERM, SIGHUP), and write JSON reports.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result};
use serde::Serialize;

/// Print a line; `false` once stdout is gone (e.g. piped into `head`).
pub fn emit(line: std::fmt::Arguments<'_>) -> bool {
    use std::io::Write;
    writeln!(std::io::stdout().lock(), "{line}").is_ok()
}

/// Print without a newline; `false` once stdout is gone.
pub fn emit_raw(text: std::fmt::Arguments<'_>) -> bool {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    write!(out, "{text}").and_then(|()| out.flush()).is_ok()
}

/// Stop on Ctrl-C, SIGTERM or SIGHUP: the flag turns true.
pub fn interrupt_flag() -> Result<Arc<AtomicBool>> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = Arc::clone(&flag);
    ctrlc::set_handler(move || f.store(true, Ordering::SeqCst))
        .context("installing the Ctrl-C/SIGTERM/SIGHUP handler")?;
    Ok(flag)
}

/// `report` as pretty JSON, also written to `out` when given.
pub fn json_report<T: Serialize + ?Sized>(report: &T, out: Option<&Path>) -> Result<String> {
    let json = serde_json::to_string_pretty(report)?;
    if let Some(path) = out {
        std::fs::write(path, &json).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(json)
}
