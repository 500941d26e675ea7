//! `stereotac info`: handshake details, configuration, device counters and clock sync of
//! one sensor.

use anyhow::Result;
use stereotac::describe;
use stereotac::device::{firmware_version, serial_number, status_line};

use crate::sensor_args::{DeviceArgs, open};

/// `stereotac info`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

pub fn run(a: Args) -> Result<()> {
    let mut opened = open(&a.device)?;
    let sensor = &mut opened.sensor;
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&describe::sensor_json(sensor)?)?
        );
        return Ok(());
    }
    let info = *sensor.info();
    let status = sensor.status()?;
    let config = sensor.config()?;
    let fit = sensor.clock_fit().copied();
    println!(
        "sensor {}: protocol v{}, firmware {}, {} strips x {} LEDs (max {}), timer {} Hz, capabilities {:#x}",
        serial_number(&info.board_id),
        info.protocol_version,
        firmware_version(&info),
        info.strips,
        info.leds_per_strip,
        info.max_leds_per_strip,
        info.timer_hz,
        info.capabilities.0
    );
    println!(
        "mode {}, period {} µs, trigger pulse {} µs, settle {} µs, power budget {} mA (scale {}/255), host timeout {} ms",
        describe::mode(config.mode),
        config.timing.phase_period_us,
        config.timing.trigger_pulse_us,
        config.timing.led_settle_us,
        config.power_budget_ma,
        config.power_scale,
        config.host_timeout_ms
    );
    for s in &config.strips {
        println!("  {}", describe::strip(s));
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
