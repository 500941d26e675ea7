//! `stereotac devices`: the sensors attached (serial number, firmware version, bus path),
//! once or, with `--watch`, as they come and go.

use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use stereotac::device::{firmware_version, serial_number};
use stereotac::transport::usb;

use crate::console::{emit, interrupt_flag};
use crate::sensor_args::{DeviceArgs, open};

/// `stereotac devices`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Keep watching: print sensors as they are plugged in and devices as they leave
    /// (Ctrl-C stops).
    #[arg(long, conflicts_with = "sim")]
    pub watch: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

pub fn run(a: Args) -> Result<()> {
    if a.watch {
        if a.device.sim {
            bail!("the argument '--watch' cannot be used with '--sim'");
        }
        return watch(a.json);
    }
    let mut rows = Vec::new();
    if a.device.sim {
        let opened = open(&a.device)?;
        let info = *opened.sensor.info();
        rows.push(serde_json::json!({
            "serial": serial_number(&info.board_id), "path": "sim",
            "firmware": firmware_version(&info), "protocol": info.protocol_version,
        }));
    } else {
        for found in crate::sensor_args::list_sensors(&a.device)? {
            // Ask each one for its version; report (not fail) if it cannot be opened.
            let firmware = match open(&DeviceArgs {
                serial: Some(found.serial.clone()),
                ..a.device.clone()
            }) {
                Ok(o) => firmware_version(o.sensor.info()),
                Err(e) => format!("unavailable: {e:#}"),
            };
            rows.push(serde_json::json!({
                "serial": found.serial, "path": found.path, "firmware": firmware,
                "product": found.product,
            }));
        }
    }
    if a.json {
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

/// Print sensor arrivals and departures until Ctrl-C.
fn watch(json: bool) -> Result<()> {
    let stop = interrupt_flag()?;
    let mut watch = usb::watch().context("watching the USB bus for sensors")?;
    eprintln!("watching for stereotac sensors (Ctrl-C stops)");
    while !stop.load(Ordering::SeqCst) {
        let Some(event) = watch.next(std::time::Instant::now() + Duration::from_millis(200)) else {
            continue;
        };
        let printed = if json {
            emit(format_args!("{}", serde_json::to_string(&event)?))
        } else {
            match event {
                usb::Hotplug::Arrived(s) => {
                    emit(format_args!("arrived  {:<18} {}", s.serial, s.path))
                }
                usb::Hotplug::Left { id } => emit(format_args!("left     (USB device {id})")),
            }
        };
        if !printed {
            break;
        }
    }
    Ok(())
}
