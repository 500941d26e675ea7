//! Bounds on what any input may make us allocate or process, in one place: every reader
//! of files written by someone else (models, calibrations, images, recordings) checks
//! against these before it allocates. They are set by what a sensor can produce, with
//! room to spare, not by what a machine could hold.

/// Largest image side (px) anything accepts: frames, model sizes, calibration image
/// sizes. No camera we support gives more.
pub const MAX_FRAME_SIDE: usize = 8192;

/// Most memory one image decode may allocate (bytes): an 8-bit RGBA image of
/// [`MAX_FRAME_SIDE`]² pixels.
pub const MAX_IMAGE_ALLOC: u64 = (MAX_FRAME_SIDE * MAX_FRAME_SIDE * 4) as u64;

/// Most the decoder may allocate before the pixels (bytes): the chunks ahead of them,
/// such as a PNG's colour profile or text, are compressed and may expand a thousandfold
/// (a 2 MB file with a 2 GiB profile). A camera's profile is a few KB; a larger one is
/// dropped, and other chunks beyond it refuse the file.
pub const MAX_IMAGE_HEADER_ALLOC: u64 = 16 << 20;

/// Most the frames of one tactile calibration folder may take decoded (bytes, 8-bit
/// RGB): 30 presses of 4K frames with their LEDs-off frames take about 2.2 GB, of
/// 640×480 frames 83 MB.
pub const MAX_CALIBRATION_FRAMES: u64 = 4 << 30;

/// Largest calibration YAML file (bytes). A full stereo calibration is about 3 KB.
pub const MAX_CALIBRATION_FILE: u64 = 1 << 20;

/// Largest model file (bytes). A model of a 640×480 frame is about 350 KB and grows with
/// the frame's area, so one of a [`MAX_FRAME_SIDE`]² frame stays near 80 MB.
pub const MAX_MODEL_FILE: u64 = 256 << 20;
