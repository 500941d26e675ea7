//! From disparity to geometry: depth `Z = f·B/d` per pixel and the point cloud
//! `Q·[u, v, d, 1]ᵀ` in the rectified left camera's frame, in the calibration's unit
//! (mm). Invalid disparities (NaN, or not positive: a point at or beyond infinity) give
//! NaN depth and no point.

use nalgebra::Matrix4;
use rayon::prelude::*;

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

/// Rows per job of [`reproject`]: enough work per job to be worth handing out, and
/// enough jobs (15 at 480 rows) for two threads to finish together.
const BAND_ROWS: usize = 32;

/// Reprojects every valid disparity with the reprojection matrix `q`. Bands of rows in
/// parallel (rayon), each band's points in pixel order, so the cloud is the same on any
/// number of threads.
pub fn reproject(disparity: &Grid<f32>, q: &Matrix4<f64>) -> PointCloud {
    let w = disparity.width();
    if w == 0 {
        return PointCloud::default();
    }
    let q = q.cast::<f32>();
    let bands: Vec<PointCloud> = disparity
        .as_slice()
        .par_chunks(w * BAND_ROWS)
        .enumerate()
        .map(|(band, values)| reproject_band(values, w, band * BAND_ROWS, &q))
        .collect();
    let total = bands.iter().map(PointCloud::len).sum();
    let mut cloud = PointCloud {
        points: Vec::with_capacity(total),
        pixels: Vec::with_capacity(total),
    };
    for band in bands {
        cloud.points.extend_from_slice(&band.points);
        cloud.pixels.extend_from_slice(&band.pixels);
    }
    cloud
}

/// The points of whole rows `values` (row `first_row` on), row by row: `Q·[u, v, d, 1]ᵀ`
/// as the row's constant part `Q·[0, v, 0, 1]ᵀ` plus `u` and `d` times their columns.
fn reproject_band(values: &[f32], w: usize, first_row: usize, q: &Matrix4<f32>) -> PointCloud {
    // At most one point per positive finite disparity: no growing, no more than needed.
    let most = values.iter().filter(|d| **d > 0.0 && d.is_finite()).count();
    let mut band = PointCloud {
        points: Vec::with_capacity(most),
        pixels: Vec::with_capacity(most),
    };
    let (col_u, col_d) = (q.column(0).into_owned(), q.column(2).into_owned());
    for (r, row) in values.chunks(w).enumerate() {
        let y = first_row + r;
        let base = q.column(1) * y as f32 + q.column(3);
        for (x, &d) in row.iter().enumerate() {
            if !(d > 0.0 && d.is_finite()) {
                continue;
            }
            let h = base + col_u * x as f32 + col_d * d;
            if h.w.abs() <= f32::EPSILON {
                continue;
            }
            let p = [h.x / h.w, h.y / h.w, h.z / h.w];
            if p.iter().all(|c| c.is_finite()) {
                band.points.push(p);
                band.pixels.push((y * w + x) as u32);
            }
        }
    }
    band
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

    /// The bands give every valid pixel's point, in pixel order, as `Q·[u, v, d, 1]ᵀ`
    /// computed whole, and the same cloud on one thread as on three; pixels with no
    /// point (NaN, infinite, zero or negative disparity) are left out.
    #[test]
    fn bands_give_the_whole_matrix_product_in_pixel_order() {
        let rig = StereoRig::sensor();
        let rect = Rectification::bouguet(&rig.calibration(), 1.0).unwrap();
        let (w, h) = (97, 3 * BAND_ROWS + 5);
        let mut rng = crate::rng::Rng::new(3);
        let disp = Grid::from_fn(w, h, |_, _| match rng.uniform() {
            u if u < 0.05 => f32::NAN,
            u if u < 0.07 => f32::INFINITY,
            u if u < 0.09 => 0.0,
            u if u < 0.10 => -3.0,
            _ => rng.range(5.0, 60.0) as f32,
        });
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| reproject(&disp, &rect.q))
        };
        let cloud = run(1);
        assert_eq!(cloud, run(3));
        let q = rect.q.cast::<f32>();
        let expected: Vec<(u32, [f32; 3])> = (0..w * h)
            .filter_map(|i| {
                let d = disp.as_slice()[i];
                (d > 0.0 && d.is_finite()).then(|| {
                    let v = q * nalgebra::Vector4::new((i % w) as f32, (i / w) as f32, d, 1.0);
                    (i as u32, [v.x / v.w, v.y / v.w, v.z / v.w])
                })
            })
            .collect();
        assert_eq!(cloud.len(), expected.len());
        for ((&pixel, p), (want_pixel, want)) in
            cloud.pixels.iter().zip(&cloud.points).zip(&expected)
        {
            assert_eq!(pixel, *want_pixel);
            for k in 0..3 {
                assert!(
                    (p[k] - want[k]).abs() <= 1e-5 * want[2].abs(),
                    "{p:?} vs {want:?}"
                );
            }
        }
    }
}
