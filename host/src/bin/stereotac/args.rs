//! Argument types more than one command takes: the lighting mode, the sequence settings
//! (`stream`, `record`), the stereo pipeline settings (`stereo`, `stereo-eval`), frame
//! sizes.

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use stereotac::clock::HostMicros;
use stereotac::device::Sensor;
use stereotac::stereo::{MatcherKind, Paths, StereoConfig};
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
    #[arg(long, allow_negative_numbers = true, value_parser = parse_duration_s)]
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
            .with_context(|| {
                format!(
                    "starting the sequence with --period-ms {} (stereotac's firmware takes \
                     1 to 60000)",
                    self.period_ms
                )
            })
    }

    /// When to stop, on the sensor's host clock (`None`: until Ctrl-C).
    pub fn deadline(&self, sensor: &Sensor) -> Result<Option<HostMicros>> {
        match self.duration_s {
            Some(s) => {
                parse_duration_s(&s.to_string())
                    .map_err(|e| anyhow::anyhow!("--duration-s: {e}"))?;
                Ok(Some(
                    sensor.clock().now_us().saturating_add((s * 1e6) as u64),
                ))
            }
            None => Ok(None),
        }
    }
}

/// Longest run a duration may ask for (s): 115 days, far beyond any recording, and far
/// from the host clock's µs range.
pub const MAX_DURATION_S: f64 = 1e7;

/// Parses a duration in seconds: finite, above 0, at most [`MAX_DURATION_S`].
pub fn parse_duration_s(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a number of seconds"))?;
    if v.is_finite() && v > 0.0 && v <= MAX_DURATION_S {
        Ok(v)
    } else {
        Err(format!(
            "{s} s: a duration must be above 0 and at most {MAX_DURATION_S} s (115 days)"
        ))
    }
}

/// Refuses a value that is another flag: options whose values may start with `-` (a
/// range from below zero) would otherwise take `--mesh` in `--colour-range --mesh` as
/// their value, and say only that it is not a range.
pub fn not_a_flag(text: &str, wanted: &str) -> Result<(), String> {
    if text.starts_with("--") {
        return Err(format!(
            "that is another flag, not a value: give this option its value first ({wanted})"
        ));
    }
    Ok(())
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
    #[arg(long, allow_negative_numbers = true, default_value_t = StereoConfig::default().near_mm)]
    pub near_mm: f64,
    /// Farthest depth searched, mm.
    #[arg(long, allow_negative_numbers = true, default_value_t = StereoConfig::default().far_mm)]
    pub far_mm: f64,
    /// Rectified focal length as a share of the cameras' (below 1 keeps more of a wide
    /// lens's field of view).
    #[arg(long, allow_negative_numbers = true, default_value_t = StereoConfig::default().rectify_scale)]
    pub scale: f64,
    /// Matching window side (odd): block matching's blocks; semi-global matching's
    /// sub-pixel refinement window (3..=31; larger: less noise on smooth surfaces, small
    /// depth steps blurred over more columns) [default: 9 with bm, 11 with sgm].
    #[arg(long)]
    pub block_size: Option<u32>,
    /// Disparity matcher: `bm` (block matching, fastest) or `sgm` (semi-global: census
    /// costs along 8 paths and sub-pixel refinement; fewer wrong pixels on slanted and
    /// weakly textured surfaces, several times block matching's time).
    #[arg(long, default_value = "bm", value_parser = choices::<MatcherKind, 2>(MatcherKind::ALL.map(MatcherKind::name)))]
    pub matcher: MatcherKind,
    /// Paths semi-global matching aggregates along: 8 (every direction, fewest
    /// streaks), 5 or 4, or 3 (along the row both ways and down, as OpenCV's
    /// StereoSGBM 3-way: fastest). Only with `--matcher sgm` [default: 8].
    #[arg(long, value_parser = choices::<Paths, 4>(["3", "4", "5", "8"]))]
    pub sgm_paths: Option<Paths>,
}

/// A value of `choices` (listed in `--help` and in clap's error), read through the
/// library's own parser.
fn choices<T, const N: usize>(
    choices: [&'static str; N],
) -> impl clap::builder::TypedValueParser<Value = T>
where
    T: std::str::FromStr<Err = String> + Clone + Send + Sync + 'static,
{
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(choices).try_map(|s| s.parse::<T>())
}

impl Default for PipelineArgs {
    fn default() -> Self {
        let c = StereoConfig::default();
        Self {
            near_mm: c.near_mm,
            far_mm: c.far_mm,
            scale: c.rectify_scale,
            block_size: None,
            matcher: MatcherKind::Bm,
            sgm_paths: None,
        }
    }
}

impl PipelineArgs {
    /// The pipeline configuration these options describe; paths for semi-global
    /// matching given with another matcher are refused (they would be ignored).
    pub fn config(&self) -> Result<StereoConfig> {
        if self.sgm_paths.is_some() && self.matcher != MatcherKind::Sgm {
            bail!("--sgm-paths sets semi-global matching's paths: add --matcher sgm");
        }
        let d = StereoConfig::default();
        Ok(StereoConfig {
            near_mm: self.near_mm,
            far_mm: self.far_mm,
            rectify_scale: self.scale,
            block_size: self.block_size,
            matcher: self.matcher,
            sgm_paths: self.sgm_paths.unwrap_or(d.sgm_paths),
            ..d
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_are_bounded_and_sizes_parsed() {
        assert_eq!(parse_duration_s("1.5"), Ok(1.5));
        for bad in ["0", "-1", "1e15", "inf", "NaN", "soon"] {
            assert!(parse_duration_s(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_size("640x480"), Ok((640, 480)));
        assert!(parse_size("100000x100000").is_err());
    }
}
