//! From disparity to geometry: depth `Z = f·B/d` per pixel and the point cloud
//! `Q·[u, v, d, 1]ᵀ` in the rectified left camera's frame, in the calibration's unit
//! (mm). Invalid disparities (NaN, or not positive: a point at or beyond infinity) give
//! NaN depth and no point.

use nalgebra::Matrix4;

use crate::grid::Grid;

/// Depth (mm) per pixel from disparity (px): `focal_px · baseline / d`.
pub fn depth_from_disparity(disparity: &Grid<f32>, focal_px: f64, baseline: f64) -> Grid<f32> {
    let fb = (focal_px * baseline) as f32;
    disparity.map(|d| if d > 0.0 { fb / d } else { f32::NAN })
}

/// A point cloud that remembers which pixel each point came from.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    /// Points `[X, Y, Z]` (mm; X right, Y down, Z forward from the left camera).
    pub points: Vec<[f32; 3]>,
    /// Row-major pixel index of each point.
    pub pixels: Vec<u32>,
}

impl PointCloud {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// `true` without points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Keeps the points whose `keep` entry is `true` (same length as the cloud).
    pub fn retain(&mut self, keep: &[bool]) {
        let mut i = 0;
        self.points.retain(|_| {
            i += 1;
            keep[i - 1]
        });
        let mut j = 0;
        self.pixels.retain(|_| {
            j += 1;
            keep[j - 1]
        });
    }
}

/// Reprojects every valid disparity with the reprojection matrix `q`.
pub fn reproject(disparity: &Grid<f32>, q: &Matrix4<f64>) -> PointCloud {
    let q = q.cast::<f32>();
    let w = disparity.width();
    let mut cloud = PointCloud::default();
    for (i, &d) in disparity.as_slice().iter().enumerate() {
        if !(d > 0.0 && d.is_finite()) {
            continue;
        }
        let (u, v) = ((i % w) as f32, (i / w) as f32);
        let h = q * nalgebra::Vector4::new(u, v, d, 1.0);
        if h.w.abs() <= f32::EPSILON {
            continue;
        }
        let p = [h.x / h.w, h.y / h.w, h.z / h.w];
        if p.iter().all(|c| c.is_finite()) {
            cloud.points.push(p);
            cloud.pixels.push(i as u32);
        }
    }
    cloud
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::rectify::Rectification;
    use crate::stereo::synthetic::StereoRig;

    #[test]
    fn q_and_depth_agree_with_the_pinhole_model() {
        let rig = StereoRig::sensor();
        let rect = Rectification::bouguet(&rig.calibration(), 1.0).unwrap();
        // A point at (30, −20, 250) mm: u = f·X/Z + cx, d = f·B/Z.
        let (x, y, z) = (30.0, -20.0, 250.0);
        let (cx, cy) = rig.centre();
        let f = rig.focal_px;
        let (u, v) = (f * x / z + cx, f * y / z + cy);
        let d = rig.disparity_at(z);
        let (ui, vi) = (u.round() as usize, v.round() as usize);
        // Put the disparity on the pixel nearest (u, v); the point moves by the rounding.
        let mut disp = Grid::filled(640, 480, f32::NAN);
        disp.set(ui, vi, d as f32);
        disp.set(0, 0, -1.0);
        let cloud = reproject(&disp, &rect.q);
        assert_eq!(cloud.len(), 1);
        let p = cloud.points[0];
        let expect = [(ui as f64 - cx) * z / f, (vi as f64 - cy) * z / f, z];
        for k in 0..3 {
            assert!(
                (f64::from(p[k]) - expect[k]).abs() < 1e-3 * z,
                "{p:?} vs {expect:?}"
            );
        }
        assert_eq!(cloud.pixels[0] as usize, vi * 640 + ui);
        let depth = depth_from_disparity(&disp, rect.focal(), rect.baseline());
        assert!((f64::from(depth.get(ui, vi)) - z).abs() < 1e-3);
        assert!(depth.get(0, 0).is_nan() && depth.get(1, 0).is_nan());
    }
}
