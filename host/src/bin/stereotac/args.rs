//! Argument types more than one command takes: the lighting mode, the sequence settings
//! (`stream`, `record`), the stereo pipeline settings (`stereo`, `stereo-eval`), frame
//! sizes.

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use stereotac::clock::HostMicros;
use stereotac::device::Sensor;
use stereotac::stereo::StereoConfig;
use stereotac_protocol::Mode;

/// Lighting modes on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
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

/// The sequence settings of `stream` and `record`.
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

impl SequenceArgs {
    /// Sets the period and mode and starts the sequence.
    pub fn start(&self, sensor: &mut Sensor) -> Result<()> {
        if self.period_ms == 0 {
            bail!("--period-ms must be at least 1");
        }
        sensor
            .start_sequence(self.mode.into(), self.period_ms.saturating_mul(1000))
            .context("starting the sequence")
    }

    /// When to stop, on the sensor's host clock (`None`: until Ctrl-C).
    pub fn deadline(&self, sensor: &Sensor) -> Result<Option<HostMicros>> {
        match self.duration_s {
            Some(s) if !(s.is_finite() && s > 0.0) => bail!("--duration-s must be positive"),
            Some(s) => Ok(Some(sensor.clock().now_us() + (s * 1e6) as u64)),
            None => Ok(None),
        }
    }
}

/// Parses a frame size `WxH` (64 to 8192 pixels a side).
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .and_then(|(w, h)| Some((w.trim().parse().ok()?, h.trim().parse().ok()?)))
        .ok_or_else(|| format!("{s:?} is not a size like 640x480"))?;
    if !(64..=8192).contains(&w) || !(64..=8192).contains(&h) {
        return Err(format!(
            "size {s:?} out of range: 64 to 8192 pixels a side, like 640x480"
        ));
    }
    Ok((w, h))
}

/// Pipeline settings shared by `stereo`, `stereo-eval` and `run` (defaults: the
/// library's [`StereoConfig`]).
#[derive(Debug, Clone, clap::Args)]
pub struct PipelineArgs {
    /// Nearest depth searched, mm.
    #[arg(long, default_value_t = StereoConfig::default().near_mm)]
    pub near_mm: f64,
    /// Farthest depth searched, mm.
    #[arg(long, default_value_t = StereoConfig::default().far_mm)]
    pub far_mm: f64,
    /// Rectified focal length as a share of the cameras' (below 1 keeps more of a wide
    /// lens's field of view).
    #[arg(long, default_value_t = StereoConfig::default().rectify_scale)]
    pub scale: f64,
    /// Matching window side (odd).
    #[arg(long, default_value_t = StereoConfig::default().block_size)]
    pub block_size: u32,
}

impl Default for PipelineArgs {
    fn default() -> Self {
        let c = StereoConfig::default();
        Self {
            near_mm: c.near_mm,
            far_mm: c.far_mm,
            scale: c.rectify_scale,
            block_size: c.block_size,
        }
    }
}

impl PipelineArgs {
    /// The pipeline configuration these options describe.
    pub fn config(&self) -> StereoConfig {
        StereoConfig {
            near_mm: self.near_mm,
            far_mm: self.far_mm,
            rectify_scale: self.scale,
            block_size: self.block_size,
            ..StereoConfig::default()
        }
    }
}
