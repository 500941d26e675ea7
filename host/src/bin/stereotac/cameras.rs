//! The camera options of `record` and `run`, and opening the cameras they name: the
//! simulated camera (with `--sim`) or V4L2 devices (Linux; the default `v4l2` feature).

use std::sync::Arc;

use anyhow::{Result, bail};
use image::RgbImage;
use stereotac::frames::FrameSource;
use stereotac::matcher::CameraSync;
use stereotac::sim::camera::{PhaseImages, SimClocking, SimStereo, SimulatedCamera};
use stereotac::tactile::render::{Optics, builtin_scenes};

use crate::args::parse_size;
use crate::sensor_args::Opened;

/// How long the simulated camera shows each built-in object before the next, µs.
const SIM_SCENE_US: f64 = 1_000_000.0;
/// Frame size of the simulated camera unless `--size` says otherwise (the sensor's).
const SIM_SIZE: (u32, u32) = (640, 480);

/// Which cameras, and how they are clocked.
#[derive(Debug, Clone, clap::Args)]
pub struct CameraArgs {
    /// Camera: `sim` (the simulated camera; needs --sim) or a V4L2 device such as
    /// /dev/video0 (Linux). Repeat for several cameras.
    #[arg(long = "camera", default_value = "sim")]
    pub cameras: Vec<String>,
    /// Exposure time, µs: the simulated camera's, and the one assumed for a V4L2 camera
    /// that does not report its own.
    #[arg(long, default_value_t = 8000.0)]
    pub exposure_us: f64,
    /// The cameras run on their own clock instead of the sensor's trigger output.
    #[arg(long)]
    pub free_running: bool,
    /// Delay from the trigger edge to the start of the exposure, µs (triggered cameras).
    #[arg(long, default_value_t = 40.0)]
    pub trigger_latency_us: f64,
    /// Frame size, WxH: the simulated camera's (default 640x480, the sensor's), and the
    /// one to ask V4L2 cameras for (default: the camera's current size).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
}

impl CameraArgs {
    /// Refuses unusable values and cameras this build cannot open, before anything is
    /// connected.
    pub fn check(&self) -> Result<()> {
        if !(self.exposure_us.is_finite() && self.exposure_us > 0.0) {
            bail!("--exposure-us must be positive");
        }
        if !(self.trigger_latency_us.is_finite() && self.trigger_latency_us >= 0.0) {
            bail!("--trigger-latency-us must be zero or positive");
        }
        match self.cameras.iter().find(|c| *c != "sim") {
            Some(name) if !cfg!(all(feature = "v4l2", target_os = "linux")) => Err(no_v4l2(name)),
            _ => Ok(()),
        }
    }

    /// How the matcher should expect the cameras to be clocked.
    pub fn sync(&self) -> CameraSync {
        if self.free_running {
            CameraSync::FreeRunning
        } else {
            CameraSync::Triggered {
                latency_us: self.trigger_latency_us,
                tolerance_us: 500.0,
            }
        }
    }

    /// The simulated camera's optics.
    pub fn sim_optics(&self) -> Optics {
        let (w, h) = self.size.unwrap_or(SIM_SIZE);
        Optics::resolution(w as usize, h as usize)
    }

    /// Whether cameras 0 and 1 are both simulated: they are then the simulated stereo
    /// pair, showing [`SimStereo`]'s scene in dark phases.
    pub fn sim_stereo(&self) -> Option<SimStereo> {
        match self.cameras.as_slice() {
            [a, b, ..] if a == "sim" && b == "sim" => {
                let optics = self.sim_optics();
                Some(SimStereo::new(optics.width as u32, optics.height as u32))
            }
            _ => None,
        }
    }

    /// Opens every camera, in order.
    pub fn open_all(&self, opened: &Opened) -> Result<Vec<Box<dyn FrameSource>>> {
        let views = self.sim_stereo().map(|s| s.dark_views());
        let mut out = Vec::new();
        for (i, name) in self.cameras.iter().enumerate() {
            let source: Box<dyn FrameSource> = if name == "sim" {
                let dark = match (i, &views) {
                    (0, Some((left, _))) => Some(left.clone()),
                    (1, Some((_, right))) => Some(right.clone()),
                    _ => None,
                };
                Box::new(self.open_sim(opened, dark)?)
            } else {
                self.open_v4l2(name)?
            };
            out.push(source);
        }
        Ok(out)
    }

    /// The simulated camera: the built-in objects pressed in turn, each for a second;
    /// `dark` is what it sees with the LEDs dark (default: a plain texture).
    fn open_sim(&self, opened: &Opened, dark: Option<RgbImage>) -> Result<SimulatedCamera> {
        let Some(timeline) = opened.timeline.clone() else {
            bail!("--camera sim renders the simulated sensor's LEDs: add --sim");
        };
        let optics = self.sim_optics();
        let scenes: Vec<PhaseImages> = builtin_scenes(&optics)
            .iter()
            .map(|(_, scene)| {
                let images = PhaseImages::render(&optics, scene);
                match &dark {
                    Some(d) => images.with_dark(d.clone()),
                    None => images,
                }
            })
            .collect();
        let clocking = if self.free_running {
            SimClocking::FreeRunning {
                period_us: 33_333.0,
                first_us: opened.sensor.clock().now_us() as f64,
            }
        } else {
            SimClocking::Triggered {
                latency_us: self.trigger_latency_us,
            }
        };
        let mut camera = SimulatedCamera::new(
            timeline,
            Arc::clone(opened.sensor.clock()),
            clocking,
            self.exposure_us,
            scenes[0].clone(),
        );
        camera.cycle_scenes(scenes, SIM_SCENE_US);
        Ok(camera)
    }

    #[cfg(all(feature = "v4l2", target_os = "linux"))]
    fn open_v4l2(&self, name: &str) -> Result<Box<dyn FrameSource>> {
        use stereotac::frames::v4l2::{V4l2Camera, V4l2Settings};
        let camera = V4l2Camera::open(
            std::path::Path::new(name),
            &V4l2Settings {
                size: self.size,
                exposure_us: self.exposure_us,
                ..V4l2Settings::default()
            },
        )?;
        Ok(Box::new(camera))
    }

    #[cfg(not(all(feature = "v4l2", target_os = "linux")))]
    fn open_v4l2(&self, name: &str) -> Result<Box<dyn FrameSource>> {
        Err(no_v4l2(name))
    }
}

fn no_v4l2(name: &str) -> anyhow::Error {
    anyhow::anyhow!(
        "camera {name}: this build has no V4L2 capture (it is Linux only, and this build \
         turned off the default `v4l2` feature); use --sim --camera sim, or build on Linux \
         with default features"
    )
}
