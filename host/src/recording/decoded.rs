//! A recording's messages decoded by topic, for readers that want values rather than
//! bytes (the Python package's `Recording`): depth maps and point clouds back in
//! millimetres (recordings keep metres, Foxglove's unit), JSON messages as JSON, log
//! lines as text, anything else as recorded.

use foxglove::Decode;
use foxglove::messages::{Log, PointCloud, RawImage, packed_element_field::NumericType};

use super::messages::depth_from_raw;
use super::topics;
use crate::grid::Grid;

/// One message's value.
#[derive(Debug, Clone, PartialEq)]
pub enum Decoded {
    /// A depth map, mm (tactile: positive where pressed in; stereo: NaN where no match).
    DepthMm(Grid<f32>),
    /// Points, mm, in the rectified left camera's frame.
    PointsMm(Vec<[f32; 3]>),
    /// A JSON message (frame labels, LED phases, clock sync, contact and stereo
    /// summaries).
    Json(serde_json::Value),
    /// A log line and its `foxglove.Log` level (1 debug … 5 fatal).
    Log {
        /// Level.
        level: i32,
        /// Text.
        message: String,
    },
    /// Any other message, as recorded.
    Bytes(Vec<u8>),
}

/// Decodes a message of `topic` recorded with `encoding`; the error says what is wrong
/// with it.
pub fn decode(topic: &str, encoding: &str, data: &[u8]) -> Result<Decoded, String> {
    match topic {
        topics::TACTILE_DEPTH | topics::STEREO_DEPTH => {
            let raw = RawImage::decode(data).map_err(|e| e.to_string())?;
            let mut depth = depth_from_raw(&raw)?;
            for d in depth.as_mut_slice() {
                *d *= 1000.0;
            }
            Ok(Decoded::DepthMm(depth))
        }
        topics::STEREO_POINTS => {
            let cloud = PointCloud::decode(data).map_err(|e| e.to_string())?;
            points_mm(&cloud).map(Decoded::PointsMm)
        }
        topics::LOG => {
            let log = Log::decode(data).map_err(|e| e.to_string())?;
            Ok(Decoded::Log {
                level: log.level,
                message: log.message,
            })
        }
        _ if encoding == "json" => serde_json::from_slice(data)
            .map(Decoded::Json)
            .map_err(|e| format!("not JSON: {e}")),
        _ => Ok(Decoded::Bytes(data.to_vec())),
    }
}

/// The x, y, z float32 fields of a `foxglove.PointCloud` (metres), in mm.
fn points_mm(cloud: &PointCloud) -> Result<Vec<[f32; 3]>, String> {
    let offset = |name: &str| {
        cloud
            .fields
            .iter()
            .find(|f| f.name == name && f.r#type == NumericType::Float32 as i32)
            .map(|f| f.offset as usize)
            .ok_or_else(|| format!("no float32 field `{name}`"))
    };
    let at = [offset("x")?, offset("y")?, offset("z")?];
    let stride = cloud.point_stride as usize;
    if stride == 0 || at.iter().any(|&o| o + 4 > stride) {
        return Err(format!(
            "point stride {stride} does not hold the fields at {at:?}"
        ));
    }
    if !cloud.data.len().is_multiple_of(stride) {
        return Err(format!(
            "{} bytes of points are not a whole number of {stride}-byte points",
            cloud.data.len()
        ));
    }
    let value =
        |p: &[u8], o: usize| f32::from_le_bytes(p[o..o + 4].try_into().expect("4 bytes")) * 1000.0;
    Ok(cloud
        .data
        .chunks_exact(stride)
        .map(|p| [value(p, at[0]), value(p, at[1]), value(p, at[2])])
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recording::messages::{depth_image, point_cloud};
    use crate::stereo::reproject::PointCloud as Cloud;
    use foxglove::Encode;

    fn encoded(m: &impl Encode) -> Vec<u8> {
        let mut buf = Vec::new();
        m.encode(&mut buf).unwrap();
        buf
    }

    #[test]
    fn depth_and_points_come_back_in_mm() {
        let depth = Grid::from_vec(3, 2, vec![0.0, 1.5, f32::NAN, 2.25, -0.5, 300.0]).unwrap();
        let data = encoded(&depth_image(&depth, 7, "cam0"));
        let Ok(Decoded::DepthMm(back)) = decode(topics::TACTILE_DEPTH, "protobuf", &data) else {
            panic!("not a depth map");
        };
        assert_eq!((back.width(), back.height()), (3, 2));
        for (a, b) in depth.as_slice().iter().zip(back.as_slice()) {
            assert!((a.is_nan() && b.is_nan()) || (a - b).abs() <= 1e-4 * a.abs().max(1.0));
        }
        let cloud = Cloud {
            points: vec![[1.0, -2.0, 150.0], [0.5, 0.25, 600.0]],
            pixels: vec![0, 1],
        };
        let data = encoded(&point_cloud(&cloud, 7, "cam0"));
        let Ok(Decoded::PointsMm(points)) = decode(topics::STEREO_POINTS, "protobuf", &data) else {
            panic!("not points");
        };
        assert_eq!(points.len(), 2);
        for (a, b) in cloud.points.iter().flatten().zip(points.iter().flatten()) {
            assert!((a - b).abs() <= 1e-4 * a.abs().max(1.0), "{a} vs {b}");
        }
    }

    #[test]
    fn damaged_messages_say_what_is_wrong() {
        let mut cloud = point_cloud(
            &Cloud {
                points: vec![[1.0, 2.0, 3.0]],
                pixels: vec![0],
            },
            1,
            "cam0",
        );
        cloud.point_stride = 8;
        let e = decode(topics::STEREO_POINTS, "protobuf", &encoded(&cloud)).unwrap_err();
        assert!(e.contains("stride"), "{e}");
        cloud.point_stride = 12;
        cloud.data = vec![0u8; 13].into();
        let e = decode(topics::STEREO_POINTS, "protobuf", &encoded(&cloud)).unwrap_err();
        assert!(e.contains("whole number"), "{e}");
        let e = decode(topics::LED_PHASE, "json", b"{not json").unwrap_err();
        assert!(e.starts_with("not JSON"), "{e}");
        assert_eq!(
            decode("/other", "cdr", b"\x01\x02"),
            Ok(Decoded::Bytes(vec![1, 2]))
        );
    }
}
