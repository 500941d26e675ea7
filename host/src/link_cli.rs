//! CLI front-ends of the host link: `devices`, `info`, `stream`, `record`, `set`, `flash`.
//!
//! Every command talks to a sensor through [`Sensor`]: over USB by default, or with
//! `--sim` to the in-process simulated sensor (the firmware's own command handling
//! behind the loopback's USB timing and a drifting clock, in real time).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use stereotac::clock::{HostClock, MonotonicClock};
use stereotac::device::{
    Connector, Sensor, SensorConfig, SensorEvent, connect_once, hex, status_line,
};
use stereotac::frames::capture::Capture;
use stereotac::frames::replay::Recorder;
use stereotac::frames::sim::{PhaseImages, SimClocking, SimulatedCamera};
use stereotac::matcher::{CameraSync, MatchedFrame, MatcherConfig, phase_str};
use stereotac::tactile::render::{Optics, builtin_scenes};
use stereotac::transport::loopback::{LedTimeline, Loopback, LoopbackConfig};
use stereotac::transport::usb;
use stereotac_protocol::{Mode, Request, Rgb, Strip, StripSettings, Timing, TriggerOutcome};

/// Board id of the simulated sensor.
const SIM_BOARD: [u8; 8] = *b"SIMSENSR";

/// Which sensor to talk to.
#[derive(Debug, Clone, clap::Args)]
pub struct DeviceArgs {
    /// Serial number of the sensor (required when several are attached).
    #[arg(long, global = true)]
    pub serial: Option<String>,
    /// Talk to the built-in simulated sensor instead of USB hardware.
    #[arg(long, global = true)]
    pub sim: bool,
    /// Use libusb instead of the built-in pure-Rust USB stack (needs a build with
    /// `--features libusb`).
    #[arg(long, global = true, conflicts_with = "sim")]
    pub libusb: bool,
}

/// The connector `--serial`/`--libusb` ask for.
fn usb_connector(device: &DeviceArgs) -> Result<Connector> {
    if device.libusb {
        return libusb_connector(device.serial.clone());
    }
    Ok(Box::new(usb::UsbConnector::new(device.serial.clone())))
}

#[cfg(feature = "libusb")]
fn libusb_connector(serial: Option<String>) -> Result<Connector> {
    Ok(Box::new(
        stereotac::transport::libusb::LibusbConnector::new(serial),
    ))
}

#[cfg(not(feature = "libusb"))]
fn libusb_connector(_serial: Option<String>) -> Result<Connector> {
    bail!(NO_LIBUSB)
}

#[cfg(not(feature = "libusb"))]
const NO_LIBUSB: &str = "this build has no libusb backend; rebuild with `--features libusb` \
    (needs libusb-1.0-0-dev and pkg-config), or drop --libusb to use the built-in USB stack";

/// The sensors on the bus, through the backend `--libusb` asks for.
fn list_sensors(device: &DeviceArgs) -> Result<Vec<usb::UsbSensor>> {
    if device.libusb {
        #[cfg(feature = "libusb")]
        return stereotac::transport::libusb::list().context("listing USB devices (libusb)");
        #[cfg(not(feature = "libusb"))]
        bail!(NO_LIBUSB);
    }
    usb::list().context("listing USB devices")
}

/// Lighting modes on the command line.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum ModeArg {
    /// Strips dark, no triggers.
    Off,
    /// LEDs dark, cameras triggered: stereo vision.
    Vision,
    /// All strips lit: contact shape.
    Contact,
    /// dx/dy alternating: photometric stereo.
    Gradient,
    /// dark, dx, dy: vision and gradients together.
    Interleaved,
}

impl From<ModeArg> for Mode {
    fn from(m: ModeArg) -> Self {
        match m {
            ModeArg::Off => Mode::Off,
            ModeArg::Vision => Mode::Vision,
            ModeArg::Contact => Mode::ContactShape,
            ModeArg::Gradient => Mode::Gradient,
            ModeArg::Interleaved => Mode::Interleaved,
        }
    }
}

/// An open sensor, plus the simulation's LED truth when it is simulated.
struct Opened {
    sensor: Sensor,
    timeline: Option<Arc<std::sync::Mutex<LedTimeline>>>,
}

fn open(device: &DeviceArgs) -> Result<Opened> {
    let clock: Arc<dyn HostClock> = Arc::new(MonotonicClock::new());
    let (connector, timeline): (Connector, _) = if device.sim {
        let link = Loopback::new(
            SIM_BOARD,
            Arc::clone(&clock),
            LoopbackConfig {
                drift_ppm: 25.0,
                boot_at_us: clock.now_us(),
                seed: clock.now_us(),
                ..LoopbackConfig::default()
            },
        );
        let timeline = link.timeline();
        (connect_once(link), Some(timeline))
    } else {
        (usb_connector(device)?, None)
    };
    let sensor = Sensor::connect(connector, clock, SensorConfig::default())
        .context("connecting to the sensor")?;
    Ok(Opened { sensor, timeline })
}

/// Stop on Ctrl-C: the flag turns true.
fn interrupt_flag() -> Result<Arc<AtomicBool>> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = Arc::clone(&flag);
    ctrlc::set_handler(move || f.store(true, Ordering::SeqCst)).context("installing Ctrl-C")?;
    Ok(flag)
}

fn version(info: &stereotac_protocol::DeviceInfo) -> String {
    let v = info.firmware_version;
    format!(
        "{}.{}.{} ({}{})",
        v.major,
        v.minor,
        v.patch,
        &hex(&info.git_hash)[..10].to_lowercase(),
        if info.git_dirty { "+dirty" } else { "" }
    )
}

/// `stereotac selftest`: the command checks of [`stereotac::selftest`].
pub fn selftest(device: &DeviceArgs, json: bool) -> Result<()> {
    let mut opened = open(device)?;
    let report = stereotac::selftest::run_command_checks(&mut opened.sensor)
        .context("running the command checks")?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        for c in &report.checks {
            let mark = if c.passed { "ok  " } else { "FAIL" };
            println!("{mark} {}", c.name);
            if !c.passed {
                println!("     {}", c.detail);
            }
        }
    }
    let failed = report.failures().count();
    if failed > 0 {
        bail!("{failed} of {} checks failed", report.checks.len());
    }
    if !json {
        println!("all {} checks passed", report.checks.len());
    }
    Ok(())
}

/// `stereotac devices --watch`: print sensor arrivals and departures until Ctrl-C.
pub fn watch_devices(json: bool) -> Result<()> {
    let stop = interrupt_flag()?;
    let mut watch = usb::watch().context("watching the USB bus for sensors")?;
    eprintln!("watching for stereotac sensors (Ctrl-C stops)");
    while !stop.load(Ordering::SeqCst) {
        let Some(event) = watch.next(std::time::Instant::now() + Duration::from_millis(200)) else {
            continue;
        };
        if json {
            let line = serde_json::to_string(&event)?;
            if !emit(format_args!("{line}")) {
                break;
            }
        } else {
            let printed = match event {
                usb::Hotplug::Arrived(s) => {
                    emit(format_args!("arrived  {:<18} {}", s.serial, s.path))
                }
                usb::Hotplug::Left { id } => emit(format_args!("left     (USB device {id})")),
            };
            if !printed {
                break;
            }
        }
    }
    Ok(())
}

/// `stereotac devices`.
pub fn devices(device: &DeviceArgs, json: bool) -> Result<()> {
    let mut rows = Vec::new();
    if device.sim {
        let opened = open(device)?;
        let info = *opened.sensor.info();
        rows.push(serde_json::json!({
            "serial": hex(&info.board_id), "path": "sim", "firmware": version(&info),
            "protocol": info.protocol_version,
        }));
    } else {
        for found in list_sensors(device)? {
            // Ask each one for its version; report (not fail) if it cannot be opened.
            let firmware = match open(&DeviceArgs {
                serial: Some(found.serial.clone()),
                ..device.clone()
            }) {
                Ok(o) => version(o.sensor.info()),
                Err(e) => format!("unavailable: {e:#}"),
            };
            rows.push(serde_json::json!({
                "serial": found.serial, "path": found.path, "firmware": firmware,
                "product": found.product,
            }));
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else if rows.is_empty() {
        println!(
            "no stereotac sensor found (USB {:04x}:{:04x}); try --sim for the simulated one",
            stereotac_protocol::USB_VID,
            stereotac_protocol::USB_PID
        );
    } else {
        println!("{:<18} {:<10} firmware", "serial", "path");
        for r in &rows {
            println!(
                "{:<18} {:<10} {}",
                r["serial"].as_str().unwrap_or(""),
                r["path"].as_str().unwrap_or(""),
                r["firmware"].as_str().unwrap_or("")
            );
        }
    }
    Ok(())
}

/// `stereotac info`.
pub fn info(device: &DeviceArgs, json: bool) -> Result<()> {
    let mut opened = open(device)?;
    let sensor = &mut opened.sensor;
    let info = *sensor.info();
    let status = sensor.status()?;
    let config = sensor.config()?;
    let fit = sensor.clock_fit().copied();
    if json {
        let value = serde_json::json!({
            "serial": hex(&info.board_id),
            "protocol": info.protocol_version,
            "firmware": version(&info),
            "leds_per_strip": info.leds_per_strip,
            "max_leds_per_strip": info.max_leds_per_strip,
            "capabilities": info.capabilities.0,
            "status": format!("{status:?}"),
            "config": format!("{config:?}"),
            "clock": fit.map(|f| serde_json::json!({
                "drift_ppm": f.drift_ppm(), "uncertainty_us": f.uncertainty_us,
                "min_rtt_us": f.min_rtt_us, "pings": f.samples })),
            "host_counters": sensor.counters(),
        });
        println!("{}", serde_json::to_string_pretty(&value)?);
        return Ok(());
    }
    println!(
        "sensor {}: protocol v{}, firmware {}, {} strips x {} LEDs (max {}), timer {} Hz, capabilities {:#x}",
        hex(&info.board_id),
        info.protocol_version,
        version(&info),
        info.strips,
        info.leds_per_strip,
        info.max_leds_per_strip,
        info.timer_hz,
        info.capabilities.0
    );
    println!(
        "mode {:?}, period {} µs, trigger pulse {} µs, settle {} µs, power budget {} mA (scale {}/255), host timeout {} ms",
        config.mode,
        config.timing.phase_period_us,
        config.timing.trigger_pulse_us,
        config.timing.led_settle_us,
        config.power_budget_ma,
        config.power_scale,
        config.host_timeout_ms
    );
    for s in config.strips {
        println!(
            "  strip {:?}: colour #{:02x}{:02x}{:02x}, brightness {}",
            s.strip, s.colour.r, s.colour.g, s.colour.b, s.brightness
        );
    }
    println!("device counters: {}", status_line(&status));
    if let Some(f) = fit {
        println!(
            "clock sync: {} pings, min round trip {} µs, drift {:+.1} ppm, uncertainty ±{:.1} µs",
            f.samples,
            f.min_rtt_us,
            f.drift_ppm(),
            f.uncertainty_us
        );
    }
    Ok(())
}

/// `stereotac stream` and `stereotac record` share the sequence settings.
#[derive(Debug, Clone, clap::Args)]
pub struct SequenceArgs {
    /// Lighting mode.
    #[arg(long, value_enum, default_value_t = ModeArg::Gradient)]
    pub mode: ModeArg,
    /// Phase period in milliseconds (250: dx and dy alternate at 4 Hz).
    #[arg(long, default_value_t = 250)]
    pub period_ms: u32,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    pub duration_s: Option<f64>,
}

fn start(sensor: &mut Sensor, seq: &SequenceArgs) -> Result<()> {
    if seq.period_ms == 0 {
        bail!("--period-ms must be at least 1");
    }
    let timing = Timing {
        phase_period_us: seq.period_ms.saturating_mul(1000),
        ..sensor.config()?.timing
    };
    sensor
        .request(Request::SetTiming(timing))
        .context("setting the period")?;
    sensor.request(Request::SetMode(seq.mode.into()))?;
    sensor
        .request(Request::Start)
        .context("starting the sequence")?;
    Ok(())
}

fn deadline(sensor: &Sensor, seq: &SequenceArgs) -> Result<Option<u64>> {
    match seq.duration_s {
        Some(s) if !(s.is_finite() && s > 0.0) => bail!("--duration-s must be positive"),
        Some(s) => Ok(Some(sensor.clock().now_us() + (s * 1e6) as u64)),
        None => Ok(None),
    }
}

/// Print a line; `false` once stdout is gone (e.g. piped into `head`).
fn emit(line: std::fmt::Arguments<'_>) -> bool {
    use std::io::Write;
    writeln!(std::io::stdout().lock(), "{line}").is_ok()
}

/// `stereotac stream`.
pub fn stream(device: &DeviceArgs, seq: &SequenceArgs, json: bool) -> Result<()> {
    let stop = interrupt_flag()?;
    let mut opened = open(device)?;
    let sensor = &mut opened.sensor;
    start(sensor, seq)?;
    let end = deadline(sensor, seq)?;
    if !json {
        emit(format_args!(
            "{:>6} {:>5} {:>16} {:>16} {:>8} {:>10} {:>7}",
            "phase", "kind", "trigger host µs", "trigger dev µs", "trigger#", "±sync µs", "lost"
        ));
    }
    while !stop.load(Ordering::SeqCst) && end.is_none_or(|e| sensor.clock().now_us() < e) {
        for event in sensor.poll(Duration::from_millis(50))? {
            let lost = sensor.counters().link.lost_events;
            match event {
                SensorEvent::Phase(p) => {
                    let (trigger, dev) = match p.event.trigger {
                        TriggerOutcome::Fired { index, edge_us } => (Some(index), Some(edge_us)),
                        TriggerOutcome::Overrun { .. } => (None, None),
                    };
                    let host = p.trigger.map(|t| t.1);
                    let shown = if json {
                        emit(format_args!(
                            "{}",
                            serde_json::json!({"event": "phase", "index": p.event.index,
                            "phase": phase_str(p.event.phase), "trigger": trigger,
                            "trigger_device_us": dev, "trigger_host_us": host,
                            "latched_host_us": p.latched_us, "sync_uncertainty_us": p.uncertainty_us,
                            "lost_events": lost})
                        ))
                    } else {
                        emit(format_args!(
                            "{:>6} {:>5} {:>16} {:>16} {:>8} {:>10.1} {:>7}",
                            p.event.index,
                            phase_str(p.event.phase),
                            host.map_or("overrun".into(), |h| format!("{h:.1}")),
                            dev.map_or("-".into(), |d| d.to_string()),
                            trigger.map_or("-".into(), |t| t.to_string()),
                            p.uncertainty_us,
                            lost
                        ))
                    };
                    if !shown {
                        stop.store(true, Ordering::SeqCst);
                    }
                }
                SensorEvent::Heartbeat(s) if json => {
                    if !emit(format_args!(
                        "{}",
                        serde_json::json!({"event": "heartbeat", "phases": s.phases,
                            "triggers": s.triggers, "overruns": s.overruns,
                            "events_dropped": s.events_dropped})
                    )) {
                        stop.store(true, Ordering::SeqCst);
                    }
                }
                SensorEvent::Heartbeat(_) | SensorEvent::Probe(_) => {}
                SensorEvent::Fault(f, at) => {
                    eprintln!("fault {:?} at host {at:.0} µs", f.kind)
                }
                SensorEvent::Reconnected { attempts } => {
                    eprintln!("reconnected after {attempts} attempts")
                }
            }
        }
    }
    sensor.request(Request::Stop)?;
    let c = sensor.counters();
    let status = sensor.status()?;
    eprintln!(
        "stopped: {} events, {} lost, {} bad frames, {} reconnects; device: {}",
        c.link.events,
        c.link.lost_events,
        c.link.bad_frames,
        c.reconnects,
        status_line(&status)
    );
    Ok(())
}

/// `stereotac record`.
#[derive(Debug, Clone, clap::Args)]
pub struct RecordArgs {
    /// Output directory (must not hold a recording already). With several cameras each
    /// records into DIR/cam0, DIR/cam1, ...
    #[arg(long)]
    pub out: PathBuf,
    /// Camera: `sim` (the simulated camera; needs --sim) or a V4L2 device such as
    /// /dev/video0 (needs a build with `--features v4l2`). Repeat for several cameras.
    #[arg(long = "camera", default_value = "sim")]
    pub cameras: Vec<String>,
    /// Exposure time, µs: the simulated camera's, and the one assumed for a V4L2 camera
    /// that does not report its own.
    #[arg(long, default_value_t = 8000.0)]
    pub exposure_us: f64,
    /// The cameras run on their own clock instead of the sensor's trigger output.
    #[arg(long)]
    pub free_running: bool,
    /// Delay from the trigger edge to the start of the exposure, µs (triggered cameras).
    #[arg(long, default_value_t = 40.0)]
    pub trigger_latency_us: f64,
    /// Frame size to ask V4L2 cameras for, WxH (default: the camera's current size).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Sequence settings.
    #[command(flatten)]
    pub sequence: SequenceArgs,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    s.split_once(['x', 'X'])
        .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
        .filter(|&(w, h)| w > 0 && h > 0)
        .ok_or_else(|| format!("{s:?} is not a size like 640x480"))
}

/// Open one `--camera`.
fn open_camera(
    name: &str,
    args: &RecordArgs,
    opened: &Opened,
) -> Result<Box<dyn stereotac::frames::FrameSource>> {
    if name == "sim" {
        let Some(timeline) = opened.timeline.clone() else {
            bail!("--camera sim renders the simulated sensor's LEDs: add --sim");
        };
        let optics = Optics::sized(320, 240);
        let scene = builtin_scenes(&optics).swap_remove(0).1;
        let clocking = if args.free_running {
            SimClocking::FreeRunning {
                period_us: 33_333.0,
                first_us: opened.sensor.clock().now_us() as f64,
            }
        } else {
            SimClocking::Triggered {
                latency_us: args.trigger_latency_us,
            }
        };
        return Ok(Box::new(SimulatedCamera::new(
            timeline,
            Arc::clone(opened.sensor.clock()),
            clocking,
            args.exposure_us,
            PhaseImages::render(&optics, &scene),
        )));
    }
    open_v4l2(name, args)
}

#[cfg(all(feature = "v4l2", target_os = "linux"))]
fn open_v4l2(name: &str, args: &RecordArgs) -> Result<Box<dyn stereotac::frames::FrameSource>> {
    use stereotac::frames::v4l2::{V4l2Camera, V4l2Settings};
    let camera = V4l2Camera::open(
        Path::new(name),
        &V4l2Settings {
            size: args.size,
            exposure_us: args.exposure_us,
            ..V4l2Settings::default()
        },
    )?;
    Ok(Box::new(camera))
}

#[cfg(not(all(feature = "v4l2", target_os = "linux")))]
fn open_v4l2(name: &str, _args: &RecordArgs) -> Result<Box<dyn stereotac::frames::FrameSource>> {
    Err(no_v4l2(name))
}

/// Refuse V4L2 cameras in a build without V4L2, before anything is connected.
fn check_cameras(cameras: &[String]) -> Result<()> {
    match cameras.iter().find(|c| *c != "sim") {
        Some(name) if !cfg!(all(feature = "v4l2", target_os = "linux")) => Err(no_v4l2(name)),
        _ => Ok(()),
    }
}

fn no_v4l2(name: &str) -> anyhow::Error {
    anyhow::anyhow!(
        "camera {name}: this build has no V4L2 capture; rebuild with `--features v4l2` \
         (Linux; needs libclang-dev), or use --sim --camera sim"
    )
}

/// One camera's capture and its recording.
struct CameraRecording {
    capture: Capture<Box<dyn stereotac::frames::FrameSource>>,
    recorder: Recorder,
    dir: PathBuf,
}

impl CameraRecording {
    /// Write labelled frames: images first, then their index lines.
    fn write(&mut self, frames: Vec<stereotac::frames::capture::LabelledFrame>) -> Result<u64> {
        let n = frames.len() as u64;
        for f in frames {
            self.recorder.write_image(&f.frame)?;
            self.recorder.write_label(&MatchedFrame {
                frame: f.frame.stamp,
                label: f.label,
            })?;
        }
        Ok(n)
    }
}

/// `stereotac record`.
pub fn record(device: &DeviceArgs, args: &RecordArgs) -> Result<()> {
    let stop = interrupt_flag()?;
    if !(args.exposure_us.is_finite() && args.exposure_us > 0.0) {
        bail!("--exposure-us must be positive");
    }
    if !(args.trigger_latency_us.is_finite() && args.trigger_latency_us >= 0.0) {
        bail!("--trigger-latency-us must be zero or positive");
    }
    check_cameras(&args.cameras)?;
    let mut opened = open(device)?;
    let sync = if args.free_running {
        CameraSync::FreeRunning
    } else {
        CameraSync::Triggered {
            latency_us: args.trigger_latency_us,
            tolerance_us: 500.0,
        }
    };
    let mut cameras = Vec::new();
    for (i, name) in args.cameras.iter().enumerate() {
        let source = open_camera(name, args, &opened)?;
        let dir = if args.cameras.len() == 1 {
            args.out.clone()
        } else {
            args.out.join(format!("cam{i}"))
        };
        eprintln!("camera {i}: {} -> {}", source.describe(), dir.display());
        let recorder = Recorder::create(&dir)
            .with_context(|| format!("starting a recording in {}", dir.display()))?;
        let capture = Capture::new(
            source,
            MatcherConfig {
                sync,
                ..MatcherConfig::default()
            },
        );
        cameras.push(CameraRecording {
            capture,
            recorder,
            dir,
        });
    }
    let sensor = &mut opened.sensor;
    start(sensor, &args.sequence)?;
    let end = deadline(sensor, &args.sequence)?;
    let progress = crate::progress::spinner("recording");
    while !stop.load(Ordering::SeqCst) && end.is_none_or(|e| sensor.clock().now_us() < e) {
        let events = sensor.poll(Duration::from_millis(20))?;
        for event in &events {
            if let SensorEvent::Phase(p) = event {
                progress.set_message(format!(
                    "phase {} ({})",
                    p.event.index,
                    phase_str(p.event.phase)
                ));
            }
        }
        for camera in &mut cameras {
            let frames = camera.capture.absorb(&events)?;
            progress.inc(camera.write(frames)?);
        }
    }
    // Ctrl-C or the end: stop the LEDs, then label and write every captured frame.
    let stopped = sensor.request(Request::Stop);
    for camera in &mut cameras {
        let frames = camera.capture.finish();
        camera.write(frames)?;
        camera.recorder.flush()?;
    }
    progress.finish_and_clear();
    stopped?;
    for camera in &cameras {
        let s = camera.capture.stats();
        let (images, lines) = camera.recorder.counts();
        println!(
            "recorded {images} frames ({lines} index lines) in {}: {} labelled, {} straddling, {} with a lost event, {} without trigger, {} unresolved; {} frames dropped, {} events lost",
            camera.dir.display(),
            s.labelled,
            s.straddling,
            s.event_missing,
            s.no_trigger,
            s.unresolved,
            s.dropped_frames,
            s.dropped_events
        );
    }
    Ok(())
}

/// `stereotac set`.
#[derive(Debug, Clone, clap::Args)]
pub struct SetArgs {
    /// Lighting mode (takes effect at the next phase).
    #[arg(long, value_enum)]
    pub mode: Option<ModeArg>,
    /// Phase period, ms.
    #[arg(long)]
    pub period_ms: Option<u32>,
    /// Trigger pulse width, µs.
    #[arg(long)]
    pub pulse_us: Option<u32>,
    /// LED settle time before the trigger, µs.
    #[arg(long)]
    pub settle_us: Option<u32>,
    /// Strip to colour (1-4) with --colour / --brightness.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=4))]
    pub strip: Option<u8>,
    /// Strip colour as RRGGBB hex.
    #[arg(long, requires = "strip", value_parser = parse_colour)]
    pub colour: Option<Rgb>,
    /// Strip brightness 0-255.
    #[arg(long, requires = "strip")]
    pub brightness: Option<u8>,
    /// WS2812 pixels per strip.
    #[arg(long)]
    pub leds: Option<u16>,
    /// LED current budget, mA.
    #[arg(long)]
    pub budget_ma: Option<u16>,
    /// Host-silence timeout, ms (0 disables).
    #[arg(long)]
    pub host_timeout_ms: Option<u32>,
}

fn parse_colour(s: &str) -> Result<Rgb, String> {
    let s = s.trim_start_matches('#');
    let v = u32::from_str_radix(s, 16)
        .ok()
        .filter(|_| s.len() == 6)
        .ok_or_else(|| format!("{s:?} is not a RRGGBB hex colour"))?;
    Ok(Rgb::new((v >> 16) as u8, (v >> 8) as u8, v as u8))
}

/// `stereotac set`.
pub fn set(device: &DeviceArgs, args: &SetArgs) -> Result<()> {
    let mut opened = open(device)?;
    let sensor = &mut opened.sensor;
    let current = sensor.config()?;
    let mut requests = Vec::new();
    if args.period_ms.is_some() || args.pulse_us.is_some() || args.settle_us.is_some() {
        requests.push(Request::SetTiming(Timing {
            phase_period_us: args
                .period_ms
                .map_or(current.timing.phase_period_us, |ms| ms.saturating_mul(1000)),
            trigger_pulse_us: args.pulse_us.unwrap_or(current.timing.trigger_pulse_us),
            led_settle_us: args.settle_us.unwrap_or(current.timing.led_settle_us),
        }));
    }
    if let Some(n) = args.strip {
        let strip = Strip::ALL[usize::from(n - 1)];
        let was = current.strips[strip.index()];
        requests.push(Request::SetStrip(StripSettings {
            strip,
            colour: args.colour.unwrap_or(was.colour),
            brightness: args.brightness.unwrap_or(was.brightness),
        }));
    }
    requests.extend(args.leds.map(Request::SetLedCount));
    requests.extend(args.budget_ma.map(Request::SetPowerBudget));
    requests.extend(args.host_timeout_ms.map(Request::SetHostTimeout));
    requests.extend(args.mode.map(|m| Request::SetMode(m.into())));
    if requests.is_empty() {
        bail!("nothing to set: see `stereotac set --help`");
    }
    for request in requests {
        sensor
            .request(request)
            .with_context(|| format!("{request:?}"))?;
        println!("ok: {request:?}");
    }
    Ok(())
}

/// Where an RP2040 boot drive (label RPI-RP2) gets mounted.
fn boot_drive() -> Option<PathBuf> {
    let user = std::env::var("USER").unwrap_or_default();
    let candidates = [
        PathBuf::from(format!("/media/{user}/RPI-RP2")),
        PathBuf::from(format!("/run/media/{user}/RPI-RP2")),
        PathBuf::from("/media/RPI-RP2"),
        PathBuf::from("/Volumes/RPI-RP2"),
    ];
    candidates
        .into_iter()
        .find(|p| p.join("INFO_UF2.TXT").exists())
}

/// `stereotac flash`.
pub fn flash(device: &DeviceArgs, file: &Path, wait_s: u64) -> Result<()> {
    let data = std::fs::read(file).with_context(|| format!("reading {}", file.display()))?;
    if data.len() < 512 || data.len() % 512 != 0 || data[..4] != [0x55, 0x46, 0x32, 0x0A] {
        bail!(
            "{} is not a UF2 file (make one with `stereotac firmware-image ELF --uf2 OUT`)",
            file.display()
        );
    }
    let mut opened = open(device)?;
    opened
        .sensor
        .request(Request::EnterBootloader)
        .context("asking the sensor to enter its USB bootloader")?;
    println!("sensor acknowledged; waiting up to {wait_s} s for the RPI-RP2 drive…");
    let clock = MonotonicClock::new();
    let until = clock.now_us() + wait_s * 1_000_000;
    while clock.now_us() < until {
        if let Some(drive) = boot_drive() {
            let target = drive.join("stereotac-firmware.uf2");
            std::fs::write(&target, &data)
                .with_context(|| format!("writing {}", target.display()))?;
            println!(
                "wrote {} ({} blocks) to {}; the sensor reboots into the new firmware",
                file.display(),
                data.len() / 512,
                drive.display()
            );
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    bail!(
        "the RPI-RP2 drive did not appear (not mounted automatically?). Mount it and copy the file yourself:\n  cp {} /path/to/RPI-RP2/",
        file.display()
    )
}
