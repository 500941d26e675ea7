//! The metadata records every recording starts with: `stereotac` (what ran: command,
//! mode, period, cameras and what their timestamps mark, the host clock's origin on the
//! Unix epoch) and `sensor` (serial, firmware, protocol). `process` reads them back.

use std::collections::BTreeMap;

use stereotac_protocol::{DeviceInfo, Mode};

use super::topics;
use super::writer::Item;
use crate::device::{firmware_version, serial_number};
use crate::matcher::StampRef;

/// What ran, for the `stereotac` record.
#[derive(Debug, Clone)]
pub struct RunInfo {
    /// The command (`run`, `record`, `demo`).
    pub command: String,
    /// The lighting mode.
    pub mode: Mode,
    /// Phase period, ms.
    pub period_ms: u32,
    /// Unix time of the host clock's zero, ns.
    pub clock_origin_unix_ns: u64,
    /// Each camera's description and what its timestamps mark.
    pub cameras: Vec<(String, StampRef)>,
}

/// How the metadata names what a camera's timestamps mark.
pub fn stamp_ref_name(s: StampRef) -> &'static str {
    match s {
        StampRef::ExposureStart => "exposure_start",
        StampRef::ExposureEnd => "exposure_end",
    }
}

/// What camera `camera`'s timestamps mark, from a `stereotac` record (exposure start
/// when it does not say); `Err` names the bad value.
pub fn stamp_ref_of(
    entries: Option<&BTreeMap<String, String>>,
    camera: usize,
) -> Result<StampRef, String> {
    let key = format!("camera{camera}_stamp");
    match entries.and_then(|e| e.get(&key)).map(String::as_str) {
        None | Some("exposure_start") => Ok(StampRef::ExposureStart),
        Some("exposure_end") => Ok(StampRef::ExposureEnd),
        Some(other) => Err(format!(
            "metadata `{}` entry `{key}`: {other:?} (exposure_start or exposure_end)",
            topics::META_RECORDING
        )),
    }
}

/// The two header records.
pub fn header(run: &RunInfo, info: &DeviceInfo, simulated: bool) -> [Item; 2] {
    let mut entries = BTreeMap::from([
        ("version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
        ("command".to_string(), run.command.clone()),
        (
            "mode".to_string(),
            crate::describe::mode(run.mode).to_string(),
        ),
        ("period_ms".to_string(), run.period_ms.to_string()),
        ("cameras".to_string(), run.cameras.len().to_string()),
        (
            "clock_origin_unix_ns".to_string(),
            run.clock_origin_unix_ns.to_string(),
        ),
    ]);
    for (i, (describe, stamp)) in run.cameras.iter().enumerate() {
        entries.insert(format!("camera{i}"), describe.clone());
        entries.insert(format!("camera{i}_stamp"), stamp_ref_name(*stamp).into());
    }
    let sensor = BTreeMap::from([
        ("serial".to_string(), serial_number(&info.board_id)),
        ("firmware".to_string(), firmware_version(info)),
        (
            "protocol_version".to_string(),
            info.protocol_version.to_string(),
        ),
        ("simulated".to_string(), simulated.to_string()),
    ]);
    [
        Item::Metadata {
            name: topics::META_RECORDING.into(),
            entries,
        },
        Item::Metadata {
            name: topics::META_SENSOR.into(),
            entries: sensor,
        },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamp_references_round_trip_and_a_bad_one_is_named() {
        for s in [StampRef::ExposureStart, StampRef::ExposureEnd] {
            let m = BTreeMap::from([("camera1_stamp".into(), stamp_ref_name(s).into())]);
            assert_eq!(stamp_ref_of(Some(&m), 1), Ok(s));
        }
        assert_eq!(stamp_ref_of(None, 0), Ok(StampRef::ExposureStart));
        let bad = BTreeMap::from([("camera0_stamp".into(), "middle".into())]);
        assert!(
            stamp_ref_of(Some(&bad), 0)
                .unwrap_err()
                .contains("\"middle\"")
        );
    }
}
