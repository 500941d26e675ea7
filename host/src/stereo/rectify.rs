//! Stereo rectification (Bouguet's method, as OpenCV's `stereoRectify`) and the
//! undistort-rectify maps that turn each raw frame into a rectified one.
//!
//! Bouguet splits the rotation between the cameras in half, then turns both so the
//! baseline lies along x: epipolar lines become image rows, disparity is along x only.
//! The rectified camera matrix is chosen here rather than derived from the lens (OpenCV's
//! fisheye `stereoRectify` returned NaN for a 160° lens whose distortion stops growing
//! near the edge): focal length `scale · min(fy)` of the two cameras, principal point at
//! the image centre for both (zero disparity at infinity).
//!
//! [`RemapTable`] is built once per camera (f64 geometry) and stores, per output pixel,
//! the source pixel and a 5-bit bilinear fraction (OpenCV's `INTER_BITS`); pixels whose
//! ray the lens cannot image, or that fall outside the frame, come out 0.

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Rotation3, Vector3};

use super::calibration::StereoCalibration;
use super::camera::Camera;

/// Why a pair cannot be rectified.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RectifyError {
    /// The baseline is mostly vertical; only side-by-side pairs are supported.
    #[error("the baseline {0:?} is not horizontal: only side-by-side pairs are supported")]
    NotHorizontal([f64; 3]),
    /// A non-positive or non-finite focal scale.
    #[error("the rectified focal scale must be finite and positive, found {0}")]
    BadScale(f64),
    /// An image too small to interpolate in.
    #[error("images must be at least 2×2 pixels, found {0}×{1}")]
    TooSmall(u32, u32),
}

/// The rectification of a stereo pair (OpenCV's `R1 R2 P1 P2 Q`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rectification {
    /// Rotation from the left camera's frame to the rectified one.
    pub r1: Matrix3<f64>,
    /// Rotation from the right camera's frame to the rectified one.
    pub r2: Matrix3<f64>,
    /// Projection of rectified-left coordinates to the rectified left image.
    pub p1: Matrix3x4<f64>,
    /// Projection of rectified-left coordinates to the rectified right image
    /// (`P2[0,3] = f·Tx`, `Tx` the signed baseline along x).
    pub p2: Matrix3x4<f64>,
    /// Reprojection: `Q·[u, v, d, 1]ᵀ` is the point (homogeneous) in rectified-left
    /// coordinates for disparity `d = u_left − u_right`.
    pub q: Matrix4<f64>,
    /// Rectified image size.
    pub width: u32,
    /// Rectified image size.
    pub height: u32,
}

impl Rectification {
    /// Bouguet's rectification, with focal length `scale · min(fy)` (1.0 keeps the
    /// cameras' scale; smaller shows more of a wide lens).
    pub fn bouguet(calib: &StereoCalibration, scale: f64) -> Result<Self, RectifyError> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(RectifyError::BadScale(scale));
        }
        let (width, height) = (calib.left.width, calib.left.height);
        if width < 2 || height < 2 {
            return Err(RectifyError::TooSmall(width, height));
        }
        // Half of the rotation each way.
        let half = Rotation3::from_matrix(&calib.r).scaled_axis() * -0.5;
        let r_half = *Rotation3::new(half).matrix();
        let t = r_half * calib.t;
        if t.x.abs() <= t.y.abs() {
            return Err(RectifyError::NotHorizontal([
                calib.t.x, calib.t.y, calib.t.z,
            ]));
        }
        // Turn the half-rotated baseline onto the x axis.
        let axis = Vector3::new(t.x.signum(), 0.0, 0.0);
        let w = t.cross(&axis);
        let turn = if w.norm() > 0.0 {
            *Rotation3::new(w / w.norm() * (t.x.abs() / t.norm()).clamp(-1.0, 1.0).acos()).matrix()
        } else {
            Matrix3::identity()
        };
        let r1 = turn * r_half.transpose();
        let r2 = turn * r_half;
        let tx = (r2 * calib.t).x;
        let f = scale * calib.left.k[(1, 1)].min(calib.right.k[(1, 1)]);
        let (cx, cy) = (f64::from(width - 1) / 2.0, f64::from(height - 1) / 2.0);
        let p1 = Matrix3x4::new(f, 0.0, cx, 0.0, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0);
        let mut p2 = p1;
        p2[(0, 3)] = f * tx;
        let q = Matrix4::new(
            1.0,
            0.0,
            0.0,
            -cx, //
            0.0,
            1.0,
            0.0,
            -cy, //
            0.0,
            0.0,
            0.0,
            f, //
            0.0,
            0.0,
            -1.0 / tx,
            0.0,
        );
        Ok(Self {
            r1,
            r2,
            p1,
            p2,
            q,
            width,
            height,
        })
    }

    /// The rectified focal length, pixels.
    pub fn focal(&self) -> f64 {
        self.p1[(0, 0)]
    }

    /// The baseline along x, in the calibration's unit (positive).
    pub fn baseline(&self) -> f64 {
        (self.p2[(0, 3)] / self.p1[(0, 0)]).abs()
    }

    /// The maps for the left and right cameras.
    pub fn maps(&self, calib: &StereoCalibration) -> (RemapTable, RemapTable) {
        (
            RemapTable::new(&calib.left, &self.r1, &self.p1, self.width, self.height),
            RemapTable::new(&calib.right, &self.r2, &self.p2, self.width, self.height),
        )
    }
}

/// Fraction bits of the bilinear weights.
const FRAC_BITS: u32 = 5;
const ONE: u32 = 1 << FRAC_BITS;
/// Marks an output pixel with no source.
const NO_SOURCE: u32 = u32::MAX;

/// Why a frame cannot be remapped.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "remap: expected a {expected_width}×{expected_height} source and a {out_width}×{out_height} output, found {found} and {found_out} bytes"
)]
pub struct RemapSizeError {
    /// Source size the table was built for.
    pub expected_width: u32,
    /// Source size the table was built for.
    pub expected_height: u32,
    /// Output size.
    pub out_width: u32,
    /// Output size.
    pub out_height: u32,
    /// Source bytes given.
    pub found: usize,
    /// Output bytes given.
    pub found_out: usize,
}

/// Where each rectified pixel comes from in the raw frame (see the module doc).
#[derive(Debug, Clone)]
pub struct RemapTable {
    width: u32,
    height: u32,
    src_width: u32,
    src_height: u32,
    /// Index of the top-left source pixel, or [`NO_SOURCE`].
    offset: Vec<u32>,
    /// Bilinear fractions (x, y), 0..=32.
    frac: Vec<[u8; 2]>,
}

impl RemapTable {
    /// The table for `camera`, rectified by rotation `r` and projection `p` to
    /// `width × height`.
    pub fn new(
        camera: &Camera,
        r: &Matrix3<f64>,
        p: &Matrix3x4<f64>,
        width: u32,
        height: u32,
    ) -> Self {
        let (f, cx, cy) = (p[(0, 0)], p[(0, 2)], p[(1, 2)]);
        let fy = p[(1, 1)];
        let back = r.transpose();
        let n = width as usize * height as usize;
        let mut offset = Vec::with_capacity(n);
        let mut frac = Vec::with_capacity(n);
        let (sw, sh) = (camera.width, camera.height);
        for v in 0..height {
            for u in 0..width {
                let ray =
                    back * Vector3::new((f64::from(u) - cx) / f, (f64::from(v) - cy) / fy, 1.0);
                let source = camera.project(&ray).and_then(|[x, y]| {
                    let (x0, fx) = split(x, sw)?;
                    let (y0, fy) = split(y, sh)?;
                    Some((y0 * sw + x0, [fx, fy]))
                });
                let (o, fr) = source.unwrap_or((NO_SOURCE, [0, 0]));
                offset.push(o);
                frac.push(fr);
            }
        }
        Self {
            width,
            height,
            src_width: sw,
            src_height: sh,
            offset,
            frac,
        }
    }

    /// Output size.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Share of output pixels that have a source.
    pub fn coverage(&self) -> f64 {
        let mapped = self.offset.iter().filter(|&&o| o != NO_SOURCE).count();
        mapped as f64 / self.offset.len().max(1) as f64
    }

    /// The frame size the table takes, `(width, height)`.
    pub fn source_size(&self) -> (u32, u32) {
        (self.src_width, self.src_height)
    }

    /// Remap one 8-bit frame (row-major, `src_width × src_height`) into `out`.
    pub fn remap(&self, src: &[u8], out: &mut [u8]) -> Result<(), RemapSizeError> {
        let sw = self.src_width as usize;
        if src.len() != sw * self.src_height as usize || out.len() != self.offset.len() {
            return Err(RemapSizeError {
                expected_width: self.src_width,
                expected_height: self.src_height,
                out_width: self.width,
                out_height: self.height,
                found: src.len(),
                found_out: out.len(),
            });
        }
        for ((o, &offset), &[fx, fy]) in out.iter_mut().zip(&self.offset).zip(&self.frac) {
            if offset == NO_SOURCE {
                *o = 0;
                continue;
            }
            // In range by construction: x0 ≤ width − 2 and y0 ≤ height − 2.
            let i = offset as usize;
            let (fx, fy) = (u32::from(fx), u32::from(fy));
            let top = u32::from(src[i]) * (ONE - fx) + u32::from(src[i + 1]) * fx;
            let bottom = u32::from(src[i + sw]) * (ONE - fx) + u32::from(src[i + sw + 1]) * fx;
            let value = top * (ONE - fy) + bottom * fy;
            *o = ((value + (1 << (2 * FRAC_BITS - 1))) >> (2 * FRAC_BITS)) as u8;
        }
        Ok(())
    }
}

/// Split a source coordinate into a cell start (≤ size − 2) and a fraction 0..=32, or
/// `None` outside `[0, size − 1]`.
fn split(x: f64, size: u32) -> Option<(u32, u8)> {
    let last = f64::from(size - 1);
    if !(0.0..=last).contains(&x) {
        return None;
    }
    let scaled = (x * f64::from(ONE)).round() as u32;
    let (cell, fraction) = (scaled / ONE, scaled % ONE);
    if cell >= size - 1 {
        Some((size - 2, ONE as u8))
    } else {
        Some((cell, fraction as u8))
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector4;

    use super::*;
    use crate::stereo::calibration::tests::sensor_pair;
    use crate::stereo::camera::Distortion;

    fn points() -> Vec<Vector3<f64>> {
        let mut v = Vec::new();
        for z in [50.0, 120.0, 300.0, 600.0] {
            for x in [-40.0, 0.0, 25.0] {
                for y in [-30.0, 10.0] {
                    v.push(Vector3::new(x * z / 300.0, y * z / 300.0, z));
                }
            }
        }
        v
    }

    #[test]
    fn rectified_rows_match_and_q_reprojects_the_point() {
        let c = sensor_pair(Distortion::NONE);
        let rect = Rectification::bouguet(&c, 1.0).unwrap();
        for r in [rect.r1, rect.r2] {
            assert!((r.transpose() * r - Matrix3::identity()).abs().max() < 1e-12);
        }
        assert!(
            (rect.baseline() - c.baseline()).abs() < 1e-9,
            "{}",
            rect.baseline()
        );
        for x in points() {
            let xr = rect.r1 * x; // rectified-left coordinates
            let left = rect.p1 * xr.push(1.0);
            let right = rect.p2 * xr.push(1.0);
            let right_cam = c.r * x + c.t;
            let (ul, vl) = (left.x / left.z, left.y / left.z);
            let (ur, vr) = (right.x / right.z, right.y / right.z);
            assert!((vl - vr).abs() < 1e-9, "rows {vl} vs {vr}");
            // The right camera seen through R2 gives the same row too.
            let via_r2 = rect.r2 * right_cam;
            let vr2 = rect.focal() * via_r2.y / via_r2.z + rect.p1[(1, 2)];
            assert!((vl - vr2).abs() < 1e-9, "R2 row {vr2} vs {vl}");
            let d = ul - ur;
            assert!((d - rect.focal() * rect.baseline() / xr.z).abs() < 1e-9);
            let h = rect.q * Vector4::new(ul, vl, d, 1.0);
            let back = h.xyz() / h.w;
            assert!((back - xr).norm() < 1e-9 * xr.norm(), "{back:?} vs {xr:?}");
        }
    }

    #[test]
    fn degenerate_inputs_are_refused() {
        let mut c = sensor_pair(Distortion::NONE);
        assert_eq!(
            Rectification::bouguet(&c, 0.0),
            Err(RectifyError::BadScale(0.0))
        );
        assert!(matches!(
            Rectification::bouguet(&c, f64::NAN),
            Err(RectifyError::BadScale(_))
        ));
        c.t = Vector3::new(0.5, -14.0, 0.0);
        assert!(matches!(
            Rectification::bouguet(&c, 1.0),
            Err(RectifyError::NotHorizontal(_))
        ));
        let mut c = sensor_pair(Distortion::NONE);
        c.left.width = 1;
        assert_eq!(
            Rectification::bouguet(&c, 1.0),
            Err(RectifyError::TooSmall(1, 480))
        );
    }

    #[test]
    fn maps_send_each_rectified_pixel_to_where_the_lens_images_its_ray() {
        for d in [
            Distortion::BrownConrady([-0.28, 0.09, 0.001, -0.0015, -0.012, 0.0, 0.0, 0.0]),
            Distortion::KannalaBrandt([0.05, -0.01, 0.002, -0.0003]),
        ] {
            let c = sensor_pair(d);
            let rect = Rectification::bouguet(&c, 0.8).unwrap();
            let (left, _) = rect.maps(&c);
            assert!(left.coverage() > 0.9, "{d:?}: {}", left.coverage());
            for x in points() {
                let xr = rect.r1 * x;
                let u = rect.focal() * xr.x / xr.z + rect.p1[(0, 2)];
                let v = rect.focal() * xr.y / xr.z + rect.p1[(1, 2)];
                let (ui, vi) = (u.round(), v.round());
                if !(0.0..640.0).contains(&ui) || !(0.0..480.0).contains(&vi) {
                    continue;
                }
                // The ray through the rectified pixel centre, seen by the raw camera.
                let ray = rect.r1.transpose()
                    * Vector3::new(
                        (ui - rect.p1[(0, 2)]) / rect.focal(),
                        (vi - rect.p1[(1, 2)]) / rect.focal(),
                        1.0,
                    );
                let [sx, sy] = c.left.project(&ray).unwrap();
                let k = (vi as usize) * 640 + ui as usize;
                let o = left.offset[k];
                let [fx, fy] = left.frac[k];
                let mx = f64::from(o % 640) + f64::from(fx) / 32.0;
                let my = f64::from(o / 640) + f64::from(fy) / 32.0;
                assert!(
                    (mx - sx).abs() <= 1.0 / 64.0 + 1e-9 && (my - sy).abs() <= 1.0 / 64.0 + 1e-9,
                    "{d:?}: map ({mx}, {my}) vs lens ({sx}, {sy})"
                );
            }
        }
    }

    #[test]
    fn remap_matches_float_bilinear_sampling_within_one_grey_level() {
        let c = sensor_pair(Distortion::BrownConrady([
            -0.2, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ]));
        let rect = Rectification::bouguet(&c, 1.0).unwrap();
        let (table, _) = rect.maps(&c);
        let (w, h) = (640usize, 480usize);
        let src: Vec<u8> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                (128.0 + 90.0 * (x / 13.0).sin() * (y / 17.0).cos()).round() as u8
            })
            .collect();
        let mut out = vec![0u8; w * h];
        table.remap(&src, &mut out).unwrap();
        let sample = |x: f64, y: f64| {
            let (x0, y0) = (x.floor().min(w as f64 - 2.0), y.floor().min(h as f64 - 2.0));
            let (fx, fy) = (x - x0, y - y0);
            let at = |xx: f64, yy: f64| f64::from(src[yy as usize * w + xx as usize]);
            (at(x0, y0) * (1.0 - fx) + at(x0 + 1.0, y0) * fx) * (1.0 - fy)
                + (at(x0, y0 + 1.0) * (1.0 - fx) + at(x0 + 1.0, y0 + 1.0) * fx) * fy
        };
        let mut worst: f64 = 0.0;
        for k in (0..w * h).step_by(7) {
            if table.offset[k] == NO_SOURCE {
                assert_eq!(out[k], 0);
                continue;
            }
            let (u, v) = ((k % w) as f64, (k / w) as f64);
            let ray = rect.r1.transpose()
                * Vector3::new(
                    (u - rect.p1[(0, 2)]) / rect.focal(),
                    (v - rect.p1[(1, 2)]) / rect.focal(),
                    1.0,
                );
            let [sx, sy] = c.left.project(&ray).unwrap();
            worst = worst.max((f64::from(out[k]) - sample(sx, sy)).abs());
        }
        // 5-bit fractions: ≤ 1/64 px of position error on a gradient ≤ ~7 grey/px,
        // plus rounding.
        assert!(worst <= 1.0, "worst {worst}");
        let mut small = vec![0u8; 10];
        assert!(table.remap(&src, &mut small).is_err());
    }

    #[test]
    fn identity_rectification_reproduces_the_frame() {
        let camera = Camera {
            width: 8,
            height: 5,
            k: Matrix3::new(10.0, 0.0, 3.5, 0.0, 10.0, 2.0, 0.0, 0.0, 1.0),
            distortion: Distortion::NONE,
        };
        let p = Matrix3x4::new(10.0, 0.0, 3.5, 0.0, 0.0, 10.0, 2.0, 0.0, 0.0, 0.0, 1.0, 0.0);
        let table = RemapTable::new(&camera, &Matrix3::identity(), &p, 8, 5);
        let src: Vec<u8> = (0..40).map(|i| (i * 6) as u8).collect();
        let mut out = vec![0u8; 40];
        table.remap(&src, &mut out).unwrap();
        assert_eq!(out, src);
        assert_eq!(table.coverage(), 1.0);
    }
}
