//! Command conformance of a connected sensor: every configuration command is
//! acknowledged and reads back as set, every invalid value is refused with its typed
//! error and counted, and the sensor is left as it was found (configuration restored,
//! sequencer stopped).
//!
//! One check for every kind of sensor: `stereotac selftest` runs it on an attached or
//! simulated sensor, the host-link tests on the in-process loopback, the HIL tests on
//! the firmware in the emulated RP2040. It talks only through [`Sensor`], so it is the
//! same code path a user's program takes.

use serde::Serialize;
use stereotac_protocol::{
    Capabilities, Config, DeviceError, Field, Mode, PROTOCOL_VERSION, Request, Response, Rgb,
    Strip, StripSettings, Timing,
};

use crate::client::ClientError;
use crate::describe;
use crate::device::{Sensor, SensorError};

/// One check and its outcome.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Check {
    /// What was checked.
    pub name: String,
    /// Whether it held.
    pub passed: bool,
    /// What was seen when it did not.
    #[serde(skip_serializing_if = "String::is_empty")]
    pub detail: String,
}

/// Every check of one run.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct SelftestReport {
    /// The checks, in the order they ran.
    pub checks: Vec<Check>,
}

impl SelftestReport {
    /// Whether every check held.
    pub fn passed(&self) -> bool {
        self.checks.iter().all(|c| c.passed)
    }

    /// The checks that failed.
    pub fn failures(&self) -> impl Iterator<Item = &Check> {
        self.checks.iter().filter(|c| !c.passed)
    }

    fn record(&mut self, name: impl Into<String>, passed: bool, detail: impl Into<String>) {
        let detail = if passed { String::new() } else { detail.into() };
        self.checks.push(Check {
            name: name.into(),
            passed,
            detail,
        });
    }
}

/// Whether a device error is the one a refusal should give.
type IsExpected = fn(&DeviceError) -> bool;

/// The settings the check applies (all valid for any sensor of this protocol).
fn test_settings() -> (Timing, StripSettings) {
    (
        Timing {
            phase_period_us: 100_000,
            ..Timing::DEFAULT
        },
        StripSettings {
            strip: Strip::YPlus,
            colour: Rgb::new(200, 0, 0),
            brightness: 90,
        },
    )
}

/// Runs the command checks on `sensor` and puts its configuration back. Errors are
/// link failures (the check could not run); a sensor that answers wrongly gives a
/// report with failed checks.
pub fn run_command_checks(sensor: &mut Sensor) -> Result<SelftestReport, SensorError> {
    let mut report = SelftestReport::default();
    let version = sensor.info().protocol_version;
    report.record(
        "protocol version",
        version == PROTOCOL_VERSION,
        format!("sensor speaks v{version}, host v{PROTOCOL_VERSION}"),
    );
    let original = sensor.config()?;
    let rejected_before = sensor.status()?.requests_rejected;
    let (timing, strip) = test_settings();
    // A pixel count other than the current one, so the read-back shows the change.
    let leds = if original.leds_per_strip == 12 {
        11
    } else {
        12
    };
    let leds = leds.min(sensor.info().max_leds_per_strip.max(1));
    let has_probe = has_probe(sensor);
    // The probe flips where there is one; the other settings change to fixed values.
    let probe = if has_probe {
        !original.probe
    } else {
        original.probe
    };
    let mut requests = vec![
        Request::SetMode(Mode::Gradient),
        Request::SetTiming(timing),
        Request::SetStrip(strip),
        Request::SetLedCount(leds),
        Request::SetPowerBudget(300),
        Request::SetHostTimeout(2000),
        Request::Start,
        Request::Stop,
    ];
    if has_probe {
        requests.push(Request::SetProbe(probe));
    }
    for request in requests {
        let answer = sensor.request(request);
        report.record(
            format!("{} acknowledged", describe::request(&request)),
            matches!(answer, Ok(Response::Ack)),
            describe::answer(&answer),
        );
    }
    let config = sensor.config()?;
    let expected = Config {
        mode: Mode::Gradient,
        timing,
        leds_per_strip: leds,
        power_budget_ma: 300,
        host_timeout_ms: 2000,
        strips: {
            let mut strips = original.strips;
            strips[strip.strip.index()] = strip;
            strips
        },
        power_scale: config.power_scale,
        probe,
    };
    report.record(
        "configuration reads back as set",
        config == expected,
        format!(
            "read {}, expected {}",
            describe::config_line(&config),
            describe::config_line(&expected)
        ),
    );
    let time = sensor.request(Request::TimeSync);
    report.record(
        "time sync answered with the device time",
        matches!(time, Ok(Response::Time(_))),
        describe::answer(&time),
    );
    let infeasible = Timing {
        phase_period_us: 1500,
        ..Timing::DEFAULT
    };
    let refusals: [(Request, IsExpected, &str); 4] = [
        (
            Request::SetLedCount(0),
            |e| *e == DeviceError::InvalidValue(Field::LedCount),
            "InvalidValue(LedCount)",
        ),
        (
            Request::SetPowerBudget(0),
            |e| *e == DeviceError::InvalidValue(Field::PowerBudget),
            "InvalidValue(PowerBudget)",
        ),
        (
            Request::SetHostTimeout(5),
            |e| *e == DeviceError::InvalidValue(Field::HostTimeout),
            "InvalidValue(HostTimeout)",
        ),
        (
            Request::SetTiming(infeasible),
            |e| matches!(e, DeviceError::TimingInfeasible { .. }),
            "TimingInfeasible",
        ),
    ];
    let probe_refusal: (Request, IsExpected, &str) = (
        Request::SetProbe(true),
        |e| *e == DeviceError::InvalidState,
        "InvalidState (no loopback probe)",
    );
    let mut refused = 0;
    for (request, wanted, name) in refusals
        .into_iter()
        .chain((!has_probe).then_some(probe_refusal))
    {
        let answer = sensor.request(request);
        let ok = matches!(&answer, Err(SensorError::Client(ClientError::Device(e))) if wanted(e));
        refused += u32::from(ok);
        report.record(
            format!("{} refused with {name}", describe::request(&request)),
            ok,
            describe::answer(&answer),
        );
    }
    // Many settings with one bad value: refused whole, nothing applied.
    let before = sensor.config()?;
    let mut bad = before.settings();
    bad.timing.phase_period_us = before.timing.phase_period_us.saturating_add(10_000);
    bad.power_budget_ma = if before.power_budget_ma == 300 {
        400
    } else {
        300
    };
    bad.leds_per_strip = 0;
    let answer = sensor.request(Request::Configure(bad));
    let ok = matches!(
        &answer,
        Err(SensorError::Client(ClientError::Device(
            DeviceError::InvalidValue(Field::LedCount)
        )))
    );
    refused += u32::from(ok);
    let after = sensor.config()?;
    report.record(
        "configure with one bad value refused with InvalidValue(LedCount), nothing applied",
        ok && after == before,
        format!(
            "{}; configuration {}",
            describe::answer(&answer),
            if after == before {
                "unchanged"
            } else {
                "changed"
            }
        ),
    );
    sensor.request(Request::SetMode(Mode::Off))?;
    let answer = sensor.request(Request::Start);
    let ok = matches!(
        answer,
        Err(SensorError::Client(ClientError::Device(
            DeviceError::InvalidState
        )))
    );
    refused += u32::from(ok);
    report.record(
        "start with mode off refused with InvalidState",
        ok,
        describe::answer(&answer),
    );
    let rejected = sensor.status()?.requests_rejected - rejected_before;
    report.record(
        "refusals counted by the device",
        rejected == refused,
        format!("device counted {rejected}, {refused} were refused"),
    );
    restore(sensor, &original)?;
    let after = sensor.config()?;
    report.record(
        "configuration restored",
        Config {
            power_scale: original.power_scale,
            ..after
        } == original,
        format!(
            "now {}, was {}",
            describe::config_line(&after),
            describe::config_line(&original)
        ),
    );
    Ok(report)
}

/// Puts `config` back (the sequencer stays stopped).
fn restore(sensor: &mut Sensor, config: &Config) -> Result<(), SensorError> {
    sensor.request(Request::Stop)?;
    sensor.request(Request::SetLedCount(config.leds_per_strip))?;
    sensor.request(Request::SetPowerBudget(config.power_budget_ma))?;
    sensor.request(Request::SetHostTimeout(config.host_timeout_ms))?;
    sensor.request(Request::SetTiming(config.timing))?;
    for strip in config.strips {
        sensor.request(Request::SetStrip(strip))?;
    }
    sensor.request(Request::SetMode(config.mode))?;
    if has_probe(sensor) {
        sensor.request(Request::SetProbe(config.probe))?;
    }
    Ok(())
}

/// Whether the sensor has the loopback probe inputs.
fn has_probe(sensor: &Sensor) -> bool {
    sensor.info().capabilities.has(Capabilities::LOOPBACK_PROBE)
}
