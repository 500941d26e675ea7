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
                let (x, y) = (p.x / p.z, p.y / p.z);
                let r2 = x * x + y * y;
                let r4 = r2 * r2;
                let r6 = r4 * r2;
                let radial = (1.0 + k[0] * r2 + k[1] * r4 + k[4] * r6)
                    / (1.0 + k[5] * r2 + k[6] * r4 + k[7] * r6);
                (
                    x * radial + 2.0 * k[2] * x * y + k[3] * (r2 + 2.0 * x * x),
                    y * radial + k[2] * (r2 + 2.0 * y * y) + 2.0 * k[3] * x * y,
                )
            }
            Distortion::KannalaBrandt(k) => {
                let r = p.x.hypot(p.y);
                if r == 0.0 {
                    return (p.z > 0.0).then(|| [self.k[(0, 2)], self.k[(1, 2)]]);
                }
                let theta = r.atan2(p.z);
                let t2 = theta * theta;
                let theta_d = theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))));
                (theta_d * p.x / r, theta_d * p.y / r)
            }
        };
        let k = &self.k;
        let u = k[(0, 0)] * x + k[(0, 1)] * y + k[(0, 2)];
        let v = k[(1, 1)] * y + k[(1, 2)];
        (u.is_finite() && v.is_finite()).then_some([u, v])
    }
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
}
