//! Renders a surface through a calibrated camera, lens model and all: the built-in
//! captures of textured targets and checkerboards, raw as the sensor's wide lenses see
//! them, so the tests run rectification, calibration and matching on what real frames
//! look like.
//!
//! Each pixel averages `sub × sub` rays spread over its area (area sampling, so edges
//! are anti-aliased as a real sensor's are). The rays of a camera are computed once
//! ([`RayGrid`], one [`Camera::unproject`] per pixel corner) and interpolated inside the
//! pixel: across one pixel the rays are close enough that the interpolated direction is
//! off by less than 10⁻³ px (4·10⁻⁴ px, 300 px off axis at f = 295). Pixels that see no
//! surface, or whose corners have no ray (past a lens model's valid range), show the
//! background.

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

use super::camera::Camera;
use crate::grid::Grid;
use crate::rng::Rng;

/// The rays through every pixel corner of a camera, computed once.
#[derive(Debug, Clone)]
pub struct RayGrid {
    width: usize,
    height: usize,
    /// `(width + 1) × (height + 1)` unit rays in the camera frame, row-major; corner
    /// `(i, j)` is at pixel coordinates `(i − ½, j − ½)`.
    corners: Vec<Option<Vector3<f64>>>,
}

impl RayGrid {
    /// Unprojects every pixel corner of `camera`.
    pub fn new(camera: &Camera) -> Self {
        let (width, height) = (camera.width as usize, camera.height as usize);
        let corners = (0..(width + 1) * (height + 1))
            .into_par_iter()
            .map(|n| {
                let (i, j) = (n % (width + 1), n / (width + 1));
                camera.unproject([i as f64 - 0.5, j as f64 - 0.5])
            })
            .collect();
        Self {
            width,
            height,
            corners,
        }
    }

    /// Image width, pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Image height, pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The four corner rays of pixel `(u, v)`: top-left, top-right, bottom-left,
    /// bottom-right; `None` if one has no ray.
    fn pixel(&self, u: usize, v: usize) -> Option<[Vector3<f64>; 4]> {
        let at = |i: usize, j: usize| self.corners[j * (self.width + 1) + i];
        Some([at(u, v)?, at(u + 1, v)?, at(u, v + 1)?, at(u + 1, v + 1)?])
    }
}

/// What the camera sees: the brightness (0 black … 1 white) where a ray meets the
/// scene, `None` where it meets nothing. Rays are in the world frame.
pub trait Surface: Sync {
    /// Brightness seen along `origin + λ·dir`, `λ > 0`.
    fn shade(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<f64>;
}

/// The skin between the cameras and the scene, and the sensor's noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Membrane {
    /// Share of each pixel's light that comes from the skin itself (0..1).
    pub haze: f64,
    /// Contrast of the skin's own pattern, grey levels (peak to peak about twice this).
    pub pattern: f64,
    /// Per-frame sensor noise, grey levels (standard deviation).
    pub noise: f64,
}

impl Membrane {
    /// The sensor's skin: a third of the light from the skin, a faint pattern, noise of
    /// 2 grey levels.
    pub fn sensor() -> Self {
        Self {
            haze: 0.35,
            pattern: 6.0,
            noise: 2.0,
        }
    }

    /// No skin and no noise.
    pub fn clear() -> Self {
        Self {
            haze: 0.0,
            pattern: 0.0,
            noise: 0.0,
        }
    }
}

/// Grey level of a black (brightness 0) and a white (1) part of the scene.
const BLACK: f64 = 30.0;
const WHITE: f64 = 230.0;
/// Brightness of rays that meet nothing.
const BACKGROUND: f64 = 0.0;
/// The skin's own grey level.
const SKIN: f64 = 170.0;

/// How one camera of a capture is placed and identified.
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    /// The camera's rays.
    pub rays: &'a RayGrid,
    /// The camera's pose: camera coordinates to world coordinates.
    pub world_from_camera: Isometry3<f64>,
    /// Which camera (1 left, 2 right): selects its skin pattern and noise stream.
    pub camera_id: u64,
}

/// Renders `surface` as `view` sees it behind `membrane`, `sub × sub` rays per pixel;
/// `frame` seeds the noise.
pub fn render(
    view: &View<'_>,
    surface: &impl Surface,
    membrane: &Membrane,
    sub: usize,
    frame: u64,
) -> Grid<u8> {
    let sub = sub.max(1);
    let origin = view.world_from_camera * Point3::origin();
    let rotation = view.world_from_camera.rotation;
    let (w, h) = (view.rays.width, view.rays.height);
    expose(w, h, view.camera_id, membrane, frame, |u, v| {
        let Some([a, b, c, d]) = view.rays.pixel(u, v) else {
            return BACKGROUND;
        };
        let mut sum = 0.0;
        for j in 0..sub {
            let ty = (j as f64 + 0.5) / sub as f64;
            let left = a + (c - a) * ty;
            let right = b + (d - b) * ty;
            for i in 0..sub {
                let tx = (i as f64 + 0.5) / sub as f64;
                let dir = rotation * (left + (right - left) * tx);
                sum += surface.shade(&origin, &dir).unwrap_or(BACKGROUND);
            }
        }
        sum / (sub * sub) as f64
    })
}

/// The `width × height` image camera `camera_id` records when pixel `(u, v)` sees the
/// scene at `brightness(u, v)` (0 black … 1 white) behind `membrane`: the skin's haze and
/// pattern mixed in, then the sensor noise of `frame`. Rows run in parallel, each with
/// its own noise stream, so the image does not depend on the thread count.
pub fn expose(
    width: usize,
    height: usize,
    camera_id: u64,
    membrane: &Membrane,
    frame: u64,
    brightness: impl Fn(usize, usize) -> f64 + Sync,
) -> Grid<u8> {
    let mut data = vec![0u8; width * height];
    data.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(v, row)| {
            let mut rng =
                Rng::new(frame.wrapping_mul(0x1_0000_0001) ^ (camera_id << 40) ^ v as u64);
            for (u, px) in row.iter_mut().enumerate() {
                let scene = BLACK + (WHITE - BLACK) * brightness(u, v);
                let skin = SKIN + membrane.pattern * skin_pattern(camera_id, u, v);
                let value = (1.0 - membrane.haze) * scene
                    + membrane.haze * skin
                    + membrane.noise * rng.gaussian();
                *px = value.round().clamp(0.0, 255.0) as u8;
            }
        });
    Grid::from_vec(width, height, data).expect("size matches")
}

/// Where the ray `origin + λ·dir` (λ > 0) meets the plane through `point` with normal
/// `normal`, or `None` if it runs parallel or away.
pub fn hit_plane(
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
    point: &Point3<f64>,
    normal: &Vector3<f64>,
) -> Option<Point3<f64>> {
    let along = normal.dot(dir);
    if along.abs() < 1e-12 {
        return None;
    }
    let lambda = normal.dot(&(point - origin)) / along;
    (lambda > 0.0 && lambda.is_finite()).then(|| origin + dir * lambda)
}

/// The skin's own faint pattern in camera `camera`'s pixel `(u, v)`, in −1..1.
fn skin_pattern(camera: u64, u: usize, v: usize) -> f64 {
    let (x, y) = (u as f64, v as f64);
    value_noise(x / 3.0, y / 3.0, 100 + camera) + value_noise(x / 40.0, y / 40.0, 200 + camera)
        - 1.0
}

/// Smoothly interpolated lattice noise in 0..1.
pub(crate) fn value_noise(x: f64, y: f64, salt: u64) -> f64 {
    let (fx, fy) = (x.floor(), y.floor());
    let (tx, ty) = (smooth(x - fx), smooth(y - fy));
    let (ix, iy) = (fx as i64, fy as i64);
    let at = |dx: i64, dy: i64| lattice(ix + dx, iy + dy, salt);
    let top = at(0, 0) + (at(1, 0) - at(0, 0)) * tx;
    let bottom = at(0, 1) + (at(1, 1) - at(0, 1)) * tx;
    top + (bottom - top) * ty
}

fn smooth(t: f64) -> f64 {
    t * t * (3.0 - 2.0 * t)
}

fn lattice(x: i64, y: i64, salt: u64) -> f64 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ salt.wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix3, Translation3};

    use super::*;
    use crate::stereo::camera::Distortion;

    /// Left half of the world (x < 0) white, right half black, on the plane z = 100.
    struct HalfPlane;

    impl Surface for HalfPlane {
        fn shade(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<f64> {
            let p = hit_plane(origin, dir, &Point3::new(0.0, 0.0, 100.0), &Vector3::z())?;
            Some(if p.x < 0.0 { 1.0 } else { 0.0 })
        }
    }

    fn pinhole(cx: f64) -> Camera {
        Camera {
            width: 16,
            height: 4,
            k: Matrix3::new(100.0, 0.0, cx, 0.0, 100.0, 1.5, 0.0, 0.0, 1.0),
            distortion: Distortion::NONE,
        }
    }

    #[test]
    fn an_edge_through_a_pixel_centre_gives_the_area_weighted_grey() {
        // The edge x = 0 images at u = cx = 7: pixel 7 is half white, half black.
        let rays = RayGrid::new(&pinhole(7.0));
        let view = View {
            rays: &rays,
            world_from_camera: Isometry3::identity(),
            camera_id: 1,
        };
        let image = render(&view, &HalfPlane, &Membrane::clear(), 4, 0);
        assert_eq!(image.get(6, 1), WHITE as u8);
        assert_eq!(image.get(7, 1), ((WHITE + BLACK) / 2.0) as u8);
        assert_eq!(image.get(8, 1), BLACK as u8);
        // A camera moved 3 mm left sees the edge 3 px further right (f·x/z = 3).
        let view = View {
            world_from_camera: Translation3::new(-3.0, 0.0, 0.0).into(),
            ..view
        };
        let image = render(&view, &HalfPlane, &Membrane::clear(), 4, 0);
        assert_eq!(image.get(9, 2), WHITE as u8);
        assert_eq!(image.get(10, 2), ((WHITE + BLACK) / 2.0) as u8);
        assert_eq!(image.get(11, 2), BLACK as u8);
    }

    #[test]
    fn rays_that_miss_show_the_background_and_haze_mixes_in_the_skin() {
        let rays = RayGrid::new(&pinhole(7.0));
        let view = View {
            rays: &rays,
            world_from_camera: Translation3::new(0.0, 0.0, 200.0).into(),
            camera_id: 1,
        };
        // The plane is behind this camera: every ray misses.
        let image = render(&view, &HalfPlane, &Membrane::clear(), 2, 0);
        assert!(image.as_slice().iter().all(|&v| v == BLACK as u8));
        let haze = Membrane {
            haze: 0.5,
            pattern: 0.0,
            noise: 0.0,
        };
        let image = render(&view, &HalfPlane, &haze, 2, 0);
        let expected = (0.5 * BLACK + 0.5 * SKIN).round() as u8;
        assert!(image.as_slice().iter().all(|&v| v == expected));
    }

    #[test]
    fn hit_plane_refuses_parallel_and_backward_rays() {
        let o = Point3::origin();
        let p = Point3::new(0.0, 0.0, 10.0);
        assert_eq!(
            hit_plane(&o, &Vector3::new(0.0, 1.0, 1.0), &p, &Vector3::z()),
            Some(Point3::new(0.0, 10.0, 10.0))
        );
        assert_eq!(hit_plane(&o, &Vector3::x(), &p, &Vector3::z()), None);
        assert_eq!(hit_plane(&o, &-Vector3::z(), &p, &Vector3::z()), None);
    }
}
