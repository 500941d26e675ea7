//! Stereo depth through the skin (Vision and Dark phases only): calibration files in,
//! rectified frames out. Matching, reprojection and filtering build on this.
//!
//! - [`yaml`]: the YAML subset calibration files use.
//! - [`camera`]: camera matrix and lens models (Brown–Conrady, Kannala–Brandt).
//! - [`calib`]: OpenCV stereo YAML and ROS `camera_info` pairs.
//! - [`rectify`]: Bouguet rectification and fixed-point remap tables.

pub mod calib;
pub mod camera;
pub mod rectify;
pub mod yaml;

pub use calib::{CalibError, StereoCalibration};
pub use camera::{Camera, Distortion};
pub use rectify::{Rectification, RectifyError, RemapTable};
