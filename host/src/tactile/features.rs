//! The model's inputs for the touched pixels of one region: each phase's normalised LED
//! colour ([`ReferencePlanes::normalise`]), made independent of the other axis' slope by
//! the other phase's brightness ([`cross_factor`]), with the pixel's position and, for the
//! lookup table, its position gain.
//!
//! The numbers are those of [`super::contact::colours_of`] then
//! [`super::model::colour_features`], computed differently for speed: a run of touched
//! pixels of a region row at a time, in vector lanes (colour planes first, then the
//! filter and the factors without branches), and only then the accepted pixels are kept
//! (a compaction whose write position advances with the filter's verdict), or, with the
//! lookup table, turned into slopes at once ([`Features::lut_slopes`]), the pixels with a
//! strip of the other phase in shadow then read again ([`super::shadowed`]).

use std::time::Instant;

use image::RgbImage;

use super::colour::{ColourFilter, ReferencePlanes};
use super::contact::{References, Roi, runs};
use super::model::{GainPlanes, Lut, cross_factor, side_light};
use super::past_reach::{Pending, Reach};
use super::rgb_planes::deinterleave;
use super::sanitize::sanitize;
use super::shadowed;
use crate::timing::ms_between as ms;

/// Feature rows of one axis and where they go.
#[derive(Debug, Default)]
pub struct AxisFeatures {
    /// `[r, b, x / width, y / height]` per accepted touched pixel.
    pub rows: Vec<[f32; 4]>,
    /// Index of each row's pixel in the region (row-major).
    pub targets: Vec<usize>,
}

/// Buffers reused across regions and frames.
#[derive(Debug, Default)]
pub struct Features {
    /// dx phase (x slopes) and dy phase (y slopes).
    pub axes: [AxisFeatures; 2],
    /// Region indices (row-major) of the touched pixels the filter rejected, per axis:
    /// slopes to fill from their neighbours ([`super::unread`]).
    pub unread: [Vec<usize>; 2],
    row: RowScratch,
}

/// One region row of both phases, as planes.
#[derive(Debug, Default)]
struct RowScratch {
    /// `[R, G, B]` planes of dx then dy.
    planes: [[Vec<f32>; 3]; 2],
    /// Normalised `[red, blue]` of dx then dy, times the other phase's factor.
    colour: [[Vec<f32>; 2]; 2],
    /// Normalised `[red, blue]` of dx then dy, without the factor (for the pixels read
    /// again, [`shadowed::reread`]).
    normalised: [[Vec<f32>; 2]; 2],
    /// Accepted by the filter, dx then dy.
    lit: [Vec<bool>; 2],
    /// Which slopes to read again, lit in both phases with a strip of the other phase in
    /// shadow ([`shadowed::marks`]).
    again: Vec<u8>,
    /// The pixels read again, packed ([`shadowed::reread`]).
    packed: shadowed::Packed,
}

/// What the features are made from.
pub struct Inputs<'a> {
    /// Phase images (the light the model works on).
    pub dx: &'a RgbImage,
    /// dy phase.
    pub dy: &'a RgbImage,
    /// Full-resolution references.
    pub refs: &'a References,
    /// Colour filter.
    pub filter: &'a ColourFilter,
    /// Position gains of every pixel of the frame per axis
    /// ([`super::model::Lut::gain_planes`]), or `None`.
    pub gains: Option<&'a [GainPlanes; 2]>,
    /// The strips' side light `κ` at every pixel of the frame
    /// ([`super::model::SideLight::planes`]) for the lookup tables, or `None`.
    pub side: Option<&'a [[f32; 2]]>,
    /// Where the lookup tables' slopes are read by the light model as well
    /// ([`super::past_reach`]), or `None`.
    pub reach: Option<Reach<'a>>,
}

/// Calls `visit(ry, first, span)` for every run of set pixels of `mask` (row-major over
/// `roi` in a frame `frame_width` wide): its region row, its first region column, and its
/// frame indices.
fn for_each_run(
    mask: &[bool],
    roi: &Roi,
    frame_width: usize,
    mut visit: impl FnMut(usize, usize, std::ops::Range<usize>),
) {
    for (ry, row) in mask.chunks_exact(roi.width.max(1)).enumerate() {
        for run in runs(row, true) {
            let start = (roi.y + ry) * frame_width + roi.x + run.start;
            visit(ry, run.start, start..start + run.len());
        }
    }
}

/// What [`Features::lut_slopes`] changed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LutCounts {
    /// Slopes bounded by `max_slope` (NaN → 0).
    pub sanitized: usize,
    /// Pixels read by the light model as well ([`super::past_reach`]).
    pub past_reach: usize,
}

/// Time spent in the two stages of [`Features::lut_slopes`] (ms).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FusedTimings {
    /// Colour filter and normalisation.
    pub colour_ms: f64,
    /// Lookup table and slope bounds.
    pub model_ms: f64,
}

impl Features {
    /// Pixels the colour filter rejected in the last region, summed over both phases.
    pub fn rejected(&self) -> usize {
        self.unread.iter().map(Vec::len).sum()
    }

    /// The features of `mask`'s pixels (row-major over `roi`) in `roi`. Only the runs
    /// of touched pixels are read (the references are large).
    pub fn collect(&mut self, inputs: &Inputs<'_>, roi: &Roi, mask: &[bool]) {
        let (w, h) = (inputs.dx.width() as usize, inputs.dx.height() as usize);
        let (inv_w, inv_h) = (1.0 / w as f32, 1.0 / h as f32);
        let touched = mask.iter().filter(|m| **m).count();
        // One spare row: every touched pixel is written, the position advances when the
        // phase was accepted.
        for axis in &mut self.axes {
            axis.rows.clear();
            axis.rows.resize(touched + 1, [0.0; 4]);
            axis.targets.clear();
            axis.targets.resize(touched + 1, 0);
        }
        let mut next = [0usize; 2];
        let (row, axes, unread) = (&mut self.row, &mut self.axes, &mut self.unread);
        unread.iter_mut().for_each(Vec::clear);
        for_each_run(mask, roi, w, |ry, first, span| {
            row.fill(inputs, span.clone());
            let yn = (roi.y + ry) as f32 * inv_h;
            for (axis, out) in axes.iter_mut().enumerate() {
                let [red, blue] = &row.colour[axis];
                let lit = &row.lit[axis];
                let mut j = next[axis];
                for (i, ((&r, &b), &ok)) in red.iter().zip(blue).zip(lit).enumerate() {
                    let rx = first + i;
                    out.rows[j] = [r, b, (roi.x + rx) as f32 * inv_w, yn];
                    out.targets[j] = ry * roi.width + rx;
                    j += usize::from(ok);
                    if !ok {
                        unread[axis].push(ry * roi.width + rx);
                    }
                }
                next[axis] = j;
            }
        });
        for (axis, n) in self.axes.iter_mut().zip(next) {
            axis.rows.truncate(n);
            axis.targets.truncate(n);
        }
    }

    /// The lookup tables' slopes of `mask`'s pixels straight into `slopes` (`[p, q]`,
    /// row-major over `roi`, zero where nothing is written), run by run: the colour and
    /// the table in one pass with no feature rows in between. Pixels the filter rejects in
    /// a phase get slope 0 on its axis; slopes are bounded by `max_slope` (NaN → 0) and
    /// the bounded ones counted, as [`super::sanitize::sanitize`] does. Needs
    /// `inputs.gains`. Returns what was changed and the time of each stage.
    pub fn lut_slopes(
        &mut self,
        inputs: &Inputs<'_>,
        roi: &Roi,
        mask: &[bool],
        luts: [&Lut; 2],
        slopes: [&mut [f32]; 2],
        max_slope: f32,
    ) -> (LutCounts, FusedTimings) {
        let w = inputs.dx.width() as usize;
        let mut timings = FusedTimings::default();
        let mut counts = LutCounts::default();
        self.unread.iter_mut().for_each(Vec::clear);
        let Some(gains) = inputs.gains else {
            return (counts, timings);
        };
        let (row, unread) = (&mut self.row, &mut self.unread);
        let [p, q] = slopes;
        // Pixels past the table's reach queue for the light model across the runs.
        let mut pending = Pending::default();
        let mut clock = Instant::now();
        for_each_run(mask, roi, w, |ry, first, span| {
            row.fill(inputs, span.clone());
            let t = Instant::now();
            timings.colour_ms += ms(clock, t);
            let at = ry * roi.width + first..ry * roi.width + first + span.len();
            for (axis, out) in [&mut p[at.clone()], &mut q[at.clone()]]
                .into_iter()
                .enumerate()
            {
                let [red, blue] = &row.colour[axis];
                luts[axis].eval_planes(red, blue, &gains[axis].0[span.clone()], out);
                let lit = &row.lit[axis];
                for (o, &ok) in out.iter_mut().zip(lit) {
                    *o = if ok { *o } else { 0.0 };
                }
                let refused = at.clone().zip(lit).filter(|(_, ok)| !**ok);
                unread[axis].extend(refused.map(|(i, _)| i));
                let fixed = sanitize(out, max_slope);
                counts.sanitized += fixed.non_finite + fixed.clamped;
            }
            // The other phase's strips light from the side too: the colours read again
            // with the cross factor corrected by the slopes just read.
            if let Some(side) = inputs.side {
                side_light_reread(
                    luts,
                    &row.colour,
                    [&row.lit[0], &row.lit[1]],
                    &side[span.clone()],
                    [&gains[0].0[span.clone()], &gains[1].0[span.clone()]],
                    [&mut p[at.clone()], &mut q[at.clone()]],
                    max_slope,
                );
            }
            // Where a strip of the other phase is in shadow the cross factor fell short:
            // those pixels are read again from their colours without it.
            let span_gains = [0, 1].map(|axis| &gains[axis].0[span.clone()]);
            let [[xr, xb], [yr, yb]] = &row.normalised;
            shadowed::reread(
                luts,
                &row.again,
                [[xr, xb], [yr, yb]],
                span_gains,
                [&mut p[at.clone()], &mut q[at.clone()]],
                max_slope,
                &mut row.packed,
            );
            // Past the table's reach the light model reads the slope as well.
            if let Some(reach) = &inputs.reach {
                // A run lies in one frame row.
                let y = (span.start / w) as f32 / inputs.dx.height() as f32;
                let x0 = span.start % w;
                let position = |k: usize| [(x0 + k) as f32 / w as f32, y];
                let [[xr, xb], [yr, yb]] = &row.colour;
                counts.past_reach += reach.extend(
                    &mut pending,
                    [&row.lit[0], &row.lit[1]],
                    [[xr, xb], [yr, yb]],
                    position,
                    span_gains,
                    at.clone(),
                    [&mut *p, &mut *q],
                    max_slope,
                );
            }
            clock = Instant::now();
            timings.model_ms += ms(t, clock);
        });
        if let Some(reach) = &inputs.reach {
            reach.finish(&mut pending, [p, q], max_slope);
            timings.model_ms += ms(clock, Instant::now());
        }
        (counts, timings)
    }
}

/// The tables' slopes `[p, q]` of a run read again [`side_light::ROUNDS`] times from its
/// model colours (`colour`, `[red, blue]` per phase) times the side light's factors
/// ([`side_light::factors`]) from the last reading, where both phases are lit; `kappa`
/// and `gains` per pixel of the run.
fn side_light_reread(
    luts: [&Lut; 2],
    colour: &[[Vec<f32>; 2]; 2],
    lit: [&[bool]; 2],
    kappa: &[[f32; 2]],
    gains: [&[[f32; 2]]; 2],
    slopes: [&mut [f32]; 2],
    max_slope: f32,
) {
    let [p, q] = slopes;
    let [[xr, xb], [yr, yb]] = colour;
    let n = [
        p.len(),
        q.len(),
        kappa.len(),
        lit[0].len(),
        lit[1].len(),
        xr.len(),
        yr.len(),
    ]
    .into_iter()
    .min()
    .unwrap_or(0);
    for k in 0..n {
        if !(lit[0][k] && lit[1][k]) || kappa[k] == [0.0; 2] {
            continue;
        }
        for _ in 0..side_light::ROUNDS {
            let [fx, fy] = side_light::factors(kappa[k], p[k], q[k]);
            if (fx - 1.0).abs() < side_light::NEGLIGIBLE
                && (fy - 1.0).abs() < side_light::NEGLIGIBLE
            {
                break;
            }
            let sp = luts[0].eval_with_gains(xr[k] * fx, xb[k] * fx, gains[0][k]);
            let sq = luts[1].eval_with_gains(yr[k] * fy, yb[k] * fy, gains[1][k]);
            if sp.is_finite() {
                p[k] = sp.clamp(-max_slope, max_slope);
            }
            if sq.is_finite() {
                q[k] = sq.clamp(-max_slope, max_slope);
            }
        }
    }
}

impl RowScratch {
    /// Planes, normalised colours, verdicts and cross factors of the pixels `span` (frame
    /// indices within one row).
    fn fill(&mut self, inputs: &Inputs<'_>, span: std::ops::Range<usize>) {
        let n = span.len();
        for (phase, image) in [inputs.dx, inputs.dy].into_iter().enumerate() {
            let raw = &image.as_raw()[3 * span.start..3 * span.end];
            let [r, g, b] = &mut self.planes[phase];
            for plane in [&mut *r, &mut *g, &mut *b] {
                plane.resize(n, 0.0);
            }
            deinterleave(raw, r, g, b);
        }
        let refs = [
            inputs.refs.dx.planes(span.clone()),
            inputs.refs.dy.planes(span),
        ];
        for ((colour, normalised), lit) in self
            .colour
            .iter_mut()
            .zip(&mut self.normalised)
            .zip(&mut self.lit)
        {
            for plane in colour.iter_mut().chain(normalised.iter_mut()) {
                plane.resize(n, 0.0);
            }
            lit.resize(n, false);
        }
        self.again.resize(n, 0);
        normalise_pair(
            &self.planes,
            &refs,
            inputs.filter,
            &mut self.colour,
            &mut self.normalised,
            &mut self.lit,
            &mut self.again,
        );
    }
}

/// Both phases' normalised colours, each times the other phase's cross factor (1 where
/// the other phase is rejected) in `colour` and as they are in `normalised`, the filter's
/// verdicts, and the marks of the slopes to read again ([`shadowed::marks`]). Runs the
/// AVX2 copy when the CPU has it.
#[allow(unsafe_code)]
fn normalise_pair(
    planes: &[[Vec<f32>; 3]; 2],
    refs: &[ReferencePlanes<'_>; 2],
    filter: &ColourFilter,
    colour: &mut [[Vec<f32>; 2]; 2],
    normalised: &mut [[Vec<f32>; 2]; 2],
    lit: &mut [Vec<bool>; 2],
    again: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::avx2() {
        // SAFETY: `normalise_pair_avx2` only needs AVX2, detected just above.
        return unsafe {
            normalise_pair_avx2(planes, refs, filter, colour, normalised, lit, again)
        };
    }
    normalise_pair_portable(planes, refs, filter, colour, normalised, lit, again)
}

/// [`normalise_pair_portable`] in 8-wide lanes (no FMA: the same numbers).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn normalise_pair_avx2(
    planes: &[[Vec<f32>; 3]; 2],
    refs: &[ReferencePlanes<'_>; 2],
    filter: &ColourFilter,
    colour: &mut [[Vec<f32>; 2]; 2],
    normalised: &mut [[Vec<f32>; 2]; 2],
    lit: &mut [Vec<bool>; 2],
    again: &mut [u8],
) {
    normalise_pair_portable(planes, refs, filter, colour, normalised, lit, again)
}

#[inline(always)]
fn normalise_pair_portable(
    planes: &[[Vec<f32>; 3]; 2],
    refs: &[ReferencePlanes<'_>; 2],
    filter: &ColourFilter,
    colour: &mut [[Vec<f32>; 2]; 2],
    normalised: &mut [[Vec<f32>; 2]; 2],
    lit: &mut [Vec<bool>; 2],
    again: &mut [u8],
) {
    let n = lit[0].len();
    // A pass per phase, then one that combines them: loops with few streams each, which
    // the compiler vectorises (one loop writing all eleven planes it did not).
    for (((planes, refs), [nr, nb]), lit) in
        planes.iter().zip(refs).zip(&mut *normalised).zip(&mut *lit)
    {
        let [r, g, b] = planes;
        let (r, g, b) = (&r[..n], &g[..n], &b[..n]);
        let (nr, nb, lit) = (&mut nr[..n], &mut nb[..n], &mut lit[..n]);
        for i in 0..n {
            let (c, ok) = refs.normalise(filter, i, [r[i], g[i], b[i]]);
            (nr[i], nb[i], lit[i]) = (c[0], c[1], ok);
        }
    }
    let [[nxr, nxb], [nyr, nyb]] = normalised;
    let (nxr, nxb, nyr, nyb) = (&nxr[..n], &nxb[..n], &nyr[..n], &nyb[..n]);
    let [lit_x, lit_y] = lit;
    let (lit_x, lit_y) = (&lit_x[..n], &lit_y[..n]);
    let [[cxr, cxb], [cyr, cyb]] = colour;
    let (cxr, cxb, cyr, cyb) = (&mut cxr[..n], &mut cxb[..n], &mut cyr[..n], &mut cyb[..n]);
    let again = &mut again[..n];
    for i in 0..n {
        let (c_dx, ok_dx) = ([nxr[i], nxb[i]], lit_x[i]);
        let (c_dy, ok_dy) = ([nyr[i], nyb[i]], lit_y[i]);
        let s_dx = if ok_dx {
            cross_factor(c_dx[0], c_dx[1])
        } else {
            1.0
        };
        let s_dy = if ok_dy {
            cross_factor(c_dy[0], c_dy[1])
        } else {
            1.0
        };
        cxr[i] = c_dx[0] * s_dy;
        cxb[i] = c_dx[1] * s_dy;
        cyr[i] = c_dy[0] * s_dx;
        cyb[i] = c_dy[1] * s_dx;
        again[i] = shadowed::marks(c_dx, c_dy, ok_dx & ok_dy);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tactile::contact::{colours_of, dilate};
    use crate::tactile::model::{Sample, colour_features};

    /// Frames, references and a mask that cross every rule of the colour filter.
    fn scene() -> (RgbImage, RgbImage, References, Roi, Vec<bool>) {
        let mut rng = crate::rng::Rng::new(21);
        let (w, h) = (61u32, 37u32);
        let mut noisy = |base: [f32; 3]| {
            RgbImage::from_fn(w, h, |x, _| {
                let base = match x {
                    0..5 => [8.0, 7.0, 8.0],
                    5..9 => [200.0, 190.0, 195.0],
                    _ => base,
                };
                image::Rgb(
                    base.map(|c| (c + rng.range(-70.0, 90.0) as f32).clamp(0.0, 255.0) as u8),
                )
            })
        };
        let (dx, dy) = (noisy([120.0, 30.0, 110.0]), noisy([100.0, 25.0, 130.0]));
        let refs = References {
            dx: crate::tactile::colour::Reference::from_image(
                &noisy([120.0, 30.0, 110.0]),
                crate::tactile::crosstalk::Unmix::IDENTITY,
            ),
            dy: crate::tactile::colour::Reference::from_image(
                &noisy([100.0, 25.0, 130.0]),
                crate::tactile::crosstalk::Unmix::IDENTITY,
            ),
        };
        let roi = Roi {
            x: 2,
            y: 3,
            width: 50,
            height: 30,
        };
        let mut mask: Vec<bool> = (0..roi.area()).map(|_| rng.uniform() < 0.05).collect();
        dilate(&mut mask, roi.width, roi.height, 2);
        (dx, dy, refs, roi, mask)
    }

    #[test]
    fn rows_equal_colours_of_then_colour_features() {
        let (dx, dy, refs, roi, mask) = scene();
        let filter = ColourFilter::default();
        let inputs = Inputs {
            side: None,
            dx: &dx,
            dy: &dy,
            refs: &refs,
            filter: &filter,
            gains: None,
            reach: None,
        };
        let mut features = Features::default();
        features.collect(&inputs, &roi, &mask);
        let mut want: [Vec<([f32; 4], usize)>; 2] = Default::default();
        let mut rejected = 0;
        for (k, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
            let (x, y) = (roi.x + k % roi.width, roi.y + k / roi.width);
            let i = y * dx.width() as usize + x;
            let at = |img: &RgbImage| img.get_pixel(x as u32, y as u32).0.map(f32::from);
            let (c, _) = colours_of(&refs, &filter, i, at(&dx), at(&dy));
            rejected += usize::from(c[0].is_nan()) + usize::from(c[2].is_nan());
            let (xn, yn) = (x as f32 / dx.width() as f32, y as f32 / dx.height() as f32);
            for (axis, f) in colour_features(c).into_iter().enumerate() {
                if let Some([r, b]) = f {
                    want[axis].push(([r, b, xn, yn], k));
                }
            }
        }
        assert_eq!(features.rejected(), rejected);
        assert!(rejected > 0 && want[0].len() > 100 && want[1].len() > 100);
        for (axis, want) in want.iter().enumerate() {
            let got = &features.axes[axis];
            assert_eq!(got.rows.len(), want.len());
            for (j, (row, k)) in want.iter().enumerate() {
                assert_eq!(got.targets[j], *k);
                for c in 0..4 {
                    // Positions are `x · (1 / width)` here and `x / width` above.
                    let tolerance = if c < 2 { 0.0 } else { 1e-6 };
                    assert!(
                        (got.rows[j][c] - row[c]).abs() <= tolerance,
                        "axis {axis} row {j}: {:?} vs {row:?}",
                        got.rows[j]
                    );
                }
            }
        }
    }

    /// The fused lookup-table pass writes exactly the slopes the feature rows give
    /// through `Lut::eval_batch`, bounded and counted as `sanitize` does.
    #[test]
    fn lut_slopes_equal_the_feature_rows_path() {
        let (dx, dy, refs, roi, mask) = scene();
        let filter = ColourFilter::default();
        let mut rng = crate::rng::Rng::new(4);
        let samples: Vec<Sample> = (0..4000)
            .map(|_| {
                let features = [
                    rng.range(0.0, 3.0) as f32,
                    rng.range(0.0, 3.0) as f32,
                    rng.uniform() as f32,
                    rng.uniform() as f32,
                ];
                // Steep enough that some slopes are bounded.
                Sample {
                    target: 6.0 * (features[0] - features[1]) * (0.5 + features[2]),
                    features,
                }
            })
            .collect();
        let lut = Lut::fit(&samples, 24, 4.0, 4, 3);
        let (w, h) = (dx.width() as usize, dx.height() as usize);
        let gain = lut.gain_planes(w, h).expect("a whole table");
        let gains = [gain.clone(), gain];
        let inputs = Inputs {
            side: None,
            dx: &dx,
            dy: &dy,
            refs: &refs,
            filter: &filter,
            gains: Some(&gains),
            reach: None,
        };
        let mut features = Features::default();
        let (mut p, mut q) = (vec![0.0f32; roi.area()], vec![0.0f32; roi.area()]);
        let (counts, _) =
            features.lut_slopes(&inputs, &roi, &mask, [&lut, &lut], [&mut p, &mut q], 3.0);
        assert_eq!(
            counts.past_reach, 0,
            "no light model, no reading past the reach"
        );
        let changed = counts.sanitized;
        let fused_rejected = features.rejected();
        let fused_unread = features.unread.clone();

        features.collect(&inputs, &roi, &mask);
        assert_eq!(features.rejected(), fused_rejected);
        // Both paths list the same refused pixels, and with the accepted ones they are
        // every touched pixel, once.
        assert_eq!(features.unread, fused_unread);
        assert!(fused_rejected > 0, "the scene crosses the filter's rules");
        for (axis, unread) in features.unread.iter().enumerate() {
            let mut all: Vec<usize> = features.axes[axis].targets.clone();
            all.extend(unread);
            all.sort_unstable();
            let touched: Vec<usize> = (0..mask.len()).filter(|&i| mask[i]).collect();
            assert_eq!(all, touched, "axis {axis}");
        }
        let mut want_changed = 0;
        let mut want = [vec![0.0f32; roi.area()], vec![0.0f32; roi.area()]];
        for (axis, want) in want.iter_mut().enumerate() {
            let rows = &features.axes[axis];
            let mut slopes = vec![0.0; rows.rows.len()];
            lut.eval_batch(&rows.rows, &mut slopes);
            let fixed = sanitize(&mut slopes, 3.0);
            want_changed += fixed.non_finite + fixed.clamped;
            for (&k, &s) in rows.targets.iter().zip(&slopes) {
                want[k] = s;
            }
        }
        // Then the pixels with a strip of the other phase in shadow are read again, from
        // their colours made pixel by pixel (`colours_of`) over the whole region.
        let at = |k: usize| (roi.y + k / roi.width) * w + roi.x + k % roi.width;
        let colours: Vec<[f32; 4]> = (0..roi.area())
            .map(|k| {
                let px = |img: &RgbImage| {
                    let v = img.as_raw();
                    let i = 3 * at(k);
                    [v[i], v[i + 1], v[i + 2]].map(f32::from)
                };
                colours_of(&refs, &filter, at(k), px(&dx), px(&dy)).0
            })
            .collect();
        let marks: Vec<u8> = colours
            .iter()
            .zip(&mask)
            .map(|(c, &touched)| {
                let lit = touched && c.iter().all(|v| !v.is_nan());
                shadowed::marks([c[0], c[1]], [c[2], c[3]], lit)
            })
            .collect();
        let region_gains: Vec<[f32; 2]> = (0..roi.area()).map(|k| gains[0].0[at(k)]).collect();
        let [want_p, want_q] = &mut want;
        let plane = |c: usize| colours.iter().map(|px| px[c]).collect::<Vec<f32>>();
        let [xr, xb, yr, yb] = [0, 1, 2, 3].map(plane);
        let again = shadowed::reread(
            [&lut, &lut],
            &marks,
            [[&xr, &xb], [&yr, &yb]],
            [&region_gains, &region_gains],
            [want_p, want_q],
            3.0,
            &mut shadowed::Packed::default(),
        );
        assert!(again > 0, "the scene has strips in shadow");
        for (axis, (got, want)) in [&p, &q].into_iter().zip(&want).enumerate() {
            assert_eq!(
                got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                "axis {axis}"
            );
        }
        assert_eq!(changed, want_changed);
        assert!(changed > 0, "some slopes were bounded");
    }
}
