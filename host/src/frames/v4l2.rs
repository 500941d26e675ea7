//! Live frames from a V4L2 camera (Linux, the default `v4l2` feature), stamped by the
//! kernel.
//!
//! The kernel stamps every buffer with `CLOCK_MONOTONIC` (the clock
//! [`crate::clock::MonotonicClock`] reads, so no conversion is needed) and a sequence
//! number that counts dropped frames. Whether the stamp marks the start of the exposure
//! or the end of the frame is in the buffer flags (`TSTAMP_SRC_SOE`/`EOF`), so
//! [`V4l2Camera::open`] grabs the first frame to learn it. A camera whose driver does
//! not stamp with the monotonic clock is refused: its frames could not be matched to
//! LED phases. The exposure time is read from the camera's `exposure_time_absolute`
//! control when it has one, else taken from the caller.
//!
//! Pixel formats: YUYV, GREY, RGB3 and MJPG, converted to RGB.

use std::path::{Path, PathBuf};
use std::time::Duration;

use image::RgbImage;
use v4l::buffer::{Flags, Metadata};
use v4l::io::mmap::Stream as MmapStream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture as _;
use v4l::{Device, FourCC};

use super::{Frame, FrameError, FrameSource};
use crate::matcher::{FrameStamp, StampRef};

/// V4L2's `V4L2_CID_EXPOSURE_ABSOLUTE`, in units of 100 µs.
const EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
/// Kernel buffers in flight.
const BUFFERS: u32 = 4;

/// Pixel formats we decode, in order of preference.
const FORMATS: [&[u8; 4]; 4] = [b"GREY", b"YUYV", b"RGB3", b"MJPG"];

/// What to ask the camera for.
#[derive(Debug, Clone, PartialEq)]
pub struct V4l2Settings {
    /// Frame size to request (the driver may choose the nearest it supports).
    pub size: Option<(u32, u32)>,
    /// Exposure time to assume when the camera does not report one, µs.
    pub exposure_us: f64,
    /// How long to wait for the first frame when opening.
    pub first_frame_timeout: Duration,
}

impl Default for V4l2Settings {
    fn default() -> Self {
        Self {
            size: None,
            exposure_us: 8000.0,
            first_frame_timeout: Duration::from_secs(3),
        }
    }
}

/// A V4L2 capture device (see the module documentation).
pub struct V4l2Camera {
    path: PathBuf,
    // Field order matters: the stream must be dropped before the device.
    stream: MmapStream<'static>,
    _device: Device,
    layout: Layout,
    stamp_ref: StampRef,
    exposure_us: f64,
    first: Option<Frame>,
    sequence_base: u64,
    last_sequence: Option<u32>,
}

impl std::fmt::Debug for V4l2Camera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("V4l2Camera")
            .field("path", &self.path)
            .field("layout", &self.layout)
            .finish_non_exhaustive()
    }
}

/// Frame size and pixel format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Bytes per line (for uncompressed formats).
    pub stride: u32,
    /// Pixel format.
    pub fourcc: [u8; 4],
}

fn camera_error(path: &Path, message: impl std::fmt::Display) -> FrameError {
    FrameError::Camera {
        device: path.display().to_string(),
        message: message.to_string(),
    }
}

impl V4l2Camera {
    /// Open `path` (e.g. `/dev/video0`), choose a pixel format we decode, start
    /// streaming and read the first frame to learn the timestamp source.
    pub fn open(path: &Path, settings: &V4l2Settings) -> Result<Self, FrameError> {
        let device = Device::with_path(path).map_err(|e| camera_error(path, e))?;
        let caps = device
            .query_caps()
            .map_err(|e| camera_error(path, format!("not a V4L2 device: {e}")))?;
        if !caps
            .capabilities
            .contains(v4l::capability::Flags::VIDEO_CAPTURE)
        {
            return Err(camera_error(path, "the device cannot capture video"));
        }
        let layout = choose_format(&device, settings.size).map_err(|m| camera_error(path, m))?;
        let exposure_us = match device.control(EXPOSURE_ABSOLUTE).map(|c| c.value) {
            Ok(v4l::control::Value::Integer(v)) if v > 0 => v as f64 * 100.0,
            _ => settings.exposure_us,
        };
        let mut stream =
            MmapStream::with_buffers(&device, v4l::buffer::Type::VideoCapture, BUFFERS)
                .map_err(|e| camera_error(path, format!("allocating buffers: {e}")))?;
        stream.set_timeout(settings.first_frame_timeout);
        let (stamp_ref, first, sequence) = {
            let (data, meta) = stream.next().map_err(|e| {
                camera_error(
                    path,
                    format!(
                        "no first frame within {:?}: {e}",
                        settings.first_frame_timeout
                    ),
                )
            })?;
            let stamp_ref = stamp_ref(meta.flags).map_err(|m| camera_error(path, m))?;
            let image = decode(layout, &data[..meta.bytesused as usize])
                .map_err(|m| camera_error(path, m))?;
            let stamp = frame_stamp(meta, 0, exposure_us);
            (stamp_ref, Frame { stamp, image }, meta.sequence)
        };
        Ok(Self {
            path: path.to_path_buf(),
            stream,
            _device: device,
            layout,
            stamp_ref,
            exposure_us,
            first: Some(first),
            sequence_base: 0,
            last_sequence: Some(sequence),
        })
    }

    /// Frame size and pixel format in use.
    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// The exposure time the frames are stamped with, µs.
    pub fn exposure_us(&self) -> f64 {
        self.exposure_us
    }
}

/// Pick the first format in [`FORMATS`] the camera offers, at the requested size.
fn choose_format(device: &Device, size: Option<(u32, u32)>) -> Result<Layout, String> {
    let offered: Vec<FourCC> = device
        .enum_formats()
        .map_err(|e| format!("listing formats: {e}"))?
        .into_iter()
        .map(|d| d.fourcc)
        .collect();
    let Some(&wanted) = FORMATS.iter().find(|f| offered.contains(&FourCC::new(f))) else {
        let names: Vec<String> = offered.iter().map(ToString::to_string).collect();
        return Err(format!(
            "none of the camera's formats ({}) is supported (GREY, YUYV, RGB3, MJPG)",
            names.join(", ")
        ));
    };
    let mut format = device
        .format()
        .map_err(|e| format!("reading the format: {e}"))?;
    format.fourcc = FourCC::new(wanted);
    if let Some((w, h)) = size {
        format.width = w;
        format.height = h;
    }
    let set = device
        .set_format(&format)
        .map_err(|e| format!("setting the format: {e}"))?;
    if set.fourcc != FourCC::new(wanted) {
        return Err(format!("the driver refused format {}", FourCC::new(wanted)));
    }
    Ok(Layout {
        width: set.width,
        height: set.height,
        stride: set.stride,
        fourcc: set.fourcc.repr,
    })
}

/// What the kernel's buffer timestamp marks; an error unless it is `CLOCK_MONOTONIC`.
fn stamp_ref(flags: Flags) -> Result<StampRef, String> {
    if flags & Flags::TIMESTAMP_MASK != Flags::TIMESTAMP_MONOTONIC {
        return Err(
            "the driver does not stamp buffers with CLOCK_MONOTONIC, so its frames cannot be matched to LED phases"
                .into(),
        );
    }
    Ok(if flags & Flags::TSTAMP_SRC_MASK == Flags::TSTAMP_SRC_SOE {
        StampRef::ExposureStart
    } else {
        StampRef::ExposureEnd
    })
}

fn frame_stamp(meta: &Metadata, sequence_base: u64, exposure_us: f64) -> FrameStamp {
    FrameStamp {
        sequence: sequence_base + u64::from(meta.sequence),
        timestamp_us: meta.timestamp.sec as f64 * 1e6 + meta.timestamp.usec as f64,
        exposure_us,
    }
}

/// Convert one buffer to RGB.
pub fn decode(layout: Layout, data: &[u8]) -> Result<RgbImage, String> {
    let (w, h) = (layout.width as usize, layout.height as usize);
    let stride = layout.stride as usize;
    let short = |per_pixel: usize| {
        let need = stride.max(w * per_pixel) * h.saturating_sub(1) + w * per_pixel;
        (data.len() < need).then(|| format!("short buffer: {} bytes, need {need}", data.len()))
    };
    let mut out = RgbImage::new(layout.width, layout.height);
    match &layout.fourcc {
        b"GREY" => {
            if let Some(e) = short(1) {
                return Err(e);
            }
            let stride = stride.max(w);
            for (y, row) in out.rows_mut().enumerate() {
                for (x, px) in row.enumerate() {
                    let v = data[y * stride + x];
                    px.0 = [v, v, v];
                }
            }
        }
        b"RGB3" => {
            if let Some(e) = short(3) {
                return Err(e);
            }
            let stride = stride.max(3 * w);
            for (y, row) in out.rows_mut().enumerate() {
                for (x, px) in row.enumerate() {
                    let i = y * stride + 3 * x;
                    px.0 = [data[i], data[i + 1], data[i + 2]];
                }
            }
        }
        b"YUYV" => {
            if !w.is_multiple_of(2) {
                return Err(format!("YUYV needs an even width, got {w}"));
            }
            if let Some(e) = short(2) {
                return Err(e);
            }
            let stride = stride.max(2 * w);
            for y in 0..h {
                for pair in 0..w / 2 {
                    let i = y * stride + 4 * pair;
                    let [y0, u, y1, v] = [data[i], data[i + 1], data[i + 2], data[i + 3]];
                    out.put_pixel(2 * pair as u32, y as u32, yuv_to_rgb(y0, u, v).into());
                    out.put_pixel(2 * pair as u32 + 1, y as u32, yuv_to_rgb(y1, u, v).into());
                }
            }
        }
        b"MJPG" => {
            let decoded = image::load_from_memory_with_format(data, image::ImageFormat::Jpeg)
                .map_err(|e| format!("MJPG frame: {e}"))?;
            out = decoded.to_rgb8();
        }
        other => return Err(format!("unsupported pixel format {}", FourCC::new(other))),
    }
    Ok(out)
}

/// BT.601 limited-range YCbCr to RGB, in integer arithmetic.
fn yuv_to_rgb(y: u8, u: u8, v: u8) -> [u8; 3] {
    let c = 298 * (i32::from(y) - 16);
    let d = i32::from(u) - 128;
    let e = i32::from(v) - 128;
    let clamp = |x: i32| ((x + 128) >> 8).clamp(0, 255) as u8;
    [
        clamp(c + 409 * e),
        clamp(c - 100 * d - 208 * e),
        clamp(c + 516 * d),
    ]
}

impl FrameSource for V4l2Camera {
    fn next_frame(&mut self, timeout: Duration) -> Result<Option<Frame>, FrameError> {
        if let Some(first) = self.first.take() {
            return Ok(Some(first));
        }
        // Poll first: v4l's `next` re-queues the previous buffer before waiting, so a
        // timeout inside it would queue that buffer twice on the following call.
        let ms = timeout.as_millis().min(i32::MAX as u128) as i32;
        let ready = self
            .stream
            .handle()
            .poll(POLLIN, ms)
            .map_err(|e| camera_error(&self.path, e))?;
        if ready == 0 {
            return Ok(None);
        }
        let (data, meta) = self
            .stream
            .next()
            .map_err(|e| camera_error(&self.path, e))?;
        // The kernel's 32-bit sequence wraps after ~2 years at 60 fps; keep it monotonic.
        if self.last_sequence.is_some_and(|last| meta.sequence < last) {
            self.sequence_base += 1 << 32;
        }
        self.last_sequence = Some(meta.sequence);
        let image = decode(self.layout, &data[..meta.bytesused as usize])
            .map_err(|m| camera_error(&self.path, m))?;
        Ok(Some(Frame {
            stamp: frame_stamp(meta, self.sequence_base, self.exposure_us),
            image,
        }))
    }

    fn stamp_ref(&self) -> StampRef {
        self.stamp_ref
    }

    fn frame_size(&self) -> Option<(u32, u32)> {
        Some((self.layout.width, self.layout.height))
    }

    fn describe(&self) -> String {
        let l = self.layout;
        format!(
            "{} ({}×{} {}, exposure {:.0} µs)",
            self.path.display(),
            l.width,
            l.height,
            FourCC::new(&l.fourcc),
            self.exposure_us
        )
    }
}

/// `POLLIN` (poll(2)'s "data to read"), the same value on every Linux architecture.
const POLLIN: i16 = 0x001;

#[cfg(test)]
mod tests {
    use super::*;

    fn layout(fourcc: &[u8; 4], width: u32, height: u32, stride: u32) -> Layout {
        Layout {
            width,
            height,
            stride,
            fourcc: *fourcc,
        }
    }

    #[test]
    fn yuyv_grey_and_rgb_decode_to_the_expected_colours() {
        // Black, white and pure BT.601 red in limited range.
        assert_eq!(yuv_to_rgb(16, 128, 128), [0, 0, 0]);
        assert_eq!(yuv_to_rgb(235, 128, 128), [255, 255, 255]);
        let red = yuv_to_rgb(81, 90, 240);
        assert!(red[0] >= 250 && red[1] <= 2 && red[2] <= 2, "{red:?}");
        // Two YUYV pixels: black then white, sharing chroma; stride with padding.
        let img = decode(layout(b"YUYV", 2, 1, 8), &[16, 128, 235, 128, 0, 0, 0, 0]).unwrap();
        assert_eq!(img.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(img.get_pixel(1, 0).0, [255, 255, 255]);
        let img = decode(layout(b"GREY", 2, 2, 3), &[1, 2, 9, 3, 4]).unwrap();
        assert_eq!(img.get_pixel(1, 1).0, [4, 4, 4]);
        let img = decode(layout(b"RGB3", 1, 1, 3), &[7, 8, 9]).unwrap();
        assert_eq!(img.get_pixel(0, 0).0, [7, 8, 9]);
    }

    #[test]
    fn short_odd_and_unknown_buffers_are_errors_not_panics() {
        assert!(
            decode(layout(b"GREY", 4, 4, 4), &[0; 15])
                .unwrap_err()
                .contains("short")
        );
        assert!(
            decode(layout(b"YUYV", 3, 1, 6), &[0; 6])
                .unwrap_err()
                .contains("even")
        );
        assert!(
            decode(layout(b"H264", 4, 4, 4), &[0; 64])
                .unwrap_err()
                .contains("H264")
        );
        assert!(decode(layout(b"MJPG", 4, 4, 0), &[0xFF, 0xD8, 0]).is_err());
    }

    #[test]
    fn mjpg_frames_decode() {
        let mut jpeg = Vec::new();
        let src = RgbImage::from_pixel(8, 8, image::Rgb([200, 40, 40]));
        image::DynamicImage::ImageRgb8(src)
            .write_to(
                &mut std::io::Cursor::new(&mut jpeg),
                image::ImageFormat::Jpeg,
            )
            .unwrap();
        let img = decode(layout(b"MJPG", 8, 8, 0), &jpeg).unwrap();
        let p = img.get_pixel(4, 4).0;
        assert!(p[0].abs_diff(200) < 8 && p[1].abs_diff(40) < 8, "{p:?}");
    }

    #[test]
    fn only_monotonic_stamps_are_accepted_and_their_source_is_read() {
        let mono = Flags::TIMESTAMP_MONOTONIC;
        assert_eq!(
            stamp_ref(mono | Flags::TSTAMP_SRC_SOE),
            Ok(StampRef::ExposureStart)
        );
        assert_eq!(stamp_ref(mono), Ok(StampRef::ExposureEnd));
        assert!(stamp_ref(Flags::TIMESTAMP_COPY).is_err());
        let meta = Metadata {
            sequence: 7,
            timestamp: v4l::Timestamp::new(12, 345_678),
            ..Metadata::default()
        };
        let s = frame_stamp(&meta, 1 << 32, 500.0);
        assert_eq!(s.sequence, (1 << 32) + 7);
        assert_eq!(s.timestamp_us, 12_345_678.0);
    }

    #[test]
    fn opening_a_missing_or_non_video_device_says_which() {
        let e = V4l2Camera::open(
            Path::new("/dev/stereotac-no-such-camera"),
            &V4l2Settings::default(),
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("/dev/stereotac-no-such-camera"),
            "{e}"
        );
        let e = V4l2Camera::open(Path::new("/dev/null"), &V4l2Settings::default()).unwrap_err();
        assert!(e.to_string().contains("not a V4L2 device"), "{e}");
    }
}
