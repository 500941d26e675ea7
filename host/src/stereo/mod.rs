//! Stereo depth through the skin (Vision and Dark phases only): calibration files in,
//! rectified frames out. Matching, reprojection and filtering build on this.
//!
//! - [`yaml`]: the YAML subset calibration files use.
//! - [`camera`]: camera matrix and lens models (Brown–Conrady, Kannala–Brandt).
//! - [`calib`]: OpenCV stereo YAML and ROS `camera_info` pairs.
//! - [`rectify`]: Bouguet rectification and fixed-point remap tables.
//! - [`prefilter`], [`block_match`], [`speckle`]: disparity by block matching.
//! - [`synthetic`]: built-in captures of textured targets behind the skin.

pub mod block_match;
pub mod calib;
pub mod camera;
pub mod prefilter;
pub mod rectify;
pub mod speckle;
pub mod synthetic;
pub mod yaml;

pub use block_match::{BlockMatchParams, BlockMatcher, DisparityMap, Kernel, MatchError};
pub use calib::{CalibError, StereoCalibration};
pub use camera::{Camera, Distortion};
pub use rectify::{Rectification, RectifyError, RemapTable};
