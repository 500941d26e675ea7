//! Selection: each pixel's disparity from its aggregated costs (winner takes all with a
//! uniqueness ratio, sub-pixel fit, left–right check), the cost and its index packed
//! into one integer so a row's minima are vector lanes ([`Packing`]).

use super::census::CENSUS_BITS;
use super::params::{SgmParams, Shape};
use super::sweep::fits_a_byte;
use crate::stereo::block_match::{Kernel, MatchStats, subpixel_offset};

/// Selects a row's disparities (`out`, which comes in all NaN: a row selected again is
/// reset to that) from its sums (`sum`, plus `other` when the paths were summed in two
/// volumes), packed as [`Packing::of`] says.
#[allow(unsafe_code)]
pub(super) fn run_select(
    kernel: Kernel,
    s: &Shape,
    p: &SgmParams,
    sum: &[u16],
    other: Option<&[u16]>,
    out: &mut [f32],
) -> MatchStats {
    let wide = |out: &mut [f32]| {
        select_with::<u32>(kernel, s, p, sum, other, out, 16)
            .expect("32-bit packing holds every sum (at most 8 · (48 + 1024))")
    };
    match Packing::of(s, p) {
        Packing::Narrow(shift) => {
            select_with::<u16>(kernel, s, p, sum, other, out, shift).unwrap_or_else(|| {
                // A clamped cost decided somewhere in the row: again, exactly.
                out.fill(f32::NAN);
                wide(out)
            })
        }
        Packing::Wide => wide(out),
    }
}

#[allow(unsafe_code)]
#[inline(always)]
pub(super) fn select_with<P: Packed>(
    kernel: Kernel,
    s: &Shape,
    p: &SgmParams,
    sum: &[u16],
    other: Option<&[u16]>,
    out: &mut [f32],
    shift: u32,
) -> Option<MatchStats> {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: AVX2, BMI1/2, POPCNT and LZCNT were detected just above.
        return unsafe { select_avx2::<P>(s, p, sum, other, out, shift) };
    }
    let _ = kernel;
    select::<P>(s, p, sum, other, out, shift)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
pub(super) fn select_avx2<P: Packed>(
    s: &Shape,
    p: &SgmParams,
    sum: &[u16],
    other: Option<&[u16]>,
    out: &mut [f32],
    shift: u32,
) -> Option<MatchStats> {
    select::<P>(s, p, sum, other, out, shift)
}

/// How [`select`] packs a candidate's aggregated cost and index into one integer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Packing {
    /// `cost << shift | k` in 16 bits (twice the lanes), costs above `u16::MAX >> shift`
    /// clamped to it. A row where a clamped cost would decide (a pixel's least cost) is
    /// selected again, wide: every result is the wide one. (A right column's best match
    /// in the left–right check is then never clamped: its candidates include the best
    /// of the pixel that reads it.)
    Narrow(u32),
    /// `cost << 16 | k` in 32 bits.
    Wide,
}

impl Packing {
    /// Narrow when the largest sum (every path at its bound, `CENSUS_BITS + p2`) shifted
    /// past the largest index fits 16 bits, or, with byte lanes ([`fits_a_byte`]: `p2`
    /// at most 103), when the clamp is at least twice the largest census cost summed
    /// over the paths (a least cost that high is a pixel matched nowhere: rare enough
    /// that a second selection costs nothing; with larger penalties paths from opposite
    /// sides of an occlusion could each carry hundreds at every candidate). At the
    /// default penalties: 3, 4 and 5 paths up to 128 disparities, 8 paths up to 64.
    pub(super) fn of(s: &Shape, p: &SgmParams) -> Self {
        let shift = usize::BITS - (s.nd - 1).leading_zeros();
        let paths = p.paths.count() as u64;
        let largest_sum = paths * (u64::from(CENSUS_BITS) + u64::from(p.p2));
        let clamp = u64::from(u16::MAX) >> shift;
        let rare = fits_a_byte(p) && clamp >= 2 * paths * u64::from(CENSUS_BITS);
        if largest_sum <= clamp || rare {
            Packing::Narrow(shift)
        } else {
            Packing::Wide
        }
    }
}

/// A candidate's aggregated cost and index `k` in one integer, the cost in the high
/// bits: the smallest is the least cost at its smallest `k`.
pub(super) trait Packed: Copy + Ord {
    /// No smaller than any packed candidate.
    const MAX: Self;
    /// The largest cost a packing holds: larger ones are clamped to it.
    fn largest_cost(shift: u32) -> u16;
    fn pack(cost: u16, k: u16, shift: u32) -> Self;
    fn cost(self, shift: u32) -> u16;
    fn index(self, shift: u32) -> usize;
}

impl Packed for u16 {
    const MAX: Self = u16::MAX;
    #[inline(always)]
    fn largest_cost(shift: u32) -> u16 {
        u16::MAX >> shift
    }
    #[inline(always)]
    fn pack(cost: u16, k: u16, shift: u32) -> Self {
        (cost.min(Self::largest_cost(shift)) << shift) | k
    }
    #[inline(always)]
    fn cost(self, shift: u32) -> u16 {
        self >> shift
    }
    #[inline(always)]
    fn index(self, shift: u32) -> usize {
        usize::from(self & ((1 << shift) - 1))
    }
}

impl Packed for u32 {
    const MAX: Self = u32::MAX;
    #[inline(always)]
    fn largest_cost(_: u32) -> u16 {
        u16::MAX
    }
    #[inline(always)]
    fn pack(cost: u16, k: u16, shift: u32) -> Self {
        (u32::from(cost) << shift) | u32::from(k)
    }
    #[inline(always)]
    fn cost(self, shift: u32) -> u16 {
        (self >> shift) as u16
    }
    #[inline(always)]
    fn index(self, shift: u32) -> usize {
        (self & ((1 << shift) - 1)) as usize
    }
}

/// One row's disparities from its aggregated sums (`sum`, plus `other` when the paths
/// were summed in two volumes): winner takes all, uniqueness, sub-pixel fit, left–right
/// check. Candidates are packed as `P` with the index in the low `shift` bits; `None`
/// (with `out` part written) where a clamped cost would decide ([`Packing::Narrow`]).
#[inline(always)]
pub(super) fn select<P: Packed>(
    s: &Shape,
    p: &SgmParams,
    sum: &[u16],
    other: Option<&[u16]>,
    out: &mut [f32],
    shift: u32,
) -> Option<MatchStats> {
    let clamp = P::largest_cost(shift);
    let (w, nd) = (s.w, s.nd);
    let mut stats = MatchStats::default();
    let mut total = vec![0u16; nd];
    let mut packed = vec![P::MAX; nd];
    let index: Vec<u16> = (0..nd as u16).collect();
    // The right image's best match per column, packed so one `min` keeps both (ties:
    // the smaller k), stored by `j = w − 1 − right column`: the candidates k of left
    // column x are then the contiguous run `j = w − 1 − x + d_min + k`.
    let check = p.lr_max_diff.is_some();
    let mut right = vec![P::MAX; w];
    let d_max = s.d_min + nd - 1;
    let mut best_k = vec![u16::MAX; w];
    for x in 0..w {
        let a = &sum[x * nd..][..nd];
        let cell: &[u16] = match other {
            Some(other) => {
                let b = &other[x * nd..][..nd];
                for ((t, &a), &b) in total.iter_mut().zip(a).zip(b) {
                    *t = a + b;
                }
                &total
            }
            None => a,
        };
        // The best candidate comes with the packing: the smallest packed value is the
        // least cost at its smallest k.
        let mut least = P::MAX;
        for ((q, &t), &k) in packed.iter_mut().zip(cell).zip(&index) {
            *q = P::pack(t, k, shift);
            least = least.min(*q);
        }
        if check && x >= s.d_min {
            // Candidates whose right column is inside the image.
            let n = (x - s.d_min).min(nd - 1) + 1;
            let j = w - 1 - (x - s.d_min);
            for (r, &q) in right[j..j + n].iter_mut().zip(&packed[..n]) {
                *r = (*r).min(q);
            }
        }
        if x < d_max {
            continue; // candidates off the right image: the invalid band
        }
        let (best, k) = (least.cost(shift), least.index(shift));
        if best == clamp {
            return None;
        }
        // Not unique: another candidate, not next to the best, within the ratio. A best
        // cost of 0 tied elsewhere counts as not unique (OpenCV's strict test keeps it).
        let limit = (u32::from(best) * 100).saturating_sub(1) / (100 - p.uniqueness_ratio);
        let t = limit.min(u32::from(u16::MAX)) as u16;
        // Counted in 16-bit lanes (a `count()` widens every lane to 64 bits); at most
        // `nd` candidates, and `nd` fits 16 bits.
        let within = cell.iter().fold(0u16, |n, &c| n + u16::from(c <= t));
        let near = (k.saturating_sub(1)..=(k + 1).min(nd - 1))
            .filter(|&i| cell[i] <= t)
            .count();
        if k == 0 || k == nd - 1 {
            stats.range_edge += 1;
            continue;
        }
        if usize::from(within) > near {
            stats.not_unique += 1;
            continue;
        }
        best_k[x] = k as u16;
        let offset = subpixel_offset(p.subpixel, cell[k - 1], best, cell[k + 1]);
        out[x] = (s.d_min + k) as f32 + offset;
    }
    if let Some(max_diff) = p.lr_max_diff {
        for x in d_max..w {
            let k = best_k[x];
            if k == u16::MAX {
                continue;
            }
            let xr = x - s.d_min - usize::from(k);
            let from_right = right[w - 1 - xr];
            // That right column's candidates include this pixel's best, whose cost is
            // below the clamp: so is the column's best.
            debug_assert!(from_right.cost(shift) < clamp);
            let right_k = from_right.index(shift);
            if right_k.abs_diff(usize::from(k)) > max_diff as usize {
                out[x] = f32::NAN;
                stats.left_right += 1;
            }
        }
    }
    Some(stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::sgm::Paths;

    /// Selection packs candidates in 16 bits where every sum and index fit (3, 4 and 5
    /// paths at the default penalties and 64 disparities), or where the costs clamped
    /// at 1023 or 511 rarely decide (8 paths at 64, 5 at 128; a row where one does is
    /// selected again in 32 bits), and in 32 otherwise; all give the same disparities
    /// and counts, bit for bit, on sums up to the bound (ties included: sums drawn from
    /// a few values), from one sum volume or two, with each kernel.
    #[test]
    fn narrow_and_wide_packing_select_the_same() {
        let shape = |nd| Shape {
            w: 200,
            h: 1,
            nd,
            d_min: 2,
        };
        let at = |paths, nd: usize| SgmParams {
            paths,
            num_disparities: nd as u32,
            ..SgmParams::default()
        };
        assert_eq!(
            Packing::of(&shape(64), &at(Paths::Three, 64)),
            Packing::Narrow(6)
        );
        assert_eq!(
            Packing::of(&shape(64), &at(Paths::Five, 64)),
            Packing::Narrow(6)
        );
        // Clamped at 1023 and 511: a second selection where that decides.
        assert_eq!(
            Packing::of(&shape(64), &at(Paths::Eight, 64)),
            Packing::Narrow(6)
        );
        assert_eq!(
            Packing::of(&shape(128), &at(Paths::Five, 128)),
            Packing::Narrow(7)
        );
        assert_eq!(
            Packing::of(&shape(128), &at(Paths::Eight, 128)),
            Packing::Wide
        );
        // Not with 16-bit path costs (p2 over 103).
        let large_p2 = SgmParams {
            p2: 104,
            ..at(Paths::Eight, 64)
        };
        assert_eq!(Packing::of(&shape(64), &large_p2), Packing::Wide);
        assert_eq!(
            Packing::of(&shape(32), &at(Paths::Eight, 32)),
            Packing::Narrow(5)
        );
        let mut rng = crate::rng::Rng::new(11);
        let narrow = [
            (Paths::Three, 64),
            (Paths::Four, 64),
            (Paths::Five, 64),
            (Paths::Three, 48),
            (Paths::Eight, 32),
            (Paths::Eight, 64),
            (Paths::Five, 128),
        ];
        for (paths, nd) in narrow {
            let (s, p) = (shape(nd), at(paths, nd));
            let Packing::Narrow(shift) = Packing::of(&s, &p) else {
                panic!("{paths:?} {nd}: narrow expected");
            };
            let largest = paths.count() as u16 * (u16::from(CENSUS_BITS) + p.p2);
            let clamped = largest > u16::MAX >> shift;
            let mut draw = |n: u64| (rng.next_u64() % n) as u16;
            let mut valid = 0;
            let mut again = 0;
            for round in 0..50 {
                // Each pixel: a clear minimum at a random candidate over costs from the
                // top half; in odd rounds the costs take few values (ties), and every
                // fourth pixel's minimum is tied with another candidate. Where the
                // packing clamps, every tenth round has one pixel whose least cost is
                // clamped.
                let mut sum = vec![0u16; s.w * nd];
                for cell in sum.chunks_exact_mut(nd) {
                    for c in cell.iter_mut() {
                        *c = if round % 2 == 1 {
                            largest - 50 * draw(4)
                        } else {
                            largest / 2 + draw(u64::from(largest / 2) + 1)
                        };
                    }
                    let k = usize::from(draw(nd as u64));
                    cell[k] = draw(u64::from(largest / 4));
                    if draw(4) == 0 {
                        cell[usize::from(draw(nd as u64))] = cell[k];
                    }
                }
                if clamped && round % 10 == 0 {
                    let x = s.w - 1 - usize::from(draw(4));
                    sum[x * nd..][..nd].fill(largest - 1);
                }
                let mut narrow = vec![f32::NAN; s.w];
                let mut wide = vec![f32::NAN; s.w];
                if select::<u16>(&s, &p, &sum, None, &mut narrow, shift).is_none() {
                    again += 1;
                }
                let b = select::<u32>(&s, &p, &sum, None, &mut wide, 16).unwrap();
                // The sums whole, and split in two volumes (as two sweeps leave them).
                let first: Vec<u16> = sum.iter().map(|&v| v / 3).collect();
                let second: Vec<u16> = sum.iter().zip(&first).map(|(v, f)| v - f).collect();
                for kernel in Kernel::tested() {
                    for split in [false, true] {
                        narrow.fill(f32::NAN);
                        let a = if split {
                            run_select(kernel, &s, &p, &first, Some(&second), &mut narrow)
                        } else {
                            run_select(kernel, &s, &p, &sum, None, &mut narrow)
                        };
                        let case = format!("{paths:?} {nd} round {round} {kernel:?} {split}");
                        assert_eq!(a, b, "{case}");
                        let same = narrow
                            .iter()
                            .zip(&wide)
                            .all(|(x, y)| x.to_bits() == y.to_bits());
                        assert!(same, "{case}");
                    }
                }
                valid += narrow.iter().filter(|v| v.is_finite()).count();
            }
            // The comparison covers chosen disparities, not only refusals, and the
            // second selection where the packing clamps (not only there).
            assert!(valid > 50 * (s.w - nd) / 4, "{paths:?} {nd}: {valid}");
            if clamped {
                assert!((5..50).contains(&again), "{paths:?} {nd}: {again} again");
            } else {
                assert_eq!(again, 0, "{paths:?} {nd}");
            }
        }
    }
}
