//! `stereotac stream`: runs the lighting sequence and prints phase events with host-clock
//! timestamps, clock-sync uncertainty and drop counters (Ctrl-C stops).

use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::Result;
use stereotac::describe;
use stereotac::device::{SensorEvent, status_line};
use stereotac::matcher::phase_str;
use stereotac_protocol::{Request, TriggerOutcome};

use crate::args::SequenceArgs;
use crate::console::{emit, interrupt_flag};
use crate::sensor_args::{DeviceArgs, open};

/// `stereotac stream`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub sequence: SequenceArgs,
    /// One JSON object per line.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

pub fn run(a: Args) -> Result<()> {
    let stop = interrupt_flag()?;
    let mut opened = open(&a.device)?;
    let sensor = &mut opened.sensor;
    a.sequence.start(sensor)?;
    let end = a.sequence.deadline(sensor)?;
    if !a.json {
        emit(format_args!(
            "{:>6} {:>5} {:>16} {:>16} {:>8} {:>10} {:>7}",
            "phase", "kind", "trigger host µs", "trigger dev µs", "trigger#", "±sync µs", "lost"
        ));
    }
    while !stop.load(Ordering::SeqCst) && end.is_none_or(|e| sensor.clock().now_us() < e) {
        for event in sensor.poll(Duration::from_millis(50))? {
            let lost = sensor.counters().link.lost_events;
            let shown = match &event {
                SensorEvent::Phase(_) | SensorEvent::Heartbeat(_) if a.json => {
                    match describe::event_json(&event, lost) {
                        Some(line) => emit(format_args!("{line}")),
                        None => true,
                    }
                }
                SensorEvent::Phase(p) => {
                    let (trigger, dev) = match p.event.trigger {
                        TriggerOutcome::Fired { index, edge_us } => (Some(index), Some(edge_us)),
                        TriggerOutcome::Overrun { .. } => (None, None),
                    };
                    let host = p.trigger.map(|t| t.1);
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
                }
                SensorEvent::Heartbeat(_) | SensorEvent::Probe(_) => true,
                SensorEvent::Fault(f, at) => {
                    eprintln!("fault {:?} at host {at:.0} µs", f.kind);
                    true
                }
                SensorEvent::Reconnected { attempts } => {
                    eprintln!("reconnected after {attempts} attempts");
                    true
                }
            };
            if !shown {
                stop.store(true, Ordering::SeqCst);
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
