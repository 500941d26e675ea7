//! The side light of strips of finite length in the cross factor, measured at
//! calibration and taken out of the lookup table's colours.
//!
//! Each phase's colour is multiplied by the other phase's `2 / (r + b)`
//! ([`super::cross_factor`]), which for matte skin lit along the axis is the normal's
//! length `|n|`, whatever the slope along this axis. A strip of finite length lights a
//! pixel that is not at its middle from the side as well, towards its middle: the other
//! phase's two strips then both brighten where the skin faces that way, so their sum is
//! `2 (1 + κ·p) / |n|` (for the dy strips and the x slope `p`) and the factor falls short
//! of `|n|` by `1 + κ·p`. The table reads the colours shrunk or stretched by it: with our
//! renderer's strips made finite (`ours-finite-strips`) the steep wall read 0.78–0.86 mm
//! instead of 0.92–1.01, its walls facing an axis 0.65–0.70 of their slope instead of
//! 0.77–0.82 even at the frame's middle.
//!
//! Calibration knows both slopes of every press pixel, so `κ` is fitted by least squares
//! of `S·|n| / 2 − 1` (`S` the other phase's colour sum, both of its strips lit) on
//! `κ(x, y)·own + λ(x, y)·other` (`own` this axis' slope; `λ`, the strips' own difference
//! in elevation, is left to the table as before) and terms even in the slopes (gloss,
//! gamma: [`EVEN`], dropped too), `κ` and `λ` smooth over the frame:
//! polynomials of degree 3 along the other phase's strips and 2 across them, in the
//! frame's centred coordinates. (Per cell of 8×6 the fit left cells without presses at
//! 0 beside cells at 0.5: a light that jumps.) A ridge of [`RIDGE`] of the normal
//! equations' mean diagonal pulls it towards no side light where presses are few (12
//! presses of a 320×240 frame of `ours-random`, without side light, fitted `κ` up to 10
//! in a corner without it, 0.19 with it; the tuning family's readings moved by at most
//! 0.01 mm). A skin whose `κ` stays under [`MIN_KAPPA`] everywhere has no side light
//! worth a reading: none is kept. The table is taught on colours times
//! `1 + κ·p` with the true slopes; reading multiplies them by `1 + κ·p̂` with the table's
//! own last reading, [`ROUNDS`] times.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::cells::frame_plane;
use super::light::SHADOWED;
use super::photometric::JointSample;

/// Largest `|κ|` kept on the frame or accepted from a file.
pub const MAX_KAPPA: f32 = 1.0;

/// A fit whose `|κ|` stays under this everywhere on the frame is not kept (our renderer's
/// strips along the whole axis fit up to 0.035 per cell of 8×6 on `ours-random` skin 1;
/// its finite strips 0.2–0.7).
pub const MIN_KAPPA: f32 = 0.05;

/// Largest coefficient accepted from a file: `κ` is at most [`MAX_KAPPA`] on the frame,
/// where every basis term is at most 1.
const MAX_COEFFICIENT: f32 = 100.0;

/// Readings of a pixel with the correction from the table's last reading. Chosen on the
/// tuning families (`ours-finite-strips` skins 1–3, 10 placements, before the ridge;
/// gentle disk / steep disk / edge ball): one reading 0.997 / 0.862 / 1.13, 0.951 /
/// 0.908 / 1.11, 0.993 / 0.940 / 1.22; two 1.027 / 0.873 / 1.16, 0.961 / 0.920 / 1.15, 1.014 / 0.976 / 1.29;
/// three as two. Our renderer's skins without side light do not keep one.
pub const ROUNDS: usize = 1;

/// A pixel whose factors are within this of 1 is not read again (its reading would move
/// by less than this share).
pub const NEGLIGIBLE: f32 = 0.005;

/// Powers of the coordinate along the other phase's strips (their side light grows
/// towards both ends, turning either way).
const ALONG: usize = 4;
/// Powers of the coordinate across them.
const ACROSS: usize = 3;
/// Terms of one polynomial.
pub const TERMS: usize = ALONG * ACROSS;

/// Terms fitted beside `κ` and `λ` and dropped: `p²` and `q²`, constant over the frame.
/// Gloss, gamma and crosstalk make the other phase's sum answer the slopes evenly
/// (`S·|n|/2 − 1` grows with `p²` whichever way the skin faces), and where presses
/// slope mostly one way (near the frame's edges, whose presses are partly outside it)
/// `κ·p` took that up: `ours-random` skin 2, whose strips run the whole axis, fitted `κ`
/// 0.30 without them, 0.05 with them (skin 1: 0.12 either way). With them, the tuning
/// family `ours-finite-strips` (skins 1–3, 10 placements, gentle disk / steep disk / edge
/// ball) read 0.990 / 0.862 / 1.12, 0.948 / 0.908 / 1.11, 0.989 / 0.930 / 1.21 →
/// 0.989 / 0.861 / 1.10, 0.947 / 0.914 / 1.09, 0.989 / 0.930 / 1.21 (with their
/// linear change over the frame as well, six terms: the same to 0.006, skin 1's `κ` 0.14).
const EVEN: usize = 2;

/// The ridge added to the normal equations' diagonal, as a share of its mean.
const RIDGE: f64 = 0.01;

/// Points per axis of the grid `κ` is checked on.
const CHECK_GRID: usize = 17;

/// `κ` of each phase's colours as a polynomial over the frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SideLight {
    /// Coefficients of `κ` for the dx colours (the dy sum's change with `p`) and for the dy
    /// colours (the dx sum's change with `q`), over [`basis`].
    pub kappa: [Vec<f32>; 2],
}

/// The basis at normalised position `(x, y)` for the colours of `phase` (0: dx, whose
/// factor comes from the dy strips, which run along x; 1: dy): `u^a · v^b`, `u` the
/// centred coordinate along the other phase's strips (`a < ALONG`), `v` the one across
/// them (`b < ACROSS`).
#[inline]
pub fn basis(phase: usize, x: f32, y: f32) -> [f32; TERMS] {
    let (cx, cy) = (2.0 * x - 1.0, 2.0 * y - 1.0);
    let (u, v) = if phase == 0 { (cx, cy) } else { (cy, cx) };
    let mut out = [0.0f32; TERMS];
    let mut vb = 1.0f32;
    for b in 0..ACROSS {
        let mut ua = 1.0f32;
        for a in 0..ALONG {
            out[b * ALONG + a] = ua * vb;
            ua *= u;
        }
        vb *= v;
    }
    out
}

/// `κ` of `phase` at `(x, y)` from its coefficients, unbounded.
fn polynomial(coefficients: &[f32], phase: usize, x: f32, y: f32) -> f32 {
    basis(phase, x, y)
        .iter()
        .zip(coefficients)
        .map(|(b, c)| b * c)
        .sum()
}

impl SideLight {
    /// Fits `κ` to the presses' pixels; `None` when there are too few pixels with every
    /// strip lit to fit it (20 per unknown), or when it stays under [`MIN_KAPPA`]
    /// everywhere.
    pub fn fit(samples: &[JointSample]) -> Option<Self> {
        let unknowns = 2 * TERMS + EVEN;
        let mut kappa: [Vec<f32>; 2] = [Vec::new(), Vec::new()];
        for (phase, coefficients) in kappa.iter_mut().enumerate() {
            let mut ata = vec![0.0f64; unknowns * unknowns];
            let mut atb = vec![0.0f64; unknowns];
            let mut used = 0usize;
            let mut row = [0.0f64; 2 * TERMS + EVEN];
            for s in samples {
                let [x, y] = s.position;
                let [p, q] = s.slope.map(f64::from);
                let c = s.colours;
                let usable = x.is_finite()
                    && y.is_finite()
                    && p.is_finite()
                    && q.is_finite()
                    && c.iter().all(|v| v.is_finite() && *v >= SHADOWED);
                if !usable {
                    continue;
                }
                let normal = (1.0 + p * p + q * q).sqrt();
                // dx colours: the dy sum against p (own) and q; dy colours: the dx sum
                // against q and p.
                let (sum, own, other) = if phase == 0 {
                    (c[2] + c[3], p, q)
                } else {
                    (c[0] + c[1], q, p)
                };
                let v = f64::from(sum) * normal / 2.0 - 1.0;
                for (j, b) in basis(phase, x, y).into_iter().enumerate() {
                    row[j] = f64::from(b) * own;
                    row[TERMS + j] = f64::from(b) * other;
                }
                // Even in both slopes: gloss and gamma (a side light is odd in `own`).
                row[2 * TERMS] = p * p;
                row[2 * TERMS + 1] = q * q;
                for i in 0..unknowns {
                    let ri = row[i];
                    for j in i..unknowns {
                        ata[i * unknowns + j] += ri * row[j];
                    }
                    atb[i] += ri * v;
                }
                used += 1;
            }
            for i in 0..unknowns {
                for j in 0..i {
                    ata[i * unknowns + j] = ata[j * unknowns + i];
                }
            }
            if used < 20 * unknowns {
                return None;
            }
            // A little ridge: where presses are few (a frame's corners) the polynomial is
            // pulled towards no side light instead of swinging wide.
            let ridge =
                RIDGE * (0..unknowns).map(|i| ata[i * unknowns + i]).sum::<f64>() / unknowns as f64;
            for i in 0..unknowns {
                ata[i * unknowns + i] += ridge;
            }
            let ata = DMatrix::from_row_slice(unknowns, unknowns, &ata);
            let solution = ata.cholesky()?.solve(&DVector::from_vec(atb));
            *coefficients = solution.iter().take(TERMS).map(|&c| c as f32).collect();
        }
        let fitted = Self { kappa };
        let largest = fitted.largest();
        (largest.is_finite() && largest >= MIN_KAPPA).then_some(fitted)
    }

    /// `[κ dx, κ dy]` at normalised position `(x, y)`, within ±[`MAX_KAPPA`].
    pub fn at(&self, x: f32, y: f32) -> [f32; 2] {
        [0, 1].map(|phase| {
            let k = polynomial(&self.kappa[phase], phase, x, y);
            if k.is_finite() {
                k.clamp(-MAX_KAPPA, MAX_KAPPA)
            } else {
                0.0
            }
        })
    }

    /// The largest `|κ|` on a grid over the frame (before the bound).
    pub fn largest(&self) -> f32 {
        let mut largest = 0.0f32;
        for iy in 0..CHECK_GRID {
            for ix in 0..CHECK_GRID {
                let (x, y) = (
                    ix as f32 / (CHECK_GRID - 1) as f32,
                    iy as f32 / (CHECK_GRID - 1) as f32,
                );
                for phase in 0..2 {
                    let k = polynomial(&self.kappa[phase], phase, x, y);
                    largest = largest.max(k.abs());
                }
            }
        }
        largest
    }

    /// [`Self::at`] at every pixel of a `width × height` frame, row by row, at the
    /// positions reconstruction gives the models (`x / width`, `y / height`).
    pub fn planes(&self, width: usize, height: usize) -> Vec<[f32; 2]> {
        frame_plane(width, height, |x, y| self.at(x, y))
    }

    /// What is wrong with a model file's entry, if anything.
    pub fn check(&self) -> Result<(), String> {
        for (phase, c) in self.kappa.iter().enumerate() {
            if c.len() != TERMS {
                return Err(format!(
                    "{} coefficients for phase {phase}, not {TERMS}",
                    c.len()
                ));
            }
            if let Some(i) = c
                .iter()
                .position(|v| !(v.is_finite() && v.abs() <= MAX_COEFFICIENT))
            {
                return Err(format!(
                    "coefficient {i} of phase {phase} is {}, not a number within ±{MAX_COEFFICIENT}",
                    c[i]
                ));
            }
        }
        Ok(())
    }
}

/// The factors `[dx, dy]` the colours of a pixel with slopes `(p, q)` and `kappa` are
/// multiplied by, each within [0.5, 2].
#[inline(always)]
pub fn factors(kappa: [f32; 2], p: f32, q: f32) -> [f32; 2] {
    let factor = |k: f32, s: f32| {
        let f = 1.0 + k * s;
        if f.is_finite() {
            f.clamp(0.5, 2.0)
        } else {
            1.0
        }
    };
    [factor(kappa[0], p), factor(kappa[1], q)]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pixels of a grid of positions and slopes whose phase sums follow a side light of
    /// `kappa(x, y)` (`[dx, dy]`) and the strips' own elevation difference `lambda`.
    fn lit(kappa: impl Fn(f32, f32) -> [f32; 2], lambda: f32) -> Vec<JointSample> {
        let mut out = Vec::new();
        for iy in 0..24 {
            for ix in 0..32 {
                let (x, y) = ((ix as f32 + 0.5) / 32.0, (iy as f32 + 0.5) / 24.0);
                for (k, p) in [-0.6f32, -0.2, 0.0, 0.3, 0.7].into_iter().enumerate() {
                    let q = [0.5f32, -0.4, 0.1, -0.7, 0.0][(k + ix + 2 * iy) % 5];
                    let n = (1.0 + p * p + q * q).sqrt();
                    let [kx, ky] = kappa(x, y);
                    // Each phase's two colours share the sum evenly.
                    let dy_half = (1.0 + kx * p + lambda * q) / n;
                    let dx_half = (1.0 + ky * q + lambda * p) / n;
                    out.push(JointSample {
                        colours: [dx_half, dx_half, dy_half, dy_half],
                        position: [x, y],
                        slope: [p, q],
                    });
                }
            }
        }
        out
    }

    #[test]
    fn a_side_light_within_the_basis_is_recovered() {
        // Finite strips: the dy strips turn the light towards +x on the left, −x on the
        // right (and more so near the frame's top and bottom), the dx strips likewise in y.
        let truth = |x: f32, y: f32| {
            let (u, v) = (2.0 * x - 1.0, 2.0 * y - 1.0);
            [-0.5 * u * (1.0 + 0.3 * v * v), -0.4 * v + 0.1 * v * v * v]
        };
        let fit = SideLight::fit(&lit(truth, 0.15)).expect("a side light");
        fit.check().expect("valid");
        // Within the ridge's pull (largest at the corners, where the basis is largest).
        for (x, y) in [(0.0, 0.0), (0.5, 0.5), (0.1, 0.9), (1.0, 0.3), (0.7, 1.0)] {
            let (got, want) = (fit.at(x, y), truth(x, y));
            for k in 0..2 {
                assert!(
                    (got[k] - want[k]).abs() < 0.02,
                    "({x}, {y}): {got:?} vs {want:?}"
                );
            }
        }
        assert!((fit.largest() - 0.65).abs() < 0.02, "{}", fit.largest());
        let planes = fit.planes(8, 6);
        assert_eq!(planes.len(), 48);
        // At the positions reconstruction gives the models: `x / width`, `y / height`.
        assert_eq!(
            planes[6 * 8 - 1],
            fit.at(7.0 * (1.0 / 8.0), 5.0 * (1.0 / 6.0))
        );
    }

    #[test]
    fn no_side_light_or_too_little_to_fit_keeps_none() {
        // Strips along the whole axis, with their elevation difference: nothing to keep.
        assert_eq!(SideLight::fit(&lit(|_, _| [0.0, 0.0], 0.3)), None);
        // Too few pixels with every strip lit: shadowed, unlit or damaged ones are not
        // counted.
        let mut few = lit(|x, _| [x - 0.5, 0.0], 0.0);
        for (k, s) in few.iter_mut().enumerate() {
            match k % 4 {
                0 => s.colours[1] = 0.05,
                1 => s.colours[2] = f32::NAN,
                2 => s.slope[0] = f32::INFINITY,
                _ => {}
            }
        }
        few.truncate(1800);
        assert_eq!(SideLight::fit(&few), None);
        assert_eq!(SideLight::fit(&[]), None);
    }

    #[test]
    fn light_even_in_the_slopes_is_not_taken_for_a_side_light() {
        // Gloss or gamma: the other phase's sum times |n| grows with p² + q², and at every
        // position the presses slope one way only (as near a frame edge).
        let mut samples = Vec::new();
        for iy in 0..24 {
            for ix in 0..32 {
                let (x, y) = ((ix as f32 + 0.5) / 32.0, (iy as f32 + 0.5) / 24.0);
                for k in 0..5 {
                    let (p, q) = (0.2 * k as f32, 0.15 * ((k + ix + iy) % 5) as f32);
                    let n = (1.0 + p * p + q * q).sqrt();
                    let half = (1.0 + 0.2 * (p * p + q * q)) / n;
                    samples.push(JointSample {
                        colours: [half; 4],
                        position: [x, y],
                        slope: [p, q],
                    });
                }
            }
        }
        assert_eq!(SideLight::fit(&samples), None);
        // A side light on top of it is still found.
        for s in &mut samples {
            let ([x, _], [p, q]) = (s.position, s.slope);
            let n = (1.0 + p * p + q * q).sqrt();
            let kappa = 0.6 * (1.0 - 2.0 * x);
            s.colours[2] = (1.0 + kappa * p + 0.2 * (p * p + q * q)) / n;
            s.colours[3] = s.colours[2];
        }
        let fit = SideLight::fit(&samples).expect("a side light");
        for x in [0.1f32, 0.5, 0.9] {
            let got = fit.at(x, 0.5)[0];
            assert!((got - 0.6 * (1.0 - 2.0 * x)).abs() < 0.05, "{x}: {got}");
        }
    }

    #[test]
    fn factors_are_bounded_and_never_nan_and_damaged_files_are_refused() {
        assert_eq!(factors([0.5, -0.5], 0.4, 0.4), [1.2, 0.8]);
        assert_eq!(factors([1.0, 1.0], 5.0, -5.0), [2.0, 0.5]);
        assert_eq!(factors([1.0, 1.0], f32::NAN, f32::INFINITY), [1.0, 1.0]);
        let mut side = SideLight {
            kappa: [vec![0.0; TERMS], vec![0.0; TERMS]],
        };
        assert_eq!(side.check(), Ok(()));
        side.kappa[1][2] = 1e6;
        assert!(
            side.check()
                .unwrap_err()
                .contains("coefficient 2 of phase 1")
        );
        side.kappa[0].pop();
        assert!(side.check().unwrap_err().contains("11 coefficients"));
        // A polynomial far past the bound is read at the bound.
        let wild = SideLight {
            kappa: [vec![50.0; TERMS], vec![-50.0; TERMS]],
        };
        assert_eq!(wild.at(0.9, 0.9), [MAX_KAPPA, -MAX_KAPPA]);
    }
}
