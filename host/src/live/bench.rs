//! `stereotac bench live`: the live path under load, on the simulated sensor in real
//! time and two simulated cameras free-running at a set frame rate (640×480, 60 fps by
//! default), in interleaved mode: what it sustains, how late depth comes, what it costs.
//!
//! Two parts, one run:
//! - **each stage alone**, against the frame rates it must keep: tactile pairs per
//!   second (LUT model, one thread: the live loop's), stereo frames per second;
//! - **the live loop** (`run`'s code: session, router, stages, recorder) for
//!   `duration_s`: frames offered and processed per second, drops, latency p50/p99
//!   from exposure end to depth ready, CPU time per frame, and resident memory after
//!   the first minute against the end (flat means no leak).
//!
//! The stage figures are ratios against their goals (60 pairs/s, 30 fps); the loop's
//! reference is the cameras' own rate: processed/offered. CPU and memory are read
//! from `/proc/self` (Linux; elsewhere they are reported missing).

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use serde::Serialize;
use stereotac_protocol::Mode;

use super::runner::{self, Hooks, Until};
use super::session::Session;
use super::{DarkPair, Output, Pipeline, PipelineError, StereoStage, TactileStage};
use crate::clock::{HostClock, MonotonicClock};
use crate::device::SensorError;
use crate::frames::Frame;
use crate::frames::FrameSource;
use crate::frames::capture::{CaptureError, GradientPair, LabelledFrame};
use crate::matcher::{CameraSync, FrameStamp, Label, MatcherConfig, StampRef};
use crate::recording::RecordingError;
use crate::recording::writer::{Recorder, RecorderOptions, clock_origin_unix_ns};
use crate::sim::camera::{PhaseImages, SimClocking, SimStereo, SimulatedCamera};
use crate::sim::link::LoopbackConfig;
use crate::stereo::{StereoConfig, StereoError, StereoPipeline};
use crate::tactile::calibrate::CalibrationError;
use crate::tactile::model::ModelKind;
use crate::tactile::poisson::SolverKind;
use crate::tactile::reconstruct::{ReconstructError, Reconstructor};
use crate::tactile::render::{Optics, builtin_scenes};
use crate::tactile::synthetic::{BUILTIN_PRESSES, builtin_calibration};
use crate::timing::quantiles;

/// What to run.
#[derive(Debug, Clone)]
pub struct LiveBenchOptions {
    /// Frame size of both cameras.
    pub size: (u32, u32),
    /// Camera frame rate, frames per second (free-running).
    pub fps: f64,
    /// LED phase period, ms (the sensor's default: 250).
    pub period_ms: u32,
    /// Length of the live loop, s.
    pub duration_s: f64,
    /// Length of each stage-alone measurement, s.
    pub stage_s: f64,
    /// Record to this MCAP file too (the recorder's cost included).
    pub mcap: Option<std::path::PathBuf>,
}

impl Default for LiveBenchOptions {
    fn default() -> Self {
        Self {
            size: (640, 480),
            fps: 60.0,
            period_ms: 250,
            duration_s: 600.0,
            stage_s: 3.0,
            mcap: None,
        }
    }
}

/// Why the benchmark could not run.
#[derive(Debug, thiserror::Error)]
pub enum LiveBenchError {
    /// The built-in calibration failed.
    #[error("built-in calibration: {0}")]
    Calibration(#[from] CalibrationError),
    /// A stage could not be set up or failed.
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    /// The simulated sensor failed.
    #[error(transparent)]
    Sensor(#[from] SensorError),
    /// Capture failed.
    #[error(transparent)]
    Capture(#[from] CaptureError),
    /// The recording failed.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// Bad options.
    #[error("{0}")]
    Options(String),
    /// The live loop stopped on a failure.
    #[error("the live loop failed: {0}")]
    Loop(String),
}

impl From<ReconstructError> for LiveBenchError {
    fn from(e: ReconstructError) -> Self {
        Self::Pipeline(e.into())
    }
}

impl From<StereoError> for LiveBenchError {
    fn from(e: StereoError) -> Self {
        Self::Pipeline(e.into())
    }
}

/// A stage alone.
#[derive(Debug, Clone, Serialize)]
pub struct StageRate {
    /// Which.
    pub stage: &'static str,
    /// Items per second sustained.
    pub per_s: f64,
    /// The goal, items per second.
    pub goal_per_s: f64,
    /// `per_s / goal_per_s`.
    pub ratio: f64,
}

/// Latency percentiles, ms.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Latency {
    /// Median.
    pub p50_ms: f64,
    /// 99th percentile.
    pub p99_ms: f64,
    /// Largest.
    pub max_ms: f64,
}

/// The live loop's figures.
#[derive(Debug, Clone, Serialize)]
pub struct LoopFigures {
    /// Seconds run.
    pub seconds: f64,
    /// Frames the cameras delivered, all cameras, per second.
    pub frames_per_s: f64,
    /// Frames labelled with a phase, per second.
    pub labelled_per_s: f64,
    /// Frames the cameras dropped or the matcher could not place (straddling, ...).
    pub frames_not_labelled: u64,
    /// Frames lost (camera sequence gaps).
    pub frames_dropped: u64,
    /// Messages the recorder dropped.
    pub recorder_drops: u64,
    /// Jobs each stage skipped for a newer one while busy: tactile pairs, stereo pairs.
    pub skipped: (u64, u64),
    /// Tactile pairs reconstructed per second.
    pub tactile_per_s: f64,
    /// Stereo frames per second.
    pub stereo_per_s: f64,
    /// Tactile latency, exposure end → depth.
    pub tactile_latency: Option<Latency>,
    /// Stereo latency.
    pub stereo_latency: Option<Latency>,
    /// Of the latency, the stages' own work (reconstruction or pipeline time; the rest
    /// is waiting for a busy stage and for the frame pair), tactile and stereo.
    pub processing: (Option<Latency>, Option<Latency>),
    /// CPU time (user + system, all threads) per delivered frame, ms.
    pub cpu_ms_per_frame: Option<f64>,
    /// Resident memory after the first minute (or the first sample), MiB.
    pub rss_mib_start: Option<f64>,
    /// Resident memory at the end, MiB.
    pub rss_mib_end: Option<f64>,
    /// Growth from start to end, percent.
    pub rss_growth_pct: Option<f64>,
}

/// One goal of the issue, met or not.
#[derive(Debug, Clone, Serialize)]
pub struct Goal {
    /// What.
    pub goal: String,
    /// Measured.
    pub measured: String,
    /// Met; `None` when this run cannot tell (too short).
    pub met: Option<bool>,
}

/// The report.
#[derive(Debug, Clone, Serialize)]
pub struct LiveBenchReport {
    /// Frame size.
    pub size: (u32, u32),
    /// Camera frame rate.
    pub fps: f64,
    /// Phase period, ms.
    pub period_ms: u32,
    /// Each stage alone.
    pub stages: Vec<StageRate>,
    /// The loop.
    pub live: LoopFigures,
    /// The goals.
    pub goals: Vec<Goal>,
}

/// Progress of the benchmark.
#[derive(Debug, Clone, Copy)]
pub enum LiveBenchProgress {
    /// Calibrating the built-in model.
    Calibrating,
    /// Timing the stages alone.
    Stages,
    /// The loop: seconds done of total.
    Loop(f64, f64),
}

/// Runs the benchmark.
pub fn run(
    options: &LiveBenchOptions,
    mut progress: impl FnMut(LiveBenchProgress),
) -> Result<LiveBenchReport, LiveBenchError> {
    let (w, h) = options.size;
    if !(options.fps.is_finite() && options.fps > 0.0 && options.fps <= 1000.0) {
        return Err(LiveBenchError::Options("--fps must be in 0..1000".into()));
    }
    if !(options.duration_s.is_finite() && options.duration_s > 0.0) {
        return Err(LiveBenchError::Options(
            "--duration-s must be positive".into(),
        ));
    }
    if !(options.stage_s.is_finite() && (0.1..=3600.0).contains(&options.stage_s)) {
        return Err(LiveBenchError::Options(format!(
            "--stage-s must be 0.1 to 3600 seconds, got {}",
            options.stage_s
        )));
    }
    progress(LiveBenchProgress::Calibrating);
    let optics = Optics::resolution(w as usize, h as usize);
    let (calibration, refs) = builtin_calibration(&optics, BUILTIN_PRESSES, |_| {})?;
    let px_per_mm = calibration.model.px_per_mm;
    let reconstructor = Reconstructor::new(
        calibration.model,
        ModelKind::Lut,
        SolverKind::Dct,
        Some((&refs.0, &refs.1).into()),
    )?;
    let stereo_rig = SimStereo::new(w, h);
    let stereo = || StereoPipeline::new(&stereo_rig.calibration(), StereoConfig::default());
    let scenes: Vec<PhaseImages> = builtin_scenes(&optics)
        .iter()
        .map(|(_, s)| PhaseImages::render(&optics, s))
        .collect();
    let views = stereo_rig.dark_views();

    progress(LiveBenchProgress::Stages);
    let stage_time = Duration::from_secs_f64(options.stage_s);
    let mut tactile = TactileStage::new(reconstructor.fresh(), px_per_mm, StampRef::ExposureStart);
    let pair = GradientPair {
        dx: labelled(scenes[0].of(stereotac_protocol::Phase::Dx).clone()),
        dy: labelled(scenes[0].of(stereotac_protocol::Phase::Dy).clone()),
        dark: None,
    };
    let tactile_rate = rate(stage_time, || {
        tactile.process(&pair, || None, 0).map(|_| ())
    })?;
    let mut stereo_stage = StereoStage::new(stereo()?, [StampRef::ExposureStart; 2]);
    let dark = DarkPair {
        left: labelled(views.0.clone()),
        right: labelled(views.1.clone()),
    };
    let stereo_rate = rate(stage_time, || {
        stereo_stage.process(&dark, || None, 0).map(|_| ())
    })?;
    let stages = vec![
        StageRate {
            stage: "tactile pairs (LUT, one thread)",
            per_s: tactile_rate,
            goal_per_s: 60.0,
            ratio: tactile_rate / 60.0,
        },
        StageRate {
            stage: "stereo frames",
            per_s: stereo_rate,
            goal_per_s: 30.0,
            ratio: stereo_rate / 30.0,
        },
    ];

    // The loop: the simulated sensor in real time, two free-running cameras.
    let clock: Arc<dyn HostClock> = Arc::new(MonotonicClock::new());
    let now = clock.now_us();
    let rig = crate::sim::connect(
        *b"BENCHLIV",
        Arc::clone(&clock),
        LoopbackConfig {
            drift_ppm: 25.0,
            boot_at_us: now,
            seed: now,
            ..LoopbackConfig::default()
        },
    )?;
    let mut sensor = rig.sensor;
    let period_us = 1e6 / options.fps;
    let mut sources: Vec<Box<dyn FrameSource>> = Vec::new();
    for (camera, dark) in [views.0, views.1].into_iter().enumerate() {
        let cam_scenes: Vec<PhaseImages> = scenes
            .iter()
            .map(|s| s.clone().with_dark(dark.clone()))
            .collect();
        let mut cam = SimulatedCamera::new(
            Arc::clone(&rig.timeline),
            Arc::clone(&clock),
            SimClocking::FreeRunning {
                period_us,
                // The second camera half a frame later: unsynchronised, as free-running
                // cameras are.
                first_us: clock.now_us() as f64 + camera as f64 * period_us / 2.0,
            },
            (period_us * 0.5).min(8000.0),
            cam_scenes[0].clone(),
        );
        cam.cycle_scenes(cam_scenes, 1_000_000.0);
        sources.push(Box::new(cam));
    }
    let recorder = Recorder::start(RecorderOptions {
        mcap: options.mcap.clone(),
        live_view: None,
        queue: 64,
        wait_when_full: false,
        clock_origin_unix_ns: clock_origin_unix_ns(clock.now_us()),
    })?;
    let mut session = Session::new(
        sources,
        MatcherConfig {
            sync: CameraSync::FreeRunning,
            ..MatcherConfig::default()
        },
    );
    let mut pipeline = Pipeline::new(
        Some(TactileStage::new(
            reconstructor,
            px_per_mm,
            StampRef::ExposureStart,
        )),
        Some(StereoStage::new(stereo()?, [StampRef::ExposureStart; 2])),
    );
    sensor.start_sequence(Mode::Interleaved, options.period_ms.saturating_mul(1000))?;
    let flag = AtomicBool::new(false);
    let start = Instant::now();
    let cpu_start = cpu_seconds();
    let mut hooks = BenchHooks {
        start,
        total_s: options.duration_s,
        progress: &mut progress,
        tactile: Vec::new(),
        stereo: Vec::new(),
        processing: (Vec::new(), Vec::new()),
        frames: 0,
        skipped: (0, 0),
        rss_start: None,
        last_progress: start,
    };
    let stopped = runner::run(
        &mut session,
        &mut sensor,
        &recorder,
        &mut pipeline,
        Until {
            flag: &flag,
            end_us: Some(clock.now_us() + (options.duration_s * 1e6) as u64),
        },
        &mut hooks,
    );
    if let runner::Stopped::Failed(e) = stopped {
        return Err(LiveBenchError::Loop(e));
    }
    let seconds = start.elapsed().as_secs_f64();
    let cpu = cpu_seconds().zip(cpu_start).map(|(b, a)| b - a);
    let rss_end = rss_mib();
    let recorder_drops = recorder.dropped().total();
    recorder.finish()?;
    let stats = session.stats();
    let labelled: u64 = stats.iter().map(|s| s.labelled).sum();
    let decided: u64 = stats.iter().map(|s| s.frames).sum();
    let frames = hooks.frames;
    let rss_start = hooks.rss_start.or(rss_end);
    let live = LoopFigures {
        seconds,
        frames_per_s: frames as f64 / seconds,
        labelled_per_s: labelled as f64 / seconds,
        frames_not_labelled: decided - labelled,
        frames_dropped: session.dropped_frames(),
        recorder_drops,
        skipped: hooks.skipped,
        tactile_per_s: hooks.tactile.len() as f64 / seconds,
        stereo_per_s: hooks.stereo.len() as f64 / seconds,
        tactile_latency: latency(hooks.tactile.clone()),
        stereo_latency: latency(hooks.stereo.clone()),
        processing: (
            latency(hooks.processing.0.clone()),
            latency(hooks.processing.1.clone()),
        ),
        cpu_ms_per_frame: cpu.map(|c| c * 1e3 / frames.max(1) as f64),
        rss_mib_start: rss_start,
        rss_mib_end: rss_end,
        rss_growth_pct: rss_start.zip(rss_end).map(|(a, b)| (b - a) / a * 100.0),
    };
    let goals = goals(&stages, &live, options);
    Ok(LiveBenchReport {
        size: options.size,
        fps: options.fps,
        period_ms: options.period_ms,
        stages,
        live,
        goals,
    })
}

/// What the loop hands the benchmark.
struct BenchHooks<'a, P> {
    start: Instant,
    total_s: f64,
    progress: &'a mut P,
    tactile: Vec<f64>,
    stereo: Vec<f64>,
    /// The stages' own time per output: tactile, stereo.
    processing: (Vec<f64>, Vec<f64>),
    frames: u64,
    skipped: (u64, u64),
    rss_start: Option<f64>,
    last_progress: Instant,
}

impl<P: FnMut(LiveBenchProgress)> Hooks for BenchHooks<'_, P> {
    type Error = LiveBenchError;

    fn frame(&mut self, _: usize, _: &LabelledFrame) -> Result<(), LiveBenchError> {
        self.frames += 1;
        let t = self.start.elapsed().as_secs_f64();
        if self.rss_start.is_none() && t >= 60f64.min(self.total_s / 2.0) {
            self.rss_start = rss_mib();
        }
        if self.last_progress.elapsed() >= Duration::from_millis(250) {
            self.last_progress = Instant::now();
            (self.progress)(LiveBenchProgress::Loop(t, self.total_s));
        }
        Ok(())
    }

    fn output(&mut self, output: &Output) -> Result<bool, LiveBenchError> {
        match output {
            Output::Tactile { record, .. } => {
                self.tactile.extend(record.latency_ms);
                self.processing.0.push(record.stage_ms.total_ms);
                self.skipped.0 = self.skipped.0.max(record.jobs_skipped);
            }
            Output::Stereo { record, .. } => {
                self.stereo.extend(record.latency_ms);
                self.processing.1.push(record.stage_ms.total_ms);
                self.skipped.1 = self.skipped.1.max(record.jobs_skipped);
            }
        }
        Ok(true)
    }

    fn warning(&mut self, _: String) {}
}

/// A frame labelled with a made-up phase, for the stage-alone timings.
fn labelled(image: image::RgbImage) -> LabelledFrame {
    LabelledFrame {
        frame: Frame {
            stamp: FrameStamp {
                sequence: 0,
                timestamp_us: 0.0,
                exposure_us: 1.0,
            },
            image,
        },
        label: Label::Unresolved,
    }
}

/// Calls of `f` per second over `time` (at least 3 calls).
fn rate<E>(time: Duration, mut f: impl FnMut() -> Result<(), E>) -> Result<f64, E> {
    let start = Instant::now();
    let mut n = 0u64;
    while n < 3 || start.elapsed() < time {
        f()?;
        n += 1;
    }
    Ok(n as f64 / start.elapsed().as_secs_f64())
}

fn latency(v: Vec<f64>) -> Option<Latency> {
    let [p50_ms, p99_ms, max_ms] = quantiles(v, [0.5, 0.99, 1.0])?;
    Some(Latency {
        p50_ms,
        p99_ms,
        max_ms,
    })
}

fn goals(stages: &[StageRate], live: &LoopFigures, options: &LiveBenchOptions) -> Vec<Goal> {
    let mut out: Vec<Goal> = stages
        .iter()
        .map(|s| Goal {
            goal: format!("{} ≥ {} /s", s.stage, s.goal_per_s),
            measured: format!("{:.1} /s (×{:.2})", s.per_s, s.ratio),
            met: Some(s.ratio >= 1.0),
        })
        .collect();
    let drops = live.frames_dropped + live.recorder_drops;
    out.push(Goal {
        goal: format!(
            "both stages together, interleaved at {} ms phases, {:.0} fps cameras: no drops",
            options.period_ms, options.fps
        ),
        measured: format!(
            "{} frames dropped, {} recorder drops",
            live.frames_dropped, live.recorder_drops
        ),
        met: Some(drops == 0),
    });
    for (what, l) in [
        ("tactile", live.tactile_latency),
        ("stereo", live.stereo_latency),
    ] {
        out.push(Goal {
            goal: format!("{what} latency p99 ≤ 30 ms"),
            measured: l.map_or("no output".into(), |l| {
                format!("p50 {:.1} ms, p99 {:.1} ms", l.p50_ms, l.p99_ms)
            }),
            met: l.map(|l| l.p99_ms <= 30.0),
        });
    }
    out.push(Goal {
        goal: "resident memory flat (≤ 5 % growth after the first minute)".into(),
        measured: match (live.rss_mib_start, live.rss_mib_end) {
            (Some(a), Some(b)) => format!("{a:.1} → {b:.1} MiB"),
            _ => "not measured (no /proc/self)".into(),
        },
        met: if live.seconds < 120.0 {
            None
        } else {
            live.rss_growth_pct.map(|g| g <= 5.0)
        },
    });
    out
}

/// CPU seconds (user + system) of this process so far, from `/proc/self/stat`.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which is in parentheses and may hold spaces).
    let rest = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let (utime, stime): (f64, f64) = (f.get(11)?.parse().ok()?, f.get(12)?.parse().ok()?);
    Some((utime + stime) / 100.0)
}

/// Resident memory, MiB, from `/proc/self/status`.
fn rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// The report as a table.
pub fn format_table(r: &LiveBenchReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let l = &r.live;
    let _ = writeln!(
        s,
        "live path, simulated sensor + 2 cameras {}×{} at {:.0} fps, interleaved, {} ms phases",
        r.size.0, r.size.1, r.fps, r.period_ms
    );
    for st in &r.stages {
        let _ = writeln!(
            s,
            "  alone: {:<32} {:8.1} /s  (goal {:>4}, ×{:.2})",
            st.stage, st.per_s, st.goal_per_s, st.ratio
        );
    }
    let lat = |x: Option<Latency>| {
        x.map_or("-".into(), |l| {
            format!(
                "p50 {:.1} / p99 {:.1} / max {:.1} ms",
                l.p50_ms, l.p99_ms, l.max_ms
            )
        })
    };
    let opt = |x: Option<f64>, unit: &str| x.map_or("-".into(), |v| format!("{v:.2} {unit}"));
    let _ = writeln!(
        s,
        "  loop {:.0} s: {:.1} frames/s delivered, {:.1} labelled/s; {} not labelled, {} dropped, {} recorder drops",
        l.seconds,
        l.frames_per_s,
        l.labelled_per_s,
        l.frames_not_labelled,
        l.frames_dropped,
        l.recorder_drops
    );
    let _ = writeln!(
        s,
        "  tactile {:.2} pairs/s ({} skipped while busy), latency {}\n  stereo  {:.2} frames/s ({} skipped while busy), latency {}",
        l.tactile_per_s,
        l.skipped.0,
        lat(l.tactile_latency),
        l.stereo_per_s,
        l.skipped.1,
        lat(l.stereo_latency)
    );
    let _ = writeln!(
        s,
        "  of which the stage's own work: tactile {}, stereo {}",
        lat(l.processing.0),
        lat(l.processing.1)
    );
    let _ = writeln!(
        s,
        "  CPU {} per frame; resident memory {} → {} ({})",
        opt(l.cpu_ms_per_frame, "ms"),
        opt(l.rss_mib_start, "MiB"),
        opt(l.rss_mib_end, "MiB"),
        opt(l.rss_growth_pct, "%")
    );
    for g in &r.goals {
        let mark = match g.met {
            Some(true) => "met   ",
            Some(false) => "MISSED",
            None => "n/a   ",
        };
        let _ = writeln!(s, "  [{mark}] {}: {}", g.goal, g.measured);
    }
    s
}
