//! Topic names: what each carries. Scripts and the docs rely on these names; the README
//! lists them.
//!
//! | topic | schema | what |
//! |---|---|---|
//! | `/stereotac/camN/image` | `foxglove.RawImage` (`rgb8`) | camera N's raw frames, stamped at exposure start |
//! | `/stereotac/camN/frame` | JSON [`FrameInfo`](super::messages::FrameInfo) | each frame's camera sequence, timing and LED phase label |
//! | `/stereotac/leds/phase` | JSON [`PhaseInfo`](super::messages::PhaseInfo) | every LED phase: schedule, write, latch, trigger (host µs) |
//! | `/stereotac/clock` | JSON [`ClockInfo`](super::messages::ClockInfo) | clock-sync state at each sensor heartbeat |
//! | `/stereotac/tactile/depth` | `foxglove.RawImage` (`32FC1`, metres) | tactile depth of each dx/dy pair (positive = pressed in) |
//! | `/stereotac/tactile/contact` | JSON [`TactileRecord`](super::messages::TactileRecord) | contact summary of each pair (the `--jsonl` line) |
//! | `/stereotac/stereo/depth` | `foxglove.RawImage` (`32FC1`, metres) | stereo depth of each dark frame pair (NaN = no match) |
//! | `/stereotac/stereo/points` | `foxglove.PointCloud` (x, y, z float32, metres) | its point cloud, rectified left camera frame |
//! | `/stereotac/stereo/summary` | JSON [`StereoRecord`](super::messages::StereoRecord) | fill, counts and timings of each stereo frame |
//! | `/stereotac/log` | `foxglove.Log` | warnings and drops, as the CLI prints them |
//!
//! Attachments: `tactile_model.json` (the model `calibrate` wrote) and
//! `stereo_calibration.yaml` (OpenCV stereo YAML). Metadata records: `stereotac`
//! (version, clock origin, mode, cameras) and `sensor` (serial, firmware, board id).

/// Camera `n`'s raw frames.
pub fn camera_image(n: usize) -> String {
    format!("/stereotac/cam{n}/image")
}

/// Camera `n`'s frame labels.
pub fn camera_frame(n: usize) -> String {
    format!("/stereotac/cam{n}/frame")
}

/// The camera number of a `/stereotac/camN/...` topic.
pub fn camera_of(topic: &str) -> Option<usize> {
    let rest = topic.strip_prefix("/stereotac/cam")?;
    let (n, _) = rest.split_once('/')?;
    n.parse().ok()
}

/// LED phases.
pub const LED_PHASE: &str = "/stereotac/leds/phase";
/// Clock-sync state.
pub const CLOCK: &str = "/stereotac/clock";
/// Tactile depth maps.
pub const TACTILE_DEPTH: &str = "/stereotac/tactile/depth";
/// Tactile contact summaries.
pub const TACTILE_CONTACT: &str = "/stereotac/tactile/contact";
/// Stereo depth maps.
pub const STEREO_DEPTH: &str = "/stereotac/stereo/depth";
/// Stereo point clouds.
pub const STEREO_POINTS: &str = "/stereotac/stereo/points";
/// Stereo frame summaries.
pub const STEREO_SUMMARY: &str = "/stereotac/stereo/summary";
/// Warnings and drops.
pub const LOG: &str = "/stereotac/log";

/// Attachment name of the tactile model.
pub const MODEL_ATTACHMENT: &str = "tactile_model.json";
/// Attachment name of the stereo calibration.
pub const CALIBRATION_ATTACHMENT: &str = "stereo_calibration.yaml";
/// Metadata record of the recording itself.
pub const META_RECORDING: &str = "stereotac";
/// Metadata record of the sensor's identity.
pub const META_SENSOR: &str = "sensor";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_topics_name_their_camera() {
        assert_eq!(camera_of(&camera_image(0)), Some(0));
        assert_eq!(camera_of(&camera_frame(12)), Some(12));
        assert_eq!(camera_of(LED_PHASE), None);
        assert_eq!(camera_of("/stereotac/camx/image"), None);
    }
}
