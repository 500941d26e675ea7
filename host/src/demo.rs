//! `stereotac demo`: a simulated sensor driven through the real protocol.

use anyhow::{Result, bail};
use stereotac::client::Client;
use stereotac::sim::SimulatedSensor;
use stereotac_protocol::{Event, Mode, Request, Timing, TriggerOutcome};

use crate::DemoMode;

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

pub fn run(
    mode: DemoMode,
    period_ms: u32,
    phases: u32,
    tactile_out: Option<&std::path::Path>,
) -> Result<()> {
    if phases == 0 {
        bail!("--phases must be at least 1");
    }
    let mode = match mode {
        DemoMode::Vision => Mode::Vision,
        DemoMode::Contact => Mode::ContactShape,
        DemoMode::Gradient => Mode::Gradient,
        DemoMode::Interleaved => Mode::Interleaved,
    };
    println!(
        "stereotac demo: simulated sensor (firmware logic on a virtual clock, real wire frames)\n"
    );
    let mut client = Client::new(SimulatedSensor::new(*b"SIMULATD"));
    let info = client.handshake()?;
    let v = info.firmware_version;
    println!(
        "handshake: protocol v{}, firmware {}.{}.{} ({}{}), board {}, {} strips x {} LEDs (max {}), timer {} Hz",
        info.protocol_version,
        v.major,
        v.minor,
        v.patch,
        &hex(&info.git_hash)[..10],
        if info.git_dirty { "+dirty" } else { "" },
        hex(&info.board_id),
        info.strips,
        info.leds_per_strip,
        info.max_leds_per_strip,
        info.timer_hz
    );
    let period_us = period_ms.saturating_mul(1000);
    client.request(Request::SetTiming(Timing {
        phase_period_us: period_us,
        ..Timing::DEFAULT
    }))?;
    client.request(Request::SetMode(mode))?;
    client.request(Request::Start)?;
    println!("mode {mode:?}, phase period {period_ms} ms\n");
    println!(
        "{:>5} {:>5} {:>14} {:>14} {:>14} {:>14} {:>9}",
        "phase", "kind", "scheduled µs", "LED write µs", "latched µs", "trigger µs", "trigger#"
    );
    let mut shown = 0;
    let mut t = client.transport_mut().now_us();
    let mut previous_edge: Option<u64> = None;
    let mut periods = Vec::new();
    while shown < phases {
        t += u64::from(period_us);
        client.transport_mut().advance_to(t);
        for (_, event) in client.poll_events()? {
            let Event::Phase(p) = event else { continue };
            if shown == phases {
                break;
            }
            let (edge, index) = match p.trigger {
                TriggerOutcome::Fired { index, edge_us } => {
                    if let Some(prev) = previous_edge.replace(edge_us) {
                        periods.push(edge_us - prev);
                    }
                    (edge_us.to_string(), index.to_string())
                }
                TriggerOutcome::Overrun { .. } => ("overrun".into(), "-".into()),
            };
            println!(
                "{:>5} {:>5} {:>14} {:>14} {:>14} {:>14} {:>9}",
                p.index,
                format!("{:?}", p.phase),
                p.scheduled_us,
                p.write_start_us,
                p.latched_us,
                edge,
                index
            );
            shown += 1;
        }
    }
    client.request(Request::Stop)?;
    let status = match client.request(Request::GetStatus)? {
        stereotac_protocol::Response::Status(s) => s,
        other => bail!("unexpected reply {other:?}"),
    };
    if let (Some(min), Some(max)) = (periods.iter().min(), periods.iter().max()) {
        println!(
            "\ntrigger period: min {min} µs, max {max} µs (nominal {period_us} µs, {} intervals)",
            periods.len()
        );
    }
    println!(
        "counters: {}; host saw {} lost events",
        stereotac::device::status_line(&status),
        client.lost_events()
    );
    if let Some(out) = tactile_out {
        crate::demo_tactile::run(out)?;
    }
    Ok(())
}
