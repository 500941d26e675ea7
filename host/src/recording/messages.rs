//! What goes on each topic: the JSON messages of our own, and conversions between our
//! frames, depth maps and point clouds and Foxglove's well-known schemas, both ways
//! (the writer encodes, `process` and the tests decode).

use foxglove::messages::{
    PackedElementField, PointCloud as FoxCloud, RawImage, Timestamp, packed_element_field,
};
use image::RgbImage;
use serde::{Deserialize, Serialize};
use stereotac_protocol::Phase;

use crate::clock::ClockFit;
use crate::device::HostPhase;
use crate::grid::Grid;
use crate::matcher::{FrameStamp, Label, phase_str};
use crate::stereo::pipeline::StereoTimings;
use crate::stereo::reproject::PointCloud;
use crate::tactile::ambient::AmbientSource;
use crate::tactile::reconstruct::StageTimings;

/// What records written before the field existed removed: nothing but the colour filter.
fn colour_filter() -> AmbientSource {
    AmbientSource::ColourFilter
}

/// One camera frame's timing and label (`/stereotac/camN/frame`). The image with the
/// same camera and `timestamp_us` is on `/stereotac/camN/image`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameInfo {
    /// The camera's frame sequence number.
    pub sequence: u64,
    /// Timestamp, host µs (exposure start or end: [`Self::stamp_ref`]).
    pub timestamp_us: f64,
    /// Exposure time, µs.
    pub exposure_us: f64,
    /// What `timestamp_us` marks: `exposure_start` or `exposure_end`.
    pub stamp_ref: StampRefName,
    /// The matcher's verdict: `phase`, `straddles`, `event_missing`, `no_trigger` or
    /// `unresolved`.
    pub label: LabelKind,
    /// Phase index (label `phase` only).
    pub index: Option<u32>,
    /// What the strips showed: `dark`, `all`, `dx`, `dy` (label `phase` only).
    pub phase: Option<String>,
    /// The trigger that started the exposure (triggered cameras).
    pub trigger: Option<u32>,
}

/// [`crate::matcher::StampRef`] by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StampRefName {
    /// The timestamp marks the start of the exposure.
    ExposureStart,
    /// The timestamp marks its end.
    ExposureEnd,
}

/// [`Label`] without its fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LabelKind {
    /// Lit by one phase.
    Phase,
    /// Across an LED change.
    Straddles,
    /// Where a phase event was lost.
    EventMissing,
    /// No trigger explains it.
    NoTrigger,
    /// Not decided (the sequence stopped).
    Unresolved,
}

impl FrameInfo {
    /// The message for a frame with `stamp` and `label` from a source stamping
    /// `stamp_ref`.
    pub fn new(stamp: FrameStamp, stamp_ref: crate::matcher::StampRef, label: Label) -> Self {
        let (kind, index, phase, trigger) = match label {
            Label::Phase {
                index,
                phase,
                trigger,
            } => (
                LabelKind::Phase,
                Some(index),
                Some(phase_str(phase).to_string()),
                trigger,
            ),
            Label::Straddles => (LabelKind::Straddles, None, None, None),
            Label::EventMissing => (LabelKind::EventMissing, None, None, None),
            Label::NoTrigger => (LabelKind::NoTrigger, None, None, None),
            Label::Unresolved => (LabelKind::Unresolved, None, None, None),
        };
        Self {
            sequence: stamp.sequence,
            timestamp_us: stamp.timestamp_us,
            exposure_us: stamp.exposure_us,
            stamp_ref: match stamp_ref {
                crate::matcher::StampRef::ExposureStart => StampRefName::ExposureStart,
                crate::matcher::StampRef::ExposureEnd => StampRefName::ExposureEnd,
            },
            label: kind,
            index,
            phase,
            trigger,
        }
    }

    /// The frame's stamp.
    pub fn stamp(&self) -> FrameStamp {
        FrameStamp {
            sequence: self.sequence,
            timestamp_us: self.timestamp_us,
            exposure_us: self.exposure_us,
        }
    }

    /// What the timestamp marks.
    pub fn stamp_ref(&self) -> crate::matcher::StampRef {
        match self.stamp_ref {
            StampRefName::ExposureStart => crate::matcher::StampRef::ExposureStart,
            StampRefName::ExposureEnd => crate::matcher::StampRef::ExposureEnd,
        }
    }

    /// The label back; `Err` names what is missing or unknown.
    pub fn label(&self) -> Result<Label, String> {
        Ok(match self.label {
            LabelKind::Phase => {
                let index = self.index.ok_or("label `phase` without `index`")?;
                let name = self
                    .phase
                    .as_deref()
                    .ok_or("label `phase` without `phase`")?;
                let phase = phase_from_str(name)
                    .ok_or_else(|| format!("unknown phase {name:?} (dark, all, dx or dy)"))?;
                Label::Phase {
                    index,
                    phase,
                    trigger: self.trigger,
                }
            }
            LabelKind::Straddles => Label::Straddles,
            LabelKind::EventMissing => Label::EventMissing,
            LabelKind::NoTrigger => Label::NoTrigger,
            LabelKind::Unresolved => Label::Unresolved,
        })
    }
}

/// A phase from its lower-case name ([`phase_str`]).
pub fn phase_from_str(name: &str) -> Option<Phase> {
    [Phase::Dark, Phase::All, Phase::Dx, Phase::Dy]
        .into_iter()
        .find(|p| phase_str(*p) == name)
}

/// One LED phase on the host clock (`/stereotac/leds/phase`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhaseInfo {
    /// Phase index k of the sequence.
    pub index: u32,
    /// What the strips showed.
    pub phase: String,
    /// LED write start, host µs.
    pub write_start_us: f64,
    /// LED latch, host µs.
    pub latched_us: f64,
    /// Trigger index, if the camera was triggered.
    pub trigger: Option<u32>,
    /// Trigger rising edge, host µs.
    pub trigger_us: Option<f64>,
    /// Clock-sync uncertainty of these times, µs.
    pub uncertainty_us: f64,
}

impl From<&HostPhase> for PhaseInfo {
    fn from(p: &HostPhase) -> Self {
        Self {
            index: p.event.index,
            phase: phase_str(p.event.phase).to_string(),
            write_start_us: p.write_start_us,
            latched_us: p.latched_us,
            trigger: p.trigger.map(|t| t.0),
            trigger_us: p.trigger.map(|t| t.1),
            uncertainty_us: p.uncertainty_us,
        }
    }
}

/// The clock-sync state (`/stereotac/clock`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ClockInfo {
    /// Host time of this state, µs.
    pub host_us: f64,
    /// Whether device times can be mapped yet.
    pub synced: bool,
    /// Device drift relative to the host, ppm.
    pub drift_ppm: Option<f64>,
    /// Largest mapping error near the fit's centre, µs.
    pub uncertainty_us: Option<f64>,
    /// Smallest ping round trip in the window, µs.
    pub min_rtt_us: Option<u64>,
    /// Pings in the window.
    pub samples: usize,
}

impl ClockInfo {
    /// The state at host time `host_us` with fit `fit`.
    pub fn new(host_us: f64, fit: Option<&ClockFit>) -> Self {
        Self {
            host_us,
            synced: fit.is_some(),
            drift_ppm: fit.map(ClockFit::drift_ppm),
            uncertainty_us: fit.map(|f| f.uncertainty_us),
            min_rtt_us: fit.map(|f| f.min_rtt_us),
            samples: fit.map_or(0, |f| f.samples),
        }
    }
}

/// One reconstructed dx/dy pair, as `stereotac run --jsonl` prints it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TactileRecord {
    /// Pairs reconstructed before this one in the run.
    pub sequence: u64,
    /// Phase index of the dx frame (the dy frame's is the next).
    pub phase: u32,
    /// End of the dx and dy exposures, host µs.
    pub exposure_end_us: [f64; 2],
    /// Whether anything touches the skin.
    pub contact: bool,
    /// Most of the pair shows no usable LED light (black, white, overexposed, LEDs off):
    /// `contact: false` then means nothing.
    #[serde(default)]
    pub unlit: bool,
    /// Which ambient light was removed: `dark-frame` (the pair's LEDs-off frame),
    /// `calibration` (the model's estimate: no LEDs-off frame came with the pair) or
    /// `colour-filter` (a model calibrated on raw frames).
    #[serde(default = "colour_filter")]
    pub ambient: AmbientSource,
    /// Imprint area, mm².
    pub area_mm2: f64,
    /// Depth-weighted centroid, mm from the frame's top-left corner (none without
    /// contact).
    pub centroid_mm: Option<[f64; 2]>,
    /// Deepest point, mm.
    pub max_depth_mm: f32,
    /// Displaced volume, mm³.
    pub volume_mm3: f64,
    /// Touched pixels whose slopes the light model read past the calibration's slopes
    /// (`tactile::past_reach`: the table's or the perceptron's; 0 with
    /// `--no-past-reach`).
    #[serde(default)]
    pub past_reach_pixels: u64,
    /// The largest share of a region's slopes its solved surface does not explain
    /// (`tactile::integrable`): above 0.15 they are not one surface's (dx and dy of two
    /// moments) and the depth is not reliable. Records written before it read 0.
    #[serde(default)]
    pub unexplained_share: f32,
    /// A contact filled its region with no skin at rest around it, so its depth has no
    /// zero (the skin covered whole, or room light that changed since the references read
    /// as contact everywhere). Records written before it read `false`.
    #[serde(default)]
    pub no_skin_at_rest: bool,
    /// Time per stage of the reconstruction, ms.
    pub stage_ms: StageTimings,
    /// From the end of the dy exposure to the depth being ready, ms (host clock); none
    /// when processed offline (`stereotac process`).
    pub latency_ms: Option<f64>,
    /// Camera frames lost so far in the run (dropped by the camera or not labelled).
    pub frames_dropped: u64,
    /// Pairs the tactile stage skipped so far for a newer one while it was busy (live
    /// only; offline nothing is skipped).
    #[serde(default)]
    pub jobs_skipped: u64,
}

/// One stereo frame's summary (`/stereotac/stereo/summary`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StereoRecord {
    /// Stereo frames before this one in the run.
    pub sequence: u64,
    /// Phase index of the dark frames.
    pub phase: u32,
    /// End of the left exposure, host µs.
    pub exposure_end_us: f64,
    /// Share of pixels with a depth, 0..1.
    pub fill: f64,
    /// Points in the cloud.
    pub points: usize,
    /// Median depth of the valid pixels, mm (none without any).
    pub median_depth_mm: Option<f32>,
    /// Time per stage, ms.
    pub stage_ms: StereoTimings,
    /// From the end of the later exposure to the depth being ready, ms; none when
    /// processed offline.
    pub latency_ms: Option<f64>,
    /// Camera frames lost so far in the run.
    pub frames_dropped: u64,
    /// Frame pairs the stereo stage skipped so far for a newer one while it was busy.
    #[serde(default)]
    pub jobs_skipped: u64,
    /// What this result should make its user look twice at ([`crate::stereo::warnings`]):
    /// almost nothing matched, the scene outside the working range.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// Foxglove's timestamp of `unix_ns`.
pub fn timestamp(unix_ns: u64) -> Timestamp {
    Timestamp::new(
        (unix_ns / 1_000_000_000).min(u64::from(u32::MAX)) as u32,
        (unix_ns % 1_000_000_000) as u32,
    )
}

/// An RGB frame as a `foxglove.RawImage` (`rgb8`).
pub fn rgb_image(image: &RgbImage, unix_ns: u64, frame_id: &str) -> RawImage {
    RawImage {
        timestamp: Some(timestamp(unix_ns)),
        frame_id: frame_id.to_string(),
        width: image.width(),
        height: image.height(),
        encoding: "rgb8".into(),
        step: image.width() * 3,
        data: image.as_raw().clone().into(),
    }
}

/// An RGB frame back from a `foxglove.RawImage` (`rgb8`, `bgr8` or `mono8`, any row
/// padding).
pub fn rgb_from_raw(raw: &RawImage) -> Result<RgbImage, String> {
    let (w, h) = (raw.width as usize, raw.height as usize);
    let channels = match raw.encoding.as_str() {
        "rgb8" | "bgr8" => 3,
        "mono8" => 1,
        other => {
            return Err(format!(
                "image encoding {other:?} (rgb8, bgr8 or mono8 only)"
            ));
        }
    };
    let step = raw.step as usize;
    let row = w.checked_mul(channels).ok_or("width too large")?;
    if w == 0 || h == 0 || step < row || raw.data.len() < step.saturating_mul(h - 1) + row {
        return Err(format!(
            "{}×{} {} image with step {} needs {} bytes, has {}",
            w,
            h,
            raw.encoding,
            step,
            step.saturating_mul(h.saturating_sub(1)) + row,
            raw.data.len()
        ));
    }
    let mut out = Vec::with_capacity(w * h * 3);
    for y in 0..h {
        let line = &raw.data[y * step..y * step + row];
        match raw.encoding.as_str() {
            "rgb8" => out.extend_from_slice(line),
            "bgr8" => line
                .chunks_exact(3)
                .for_each(|p| out.extend_from_slice(&[p[2], p[1], p[0]])),
            _ => line.iter().for_each(|&v| out.extend_from_slice(&[v, v, v])),
        }
    }
    RgbImage::from_raw(raw.width, raw.height, out).ok_or_else(|| "image size".to_string())
}

/// A depth map in mm as a `foxglove.RawImage` in metres (`32FC1`, as ROS depth images).
pub fn depth_image(depth_mm: &Grid<f32>, unix_ns: u64, frame_id: &str) -> RawImage {
    let mut data = Vec::with_capacity(depth_mm.as_slice().len() * 4);
    for &v in depth_mm.as_slice() {
        data.extend_from_slice(&(v * 1e-3).to_le_bytes());
    }
    RawImage {
        timestamp: Some(timestamp(unix_ns)),
        frame_id: frame_id.to_string(),
        width: depth_mm.width() as u32,
        height: depth_mm.height() as u32,
        encoding: "32FC1".into(),
        step: depth_mm.width() as u32 * 4,
        data: data.into(),
    }
}

/// A `32FC1` depth image back, in metres as stored.
pub fn depth_from_raw(raw: &RawImage) -> Result<Grid<f32>, String> {
    if raw.encoding != "32FC1" {
        return Err(format!("depth encoding {:?} (32FC1 only)", raw.encoding));
    }
    let (w, h, step) = (raw.width as usize, raw.height as usize, raw.step as usize);
    if w == 0 || h == 0 || step < w * 4 || raw.data.len() < step * (h - 1) + w * 4 {
        return Err(format!(
            "{w}×{h} depth image with step {step}: data too short"
        ));
    }
    Ok(Grid::from_fn(w, h, |x, y| {
        let at = y * step + x * 4;
        f32::from_le_bytes(raw.data[at..at + 4].try_into().expect("4 bytes"))
    }))
}

/// A point cloud in mm as a `foxglove.PointCloud` in metres (x, y, z float32).
pub fn point_cloud(cloud: &PointCloud, unix_ns: u64, frame_id: &str) -> FoxCloud {
    let field = |name: &str, offset| PackedElementField {
        name: name.into(),
        offset,
        r#type: packed_element_field::NumericType::Float32 as i32,
    };
    let mut data = Vec::with_capacity(cloud.points.len() * 12);
    for p in &cloud.points {
        for v in p {
            data.extend_from_slice(&(v * 1e-3).to_le_bytes());
        }
    }
    FoxCloud {
        timestamp: Some(timestamp(unix_ns)),
        frame_id: frame_id.to_string(),
        pose: None,
        point_stride: 12,
        fields: vec![field("x", 0), field("y", 4), field("z", 8)],
        data: data.into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matcher::StampRef;

    #[test]
    fn frame_info_gives_back_every_label() {
        let stamp = FrameStamp {
            sequence: 7,
            timestamp_us: 1234.5,
            exposure_us: 8000.0,
        };
        for label in [
            Label::Phase {
                index: 3,
                phase: Phase::Dy,
                trigger: Some(2),
            },
            Label::Phase {
                index: 4,
                phase: Phase::Dark,
                trigger: None,
            },
            Label::Straddles,
            Label::EventMissing,
            Label::NoTrigger,
            Label::Unresolved,
        ] {
            let info = FrameInfo::new(stamp, StampRef::ExposureEnd, label);
            let back: FrameInfo =
                serde_json::from_str(&serde_json::to_string(&info).unwrap()).unwrap();
            assert_eq!(back.label(), Ok(label));
            assert_eq!(back.stamp(), stamp);
            assert_eq!(back.stamp_ref(), StampRef::ExposureEnd);
        }
        let bad = FrameInfo {
            phase: Some("uv".into()),
            ..FrameInfo::new(
                stamp,
                StampRef::ExposureStart,
                Label::Phase {
                    index: 1,
                    phase: Phase::Dx,
                    trigger: None,
                },
            )
        };
        assert!(bad.label().unwrap_err().contains("unknown phase \"uv\""));
    }

    #[test]
    fn images_and_depth_survive_the_round_trip() {
        let img = RgbImage::from_fn(5, 3, |x, y| image::Rgb([x as u8, y as u8, 9]));
        let raw = rgb_image(&img, 1_500_000_000_123, "cam0");
        assert_eq!(raw.timestamp, Some(Timestamp::new(1500, 123)));
        assert_eq!(rgb_from_raw(&raw).unwrap(), img);
        let bgr = RawImage {
            encoding: "bgr8".into(),
            ..raw.clone()
        };
        assert_eq!(rgb_from_raw(&bgr).unwrap().get_pixel(4, 2).0, [9, 2, 4]);
        let short = RawImage {
            data: raw.data.slice(0..20),
            ..raw
        };
        assert!(
            rgb_from_raw(&short)
                .unwrap_err()
                .contains("needs 45 bytes, has 20")
        );

        let depth = Grid::from_fn(4, 2, |x, y| if x == 3 { f32::NAN } else { (x + y) as f32 });
        let back = depth_from_raw(&depth_image(&depth, 0, "cam0")).unwrap();
        for (a, b) in depth.as_slice().iter().zip(back.as_slice()) {
            assert!(
                a.is_nan() && b.is_nan() || (a * 1e-3 - b).abs() == 0.0,
                "{a} {b}"
            );
        }
    }

    #[test]
    fn a_point_cloud_is_three_float32_fields_in_metres() {
        let cloud = PointCloud {
            points: vec![[1000.0, -2000.0, 500.0]],
            pixels: vec![0],
        };
        let fox = point_cloud(&cloud, 0, "cam0");
        assert_eq!(fox.point_stride, 12);
        let xyz: Vec<f32> = fox
            .data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        assert_eq!(xyz, vec![1.0, -2.0, 0.5]);
        assert_eq!(
            fox.fields
                .iter()
                .map(|f| f.name.as_str())
                .collect::<Vec<_>>(),
            ["x", "y", "z"]
        );
    }
}
