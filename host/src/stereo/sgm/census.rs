//! Census costs: 7×7 census signatures (48 comparisons of each pixel with its
//! neighbours, borders clamped) kept as six byte planes a row, and a row's Hamming
//! distances to every candidate, compiled portable, for AVX2 (nibble tables) and for
//! AVX-512's byte population count, chosen at run time.

use rayon::prelude::*;

use super::params::Shape;
use crate::grid::Grid;
use crate::stereo::block_match::Kernel;

/// Census window radius: 7×7, 48 comparisons.
pub(super) const CENSUS_RADIUS: usize = 3;
/// Largest census cost (every comparison differs); also the cost of a candidate off the
/// right image.
pub(super) const CENSUS_BITS: u8 = 48;

/// Which view a census is made for, which sets how its planes are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum View {
    /// Left to right.
    Left,
    /// Right to left with `pad` bytes after each plane row, so a left pixel's
    /// candidates (right columns `x − d_min` down to `x − d_min − nd + 1`) are one
    /// forward run of each plane ([`costs`]): `pad ≥ nd + d_min` keeps every run inside.
    Right { pad: usize },
}

/// 7×7 census signatures of one view (bit set where the neighbour is brighter than the
/// centre; neighbours outside the image are read at the nearest edge pixel), kept as six
/// byte planes a row, as [`costs`] reads them: byte `j` of every pixel of row `y` is
/// the run `data[(y·6 + j)·stride..]`, the `j`-th eight comparisons, the first in the
/// top bit.
pub(super) struct CensusPlanes {
    /// What [`CensusPlanes::signature`] needs to find a pixel.
    #[cfg(test)]
    pub(super) width: usize,
    #[cfg(test)]
    pub(super) height: usize,
    #[cfg(test)]
    view: View,
    /// Bytes a plane row: the width, plus the right view's padding.
    stride: usize,
    data: Vec<u8>,
}

impl CensusPlanes {
    /// Row `y`'s six planes, `stride` bytes each.
    pub(super) fn row(&self, y: usize) -> [&[u8]; CENSUS_BYTES] {
        let row = &self.data[y * CENSUS_BYTES * self.stride..][..CENSUS_BYTES * self.stride];
        std::array::from_fn(|j| &row[j * self.stride..][..self.stride])
    }

    /// The buffer, to be kept for the next frame.
    pub(super) fn into_vec(self) -> Vec<u8> {
        self.data
    }

    /// Pixel `(x, y)`'s signature, byte `j` in bits `8j..8j + 8`.
    #[cfg(test)]
    pub(super) fn signature(&self, x: usize, y: usize) -> u64 {
        let at = match self.view {
            View::Left => x,
            View::Right { .. } => self.width - 1 - x,
        };
        self.row(y)
            .iter()
            .enumerate()
            .map(|(j, plane)| u64::from(plane[at]) << (8 * j))
            .sum()
    }
}

/// The census of `img` for `view`, rows in parallel, into `kept` (its contents are
/// overwritten; the right view's padding is never read as a cost).
pub(super) fn census(
    kernel: Kernel,
    img: &Grid<u8>,
    view: View,
    mut kept: Vec<u8>,
) -> CensusPlanes {
    let (w, h) = (img.width(), img.height());
    let stride = match view {
        View::Left => w,
        View::Right { pad } => w + pad,
    };
    let len = h * CENSUS_BYTES * stride;
    // Every plane byte a kept cost comes from is written below (the padding is read only
    // for candidates off the image, whose costs are then overwritten): a buffer of the
    // right size is taken as it is (zeroing it cost 0.5 ms a frame at 640×480).
    if kept.len() != len {
        kept.clear();
        kept.resize(len, 0);
    }
    kept.par_chunks_mut((CENSUS_BYTES * stride).max(1))
        .enumerate()
        .for_each(|(y, planes)| run_census_row(kernel, img, y, view, planes));
    CensusPlanes {
        #[cfg(test)]
        width: w,
        #[cfg(test)]
        height: h,
        #[cfg(test)]
        view,
        stride,
        data: kept,
    }
}

#[allow(unsafe_code)]
pub(super) fn run_census_row(
    kernel: Kernel,
    img: &Grid<u8>,
    y: usize,
    view: View,
    planes: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: AVX2, BMI1/2, POPCNT and LZCNT were detected just above.
        return unsafe { census_row_avx2(img, y, view, planes) };
    }
    let _ = kernel;
    census_row(img, y, view, planes)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
pub(super) fn census_row_avx2(img: &Grid<u8>, y: usize, view: View, planes: &mut [u8]) {
    census_row(img, y, view, planes)
}

/// One row of census planes (`planes`: the row's six plane rows, each `len / 6` bytes).
/// One comparison of every pixel at a time, eight of them gathered in byte lanes, and
/// each byte written to its plane (reversed for the right view), so the work runs in
/// vector lanes.
#[inline(always)]
pub(super) fn census_row(img: &Grid<u8>, y: usize, view: View, planes: &mut [u8]) {
    let (w, h) = (img.width(), img.height());
    let stride = planes.len() / CENSUS_BYTES;
    let r = CENSUS_RADIUS;
    let centre = img.row(y);
    let mut byte = vec![0u8; w];
    let mut taken = 0usize;
    for dy in 0..=2 * r {
        let src = img.row((y + dy).saturating_sub(r).min(h - 1));
        for dx in 0..=2 * r {
            if dx == r && dy == r {
                continue;
            }
            compare_shifted(src, dx as isize - r as isize, centre, &mut byte);
            taken += 1;
            if taken.is_multiple_of(8) {
                let plane = &mut planes[(taken / 8 - 1) * stride..][..w];
                match view {
                    View::Left => plane.copy_from_slice(&byte),
                    View::Right { .. } => {
                        for (o, &b) in plane.iter_mut().zip(byte.iter().rev()) {
                            *o = b;
                        }
                    }
                }
            }
        }
    }
}

/// One census comparison for a row: `byte[x] = byte[x] << 1 | (src[x + shift] > centre[x])`,
/// `x + shift` clamped to the row. Inside the row the neighbours are read in place, a
/// straight run the compiler vectorises; the few clamped ones at either end one by one.
#[inline(always)]
pub(super) fn compare_shifted(src: &[u8], shift: isize, centre: &[u8], byte: &mut [u8]) {
    let w = src.len();
    let mut one = |x: usize| {
        let n = src[(x as isize + shift).clamp(0, w as isize - 1) as usize];
        byte[x] = (byte[x] << 1) | u8::from(n > centre[x]);
    };
    // Columns whose neighbour is inside the row: lo..hi.
    let lo = shift.min(0).unsigned_abs().min(w);
    let hi = w.saturating_sub(shift.max(0).unsigned_abs()).max(lo);
    for x in (0..lo).chain(hi..w) {
        one(x);
    }
    if lo == hi {
        return; // a row no wider than the shift: every neighbour clamped
    }
    let from = (lo as isize + shift) as usize;
    let inside = byte[lo..hi]
        .iter_mut()
        .zip(&src[from..])
        .zip(&centre[lo..hi]);
    for ((b, &n), &c) in inside {
        *b = (*b << 1) | u8::from(n > c);
    }
}

/// A row's census planes, as [`costs`] takes them.
pub(super) type PlaneRow<'a> = [&'a [u8]; CENSUS_BYTES];

#[allow(unsafe_code)]
pub(super) fn run_costs(
    kernel: Kernel,
    s: &Shape,
    left: PlaneRow<'_>,
    right: PlaneRow<'_>,
    out: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    if counts_with_vpopcntb(kernel) {
        // SAFETY: AVX2, BMI, AVX-512 F, BW, VL and BITALG were detected (`avx512_popcnt`).
        return unsafe { costs_avx512(s, left, right, out) };
    }
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: AVX2, BMI1/2, POPCNT and LZCNT were detected just above.
        return unsafe { costs_avx2(s, left, right, out) };
    }
    let _ = kernel;
    costs(s, left, right, out)
}

/// Whether the census costs of `kernel` count with AVX-512's `VPOPCNTB` here: the AVX2
/// kernel on a CPU that has it ([`crate::cpu::avx512_popcnt`]).
pub(super) fn counts_with_vpopcntb(kernel: Kernel) -> bool {
    kernel == Kernel::Avx2 && crate::cpu::avx512_popcnt()
}

/// With AVX-512's byte population count the compiler counts 64 bytes an instruction
/// instead of two table lookups per nibble; the same costs.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt,avx512f,avx512bw,avx512vl,avx512bitalg")]
pub(super) fn costs_avx512(s: &Shape, left: PlaneRow<'_>, right: PlaneRow<'_>, out: &mut [u8]) {
    costs(s, left, right, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
pub(super) fn costs_avx2(s: &Shape, left: PlaneRow<'_>, right: PlaneRow<'_>, out: &mut [u8]) {
    costs(s, left, right, out)
}

/// Bytes in a census signature (48 comparisons).
pub(super) const CENSUS_BYTES: usize = CENSUS_BITS as usize / 8;

/// One row of census costs: `out[x·nd + k]` compares left `x` with right `x − d`.
///
/// The right view's planes are stored right to left ([`View::Right`]), so a pixel's
/// candidates (right columns `x − d_min` down to `x − d_min − nd + 1`) are one forward
/// run of each plane: the Hamming distance is the sum of six byte population counts, in
/// vector lanes. The planes run on past the image's left edge (the padding), so a pixel
/// with candidates off the right image reads them as the others and then gives them the
/// largest cost.
#[inline(always)]
pub(super) fn costs(s: &Shape, left: PlaneRow<'_>, right: PlaneRow<'_>, out: &mut [u8]) {
    let w = s.w;
    let [l0, l1, l2, l3, l4, l5] = left.map(|p| &p[..w]);
    for (x, cell) in out.chunks_exact_mut(s.nd).enumerate().take(w) {
        // Right x for k = 0 is x − d_min, stored at m = w − 1 − x + d_min.
        let m = w - 1 - x + s.d_min;
        let runs = right.map(|p| &p[m..m + s.nd]);
        let b = [l0[x], l1[x], l2[x], l3[x], l4[x], l5[x]];
        hamming_runs(b, runs, cell);
        // Candidates k with x − d_min − k < 0 fall off the right image.
        let inside = (x + 1).saturating_sub(s.d_min).min(s.nd);
        cell[inside..].fill(CENSUS_BITS);
    }
}

/// `out[k]`: the Hamming distance between the signature whose bytes are `b` and the one
/// whose bytes are `runs[j][k]`. Byte population counts, which the compiler keeps in
/// vector lanes (a table lookup per nibble with AVX2).
#[inline(always)]
pub(super) fn hamming_runs(b: [u8; CENSUS_BYTES], runs: PlaneRow<'_>, out: &mut [u8]) {
    let n = out.len();
    let [r0, r1, r2, r3, r4, r5] = runs.map(|r| &r[..n]);
    // At most 48 ones: wrapping adds never wrap, and keep the loop free of overflow
    // checks in dev and test builds (which then ran it scalar).
    let ones = |a: u8, r: u8| (a ^ r).count_ones() as u8;
    for k in 0..n {
        out[k] = ones(b[0], r0[k])
            .wrapping_add(ones(b[1], r1[k]))
            .wrapping_add(ones(b[2], r2[k]))
            .wrapping_add(ones(b[3], r3[k]))
            .wrapping_add(ones(b[4], r4[k]))
            .wrapping_add(ones(b[5], r5[k]));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::sgm::tests::shifted_pair;

    /// The census planes against the definition: for every pixel of a view (left or
    /// right, each kernel), comparison `t` of the 48 (rows then columns of the 7×7
    /// window, the centre skipped; neighbours clamped to the image) in bit
    /// `8·(t / 8) + 7 − t % 8` of its signature.
    #[test]
    fn census_planes_hold_each_comparison() {
        // Rows narrower than the window too: every neighbour clamped.
        for (iw, ih) in [(37, 11), (5, 2), (2, 3), (1, 1)] {
            let (img, _) = shifted_pair(iw, ih, |x, y| 4.0 + 0.3 * x as f32 + 0.1 * y as f32);
            let (w, h) = (iw as isize, ih as isize);
            let at = |x: isize, y: isize| {
                img.get(x.clamp(0, w - 1) as usize, y.clamp(0, h - 1) as usize)
            };
            for kernel in Kernel::tested() {
                for view in [View::Left, View::Right { pad: 5 }] {
                    // A kept buffer of the right size with stale contents is overwritten.
                    let stale = vec![0xa5; ih * CENSUS_BYTES * (iw + 5)];
                    let kept = if view == View::Left {
                        Vec::new()
                    } else {
                        stale
                    };
                    let planes = census(kernel, &img, view, kept);
                    let mut ones = 0;
                    for y in 0..h {
                        for x in 0..w {
                            let mut want = 0u64;
                            let mut t = 0;
                            for dy in -3..=3 {
                                for dx in -3..=3 {
                                    if (dx, dy) == (0, 0) {
                                        continue;
                                    }
                                    if at(x + dx, y + dy) > at(x, y) {
                                        want |= 1 << (8 * (t / 8) + 7 - t % 8);
                                    }
                                    t += 1;
                                }
                            }
                            let got = planes.signature(x as usize, y as usize);
                            assert_eq!(got, want, "{iw}x{ih} {kernel:?} {view:?} ({x}, {y})");
                            ones += want.count_ones();
                        }
                    }
                    // Both answers occur: not a census of all zeros or all ones.
                    if iw * ih > 100 {
                        assert!(ones > 1000 && ones < 37 * 11 * 47, "{ones}");
                    }
                }
            }
        }
    }

    /// A census cost kernel agrees cell for cell with the portable one: rows of several
    /// widths and disparity counts, so the 64-byte lanes have tails.
    fn check_cost_kernel(
        name: &str,
        kernel: impl Fn(&Shape, PlaneRow<'_>, PlaneRow<'_>, &mut [u8]),
    ) {
        for (w, nd, d_min) in [(75, 16, 3), (130, 64, 0), (97, 48, 5)] {
            let (l, r) = shifted_pair(w, 9, |x, _| 4.0 + 0.05 * x as f32);
            let s = Shape { w, h: 9, nd, d_min };
            let (cl, cr) = (
                census(Kernel::Portable, &l, View::Left, Vec::new()),
                census(
                    Kernel::Portable,
                    &r,
                    View::Right { pad: nd + d_min },
                    Vec::new(),
                ),
            );
            for y in 0..s.h {
                let mut expected = vec![0; w * nd];
                costs(&s, cl.row(y), cr.row(y), &mut expected);
                let mut got = vec![0; w * nd];
                kernel(&s, cl.row(y), cr.row(y), &mut got);
                assert!(got == expected, "{name}, width {w}, {nd} d, row {y}");
                assert!(expected.iter().any(|&c| c > 0), "costs all zero");
            }
        }
    }

    /// The census costs of AVX2's nibble tables are the portable ones.
    #[test]
    #[cfg_attr(
        not(build_cpu_avx2_bmi),
        ignore = "needs AVX2 and BMI, which this machine lacks"
    )]
    #[allow(unsafe_code)]
    fn avx2_costs_are_the_portable_costs() {
        #[cfg(target_arch = "x86_64")]
        {
            assert!(
                crate::cpu::avx2_bmi(),
                "needs AVX2 and BMI: this CPU lacks them"
            );
            // SAFETY: the CPU has AVX2 and BMI (asserted above).
            check_cost_kernel("AVX2", |s, l, r, out| unsafe { costs_avx2(s, l, r, out) });
        }
        #[cfg(not(target_arch = "x86_64"))]
        panic!("no AVX2 kernel on this architecture");
    }

    /// The census costs of AVX-512's byte population count are the portable ones
    /// (whatever `STEREOTAC_NO_AVX512` says: it only keeps the pipeline off them).
    #[test]
    #[cfg_attr(
        not(build_cpu_avx512_popcnt),
        ignore = "needs AVX-512 BITALG, which this machine lacks"
    )]
    #[allow(unsafe_code)]
    fn avx512_costs_are_the_portable_costs() {
        #[cfg(target_arch = "x86_64")]
        {
            assert!(
                crate::cpu::has_avx512_popcnt(),
                "needs AVX-512 BITALG: this CPU lacks it"
            );
            // SAFETY: the CPU has AVX-512 F, BW, VL and BITALG (asserted above).
            check_cost_kernel("AVX-512", |s, l, r, out| unsafe {
                costs_avx512(s, l, r, out)
            });
        }
        #[cfg(not(target_arch = "x86_64"))]
        panic!("no AVX-512 kernel on this architecture");
    }
}
