//! Built-in stereo captures from our renderer, for the demo, the evaluation, the
//! benchmark and the tests: a textured target seen by the sensor's two cameras through
//! the hazy skin, with sensor noise.
//!
//! The rig is an ideal pinhole pair (no distortion, no rotation) in the calibration's
//! own convention, so its [`StereoCalibration`] runs the full pipeline (identity
//! rectification) and the ground truth is exact: a pixel at disparity `d` lies at depth
//! `f·B/d`. The target's texture is value noise in world millimetres over six octaves
//! (0.25 to 8 mm cells), area-sampled 3×3 per pixel, so the two views agree the way real
//! ones do. The skin adds a fixed low-contrast pattern of its own to each camera (it is
//! a few millimetres away: its disparity is far outside any search range) and lowers
//! the target's contrast; each frame adds Gaussian noise.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Vector3};

use super::calibration::StereoCalibration;
use super::camera::{Camera, Distortion};
use super::reproject::PointCloud;
use crate::grid::Grid;
use crate::rng::Rng;

pub use super::scene::Membrane;
use super::scene::{self, RayGrid, Surface, View, value_noise};

/// An ideal rectified pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoRig {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Focal length, pixels.
    pub focal_px: f64,
    /// Distance between the cameras, mm (the right camera sits at `+x`).
    pub baseline_mm: f64,
}

impl StereoRig {
    /// The sensor's geometry: 640×480, 14 mm baseline, the focal length of its wide
    /// lenses after rectification.
    pub fn sensor() -> Self {
        Self {
            width: 640,
            height: 480,
            focal_px: 336.0,
            baseline_mm: 14.0,
        }
    }

    /// The principal point (image centre, as rectification places it).
    pub fn centre(&self) -> (f64, f64) {
        (
            (self.width as f64 - 1.0) / 2.0,
            (self.height as f64 - 1.0) / 2.0,
        )
    }

    /// The rig as a calibration (pinhole cameras, `T = (−B, 0, 0)`).
    pub fn calibration(&self) -> StereoCalibration {
        let (cx, cy) = self.centre();
        let f = self.focal_px;
        let camera = Camera {
            width: self.width as u32,
            height: self.height as u32,
            k: Matrix3::new(f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0),
            distortion: Distortion::NONE,
        };
        StereoCalibration {
            left: camera,
            right: camera,
            r: Matrix3::identity(),
            t: Vector3::new(-self.baseline_mm, 0.0, 0.0),
        }
    }

    /// Disparity (pixels) of a point at depth `z_mm`.
    pub fn disparity_at(&self, z_mm: f64) -> f64 {
        self.focal_px * self.baseline_mm / z_mm
    }

    /// The true disparity of every left pixel (at its centre) when the rig sees `plane`.
    pub fn true_disparity(&self, plane: &Plane) -> Grid<f32> {
        let (cx, cy) = self.centre();
        Grid::from_fn(self.width, self.height, |x, y| {
            let (a, b) = (
                (x as f64 - cx) / self.focal_px,
                (y as f64 - cy) / self.focal_px,
            );
            self.disparity_at(plane.depth_along(a, b, 0.0)) as f32
        })
    }
}

/// A calibration like the sensor's wide lenses (Kannala–Brandt, a slightly rotated and
/// offset 14 mm baseline), for benchmarks of the rectification maps.
pub fn fisheye_calibration() -> StereoCalibration {
    let camera = Camera {
        width: 640,
        height: 480,
        k: Matrix3::new(420.0, 0.0, 320.0, 0.0, 420.0, 240.0, 0.0, 0.0, 1.0),
        distortion: Distortion::KannalaBrandt([0.05, -0.01, 0.002, -0.0003]),
    };
    StereoCalibration {
        left: camera,
        right: camera,
        r: *Rotation3::from_euler_angles(0.01, -0.02, 0.005).matrix(),
        t: Vector3::new(-14.0, 0.3, -0.2),
    }
}

/// A pair like the sensor's 160° lenses: Kannala–Brandt, f ≈ 295 px on 640×480 (about
/// 128° across the width, 160° across the diagonal), cameras that differ slightly, and a
/// slightly rotated and offset 14 mm baseline. The ground truth of the calibration
/// tests and of the raw-lens captures.
pub fn wide_fisheye_calibration() -> StereoCalibration {
    let camera = |fx, fy, cx, cy, k: [f64; 4]| Camera {
        width: 640,
        height: 480,
        k: Matrix3::new(fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0),
        distortion: Distortion::KannalaBrandt(k),
    };
    StereoCalibration {
        left: camera(
            295.0,
            294.0,
            321.5,
            238.0,
            [-0.015, 0.003, -0.0004, 0.00002],
        ),
        right: camera(
            297.0,
            296.5,
            317.0,
            242.5,
            [-0.012, 0.002, -0.0003, 0.00001],
        ),
        r: *Rotation3::from_euler_angles(0.008, -0.015, 0.004).matrix(),
        t: Vector3::new(-14.0, 0.25, -0.15),
    }
}

/// A target plane `Z = z + tilt_x·X + tilt_y·Y` (mm, left camera's frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Depth on the optical axis, mm.
    pub z_mm: f64,
    /// dZ/dX.
    pub tilt_x: f64,
    /// dZ/dY.
    pub tilt_y: f64,
}

impl Plane {
    /// A plane facing the cameras at `z_mm`.
    pub fn facing(z_mm: f64) -> Self {
        Self {
            z_mm,
            tilt_x: 0.0,
            tilt_y: 0.0,
        }
    }

    /// Depth where the ray through normalised image point `(a, b)` meets the plane,
    /// from a camera at `X = x0` on the baseline.
    fn depth_along(&self, a: f64, b: f64, x0: f64) -> f64 {
        // Z = z + tx·(x0 + a·Z) + ty·(b·Z)  ⇒  Z = (z + tx·x0) / (1 − tx·a − ty·b).
        (self.z_mm + self.tilt_x * x0) / (1.0 - self.tilt_x * a - self.tilt_y * b)
    }
}

/// Renders one left/right frame of `plane` behind `membrane`; `frame` seeds the noise
/// (the texture and the skin pattern are the same in every frame).
pub fn render_pair(
    rig: &StereoRig,
    plane: &Plane,
    membrane: &Membrane,
    frame: u64,
) -> (Grid<u8>, Grid<u8>) {
    let (left, right) = rayon::join(
        || render_view(rig, plane, membrane, 0.0, 1, frame),
        || render_view(rig, plane, membrane, rig.baseline_mm, 2, frame),
    );
    (left, right)
}

/// One camera at `X = x0` on the baseline.
fn render_view(
    rig: &StereoRig,
    plane: &Plane,
    membrane: &Membrane,
    x0: f64,
    camera: u64,
    frame: u64,
) -> Grid<u8> {
    const SUB: usize = 3;
    let (cx, cy) = rig.centre();
    let f = rig.focal_px;
    scene::expose(rig.width, rig.height, camera, membrane, frame, |u, v| {
        let mut sum = 0.0;
        for j in 0..SUB {
            for i in 0..SUB {
                let su = u as f64 + (i as f64 + 0.5) / SUB as f64 - 0.5;
                let sv = v as f64 + (j as f64 + 0.5) / SUB as f64 - 0.5;
                let (a, b) = ((su - cx) / f, (sv - cy) / f);
                let z = plane.depth_along(a, b, x0);
                sum += if z > 0.0 {
                    target_texture(x0 + a * z, b * z)
                } else {
                    0.0
                };
            }
        }
        sum / (SUB * SUB) as f64
    })
}

/// A flat target through `point` with normal `normal` (world = the left camera's
/// frame), printed with the built-in texture (a function of the world `X, Y` where a ray
/// meets it, so both views see the same print).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TexturedPlane {
    /// A point on the plane, mm.
    pub point: Point3<f64>,
    /// Its normal.
    pub normal: Vector3<f64>,
}

impl Surface for TexturedPlane {
    fn shade(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<f64> {
        let hit = scene::hit_plane(origin, dir, &self.point, &self.normal)?;
        Some(target_texture(hit.x, hit.y))
    }
}

/// Raw captures through a calibrated pair, lens distortion, rotation and all: what the
/// sensor's cameras deliver before rectification. The rays are computed once.
#[derive(Debug, Clone)]
pub struct RawRig {
    calib: StereoCalibration,
    left: RayGrid,
    right: RayGrid,
}

impl RawRig {
    /// A rig with `calib`'s cameras.
    pub fn new(calib: &StereoCalibration) -> Self {
        let (left, right) =
            rayon::join(|| RayGrid::new(&calib.left), || RayGrid::new(&calib.right));
        Self {
            calib: *calib,
            left,
            right,
        }
    }

    /// The true calibration.
    pub fn calibration(&self) -> &StereoCalibration {
        &self.calib
    }

    /// One left/right frame of `surface` behind `membrane` (3×3 rays per pixel); `frame`
    /// seeds the noise.
    pub fn render(
        &self,
        surface: &impl Surface,
        membrane: &Membrane,
        frame: u64,
    ) -> (Grid<u8>, Grid<u8>) {
        self.render_sampled(surface, membrane, 3, frame)
    }

    /// [`Self::render`] with `sub × sub` rays per pixel.
    pub fn render_sampled(
        &self,
        surface: &impl Surface,
        membrane: &Membrane,
        sub: usize,
        frame: u64,
    ) -> (Grid<u8>, Grid<u8>) {
        let left = View {
            rays: &self.left,
            world_from_camera: Isometry3::identity(),
            camera_id: 1,
        };
        let right = View {
            rays: &self.right,
            world_from_camera: self.calib.world_from_right(),
            camera_id: 2,
        };
        rayon::join(
            || scene::render(&left, surface, membrane, sub, frame),
            || scene::render(&right, surface, membrane, sub, frame),
        )
    }
}

/// The target's printed texture at `(x, y)` mm, in 0..1.
fn target_texture(x: f64, y: f64) -> f64 {
    let mut sum = 0.0;
    let mut cell = 0.25;
    for octave in 0..6u64 {
        sum += value_noise(x / cell, y / cell, octave);
        cell *= 2.0;
    }
    sum / 6.0
}

/// A `w`×`h` depth camera (focal 336 px at 640 wide) looking at a plane slanted
/// `slope` (dZ/dX), with a box standing 40 mm out of it (a depth step), noise of
/// `noise` mm, holes, and flying pixels (random depth) at 1 % of the pixels; returns
/// the cloud and which points fly. The outlier filters' test and bench input.
pub fn camera_cloud(w: usize, h: usize, slope: f32, noise: f32) -> (PointCloud, Vec<bool>) {
    let f = 336.0 * w as f32 / 640.0;
    let (cx, cy) = (w as f32 / 2.0, h as f32 / 2.0);
    let mut rng = Rng::new(7);
    let mut cloud = PointCloud::default();
    let mut flying = Vec::new();
    for v in 0..h {
        for u in 0..w {
            let (x, y) = ((u as f32 - cx) / f, (v as f32 - cy) / f);
            // Z of the plane Z = 200 + slope·X along the ray (x, y, 1)·Z.
            let mut z = 200.0 / (1.0 - slope * x);
            if (u as f32 - cx).abs() < w as f32 / 8.0 && (v as f32 - cy).abs() < h as f32 / 8.0 {
                z -= 40.0;
            }
            let roll = rng.uniform() as f32;
            if roll < 0.02 {
                continue; // a hole
            }
            let fly = roll > 0.99;
            if fly {
                z = 80.0 + 400.0 * rng.uniform() as f32;
            } else {
                z += noise * (rng.uniform() as f32 - 0.5);
            }
            cloud.points.push([x * z, y * z, z]);
            cloud.pixels.push((v * w + u) as u32);
            flying.push(fly);
        }
    }
    (cloud, flying)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_views_agree_at_the_planes_disparity() {
        // Without skin and noise, right(u − d) ≈ left(u) for d = f·B/Z.
        let rig = StereoRig {
            width: 200,
            height: 40,
            ..StereoRig::sensor()
        };
        let plane = Plane::facing(200.0);
        let d = rig.disparity_at(200.0); // 23.52
        let (l, r) = render_pair(&rig, &plane, &Membrane::clear(), 0);
        let mut err_at_d = 0.0;
        let mut err_at_0 = 0.0;
        for y in 5..35 {
            for x in 60..190 {
                let xr = x as f64 - d;
                let (i, t) = (xr.floor() as usize, xr - xr.floor());
                let rv = f64::from(r.get(i, y)) * (1.0 - t) + f64::from(r.get(i + 1, y)) * t;
                err_at_d += (rv - f64::from(l.get(x, y))).abs();
                err_at_0 += (f64::from(r.get(x, y)) - f64::from(l.get(x, y))).abs();
            }
        }
        assert!(err_at_d * 5.0 < err_at_0, "{err_at_d} vs {err_at_0}");
        // Noise differs per frame, the rest does not.
        let m = Membrane::sensor();
        let (a, _) = render_pair(&rig, &plane, &m, 1);
        let (b, _) = render_pair(&rig, &plane, &m, 2);
        let (c, _) = render_pair(&rig, &plane, &m, 1);
        assert_ne!(a, b);
        assert_eq!(a, c);
    }

    #[test]
    fn a_tilted_plane_meets_the_rays_where_it_should() {
        let p = Plane {
            z_mm: 100.0,
            tilt_x: 0.5,
            tilt_y: -0.2,
        };
        let (a, b) = (0.3, -0.1);
        let z = p.depth_along(a, b, 14.0);
        let (x, y) = (14.0 + a * z, b * z);
        assert!((z - (100.0 + 0.5 * x - 0.2 * y)).abs() < 1e-9);
        // The true disparity map: at the principal point, f·B / z.
        let rig = StereoRig {
            width: 5,
            height: 3,
            ..StereoRig::sensor()
        };
        let d = rig.true_disparity(&p);
        assert!((f64::from(d.get(2, 1)) - rig.disparity_at(100.0)).abs() < 1e-4);
    }
}
