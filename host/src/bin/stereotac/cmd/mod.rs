//! One command a file: each holds its `Args` (clap) and `run`, parses and prints, and
//! leaves the work to the library.

pub mod bench;
pub mod calibrate;
pub mod demo;
pub mod devices;
pub mod export;
pub mod firmware_image;
pub mod flash;
pub mod info;
pub mod process;
pub mod reconstruct;
pub mod record;
pub mod run;
pub mod selftest;
pub mod set;
pub mod stereo;
pub mod stereo_calibrate;
pub mod stereo_convert;
pub mod stereo_eval;
pub mod stream;
