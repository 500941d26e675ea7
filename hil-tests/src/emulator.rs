//! The emulated RP2040: the Node harness (`emulator/harness.mjs`) as a child process,
//! driven in lock-step, and the transport and host clock that put it behind the host
//! library exactly where a USB sensor would be.
//!
//! Simulated time moves only when a command asks: [`Emulator::run_until`] runs the
//! firmware to a simulated instant (or until it sends something on bulk IN), collecting
//! the pin trace, RTT (defmt) bytes and any emulator faults on the way.
//! [`EmulatedClock`] is the host clock of a test: simulated time, optionally offset and
//! drifting, so clock sync has something to find. Sleeping on it runs the emulator.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use serde::Deserialize;
use stereotac::clock::{HostClock, HostMicros};
use stereotac::transport::{Transport, TransportError};

use crate::trace::{Edge, PinTrace};

/// Why the emulator failed.
#[derive(Debug, thiserror::Error)]
pub enum EmulatorError {
    /// Node could not be started.
    #[error("could not start node ({0}); install Node.js 20 or newer")]
    Spawn(std::io::Error),
    /// The firmware did not enumerate.
    #[error("the emulated firmware did not enumerate: {0}")]
    Boot(String),
    /// The harness answered with an error or went away.
    #[error("emulator: {0}")]
    Harness(String),
    /// The defmt log could not be decoded.
    #[error("defmt log: {0}")]
    Log(String),
    /// The firmware halted (runaway CPU, unknown breakpoint).
    #[error("the emulated CPU halted at {t_ns} ns: {faults:?}")]
    Halted {
        /// Simulated time.
        t_ns: u64,
        /// What the emulator reported.
        faults: Vec<String>,
    },
}

/// The harness's reply to `run` (and the boot report).
#[derive(Debug, Deserialize)]
struct Report {
    #[serde(default)]
    t_ns: u64,
    #[serde(default, rename = "in")]
    input: String,
    #[serde(default)]
    edges: Vec<u64>,
    #[serde(default)]
    rtt: String,
    #[serde(default)]
    faults: Vec<String>,
    #[serde(default)]
    halted: bool,
    #[serde(default)]
    bootloader: bool,
    #[serde(default)]
    ready: bool,
    #[serde(default)]
    error: Option<String>,
    #[serde(default)]
    serial: Option<String>,
    #[serde(default)]
    device: Option<String>,
    #[serde(default)]
    status: Option<String>,
    #[serde(default)]
    data: Option<String>,
}

/// What enumeration found.
#[derive(Debug, Clone)]
pub struct Enumeration {
    /// The USB serial number string.
    pub serial: String,
    /// The device descriptor.
    pub device_descriptor: Vec<u8>,
}

impl Enumeration {
    /// idVendor and idProduct.
    pub fn vid_pid(&self) -> (u16, u16) {
        let d = &self.device_descriptor;
        (
            u16::from_le_bytes([d[8], d[9]]),
            u16::from_le_bytes([d[10], d[11]]),
        )
    }
}

/// How a control transfer ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ControlOutcome {
    /// Completed, with the IN data (if any).
    Ok(Vec<u8>),
    /// The device stalled the request.
    Stall,
    /// No answer within 100 ms.
    Timeout,
}

/// The Node harness running the firmware (see the module documentation).
#[derive(Debug)]
pub struct Emulator {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    now_ns: u64,
    pending_in: Vec<u8>,
    trace: PinTrace,
    rtt: Vec<u8>,
    elf: PathBuf,
    faults: Vec<String>,
    bootloader: bool,
    enumeration: Enumeration,
}

/// The harness directory (`hil-tests/emulator`).
pub fn harness_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("emulator")
}

fn hex_bytes(text: &str) -> Result<Vec<u8>, EmulatorError> {
    hex::decode(text).map_err(|e| EmulatorError::Harness(format!("bad hex from harness: {e}")))
}

impl Emulator {
    /// Boot `elf` in the emulator and enumerate it as a USB host would.
    pub fn start(elf: &Path) -> Result<Self, EmulatorError> {
        let mut child = Command::new("node")
            .arg(harness_dir().join("harness.mjs"))
            .arg(elf)
            .current_dir(harness_dir())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(EmulatorError::Spawn)?;
        let stdin = child.stdin.take().expect("piped stdin");
        let stdout = BufReader::new(child.stdout.take().expect("piped stdout"));
        let mut emulator = Self {
            child,
            stdin,
            stdout,
            now_ns: 0,
            pending_in: Vec::new(),
            trace: PinTrace::default(),
            rtt: Vec::new(),
            elf: elf.to_path_buf(),
            faults: Vec::new(),
            bootloader: false,
            enumeration: Enumeration {
                serial: String::new(),
                device_descriptor: Vec::new(),
            },
        };
        let boot = emulator.read_report()?;
        if !boot.ready {
            return Err(EmulatorError::Boot(
                boot.error.unwrap_or_else(|| "no reason given".into()),
            ));
        }
        emulator.enumeration = Enumeration {
            serial: boot.serial.clone().unwrap_or_default(),
            device_descriptor: hex_bytes(boot.device.as_deref().unwrap_or(""))?,
        };
        emulator.absorb(boot)?;
        Ok(emulator)
    }

    fn command(&mut self, command: serde_json::Value) -> Result<Report, EmulatorError> {
        writeln!(self.stdin, "{command}")
            .and_then(|()| self.stdin.flush())
            .map_err(|e| EmulatorError::Harness(format!("writing a command: {e}")))?;
        let report = self.read_report()?;
        match report.error {
            Some(e) => Err(EmulatorError::Harness(e)),
            None => Ok(report),
        }
    }

    fn read_report(&mut self) -> Result<Report, EmulatorError> {
        let mut line = String::new();
        let n = self
            .stdout
            .read_line(&mut line)
            .map_err(|e| EmulatorError::Harness(format!("reading a reply: {e}")))?;
        if n == 0 {
            return Err(EmulatorError::Harness("the harness exited".into()));
        }
        serde_json::from_str(&line)
            .map_err(|e| EmulatorError::Harness(format!("bad reply {line:?}: {e}")))
    }

    /// Take in what a reply carries.
    fn absorb(&mut self, report: Report) -> Result<(), EmulatorError> {
        self.now_ns = self.now_ns.max(report.t_ns);
        self.pending_in.extend(hex_bytes(&report.input)?);
        self.rtt.extend(hex_bytes(&report.rtt)?);
        self.trace
            .extend(report.edges.chunks_exact(3).map(|e| Edge {
                t_ns: e[0],
                pin: e[1] as u8,
                high: e[2] == 1,
            }));
        self.faults.extend(report.faults);
        self.bootloader |= report.bootloader;
        if report.halted && !self.bootloader {
            return Err(EmulatorError::Halted {
                t_ns: report.t_ns,
                faults: self.faults.clone(),
            });
        }
        Ok(())
    }

    /// Run the firmware until `t_ns` (simulated), or until it sends bulk IN data when
    /// `stop_on_in`.
    pub fn run_until(&mut self, t_ns: u64, stop_on_in: bool) -> Result<(), EmulatorError> {
        if t_ns <= self.now_ns && !stop_on_in {
            return Ok(());
        }
        let report = self.command(serde_json::json!({
            "op": "run", "until_ns": t_ns, "stop_on_in": stop_on_in,
        }))?;
        self.absorb(report)
    }

    /// Queue bytes for the bulk OUT endpoint.
    pub fn send(&mut self, bytes: &[u8]) -> Result<(), EmulatorError> {
        self.command(serde_json::json!({"op": "send", "data": hex::encode(bytes)}))?;
        Ok(())
    }

    /// Whether the host reads bulk IN (false: the device's IN transfers stay pending).
    pub fn set_reading(&mut self, on: bool) -> Result<(), EmulatorError> {
        self.command(serde_json::json!({"op": "reading", "on": on}))?;
        Ok(())
    }

    /// One control transfer on endpoint 0.
    pub fn control(
        &mut self,
        setup: [u8; 8],
        data: &[u8],
    ) -> Result<ControlOutcome, EmulatorError> {
        let mut report = self.command(serde_json::json!({
            "op": "control", "setup": hex::encode(setup), "data": hex::encode(data),
        }))?;
        let status = report.status.take().unwrap_or_default();
        let data = hex_bytes(report.data.as_deref().unwrap_or(""))?;
        self.absorb(report)?;
        Ok(match status.as_str() {
            "ok" => ControlOutcome::Ok(data),
            "stall" => ControlOutcome::Stall,
            _ => ControlOutcome::Timeout,
        })
    }

    /// Simulated time, ns since reset.
    pub fn now_ns(&self) -> u64 {
        self.now_ns
    }

    /// Bulk IN bytes received and not yet taken.
    pub fn take_in(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.pending_in)
    }

    /// The pin trace so far.
    pub fn trace(&self) -> &PinTrace {
        &self.trace
    }

    /// The pin trace, to clear old edges.
    pub fn trace_mut(&mut self) -> &mut PinTrace {
        &mut self.trace
    }

    /// RTT (defmt) bytes the firmware logged.
    pub fn rtt(&self) -> &[u8] {
        &self.rtt
    }

    /// The firmware's defmt log so far, decoded with the ELF's string table: one line
    /// per message, with the firmware's timestamp and level.
    pub fn log(&self) -> Result<Vec<String>, EmulatorError> {
        let elf = std::fs::read(&self.elf)
            .map_err(|e| EmulatorError::Log(format!("{}: {e}", self.elf.display())))?;
        let table = defmt_decoder::Table::parse(&elf)
            .map_err(|e| EmulatorError::Log(e.to_string()))?
            .ok_or_else(|| EmulatorError::Log("the ELF has no defmt table".into()))?;
        let mut decoder = table.new_stream_decoder();
        decoder.received(&self.rtt);
        let mut lines = Vec::new();
        loop {
            match decoder.decode() {
                Ok(frame) => lines.push(frame.display(false).to_string()),
                Err(defmt_decoder::DecodeError::UnexpectedEof) => return Ok(lines),
                Err(defmt_decoder::DecodeError::Malformed) if table.encoding().can_recover() => {}
                Err(defmt_decoder::DecodeError::Malformed) => {
                    return Err(EmulatorError::Log(format!(
                        "malformed frame after {} messages",
                        lines.len()
                    )));
                }
            }
        }
    }

    /// Emulator warnings (unimplemented registers and the like).
    pub fn faults(&self) -> &[String] {
        &self.faults
    }

    /// Whether the firmware asked for the USB bootloader.
    pub fn bootloader_requested(&self) -> bool {
        self.bootloader
    }

    /// What enumeration found.
    pub fn enumeration(&self) -> &Enumeration {
        &self.enumeration
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        let _ = writeln!(self.stdin, "{}", serde_json::json!({"op": "quit"}));
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// An emulator shared by the transport, the clock and the test.
pub type SharedEmulator = Arc<Mutex<Emulator>>;

/// Lock, tolerating a panicked holder (the emulator state is still valid).
pub fn lock(emulator: &SharedEmulator) -> MutexGuard<'_, Emulator> {
    emulator.lock().unwrap_or_else(|e| e.into_inner())
}

/// The host clock of an emulated test: simulated time, offset by `offset_us` and
/// running `host_ppm` faster than the device's crystal.
#[derive(Debug, Clone)]
pub struct EmulatedClock {
    emulator: SharedEmulator,
    offset_us: f64,
    scale: f64,
}

impl EmulatedClock {
    /// A host clock reading `offset_us + sim_us · (1 + host_ppm·10⁻⁶)`.
    pub fn new(emulator: SharedEmulator, offset_us: u64, host_ppm: f64) -> Self {
        Self {
            emulator,
            offset_us: offset_us as f64,
            scale: 1.0 + host_ppm * 1e-6,
        }
    }

    /// Host µs of a simulated instant.
    pub fn host_of_ns(&self, t_ns: u64) -> f64 {
        self.offset_us + t_ns as f64 / 1000.0 * self.scale
    }

    /// Simulated ns of a host instant (rounded up).
    pub fn ns_of_host(&self, t_us: HostMicros) -> u64 {
        (((t_us as f64 - self.offset_us) / self.scale) * 1000.0)
            .ceil()
            .max(0.0) as u64
    }
}

impl HostClock for EmulatedClock {
    fn now_us(&self) -> HostMicros {
        self.host_of_ns(lock(&self.emulator).now_ns()).floor() as HostMicros
    }

    fn sleep_until(&self, t: HostMicros) {
        let mut emulator = lock(&self.emulator);
        let now_ns = emulator.now_ns();
        if (t as f64) <= self.host_of_ns(now_ns) {
            return;
        }
        // Always move forward: host µs are whole, simulated time is finer.
        let target = self.ns_of_host(t).max(now_ns + 1);
        // A failure here shows up at the transport's next call.
        let _ = emulator.run_until(target, false);
    }

    fn is_virtual(&self) -> bool {
        true
    }
}

/// The emulated sensor's bulk endpoints as a [`Transport`].
#[derive(Debug)]
pub struct EmulatedTransport {
    emulator: SharedEmulator,
    clock: EmulatedClock,
}

impl EmulatedTransport {
    /// A transport on `emulator`, timed by `clock`.
    pub fn new(emulator: SharedEmulator, clock: EmulatedClock) -> Self {
        Self { emulator, clock }
    }
}

fn transport_error(e: EmulatorError) -> TransportError {
    match e {
        EmulatorError::Harness(_) | EmulatorError::Halted { .. } => TransportError::Disconnected,
        other => TransportError::Io(other.to_string()),
    }
}

impl Transport for EmulatedTransport {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        lock(&self.emulator).send(bytes).map_err(transport_error)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Vec<u8>, TransportError> {
        let mut emulator = lock(&self.emulator);
        if emulator.bootloader_requested() {
            return Err(TransportError::Disconnected);
        }
        let pending = emulator.take_in();
        if !pending.is_empty() {
            return Ok(pending);
        }
        // At least 1 µs of simulated time per call, so a polling loop always advances.
        let step_ns = (timeout.as_nanos() as f64 / self.clock.scale).ceil() as u64;
        let until = emulator.now_ns() + step_ns.max(1000);
        emulator.run_until(until, true).map_err(transport_error)?;
        Ok(emulator.take_in())
    }
}
