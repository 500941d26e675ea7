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
/// left as they are. `raw(k)` gives pixel `k`'s normalised colours `[[red, blue] of dx,
/// of dy]` (without any cross factor); `gains` the table's position gains `[positive,
/// negative]` of each pixel, per axis. Slopes stay within ±`max_slope`. Returns how many
/// pixels were read again.
pub fn reread(
    luts: [&Lut; 2],
    marks: &[u8],
    raw: impl Fn(usize) -> [[f32; 2]; 2],
    gains: [&[[f32; 2]]; 2],
    slopes: [&mut [f32]; 2],
    max_slope: f32,
) -> usize {
    let [p, q] = slopes;
    let n = marks.len().min(p.len()).min(q.len());
    let mut count = 0;
    // Most touched pixels have no strip in shadow.
    for (k, &mark) in marks[..n].iter().enumerate().filter(|(_, m)| **m != 0) {
        count += 1;
        let again = [mark & 1 != 0, mark & 2 != 0];
        let colours = raw(k);
        // The factor each phase's colour had: the other phase's.
        let had = [
            cross_factor(colours[1][0], colours[1][1]),
            cross_factor(colours[0][0], colours[0][1]),
        ];
        let mut read = [p[k], q[k]];
        for _ in 0..ITERATIONS {
            let normal = (1.0 + read[0] * read[0] + read[1] * read[1]).sqrt();
            for axis in (0..2).filter(|&a| again[a]) {
                let factor = normal.max(had[axis]).min(MAX_NORMAL);
                let [red, blue] = colours[axis];
                let s = luts[axis].eval_with_gains(red * factor, blue * factor, gains[axis][k]);
                // A reading that is not a number keeps the last one.
                if s.is_finite() {
                    read[axis] = s.clamp(-max_slope, max_slope);
                }
            }
        }
        [p[k], q[k]] = read;
    }
    count
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
        let n = reread(
            [&lut, &lut],
            &[mark],
            |_| c,
            [gains, gains],
            [&mut p, &mut q],
            5.0,
        );
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
        let n = reread(
            [&lut, &lut],
            &marks,
            |k| colours[k],
            [gains, gains],
            [&mut p, &mut q],
            1.0,
        );
        assert_eq!(n, 2);
        assert_eq!((p[0], q[0]), (before.0[0], before.1[0]));
        assert!(p[1] >= before.0[1] && q[1] >= before.1[1], "{p:?} {q:?}");
        assert!(
            p.iter().chain(&q).all(|s| s.is_finite() && s.abs() <= 1.0),
            "{p:?} {q:?}"
        );
    }
}
