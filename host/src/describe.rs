//! Plain words for protocol values (requests, answers, modes, strips, configurations),
//! for people and for JSON: what `set`, `info` and `selftest` print instead of Rust's
//! debug text. Strips are named by number and side everywhere (`strip 1 (x−)`).

use serde_json::{Value, json};
use stereotac_protocol::{
    Config, Mode, Request, Response, Rgb, Settings, Status, StripSettings, Timing,
};

use crate::device::{Sensor, SensorError, SensorEvent, firmware_version, serial_number};
use crate::matcher::phase_str;

/// A mode as the CLI's `--mode` names it.
pub fn mode(mode: Mode) -> &'static str {
    match mode {
        Mode::Off => "off",
        Mode::Vision => "vision",
        Mode::ContactShape => "contact",
        Mode::Gradient => "gradient",
        Mode::Interleaved => "interleaved",
    }
}

/// The mode `name` names (as [`mode`] writes it), if any.
pub fn mode_named(name: &str) -> Option<Mode> {
    [
        Mode::Off,
        Mode::Vision,
        Mode::ContactShape,
        Mode::Gradient,
        Mode::Interleaved,
    ]
    .into_iter()
    .find(|m| mode(*m).eq_ignore_ascii_case(name.trim()))
}

/// `#rrggbb`.
pub fn colour(c: Rgb) -> String {
    format!("#{:02x}{:02x}{:02x}", c.r, c.g, c.b)
}

/// `strip 1 (x−): colour #0000ff, brightness 128`.
pub fn strip(s: &StripSettings) -> String {
    format!(
        "{}: colour {}, brightness {}",
        s.strip,
        colour(s.colour),
        s.brightness
    )
}

/// `period 250000 µs, trigger pulse 100 µs, settle 500 µs`.
pub fn timing(t: &Timing) -> String {
    format!(
        "period {} µs, trigger pulse {} µs, settle {} µs",
        t.phase_period_us, t.trigger_pulse_us, t.led_settle_us
    )
}

/// What a request asks for, e.g. `set strip 2 (y−): colour #ff0000, brightness 40`.
pub fn request(r: &Request) -> String {
    match r {
        Request::GetInfo => "get info".into(),
        Request::GetStatus => "get status".into(),
        Request::GetConfig => "get configuration".into(),
        Request::SetMode(m) => format!("set mode {}", mode(*m)),
        Request::SetTiming(t) => format!("set timing: {}", timing(t)),
        Request::SetStrip(s) => format!("set {}", strip(s)),
        Request::SetLedCount(n) => format!("set LEDs per strip to {n}"),
        Request::SetPowerBudget(ma) => format!("set power budget to {ma} mA"),
        Request::SetHostTimeout(ms) => format!("set host timeout to {ms} ms"),
        Request::Start => "start".into(),
        Request::Stop => "stop".into(),
        Request::TimeSync => "time sync".into(),
        Request::EnterBootloader => "enter the USB bootloader".into(),
        Request::SetProbe(on) => format!("turn the loopback probe {}", on_off(*on)),
        Request::Configure(s) => format!("configure: {}", settings_line(s)),
    }
}

/// Everything a `Configure` sets, on one line.
pub fn settings_line(s: &Settings) -> String {
    let strips: Vec<String> = s.strips.iter().map(strip).collect();
    format!(
        "mode {}, {}, {} LEDs per strip, power budget {} mA, host timeout {} ms; {}",
        mode(s.mode),
        timing(&s.timing),
        s.leds_per_strip,
        s.power_budget_ma,
        s.host_timeout_ms,
        strips.join("; ")
    )
}

/// How the device answered: `acknowledged`, `refused: …`, or what it sent.
pub fn answer(a: &Result<Response, SensorError>) -> String {
    match a {
        Ok(Response::Ack) => "acknowledged".into(),
        Ok(Response::Config(c)) => format!("configuration {}", config_line(c)),
        Ok(Response::Time(t)) => format!("device time {t} µs"),
        Ok(Response::Status(_)) => "a status".into(),
        Ok(Response::Info(_)) => "the device info".into(),
        Err(e) => format!("refused: {e}"),
    }
}

/// A whole configuration on one line: its settings, then what the device derives.
pub fn config_line(c: &Config) -> String {
    format!(
        "{}; brightness scale {}/255 under the power budget, probe {}",
        settings_line(&c.settings()),
        c.power_scale,
        on_off(c.probe)
    )
}

/// A configuration as a JSON object (strips by number and side).
pub fn config_json(c: &Config) -> Value {
    json!({
        "mode": mode(c.mode),
        "phase_period_us": c.timing.phase_period_us,
        "trigger_pulse_us": c.timing.trigger_pulse_us,
        "led_settle_us": c.timing.led_settle_us,
        "leds_per_strip": c.leds_per_strip,
        "power_budget_ma": c.power_budget_ma,
        "power_scale": c.power_scale,
        "host_timeout_ms": c.host_timeout_ms,
        "probe": c.probe,
        "strips": c.strips.iter().map(|s| json!({
            "strip": s.strip.number(),
            "side": s.strip.side(),
            "colour": colour(s.colour),
            "brightness": s.brightness,
        })).collect::<Vec<_>>(),
    })
}

/// The device's status as a JSON object (the mode named as `--mode` names it).
pub fn status_json(s: &Status) -> Value {
    let mut v = serde_json::to_value(s).unwrap_or(Value::Null);
    v["mode"] = mode(s.mode).into();
    v
}

fn on_off(on: bool) -> &'static str {
    if on { "on" } else { "off" }
}

/// One sensor's identity, configuration, counters and clock sync as JSON (what
/// `stereotac info --json` prints); asks the sensor for its status and configuration.
pub fn sensor_json(sensor: &mut Sensor) -> Result<Value, SensorError> {
    let info = *sensor.info();
    let status = sensor.status()?;
    let config = sensor.config()?;
    let fit = sensor.clock_fit().copied();
    Ok(json!({
        "serial": serial_number(&info.board_id),
        "protocol": info.protocol_version,
        "firmware": firmware_version(&info),
        "leds_per_strip": info.leds_per_strip,
        "max_leds_per_strip": info.max_leds_per_strip,
        "capabilities": info.capabilities.0,
        "status": status_json(&status),
        "config": config_json(&config),
        "clock": fit.map(|f| json!({
            "drift_ppm": f.drift_ppm(), "uncertainty_us": f.uncertainty_us,
            "min_rtt_us": f.min_rtt_us, "pings": f.samples })),
        "host_counters": sensor.counters(),
    }))
}

/// One sensor event as JSON (what `stereotac stream --json` prints), `lost_events` the
/// link's count of lost events so far; `None` for the probe's readings.
pub fn event_json(event: &SensorEvent, lost_events: u64) -> Option<Value> {
    use stereotac_protocol::TriggerOutcome;
    match event {
        SensorEvent::Phase(p) => {
            let (trigger, dev) = match p.event.trigger {
                TriggerOutcome::Fired { index, edge_us } => (Some(index), Some(edge_us)),
                TriggerOutcome::Overrun { .. } => (None, None),
            };
            Some(json!({"event": "phase", "index": p.event.index,
                "phase": phase_str(p.event.phase), "trigger": trigger,
                "trigger_device_us": dev, "trigger_host_us": p.trigger.map(|t| t.1),
                "latched_host_us": p.latched_us, "sync_uncertainty_us": p.uncertainty_us,
                "lost_events": lost_events}))
        }
        SensorEvent::Heartbeat(s) => Some(json!({"event": "heartbeat", "phases": s.phases,
            "triggers": s.triggers, "overruns": s.overruns,
            "events_dropped": s.events_dropped})),
        SensorEvent::Fault(f, at) => Some(json!({"event": "fault",
            "kind": format!("{:?}", f.kind), "host_us": at})),
        SensorEvent::Reconnected { attempts } => {
            Some(json!({"event": "reconnected", "attempts": attempts}))
        }
        SensorEvent::Probe(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereotac_protocol::Strip;

    #[test]
    fn requests_read_as_words() {
        let s = StripSettings {
            strip: Strip::YMinus,
            colour: Rgb::new(255, 0, 16),
            brightness: 40,
        };
        assert_eq!(
            request(&Request::SetStrip(s)),
            "set strip 2 (y−): colour #ff0010, brightness 40"
        );
        assert_eq!(
            request(&Request::SetMode(Mode::ContactShape)),
            "set mode contact"
        );
        assert_eq!(answer(&Ok(Response::Ack)), "acknowledged");
    }

    #[test]
    fn a_configuration_is_a_json_object_with_numbered_strips() {
        let c = Config {
            mode: Mode::Gradient,
            timing: Timing::DEFAULT,
            strips: Strip::ALL.map(|strip| StripSettings {
                strip,
                colour: Rgb::new(0, 0, 255),
                brightness: 10,
            }),
            leds_per_strip: 8,
            power_budget_ma: 500,
            host_timeout_ms: 0,
            power_scale: 255,
            probe: false,
        };
        let v = config_json(&c);
        assert_eq!(v["mode"], "gradient");
        assert_eq!(v["strips"][2]["strip"], 3);
        assert_eq!(v["strips"][2]["side"], "x+");
        assert_eq!(v["strips"][0]["colour"], "#0000ff");
        assert!(!config_line(&c).contains('{'), "{}", config_line(&c));
    }

    #[test]
    fn modes_are_read_back_by_name() {
        for m in [
            Mode::Off,
            Mode::Vision,
            Mode::ContactShape,
            Mode::Gradient,
            Mode::Interleaved,
        ] {
            assert_eq!(mode_named(mode(m)), Some(m));
        }
        assert_eq!(mode_named(" Gradient "), Some(Mode::Gradient));
        assert_eq!(mode_named("strobe"), None);
    }
}
