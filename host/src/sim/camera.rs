//! A simulated camera: renders whatever the LEDs really showed during each exposure.
//!
//! It reads the loopback's ground truth ([`LedTimeline`]) and integrates the light over
//! the exposure: an exposure inside one steady phase gives that phase's image exactly;
//! one across an LED change gives the time-weighted blend, which is what a real sensor
//! integrates and what the matcher must reject. Triggered (one frame per trigger edge,
//! after a latency) and free-running (fixed frame rate) cameras are both modelled, and
//! dropped frames can be injected.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use image::RgbImage;
use stereotac_protocol::Phase;

use super::link::LedTimeline;
use crate::clock::HostClock;
use crate::frames::{Frame, FrameError, FrameSource};
use crate::grid::Grid;
use crate::matcher::{FrameStamp, StampRef};
use crate::stereo::StereoCalibration;
use crate::stereo::synthetic::{Membrane, Plane, StereoRig, render_pair};
use crate::tactile::render::{Optics, Scene, render};

/// How the simulated camera is clocked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SimClocking {
    /// One exposure per trigger edge, starting `latency_us` after it.
    Triggered {
        /// Edge-to-exposure latency, µs.
        latency_us: f64,
    },
    /// Exposures every `period_us` from `first_us` (host clock).
    FreeRunning {
        /// Frame period, µs.
        period_us: f64,
        /// Start of the first exposure, host µs.
        first_us: f64,
    },
}

/// The images of each lighting phase (rendered once).
#[derive(Debug, Clone)]
pub struct PhaseImages {
    dark: RgbImage,
    all: RgbImage,
    dx: RgbImage,
    dy: RgbImage,
}

impl PhaseImages {
    /// Render `scene` under every phase with `optics`. Dark is the world seen through
    /// the skin (a dim texture); All is both gradient pairs' light together.
    pub fn render(optics: &Optics, scene: &Scene) -> Self {
        let pair = render(optics, scene, 0);
        Self::from_gradients(pair.dx, pair.dy)
    }

    /// The phases of a rendered dx/dy pair: Dark a dim texture, All both together.
    pub fn from_gradients(dx: RgbImage, dy: RgbImage) -> Self {
        let (w, h) = dx.dimensions();
        let dark = RgbImage::from_fn(w, h, |x, y| {
            let v = (((x / 16 + y / 16) % 2) * 40 + 20 + (x * 7 + y * 13) % 17) as u8;
            image::Rgb([v, v, v])
        });
        let all = RgbImage::from_fn(w, h, |x, y| {
            let (a, b) = (dx.get_pixel(x, y).0, dy.get_pixel(x, y).0);
            image::Rgb(std::array::from_fn(|c| a[c].saturating_add(b[c] / 2)))
        });
        Self { dark, all, dx, dy }
    }

    /// The same phases with another LEDs-dark image (a stereo camera's view of the
    /// world through the skin).
    pub fn with_dark(mut self, dark: RgbImage) -> Self {
        self.dark = dark;
        self
    }

    /// The image of one phase.
    pub fn of(&self, phase: Phase) -> &RgbImage {
        match phase {
            Phase::Dark => &self.dark,
            Phase::All => &self.all,
            Phase::Dx => &self.dx,
            Phase::Dy => &self.dy,
        }
    }

    /// Time-weighted blend of phases' images.
    fn blend(&self, light: &[(Phase, f64)]) -> RgbImage {
        if let [(phase, _)] = light {
            return self.of(*phase).clone();
        }
        let total: f64 = light.iter().map(|l| l.1).sum();
        let (w, h) = self.dark.dimensions();
        RgbImage::from_fn(w, h, |x, y| {
            let mut acc = [0.0f64; 3];
            for (phase, us) in light {
                let p = self.of(*phase).get_pixel(x, y).0;
                for c in 0..3 {
                    acc[c] += f64::from(p[c]) * us / total;
                }
            }
            image::Rgb(acc.map(|v| v.round().clamp(0.0, 255.0) as u8))
        })
    }
}

/// The simulated sensor's stereo pair at any frame size: its two cameras 14 mm apart
/// (ideal, rectified: [`StereoRig`] scaled from 640×480) and what they see through the
/// skin with the LEDs dark, a textured board 150 mm away, turned a little.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimStereo {
    /// The rig.
    pub rig: StereoRig,
    /// The board.
    pub plane: Plane,
}

impl SimStereo {
    /// The rig at `width×height`.
    pub fn new(width: u32, height: u32) -> Self {
        let sensor = StereoRig::sensor();
        Self {
            rig: StereoRig {
                width: width as usize,
                height: height as usize,
                focal_px: sensor.focal_px * f64::from(width) / sensor.width as f64,
                ..sensor
            },
            plane: Plane {
                z_mm: 150.0,
                tilt_x: 0.15,
                tilt_y: -0.1,
            },
        }
    }

    /// Its calibration (what `run --sim` uses when no `--calib` is given).
    pub fn calibration(&self) -> StereoCalibration {
        self.rig.calibration()
    }

    /// The left and right LEDs-dark views.
    pub fn dark_views(&self) -> (RgbImage, RgbImage) {
        let (l, r) = render_pair(&self.rig, &self.plane, &Membrane::sensor(), 0);
        let rgb = |g: &Grid<u8>| {
            RgbImage::from_fn(g.width() as u32, g.height() as u32, |x, y| {
                let v = g.get(x as usize, y as usize);
                image::Rgb([v, v, v])
            })
        };
        (rgb(&l), rgb(&r))
    }
}

/// The simulated camera (see the module documentation).
#[derive(Debug)]
pub struct SimulatedCamera {
    timeline: Arc<Mutex<LedTimeline>>,
    clock: Arc<dyn HostClock>,
    clocking: SimClocking,
    exposure_us: f64,
    images: PhaseImages,
    sequence: u64,
    /// Triggered: the timeline span after the last one whose trigger was taken;
    /// free-running: frames taken.
    cursor: usize,
    drop_every: Option<u64>,
    cycle: Option<SceneCycle>,
    unplugged_at_us: Option<f64>,
}

/// Scenes shown in turn.
#[derive(Debug)]
struct SceneCycle {
    scenes: Vec<PhaseImages>,
    step: SceneStep,
}

/// When the next scene of a cycle comes.
#[derive(Debug, Clone, Copy)]
enum SceneStep {
    /// Every `every_us` of host time from `from_us`.
    Time { every_us: f64, from_us: f64 },
    /// Every `phases` LED phases (by phase index): a scene never changes inside a
    /// phase group, so a dx/dy pair never shows two scenes.
    Phases(u32),
}

impl SimulatedCamera {
    /// A camera on the loopback's LED truth, switched on now: like a real one it answers
    /// only the triggers that come after this moment.
    pub fn new(
        timeline: Arc<Mutex<LedTimeline>>,
        clock: Arc<dyn HostClock>,
        clocking: SimClocking,
        exposure_us: f64,
        images: PhaseImages,
    ) -> Self {
        let cursor = match clocking {
            SimClocking::Triggered { latency_us } => {
                let now = clock.now_us() as f64;
                let truth = timeline.lock().unwrap_or_else(|e| e.into_inner());
                let spans = truth.spans();
                spans
                    .iter()
                    .position(|s| s.trigger.is_some_and(|(_, edge)| edge + latency_us >= now))
                    .unwrap_or(spans.len())
            }
            SimClocking::FreeRunning { .. } => 0,
        };
        Self {
            timeline,
            clock,
            clocking,
            exposure_us,
            images,
            sequence: 0,
            cursor,
            drop_every: None,
            cycle: None,
            unplugged_at_us: None,
        }
    }

    /// Show another scene from the next frame on (an object pressed into the skin).
    pub fn set_images(&mut self, images: PhaseImages) {
        self.images = images;
        self.cycle = None;
    }

    /// Show `scenes` in turn from now on, each for `every_us` (objects pressed and
    /// lifted one after another); an exposure shows the scene of its start. Nothing
    /// changes when `scenes` is empty or `every_us` is not positive.
    pub fn cycle_scenes(&mut self, scenes: Vec<PhaseImages>, every_us: f64) {
        if scenes.is_empty() || !(every_us.is_finite() && every_us > 0.0) {
            return;
        }
        self.cycle = Some(SceneCycle {
            scenes,
            step: SceneStep::Time {
                every_us,
                from_us: self.clock.now_us() as f64,
            },
        });
    }

    /// Show `scenes` in turn by the sequence's phase index: scene `k` lights phases
    /// `k·phases .. (k+1)·phases` (then again from the first). With `phases` the length
    /// of the mode's cycle (2 gradient, 3 interleaved) each dx/dy pair shows one scene.
    /// Nothing changes when `scenes` is empty or `phases` is 0.
    pub fn cycle_scenes_by_phase(&mut self, scenes: Vec<PhaseImages>, phases: u32) {
        if scenes.is_empty() || phases == 0 {
            return;
        }
        self.cycle = Some(SceneCycle {
            scenes,
            step: SceneStep::Phases(phases),
        });
    }

    /// The scene an exposure starting at `start_us`, in phase `phase_index`, shows.
    fn images_at(&self, start_us: f64, phase_index: Option<u32>) -> &PhaseImages {
        let Some(c) = &self.cycle else {
            return &self.images;
        };
        let k = match c.step {
            SceneStep::Time { every_us, from_us } => {
                ((start_us - from_us) / every_us).floor().max(0.0) as usize
            }
            SceneStep::Phases(n) => (phase_index.unwrap_or(0) / n) as usize,
        };
        &c.scenes[k % c.scenes.len()]
    }

    /// Pull the camera's cable at host time `at_us`: from then on it fails as an
    /// unplugged V4L2 camera does.
    pub fn unplug_at(&mut self, at_us: f64) {
        self.unplugged_at_us = Some(at_us);
    }

    /// Drop every `n`th frame (the sequence number still advances, as a camera's does).
    pub fn drop_every(&mut self, n: u64) {
        self.drop_every = Some(n.max(2));
    }

    /// Start of the next exposure, and the cursor after it, if the truth holds it.
    fn next_start(&self, timeline: &LedTimeline) -> Option<(f64, usize)> {
        match self.clocking {
            SimClocking::Triggered { latency_us } => timeline.spans()
                [self.cursor.min(timeline.spans().len())..]
                .iter()
                .enumerate()
                .find_map(|(i, s)| {
                    s.trigger
                        .map(|(_, edge)| (edge + latency_us, self.cursor + i + 1))
                }),
            SimClocking::FreeRunning {
                period_us,
                first_us,
            } => Some((first_us + self.cursor as f64 * period_us, self.cursor + 1)),
        }
    }

    /// The next frame if its exposure is over and the LED truth covers it.
    fn take_ready(&mut self) -> Option<Frame> {
        loop {
            let timeline = self.timeline.lock().unwrap_or_else(|e| e.into_inner());
            let (start, cursor) = self.next_start(&timeline)?;
            let end = start + self.exposure_us;
            if end > timeline.known_until_us() || end > self.clock.now_us() as f64 {
                return None;
            }
            let light = timeline.exposure(start, end);
            let spans = timeline.spans();
            let phase_index = spans
                .partition_point(|s| s.from_us <= start)
                .checked_sub(1)
                .and_then(|i| spans[i].phase_index);
            drop(timeline);
            self.cursor = cursor;
            let sequence = self.sequence;
            self.sequence += 1;
            if self
                .drop_every
                .is_some_and(|n| (sequence + 1).is_multiple_of(n))
            {
                continue;
            }
            return Some(Frame {
                stamp: FrameStamp {
                    sequence,
                    timestamp_us: start,
                    exposure_us: self.exposure_us,
                },
                image: self.images_at(start, phase_index).blend(&light),
            });
        }
    }
}

impl FrameSource for SimulatedCamera {
    fn next_frame(&mut self, timeout: Duration) -> Result<Option<Frame>, FrameError> {
        if self
            .unplugged_at_us
            .is_some_and(|t| self.clock.now_us() as f64 >= t)
        {
            return Err(FrameError::Camera {
                device: "simulated camera".into(),
                message: "No such device (os error 19): unplugged".into(),
            });
        }
        let deadline = self.clock.now_us() + timeout.as_micros() as u64;
        loop {
            if let Some(frame) = self.take_ready() {
                return Ok(Some(frame));
            }
            // A virtual clock only moves when the sensor is polled: return and let it.
            let now = self.clock.now_us();
            if self.clock.is_virtual() || now >= deadline {
                return Ok(None);
            }
            self.clock.sleep_until((now + 1000).min(deadline));
        }
    }

    fn stamp_ref(&self) -> StampRef {
        StampRef::ExposureStart
    }

    fn frame_size(&self) -> Option<(u32, u32)> {
        Some(self.images.dark.dimensions())
    }

    fn describe(&self) -> String {
        match self.clocking {
            SimClocking::Triggered { latency_us } => format!(
                "simulated camera (triggered, latency {latency_us} µs, exposure {} µs)",
                self.exposure_us
            ),
            SimClocking::FreeRunning { period_us, .. } => format!(
                "simulated camera (free-running at {:.1} fps, exposure {} µs)",
                1e6 / period_us,
                self.exposure_us
            ),
        }
    }
}
