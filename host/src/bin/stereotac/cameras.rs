//! The camera options of `record` and `run`: the simulated camera (with `--sim`) or
//! V4L2 devices (Linux; the default `v4l2` feature), opened by the library's
//! [`CameraSetup`].

use anyhow::Result;
use stereotac::frames::FrameSource;
use stereotac::live::cameras::CameraSetup;
use stereotac::matcher::CameraSync;
use stereotac::sim::camera::SimStereo;
use stereotac::tactile::render::Optics;

use crate::args::parse_size;
use crate::sensor_args::Opened;

/// Which cameras, and how they are clocked.
#[derive(Debug, Clone, clap::Args)]
pub struct CameraArgs {
    /// Camera: `sim` (the simulated camera; needs --sim) or a V4L2 device such as
    /// /dev/video0 (Linux). Repeat for several cameras.
    #[arg(long = "camera", default_value = "sim")]
    pub cameras: Vec<String>,
    /// Exposure time, µs: the simulated camera's, and the one assumed for a V4L2 camera
    /// that does not report its own.
    #[arg(long, allow_negative_numbers = true, default_value_t = 8000.0)]
    pub exposure_us: f64,
    /// The cameras run on their own clock instead of the sensor's trigger output.
    #[arg(long)]
    pub free_running: bool,
    /// Delay from the trigger edge to the start of the exposure, µs (triggered cameras).
    #[arg(long, allow_negative_numbers = true, default_value_t = 40.0)]
    pub trigger_latency_us: f64,
    /// Frame size, WxH: the simulated camera's (default 640x480, the sensor's), and the
    /// one to ask V4L2 cameras for (default: the camera's current size).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
}

impl CameraArgs {
    /// The library's camera setup these options describe.
    pub fn setup(&self) -> CameraSetup {
        CameraSetup {
            cameras: self.cameras.clone(),
            exposure_us: self.exposure_us,
            free_running: self.free_running,
            trigger_latency_us: self.trigger_latency_us,
            size: self.size,
        }
    }

    /// Refuses unusable values and cameras this build cannot open, before anything is
    /// connected.
    pub fn check(&self) -> Result<()> {
        Ok(self.setup().check()?)
    }

    /// How the matcher should expect the cameras to be clocked.
    pub fn sync(&self) -> CameraSync {
        self.setup().sync()
    }

    /// The simulated camera's optics.
    pub fn sim_optics(&self) -> Optics {
        self.setup().sim_optics()
    }

    /// Whether cameras 0 and 1 are both simulated (the simulated stereo pair).
    pub fn sim_stereo(&self) -> Option<SimStereo> {
        self.setup().sim_stereo()
    }

    /// Opens every camera, in order.
    pub fn open_all(&self, opened: &Opened) -> Result<Vec<Box<dyn FrameSource>>> {
        Ok(self.setup().open_all(opened)?)
    }
}
