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

/// A file grown past the process's size limit (`ulimit -f`) makes the write fail with
/// an error each command reports (naming the file, finishing what it can) instead of
/// SIGXFSZ killing the process without a word.
pub fn write_errors_not_signals() {
    #[cfg(target_os = "linux")]
    #[allow(unsafe_code)]
    // SAFETY: setting a signal's disposition to "ignore" before any thread starts;
    // SIGXFSZ has no handler of ours to race with.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

/// `e`, said to be about `path` (`doing` it) unless it names the file already: the
/// library's errors about a file mostly do, and "reading X: X: …" reads badly.
pub fn naming_file(e: impl Into<anyhow::Error>, doing: &str, path: &Path) -> anyhow::Error {
    let e = e.into();
    if format!("{e:#}").contains(&format!("{}:", path.display())) {
        e
    } else {
        e.context(format!("{doing} {}", path.display()))
    }
}

/// `report` as pretty JSON, also written to `out` when given.
pub fn json_report<T: Serialize + ?Sized>(report: &T, out: Option<&Path>) -> Result<String> {
    let json = serde_json::to_string_pretty(report)?;
    if let Some(path) = out {
        std::fs::write(path, &json).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(json)
}
