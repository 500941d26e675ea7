//! Slopes read again where a strip of the other phase is in shadow, for the lookup table.
//!
//! Each phase's colour is multiplied by the other phase's `2 / (r + b)`
//! ([`cross_factor`](super::model::cross_factor)): for matte skin that is the normal's
//! length `|n| = √(1 + p² + q²)`, the factor by which a tilted facet is darker, as long as
//! both strips of the other phase light the facet. A facet steeper along the other axis
//! than the elevation of the strip it turns away from gets nothing from that strip; the
//! sum then no longer falls as `1 / |n|`, the factor stays short of `|n|` and the slope
//! along this axis reads short. On the independent renderer (`phys-matte`, skin 1, a 1 mm
//! disk with wall slope 1.31) the diagonal walls read 0.66–0.75 of the disk's depth along
//! a line to its centre while walls facing an axis read about 0.94; with the true `|n|`
//! in the factor twelve diagonals read 0.99 on average (0.70–1.31 one by one).
//!
//! Where a strip of the other phase brings less than [`SHADOWED`] of its flat-skin light,
//! the pixel's slopes are read again, [`ITERATIONS`] times, with the factor
//! `max(cross factor, √(1 + p² + q²))` from the last reading (at most 3, the cross
//! factor's own bound). The iteration converges slowly: a slope read longer makes `|n|`
//! longer, which lengthens the slope again, and where both phases have a strip in shadow
//! the colours barely tell the slope from the normal's length. So it stops early: two
//! iterations are the fewest that brought the steep wall of both tuning families
//! (`ours-nominal`, `ours-random`) to 0.90 mm (`bench skins`, two balls: 0.934 and 0.874
//! before, 0.959 and 0.892 with one, 0.982 and 0.902 with two, 0.999 and 0.910 with
//! three). [`SHADOWED`] is the light and photometric models' shadow level, not tuned
//! here.

use super::model::{Lut, cross_factor};

/// A strip brings less than this share of its flat-skin light (normalised colour): in
/// shadow. The light and photometric models' shadow level, the same number.
pub use super::model::light::SHADOWED;
/// Readings of a pixel with a strip of the other phase in shadow.
pub const ITERATIONS: usize = 2;
/// The largest normal length used (the cross factor's own bound).
const MAX_NORMAL: f32 = 3.0;

/// Which of a pixel's slopes to read again, from its normalised colours `[red, blue]` of
/// dx and dy: bit 0 the slope along x (a strip of dy in shadow), bit 1 along y; 0 unless
/// `lit` (both phases accepted by the colour filter). Branch-free, for vector lanes.
#[inline(always)]
pub fn marks(dx: [f32; 2], dy: [f32; 2], lit: bool) -> u8 {
    let x = lit & (dy[0].min(dy[1]) < SHADOWED);
    let y = lit & (dx[0].min(dx[1]) < SHADOWED);
    u8::from(x) | (u8::from(y) << 1)
}

/// Reads again the slopes (`slopes[0]` along x, from the dx phase; `slopes[1]` along y)
/// of the pixels `marks` names ([`marks`]; see the module documentation); the others are
/// left as they are. `colours` are the run's normalised colours `[[red, blue] of dx, of
/// dy]` per pixel (without any cross factor); `gains` the table's position gains
/// `[positive, negative]` of each pixel, per axis. Slopes stay within ±`max_slope`.
/// Returns how many pixels were read again.
///
/// The marked pixels are packed side by side in `packed` first, so that each reading is
/// one pass of the table over contiguous lanes ([`Lut::eval_planes`], eight pixels at a
/// time) instead of one pixel at a time: on a wall most of a run is marked. They are
/// packed in three groups, those read again along x only, along both axes, along y only,
/// so that each axis is read over one contiguous range of them and no pixel on an axis it
/// does not need. The readings are those of the pixel-by-pixel order, bit for bit (a test
/// holds them to it).
pub fn reread(
    luts: [&Lut; 2],
    marks: &[u8],
    colours: [[&[f32]; 2]; 2],
    gains: [&[[f32; 2]]; 2],
    slopes: [&mut [f32]; 2],
    max_slope: f32,
    packed: &mut Packed,
) -> usize {
    let [p, q] = slopes;
    let n = [
        marks.len(),
        p.len(),
        q.len(),
        gains[0].len(),
        gains[1].len(),
    ]
    .into_iter()
    .chain(colours.iter().flatten().map(|c| c.len()))
    .min()
    .unwrap_or(0);
    let ranges = packed.pack(&marks[..n], colours, gains, [&*p, &*q]);
    let m = packed.at.len();
    if m == 0 {
        return 0;
    }
    let Packed {
        at,
        colour,
        had,
        gains,
        read,
        normal,
        scaled,
        out,
    } = packed;
    for _ in 0..ITERATIONS {
        let [rp, rq] = &*read;
        for ((n, &p), &q) in normal.iter_mut().zip(rp).zip(rq) {
            *n = (1.0 + p * p + q * q).sqrt();
        }
        // Both axes from the normal of the last reading, as pixel by pixel.
        for (axis, range) in ranges.iter().enumerate() {
            let [red, blue] = colour[axis].each_ref().map(|c| &c[range.clone()]);
            let [sr, sb] = scaled.each_mut().map(|c| &mut c[range.clone()]);
            let (normal, had) = (&normal[range.clone()], &had[axis][range.clone()]);
            for ((((sr, sb), &n), &h), (&r, &b)) in sr
                .iter_mut()
                .zip(sb.iter_mut())
                .zip(normal)
                .zip(had)
                .zip(red.iter().zip(blue))
            {
                let factor = n.max(h).min(MAX_NORMAL);
                (*sr, *sb) = (r * factor, b * factor);
            }
            let out = &mut out[range.clone()];
            luts[axis].eval_planes(sr, sb, &gains[axis][range.clone()], out);
            // A reading that is not a number keeps the last one.
            for (read, &s) in read[axis][range.clone()].iter_mut().zip(&*out) {
                if s.is_finite() {
                    *read = s.clamp(-max_slope, max_slope);
                }
            }
        }
    }
    for (j, &k) in at.iter().enumerate() {
        (p[k], q[k]) = (read[0][j], read[1][j]);
    }
    m
}

/// The marked pixels of a run side by side, for [`reread`]; kept between runs so that
/// its buffers are allocated once.
#[derive(Debug, Default)]
pub struct Packed {
    /// Each packed pixel's index in the run: first those read again along x only, then
    /// along both axes, then along y only.
    at: Vec<usize>,
    /// Its normalised `[red, blue]` of dx, of dy.
    colour: [[Vec<f32>; 2]; 2],
    /// The factor its colour of dx (dy) had: the other phase's cross factor.
    had: [Vec<f32>; 2],
    /// Its table gains per axis.
    gains: [Vec<[f32; 2]>; 2],
    /// Its slopes `[p, q]` as last read.
    read: [Vec<f32>; 2],
    /// `√(1 + p² + q²)` of the last reading.
    normal: Vec<f32>,
    /// `[red, blue]` times the factor, for the table.
    scaled: [Vec<f32>; 2],
    /// The table's reading.
    out: Vec<f32>,
}

impl Packed {
    /// Packs the pixels `marks` names; returns the range of the packed pixels read again
    /// along x, and along y.
    fn pack(
        &mut self,
        marks: &[u8],
        colours: [[&[f32]; 2]; 2],
        gains: [&[[f32; 2]]; 2],
        slopes: [&[f32]; 2],
    ) -> [std::ops::Range<usize>; 2] {
        self.at.clear();
        let mut ends = [0; 3];
        for (group, mark) in [1u8, 3, 2].into_iter().enumerate() {
            let named = marks.iter().enumerate().filter(|(_, m)| **m == mark);
            self.at.extend(named.map(|(k, _)| k));
            ends[group] = self.at.len();
        }
        let at = &self.at;
        let pick = |v: &mut Vec<f32>, from: &[f32]| {
            v.clear();
            v.extend(at.iter().map(|&k| from[k]));
        };
        for axis in 0..2 {
            for (packed, from) in self.colour[axis].iter_mut().zip(colours[axis]) {
                pick(packed, from);
            }
            self.gains[axis].clear();
            self.gains[axis].extend(at.iter().map(|&k| gains[axis][k]));
            pick(&mut self.read[axis], slopes[axis]);
        }
        for (axis, other) in [(0, 1), (1, 0)] {
            let [red, blue] = &self.colour[other];
            self.had[axis].clear();
            let factors = red.iter().zip(blue).map(|(&r, &b)| cross_factor(r, b));
            self.had[axis].extend(factors);
        }
        let m = at.len();
        self.normal.resize(m, 0.0);
        let [sr, sb] = &mut self.scaled;
        for v in [sr, sb, &mut self.out] {
            v.resize(m, 0.0);
        }
        [0..ends[1], ends[0]..ends[2]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Cotangent of the strips' elevation (30°) on the analytic skin.
    const COT: f32 = 1.732_050_8;

    /// Normalised colours `[[red, blue] of dx, of dy]` of matte skin with slopes `(p, q)`
    /// under strips at 30° elevation: each strip `max(0, 1 ± slope · cot e) / |n|`.
    fn lambertian(p: f32, q: f32) -> [[f32; 2]; 2] {
        let n = (1.0 + p * p + q * q).sqrt();
        [p, q].map(|s| [(1.0 + s * COT).max(0.0) / n, (1.0 - s * COT).max(0.0) / n])
    }

    /// A table exact for walls facing its axis (the other slope 0, so the cross factor is
    /// `|n|`): both strips lit, `(r − b) / (2 cot e)`; one in shadow, from the other.
    fn analytic_lut() -> Lut {
        let (bins, max_value) = (401usize, 4.0f32);
        let step = max_value / (bins - 1) as f32;
        let mut table = Vec::with_capacity(bins * bins);
        for i in 0..bins {
            for j in 0..bins {
                let (r, b) = (i as f32 * step, j as f32 * step);
                table.push(if b <= 0.0 {
                    (r - 1.0) / COT
                } else if r <= 0.0 {
                    (1.0 - b) / COT
                } else {
                    (r - b) / (2.0 * COT)
                });
            }
        }
        Lut {
            bins,
            max_value,
            cells_x: 1,
            cells_y: 1,
            table,
            gain: vec![1.0],
            gain_negative: vec![1.0],
        }
    }

    /// The slopes the table reads from colours times the cross factors, as the fast path.
    fn first_reading(lut: &Lut, c: [[f32; 2]; 2]) -> [f32; 2] {
        let had = [
            cross_factor(c[1][0], c[1][1]),
            cross_factor(c[0][0], c[0][1]),
        ];
        [0, 1].map(|a| lut.eval_with_gains(c[a][0] * had[a], c[a][1] * had[a], [1.0, 1.0]))
    }

    /// Colours per pixel as the planes [`reread`] takes.
    fn planes(colours: &[[[f32; 2]; 2]]) -> [[Vec<f32>; 2]; 2] {
        [0, 1].map(|phase| [0, 1].map(|c| colours.iter().map(|px| px[phase][c]).collect()))
    }

    /// [`reread`] of `colours` with fresh buffers.
    fn reread_colours(
        lut: &Lut,
        marks: &[u8],
        colours: &[[[f32; 2]; 2]],
        gains: &[[f32; 2]],
        slopes: [&mut [f32]; 2],
        max_slope: f32,
    ) -> usize {
        let [dx, dy] = planes(colours);
        reread(
            [lut, lut],
            marks,
            [[&dx[0], &dx[1]], [&dy[0], &dy[1]]],
            [gains, gains],
            slopes,
            max_slope,
            &mut Packed::default(),
        )
    }

    /// The reading pixel by pixel, as the module documentation has it: the reference the
    /// packed lanes are held to.
    fn reread_one_by_one(
        lut: &Lut,
        marks: &[u8],
        colours: &[[[f32; 2]; 2]],
        gains: &[[f32; 2]],
        [p, q]: [&mut [f32]; 2],
        max_slope: f32,
    ) {
        for (k, &mark) in marks.iter().enumerate().filter(|(_, m)| **m != 0) {
            let c = colours[k];
            let had = [
                cross_factor(c[1][0], c[1][1]),
                cross_factor(c[0][0], c[0][1]),
            ];
            let mut read = [p[k], q[k]];
            for _ in 0..ITERATIONS {
                let normal = (1.0 + read[0] * read[0] + read[1] * read[1]).sqrt();
                for axis in (0..2).filter(|&a| mark & (1 << a) != 0) {
                    let factor = normal.max(had[axis]).min(MAX_NORMAL);
                    let [red, blue] = c[axis];
                    let s = lut.eval_with_gains(red * factor, blue * factor, gains[k]);
                    if s.is_finite() {
                        read[axis] = s.clamp(-max_slope, max_slope);
                    }
                }
            }
            [p[k], q[k]] = read;
        }
    }

    /// Many pixels, most of them marked (whole lanes of eight and a remainder), with
    /// colours that are not numbers, out of the table, negative, and gains of both signs:
    /// the packed lanes read what the pixel-by-pixel order reads, bit for bit.
    #[test]
    fn packed_lanes_read_as_pixel_by_pixel() {
        let lut = analytic_lut();
        let mut rng = crate::rng::Rng::new(7);
        let n = 203;
        let colours: Vec<[[f32; 2]; 2]> = (0..n)
            .map(|k| match k % 37 {
                0 => [[f32::NAN, 1.0], [0.1, 0.0]],
                1 => [[9.0, -1.0], [0.0, f32::INFINITY]],
                _ => lambertian(rng.range(-2.0, 2.0) as f32, rng.range(-2.0, 2.0) as f32),
            })
            .collect();
        let marks: Vec<u8> = (0..n).map(|k| [3, 1, 2, 0, 3, 1][k % 6]).collect();
        let gains: Vec<[f32; 2]> = (0..n)
            .map(|_| [rng.range(0.5, 1.5) as f32, rng.range(0.5, 1.5) as f32])
            .collect();
        let start: Vec<f32> = (0..2 * n).map(|_| rng.range(-1.5, 1.5) as f32).collect();
        let (mut p, mut q) = (start[..n].to_vec(), start[n..].to_vec());
        let (mut want_p, mut want_q) = (p.clone(), q.clone());
        let read = reread_colours(&lut, &marks, &colours, &gains, [&mut p, &mut q], 1.3);
        reread_one_by_one(
            &lut,
            &marks,
            &colours,
            &gains,
            [&mut want_p, &mut want_q],
            1.3,
        );
        assert_eq!(read, marks.iter().filter(|m| **m != 0).count());
        let bits = |v: &[f32]| v.iter().map(|s| s.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&p), bits(&want_p));
        assert_eq!(bits(&q), bits(&want_q));
        assert_ne!(bits(&p), bits(&start[..n]), "some slopes were read again");
    }

    #[test]
    fn marks_name_the_slope_whose_other_phase_has_a_strip_in_shadow() {
        assert_eq!(marks([1.0, 1.0], [1.0, 1.0], true), 0);
        assert_eq!(
            marks([1.0, 1.0], [1.9, 0.0], true),
            1,
            "dy in shadow: x again"
        );
        assert_eq!(
            marks([0.05, 1.6], [1.0, 1.0], true),
            2,
            "dx in shadow: y again"
        );
        assert_eq!(marks([0.0, 1.6], [1.9, 0.0], true), 3);
        assert_eq!(marks([0.0, 1.6], [1.9, 0.0], false), 0, "not lit: never");
        assert_eq!(marks([f32::NAN; 2], [f32::NAN; 2], true), 0);
    }

    /// A wall steep along y (q = 1.2, one dy strip in shadow) with p = 0.4: the cross
    /// factor of dy falls short of |n| and p reads 0.26; read again, 0.40 (both against the
    /// analytic skin). q, whose factor came from the lit dx phase, is not read again.
    #[test]
    fn a_slope_beside_a_shadowed_strip_reads_as_the_analytic_skin() {
        let lut = analytic_lut();
        let c = lambertian(0.4, 1.2);
        let mark = marks(c[0], c[1], true);
        assert_eq!(mark, 1, "{c:?}");
        let [p0, q0] = first_reading(&lut, c);
        assert!((p0 - 0.26).abs() < 0.01, "{p0}");
        assert!((q0 - 1.2).abs() < 0.005, "{q0}");
        let (mut p, mut q) = ([p0], [q0]);
        let gains: &[[f32; 2]] = &[[1.0, 1.0]];
        let n = reread_colours(&lut, &[mark], &[c], gains, [&mut p, &mut q], 5.0);
        assert_eq!(n, 1);
        assert!((p[0] - 0.4).abs() < 0.01, "{}", p[0]);
        assert_eq!(q[0], q0);
    }

    /// Unmarked pixels keep their slopes bit for bit; a pixel with strips in shadow in
    /// both phases never reads shorter than before, stays finite and within the bound,
    /// also from colours that are not numbers.
    #[test]
    fn unmarked_pixels_are_untouched_and_readings_stay_bounded() {
        let lut = analytic_lut();
        let gains: &[[f32; 2]] = &[[1.0, 1.0]; 3];
        let both = lambertian(1.2, 1.2);
        let colours = [lambertian(0.1, 0.2), both, [[f32::NAN; 2]; 2]];
        let mut p = [0.123, 0.0, 0.5];
        let mut q = [0.456, 0.0, 0.5];
        [p[1], q[1]] = first_reading(&lut, both);
        let before = (p, q);
        let marks = [0, marks(both[0], both[1], true), 3];
        assert_eq!(marks[1], 3);
        let n = reread_colours(&lut, &marks, &colours, gains, [&mut p, &mut q], 1.0);
        assert_eq!(n, 2);
        assert_eq!((p[0], q[0]), (before.0[0], before.1[0]));
        assert!(p[1] >= before.0[1] && q[1] >= before.1[1], "{p:?} {q:?}");
        assert!(
            p.iter().chain(&q).all(|s| s.is_finite() && s.abs() <= 1.0),
            "{p:?} {q:?}"
        );
    }
}
