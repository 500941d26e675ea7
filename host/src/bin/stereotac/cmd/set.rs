//! `stereotac set`: change colours, brightness, timing, LED count, power budget or mode.

use anyhow::{Context, Result, bail};
use stereotac::describe;
use stereotac_protocol::{Request, Rgb, Settings, Strip, StripSettings, Timing};

use crate::args::ModeArg;
use crate::sensor_args::{DeviceArgs, open};

/// `stereotac set`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
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
    #[arg(long, value_parser = parse_strip)]
    pub strip: Option<Strip>,
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
    #[command(flatten)]
    pub device: DeviceArgs,
}

fn parse_strip(s: &str) -> Result<Strip, String> {
    s.parse()
        .ok()
        .and_then(Strip::from_number)
        .ok_or_else(|| format!("{s:?} is not a strip number: 1 (x−), 2 (y−), 3 (x+) or 4 (y+)"))
}

fn parse_colour(s: &str) -> Result<Rgb, String> {
    let s = s.trim_start_matches('#');
    let v = u32::from_str_radix(s, 16)
        .ok()
        .filter(|_| s.len() == 6)
        .ok_or_else(|| format!("{s:?} is not a RRGGBB hex colour"))?;
    Ok(Rgb::new((v >> 16) as u8, (v >> 8) as u8, v as u8))
}

pub fn run(a: Args) -> Result<()> {
    let mut opened = open(&a.device)?;
    let sensor = &mut opened.sensor;
    let current = sensor.config()?;
    let (settings, changes) = changed(&a, current.settings());
    if changes.is_empty() {
        bail!("nothing to set: see `stereotac set --help`");
    }
    // One request carrying everything: the device checks every value before applying
    // any, so a refused one leaves it exactly as it was.
    sensor
        .request(Request::Configure(settings))
        .with_context(|| format!("{} (nothing was changed)", changes.join(", ")))?;
    for change in changes {
        println!("ok: {change}");
    }
    Ok(())
}

/// `current` with the options applied, and each change in words.
fn changed(a: &Args, current: Settings) -> (Settings, Vec<String>) {
    let mut s = current;
    let mut changes = Vec::new();
    if a.period_ms.is_some() || a.pulse_us.is_some() || a.settle_us.is_some() {
        s.timing = Timing {
            phase_period_us: a
                .period_ms
                .map_or(current.timing.phase_period_us, |ms| ms.saturating_mul(1000)),
            trigger_pulse_us: a.pulse_us.unwrap_or(current.timing.trigger_pulse_us),
            led_settle_us: a.settle_us.unwrap_or(current.timing.led_settle_us),
        };
        changes.push(describe::request(&Request::SetTiming(s.timing)));
    }
    if let Some(strip) = a.strip {
        let was = current.strips[strip.index()];
        let new = StripSettings {
            strip,
            colour: a.colour.unwrap_or(was.colour),
            brightness: a.brightness.unwrap_or(was.brightness),
        };
        s.strips[strip.index()] = new;
        changes.push(describe::request(&Request::SetStrip(new)));
    }
    if let Some(n) = a.leds {
        s.leds_per_strip = n;
        changes.push(describe::request(&Request::SetLedCount(n)));
    }
    if let Some(ma) = a.budget_ma {
        s.power_budget_ma = ma;
        changes.push(describe::request(&Request::SetPowerBudget(ma)));
    }
    if let Some(ms) = a.host_timeout_ms {
        s.host_timeout_ms = ms;
        changes.push(describe::request(&Request::SetHostTimeout(ms)));
    }
    if let Some(m) = a.mode {
        s.mode = m.into();
        changes.push(describe::request(&Request::SetMode(s.mode)));
    }
    (s, changes)
}
