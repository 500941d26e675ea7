//! Stereo depth through the skin (Vision and Dark phases only): calibration files in,
//! rectified frames, disparity, depth and point clouds out, and the depth-camera
//! evaluation that measures them.
//!
//! - [`yaml`]: the YAML subset calibration files use.
//! - [`camera`]: camera matrix and lens models (Brown–Conrady, Kannala–Brandt).
//! - [`calibration`]: the stereo calibration, read from and written to OpenCV stereo YAML
//!   and ROS `camera_info` pairs.
//! - [`board`]: checkerboard targets and built-in views of them.
//! - `board_calibration` (feature `calibrate`): the solver that calibrates a stereo pair
//!   from checkerboard images.
//! - [`rectify`]: Bouguet rectification and fixed-point remap tables.
//! - [`prefilter`], [`block_match`], [`speckle`]: disparity by block matching.
//! - [`matcher`]: the one a pipeline runs, block matching or semi-global.
//! - [`sgm`]: disparity by semi-global matching (census costs, 4 or 8 paths).
//! - [`postfilter`]: spatial, temporal and hole-filling filters on disparity.
//! - [`reproject`], [`outliers`]: depth, point clouds, statistical outlier removal.
//! - [`pipeline`]: the whole frame, raw views to point cloud, with timings.
//! - [`scene`]: renders surfaces through a calibrated camera, lens model and all.
//! - [`synthetic`]: built-in captures of textured targets behind the skin.
//! - [`eval`]: Z-accuracy, RMS error, temporal noise and fill rate of flat targets.
//! - [`opencv`]: OpenCV's StereoBM and StereoSGBM run on the same images, as references.
//! - [`output`]: a processed frame's files (depth and disparity as NPY and PNG, point
//!   cloud as PLY, `summary.json`).
//! - [`bench`]: the stereo benchmark (remap, matching per kernel, the whole frame,
//!   OpenCV's StereoBM in the same run).

pub mod bench;
pub mod block_match;
pub mod board;
#[cfg(feature = "calibrate")]
pub mod board_calibration;
pub mod calibration;
pub mod camera;
pub mod eval;
pub mod matcher;
pub mod opencv;
pub mod outliers;
pub mod output;
pub mod pipeline;
pub mod postfilter;
pub mod prefilter;
pub mod rectify;
pub mod reproject;
pub mod ros_info;
pub mod scene;
pub mod sgm;
pub mod speckle;
pub mod synthetic;
pub mod warnings;
pub mod yaml;

pub use block_match::{BlockMatchParams, BlockMatcher, DisparityMap, Kernel, MatchError};
pub use calibration::{CalibError, LengthUnit, StereoCalibration};
pub use camera::{Camera, Distortion};
pub use matcher::{Matcher, MatcherKind};
pub use pipeline::{StereoConfig, StereoError, StereoFrame, StereoPipeline};
pub use rectify::{Rectification, RectifyError, RemapTable};
pub use sgm::{Paths, SemiGlobalMatcher, SgmParams};
