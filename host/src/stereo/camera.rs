//! One camera's intrinsics: the camera matrix and a lens model, and the projection of a
//! point in camera coordinates to a pixel.
//!
//! Two lens models, as ROS and OpenCV define them:
//! - Brown–Conrady (ROS `plumb_bob` / `rational_polynomial`, OpenCV's default model):
//!   `k1 k2 p1 p2 k3 k4 k5 k6`, radial `(1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ +
//!   k6 r⁶)` plus tangential terms, on the normalised image plane; only points in front of
//!   the camera project.
//! - Kannala–Brandt (ROS `equidistant`, OpenCV's `fisheye` module): `k1..k4`, the image
//!   radius is `θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)` for a ray at angle `θ` from the
//!   axis, so rays up to and beyond 90° project (160° lenses).

use nalgebra::{Matrix3, Vector3};

/// A lens model and its coefficients.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Distortion {
    /// Brown–Conrady: `k1 k2 p1 p2 k3 k4 k5 k6` (missing ones are zero).
    BrownConrady([f64; 8]),
    /// Kannala–Brandt equidistant fisheye: `k1 k2 k3 k4`.
    KannalaBrandt([f64; 4]),
}

impl Distortion {
    /// No distortion (a pinhole).
    pub const NONE: Distortion = Distortion::BrownConrady([0.0; 8]);

    /// The model's name as this crate's OpenCV YAML writes it (`plumb_bob` or
    /// `fisheye`; ROS files call the fisheye model `equidistant`).
    pub fn model_name(&self) -> &'static str {
        match self {
            Distortion::BrownConrady(_) => "plumb_bob",
            Distortion::KannalaBrandt(_) => "fisheye",
        }
    }

    /// The model for messages, with the names files give it.
    pub fn model_label(&self) -> &'static str {
        match self {
            Distortion::BrownConrady(_) => "Brown–Conrady (plumb_bob, rational_polynomial)",
            Distortion::KannalaBrandt(_) => "Kannala–Brandt (fisheye, equidistant)",
        }
    }

    /// The coefficients as a file lists them (Brown–Conrady: 5, or 8 when the rational
    /// terms are used).
    pub fn coefficients(&self) -> Vec<f64> {
        match self {
            Distortion::BrownConrady(k) if k[5..].iter().all(|&v| v == 0.0) => k[..5].to_vec(),
            Distortion::BrownConrady(k) => k.to_vec(),
            Distortion::KannalaBrandt(k) => k.to_vec(),
        }
    }

    /// Whether every coefficient is finite.
    pub fn is_finite(&self) -> bool {
        self.coefficients().iter().all(|v| v.is_finite())
    }
}

/// A calibrated camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Camera matrix `[fx s cx; 0 fy cy; 0 0 1]`.
    pub k: Matrix3<f64>,
    /// Lens model.
    pub distortion: Distortion,
}

impl Camera {
    /// The pixel where a point in camera coordinates (z forward) appears, or `None` when
    /// the model cannot image it (behind a pinhole camera, at the optical centre).
    pub fn project(&self, p: &Vector3<f64>) -> Option<[f64; 2]> {
        let (x, y) = match self.distortion {
            Distortion::BrownConrady(k) => {
                if p.z <= 0.0 {
                    return None;
                }
                brown_conrady(&k, p.x / p.z, p.y / p.z)
            }
            Distortion::KannalaBrandt(k) => {
                let r = p.x.hypot(p.y);
                if r == 0.0 {
                    return (p.z > 0.0).then(|| [self.k[(0, 2)], self.k[(1, 2)]]);
                }
                let theta_d = kannala_brandt(&k, r.atan2(p.z));
                (theta_d * p.x / r, theta_d * p.y / r)
            }
        };
        let k = &self.k;
        let u = k[(0, 0)] * x + k[(0, 1)] * y + k[(0, 2)];
        let v = k[(1, 1)] * y + k[(1, 2)];
        (u.is_finite() && v.is_finite()).then_some([u, v])
    }

    /// The unit ray (camera coordinates) that images at pixel `(u, v)`: the inverse of
    /// [`Self::project`], solved by Newton's method on the lens polynomial.
    ///
    /// `None` when no ray images there: outside the range where the lens model is
    /// monotonic (a Kannala–Brandt polynomial that turns back, a Brown–Conrady model
    /// folding over far off-axis) or for a non-finite input.
    pub fn unproject(&self, pixel: [f64; 2]) -> Option<Vector3<f64>> {
        let k = &self.k;
        let yd = (pixel[1] - k[(1, 2)]) / k[(1, 1)];
        let xd = (pixel[0] - k[(0, 2)] - k[(0, 1)] * yd) / k[(0, 0)];
        if !(xd.is_finite() && yd.is_finite()) {
            return None;
        }
        let ray = match self.distortion {
            Distortion::KannalaBrandt(c) => {
                let theta_d = xd.hypot(yd);
                if theta_d == 0.0 {
                    return Some(Vector3::z());
                }
                let theta = invert_kannala_brandt(&c, theta_d)?;
                let s = theta.sin() / theta_d;
                Vector3::new(xd * s, yd * s, theta.cos())
            }
            Distortion::BrownConrady(c) => {
                let (x, y) = invert_brown_conrady(&c, xd, yd)?;
                Vector3::new(x, y, 1.0).normalize()
            }
        };
        ray.iter().all(|v| v.is_finite()).then_some(ray)
    }
}

/// Brown–Conrady distortion of a normalised image point.
fn brown_conrady(k: &[f64; 8], x: f64, y: f64) -> (f64, f64) {
    let r2 = x * x + y * y;
    let r4 = r2 * r2;
    let r6 = r4 * r2;
    let radial =
        (1.0 + k[0] * r2 + k[1] * r4 + k[4] * r6) / (1.0 + k[5] * r2 + k[6] * r4 + k[7] * r6);
    (
        x * radial + 2.0 * k[2] * x * y + k[3] * (r2 + 2.0 * x * x),
        y * radial + k[2] * (r2 + 2.0 * y * y) + 2.0 * k[3] * x * y,
    )
}

/// Kannala–Brandt image radius `θ_d` of a ray at angle `θ` from the axis.
fn kannala_brandt(k: &[f64; 4], theta: f64) -> f64 {
    let t2 = theta * theta;
    theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
}

/// `dθ_d/dθ` of [`kannala_brandt`].
fn kannala_brandt_slope(k: &[f64; 4], theta: f64) -> f64 {
    let t2 = theta * theta;
    1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])))
}

/// Newton's method on the normalised image plane converges to this residual.
const UNPROJECT_TOLERANCE: f64 = 1e-12;
/// Newton steps before giving up.
const UNPROJECT_STEPS: usize = 30;

/// The angle `θ ∈ [0, π)` with `kannala_brandt(θ) = θ_d`, on the branch where the
/// polynomial still increases from the axis.
fn invert_kannala_brandt(k: &[f64; 4], theta_d: f64) -> Option<f64> {
    let mut theta = theta_d.min(3.0);
    for _ in 0..UNPROJECT_STEPS {
        let slope = kannala_brandt_slope(k, theta);
        if slope.is_nan() || slope <= 0.0 {
            return None;
        }
        let step = (kannala_brandt(k, theta) - theta_d) / slope;
        theta = (theta - step).clamp(0.0, std::f64::consts::PI - 1e-9);
        if step.abs() <= UNPROJECT_TOLERANCE * theta_d.max(1.0) {
            // A root past the polynomial's first maximum images the same radius as one
            // before it would: refuse it, the lens cannot tell them apart.
            let increasing =
                (0..=16).all(|i| kannala_brandt_slope(k, theta * i as f64 / 16.0) > 0.0);
            return increasing.then_some(theta);
        }
    }
    None
}

/// The undistorted normalised point whose Brown–Conrady image is `(xd, yd)`: Newton's
/// method with a finite-difference Jacobian, started at the distorted point.
fn invert_brown_conrady(k: &[f64; 8], xd: f64, yd: f64) -> Option<(f64, f64)> {
    let (mut x, mut y) = (xd, yd);
    const H: f64 = 1e-7;
    for _ in 0..UNPROJECT_STEPS {
        let (fx, fy) = brown_conrady(k, x, y);
        let (ex, ey) = (fx - xd, fy - yd);
        if ex.hypot(ey) <= UNPROJECT_TOLERANCE * (1.0 + xd.hypot(yd)) {
            return Some((x, y));
        }
        let (ax, ay) = brown_conrady(k, x + H, y);
        let (bx, by) = brown_conrady(k, x - H, y);
        let (cx, cy) = brown_conrady(k, x, y + H);
        let (dx, dy) = brown_conrady(k, x, y - H);
        let (j11, j21) = ((ax - bx) / (2.0 * H), (ay - by) / (2.0 * H));
        let (j12, j22) = ((cx - dx) / (2.0 * H), (cy - dy) / (2.0 * H));
        let det = j11 * j22 - j12 * j21;
        // A fold (non-positive Jacobian) means the model maps two points here.
        if det.is_nan() || det <= 0.0 {
            return None;
        }
        x -= (j22 * ex - j12 * ey) / det;
        y -= (j11 * ey - j21 * ex) / det;
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(distortion: Distortion) -> Camera {
        Camera {
            width: 640,
            height: 480,
            k: Matrix3::new(500.0, 0.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0),
            distortion,
        }
    }

    #[test]
    fn brown_conrady_without_distortion_is_a_pinhole() {
        let c = camera(Distortion::NONE);
        let [u, v] = c.project(&Vector3::new(0.1, -0.2, 2.0)).unwrap();
        assert!((u - (320.0 + 500.0 * 0.05)).abs() < 1e-12);
        assert!((v - (240.0 - 510.0 * 0.1)).abs() < 1e-12);
        assert_eq!(c.project(&Vector3::new(0.0, 0.0, -1.0)), None);
    }

    #[test]
    fn brown_conrady_radial_term_matches_the_formula() {
        let c = camera(Distortion::BrownConrady([
            0.1, 0.01, 0.0, 0.0, 0.001, 0.0, 0.0, 0.0,
        ]));
        let (x, y) = (0.3, 0.4); // r² = 0.25
        let radial = 1.0 + 0.1 * 0.25 + 0.01 * 0.0625 + 0.001 * 0.015625;
        let [u, _] = c.project(&Vector3::new(x, y, 1.0)).unwrap();
        assert!((u - (320.0 + 500.0 * x * radial)).abs() < 1e-12);
    }

    #[test]
    fn kannala_brandt_is_equidistant_up_to_and_beyond_90_degrees() {
        let c = camera(Distortion::KannalaBrandt([0.0; 4]));
        for deg in [10.0f64, 45.0, 80.0, 95.0] {
            let t = deg.to_radians();
            let [u, v] = c.project(&Vector3::new(t.sin(), 0.0, t.cos())).unwrap();
            assert!((u - (320.0 + 500.0 * t)).abs() < 1e-9, "{deg}°");
            assert!((v - 240.0).abs() < 1e-12);
        }
        assert_eq!(
            c.project(&Vector3::new(0.0, 0.0, 1.0)),
            Some([320.0, 240.0])
        );
    }

    fn assert_round_trip(c: &Camera, pixel: [f64; 2]) {
        let ray = c
            .unproject(pixel)
            .unwrap_or_else(|| panic!("no ray at {pixel:?}"));
        assert!((ray.norm() - 1.0).abs() < 1e-12);
        let back = c.project(&ray).unwrap();
        assert!(
            (back[0] - pixel[0]).abs() < 1e-8 && (back[1] - pixel[1]).abs() < 1e-8,
            "{pixel:?} -> {back:?}"
        );
    }

    #[test]
    fn unproject_inverts_a_pinhole_analytically() {
        let c = camera(Distortion::NONE);
        let ray = c
            .unproject([320.0 + 500.0 * 0.2, 240.0 - 510.0 * 0.1])
            .unwrap();
        let expected = Vector3::new(0.2, -0.1, 1.0).normalize();
        assert!((ray - expected).norm() < 1e-12);
        assert_eq!(c.unproject([320.0, 240.0]).unwrap(), Vector3::z());
        assert_eq!(c.unproject([f64::NAN, 0.0]), None);
    }

    #[test]
    fn unproject_inverts_both_lens_models_across_the_image() {
        let brown = camera(Distortion::BrownConrady([
            -0.28, 0.09, 0.001, -0.0005, -0.01, 0.0, 0.0, 0.0,
        ]));
        // A 160° fisheye: f = 230 px puts 80° off axis at about 320 px from the centre.
        let mut fisheye = camera(Distortion::KannalaBrandt([-0.02, 0.004, -0.0005, 0.00002]));
        fisheye.k = Matrix3::new(230.0, 0.0, 321.0, 0.0, 229.0, 239.0, 0.0, 0.0, 1.0);
        for c in [brown, fisheye] {
            for v in [0.0, 120.0, 239.5, 479.0] {
                for u in [0.0, 100.0, 320.0, 639.0] {
                    assert_round_trip(&c, [u, v]);
                }
            }
        }
        let theta = 80f64.to_radians();
        let [u, v] = fisheye
            .project(&Vector3::new(theta.sin(), 0.0, theta.cos()))
            .unwrap();
        let ray = fisheye.unproject([u, v]).unwrap();
        assert!((ray.z.acos() - theta).abs() < 1e-10);
        // Past 90°: the ray points backwards and still round-trips.
        let theta = 95f64.to_radians();
        let back = fisheye
            .project(&Vector3::new(0.0, theta.sin(), theta.cos()))
            .unwrap();
        assert!(fisheye.unproject(back).unwrap().z < 0.0);
    }

    #[test]
    fn unproject_refuses_radii_past_the_lens_polynomials_turning_point() {
        // θ_d = θ(1 − 0.2 θ²) peaks at θ = 1.29 rad with θ_d = 0.86.
        let c = camera(Distortion::KannalaBrandt([-0.2, 0.0, 0.0, 0.0]));
        assert!(c.unproject([320.0 + 500.0 * 0.8, 240.0]).is_some());
        assert_eq!(c.unproject([320.0 + 500.0 * 0.9, 240.0]), None);
        // A strong barrel Brown–Conrady model folds over far off axis.
        let c = camera(Distortion::BrownConrady([
            -0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ]));
        assert_eq!(c.unproject([320.0 + 500.0 * 2.0, 240.0]), None);
    }
}
