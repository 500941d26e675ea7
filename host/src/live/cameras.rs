//! The cameras of a live session, and opening them: the simulated camera (it renders the
//! simulated sensor's LEDs: the built-in objects pressed in turn, and a textured scene
//! in dark phases) or V4L2 devices (Linux; the default `v4l2` feature). One place for
//! `run`, `record` and the Python package.

use std::sync::Arc;

use image::RgbImage;

use crate::frames::{FrameError, FrameSource};
use crate::matcher::CameraSync;
use crate::sensors::OpenedSensor;
use crate::sim::camera::{PhaseImages, SimClocking, SimStereo, SimulatedCamera};
use crate::tactile::render::{Optics, builtin_scenes};

/// How long the simulated camera shows each built-in object before the next, µs.
const SIM_SCENE_US: f64 = 1_000_000.0;
/// Frame size of the simulated camera unless told otherwise (the sensor's).
pub const SIM_SIZE: (u32, u32) = (640, 480);
/// The name that stands for the simulated camera.
pub const SIM_CAMERA: &str = "sim";

/// Which cameras, and how they are clocked.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraSetup {
    /// `sim` or a V4L2 device path (`/dev/video0`), in camera order.
    pub cameras: Vec<String>,
    /// Exposure time, µs: the simulated camera's, and the one assumed for a V4L2 camera
    /// that does not report its own.
    pub exposure_us: f64,
    /// The cameras run on their own clock instead of the sensor's trigger output.
    pub free_running: bool,
    /// Delay from the trigger edge to the start of the exposure, µs (triggered cameras).
    pub trigger_latency_us: f64,
    /// Frame size: the simulated camera's, and the one to ask V4L2 cameras for (`None`:
    /// 640×480 simulated, the camera's current size for V4L2).
    pub size: Option<(u32, u32)>,
}

impl Default for CameraSetup {
    fn default() -> Self {
        Self {
            cameras: vec![SIM_CAMERA.into()],
            exposure_us: 8000.0,
            free_running: false,
            trigger_latency_us: 40.0,
            size: None,
        }
    }
}

/// Why the cameras could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum CameraSetupError {
    /// A value that cannot be used.
    #[error("{0}")]
    Setting(String),
    /// A simulated camera without the simulated sensor.
    #[error(
        "camera {0}: the simulated camera renders the simulated sensor's LEDs: use the \
         simulated sensor (--sim; in Python, Sensor(sim=True))"
    )]
    SimNeedsSimSensor(usize),
    /// A V4L2 camera in a build without V4L2.
    #[error(
        "camera {0}: this build has no V4L2 capture (it is Linux only, and this build \
         turned off the default `v4l2` feature); use the simulated sensor and camera, or \
         build on Linux with default features"
    )]
    NoV4l2(String),
    /// Opening a camera failed.
    #[error(transparent)]
    Open(#[from] FrameError),
}

impl CameraSetup {
    /// Refuses unusable values and cameras this build cannot open, before anything is
    /// connected.
    pub fn check(&self) -> Result<(), CameraSetupError> {
        if !(self.exposure_us.is_finite() && self.exposure_us > 0.0) {
            return Err(CameraSetupError::Setting(
                "--exposure-us must be positive".into(),
            ));
        }
        if !(self.trigger_latency_us.is_finite() && self.trigger_latency_us >= 0.0) {
            return Err(CameraSetupError::Setting(
                "--trigger-latency-us must be zero or positive".into(),
            ));
        }
        if self.cameras.is_empty() {
            return Err(CameraSetupError::Setting("no camera given".into()));
        }
        match self.cameras.iter().find(|c| *c != SIM_CAMERA) {
            Some(name) if !cfg!(all(feature = "v4l2", target_os = "linux")) => {
                Err(CameraSetupError::NoV4l2(name.clone()))
            }
            _ => Ok(()),
        }
    }

    /// Refuses an exposure that cannot fit in one LED phase of `period_ms`: every frame
    /// would straddle two phases and none could be labelled. Known here for simulated
    /// cameras only (a V4L2 camera reports its own exposure); the trigger latency counts
    /// for triggered cameras.
    pub fn check_fits_phase(&self, period_ms: u32) -> Result<(), CameraSetupError> {
        let latency = if self.free_running {
            0.0
        } else {
            self.trigger_latency_us
        };
        let all_sim = self.cameras.iter().all(|c| c == SIM_CAMERA);
        if all_sim && self.exposure_us + latency >= f64::from(period_ms) * 1000.0 {
            return Err(CameraSetupError::Setting(format!(
                "--exposure-us {} plus --trigger-latency-us {latency} does not fit in one \
                 phase of --period-ms {period_ms}: every frame would straddle two LED phases \
                 and none could be labelled; shorten the exposure or lengthen the period",
                self.exposure_us
            )));
        }
        Ok(())
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
            [a, b, ..] if a == SIM_CAMERA && b == SIM_CAMERA => {
                let optics = self.sim_optics();
                Some(SimStereo::new(optics.width as u32, optics.height as u32))
            }
            _ => None,
        }
    }

    /// Opens every camera, in order.
    pub fn open_all(
        &self,
        opened: &OpenedSensor,
    ) -> Result<Vec<Box<dyn FrameSource>>, CameraSetupError> {
        let views = self.sim_stereo().map(|s| s.dark_views());
        let mut out = Vec::new();
        for (i, name) in self.cameras.iter().enumerate() {
            let source: Box<dyn FrameSource> = if name == SIM_CAMERA {
                let dark = match (i, &views) {
                    (0, Some((left, _))) => Some(left.clone()),
                    (1, Some((_, right))) => Some(right.clone()),
                    _ => None,
                };
                Box::new(self.open_sim(i, opened, dark)?)
            } else {
                self.open_v4l2(name)?
            };
            out.push(source);
        }
        Ok(out)
    }

    /// The simulated camera: the built-in objects pressed in turn, each for a second;
    /// `dark` is what it sees with the LEDs dark (default: a plain texture).
    fn open_sim(
        &self,
        index: usize,
        opened: &OpenedSensor,
        dark: Option<RgbImage>,
    ) -> Result<SimulatedCamera, CameraSetupError> {
        let Some(timeline) = opened.timeline.clone() else {
            return Err(CameraSetupError::SimNeedsSimSensor(index));
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
    fn open_v4l2(&self, name: &str) -> Result<Box<dyn FrameSource>, CameraSetupError> {
        use crate::frames::v4l2::{V4l2Camera, V4l2Settings};
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
    fn open_v4l2(&self, name: &str) -> Result<Box<dyn FrameSource>, CameraSetupError> {
        Err(CameraSetupError::NoV4l2(name.to_string()))
    }
}
