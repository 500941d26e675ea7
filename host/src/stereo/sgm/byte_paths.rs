//! Several aggregation paths of one pixel in one run over its disparities, in byte
//! lanes with AVX2 intrinsics.
//!
//! The portable step ([`super::step`]) is the definition. Compiled for AVX2, the
//! compiler runs it 16 lanes at a time, one path after another, and reads, widens and
//! writes the pixel's 16-bit sums once per path. Here the paths of a pixel (the one along
//! the row and those from the row before: up to four) take 32 disparities at a time, and
//! their sum stays in registers until it is written once. With it, 8-path matching at
//! 640×480 and 64 disparities went from about 46 to 32–33 ms on one core (a scratch
//! probe, the least of 60 frames), 5 paths from 31 to 24; inlined into the sweep
//! instead of called per pixel, 8 paths about 33 → 30.
//!
//! Only byte lanes (every path cost fits a byte: [`super::fits_a_byte`]) and disparity
//! counts that are multiples of 32; the sweeps use the portable steps elsewhere, and at
//! the pixels where a path starts.

use std::arch::x86_64::*;

/// A path's values at the pixel it comes from, padded as a `PathRow`'s (`d` at index
/// `d + 1`, padding either side), and their minimum over every `d`.
pub(super) type Source<'a> = (&'a [u8], u8);

/// Steps `N` paths of one pixel from its census costs `cost` (`nd` of them, a multiple
/// of 32): path `r` from `from[r]` into `out[r]`, with the formula of
/// [`super::step`], bit for bit. The sum of the `N` new path costs is written into `sum`
/// (added to it with `ADD`). Returns each path's minimum.
///
/// Every value of a source is at least its minimum (padding included), so
/// `min(L', L'± + p1, min L' + p2) − min L'` equals `min(min(L', L'± + p1) − min L', p2)`:
/// only the minimum is broadcast per path, and no intermediate leaves a byte.
///
/// # Safety
/// The CPU has AVX2. Inlined into its callers (which enable AVX2) so the intrinsics
/// are too; a target-feature function is a call per pixel.
#[inline(always)]
#[allow(unsafe_code)]
pub(super) unsafe fn step_paths<const N: usize, const ADD: bool>(
    cost: &[u8],
    from: [Source<'_>; N],
    p1: u8,
    p2: u8,
    out: [&mut [u8]; N],
    sum: &mut [u16],
) -> [u8; N] {
    let nd = cost.len();
    assert!(nd.is_multiple_of(32) && sum.len() == nd, "{nd} disparities");
    for r in 0..N {
        assert!(from[r].0.len() >= nd + 2 && out[r].len() == nd);
    }
    // SAFETY: AVX2, by this function's contract. In the loop, k + 32 <= nd bounds the
    // loads of `cost` and the stores of `out[r]` and `sum`; a source's loads end at
    // k + 2 + 32 <= nd + 2 (asserted above).
    unsafe {
        let p1 = _mm256_set1_epi8(p1 as i8);
        let p2 = _mm256_set1_epi8(p2 as i8);
        let prev_min = from.map(|(_, m)| _mm256_set1_epi8(m as i8));
        let mut least = [_mm256_set1_epi8(-1); N];
        let mut k = 0;
        while k < nd {
            let c = _mm256_loadu_si256(cost.as_ptr().add(k).cast());
            let mut lo = _mm256_setzero_si256();
            let mut hi = _mm256_setzero_si256();
            for r in 0..N {
                let p = from[r].0.as_ptr().add(k);
                let below = _mm256_loadu_si256(p.cast());
                let here = _mm256_loadu_si256(p.add(1).cast());
                let above = _mm256_loadu_si256(p.add(2).cast());
                let step = _mm256_adds_epu8(_mm256_min_epu8(below, above), p1);
                let best = _mm256_min_epu8(here, step);
                let rise = _mm256_min_epu8(_mm256_subs_epu8(best, prev_min[r]), p2);
                let l = _mm256_add_epi8(c, rise);
                _mm256_storeu_si256(out[r].as_mut_ptr().add(k).cast(), l);
                least[r] = _mm256_min_epu8(least[r], l);
                lo = _mm256_add_epi16(lo, _mm256_cvtepu8_epi16(_mm256_castsi256_si128(l)));
                hi = _mm256_add_epi16(hi, _mm256_cvtepu8_epi16(_mm256_extracti128_si256(l, 1)));
            }
            let s = sum.as_mut_ptr().add(k);
            if ADD {
                lo = _mm256_add_epi16(lo, _mm256_loadu_si256(s.cast()));
                hi = _mm256_add_epi16(hi, _mm256_loadu_si256(s.add(16).cast()));
            }
            _mm256_storeu_si256(s.cast(), lo);
            _mm256_storeu_si256(s.add(16).cast(), hi);
            k += 32;
        }
        least.map(|v| min_byte(v))
    }
}

/// The least of 32 bytes.
///
/// # Safety
/// As [`step_paths`].
#[inline(always)]
#[allow(unsafe_code)]
unsafe fn min_byte(v: __m256i) -> u8 {
    // SAFETY: AVX2 (and so SSE4.1), by this function's contract.
    unsafe {
        let m = _mm_min_epu8(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
        // Each 16-bit lane's low byte becomes the least of its two bytes, its high byte 0.
        let m = _mm_min_epu8(m, _mm_srli_epi16(m, 8));
        (_mm_cvtsi128_si32(_mm_minpos_epu16(m)) & 0xff) as u8
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use crate::stereo::sgm::sweep::{Lane, Penalties, step};

    /// Every path and sum equals the portable step's, at 32 and 64 disparities, with
    /// values at the byte bound, padding beside them, and sums added to or written.
    #[test]
    #[cfg_attr(not(build_cpu_avx2), ignore = "needs AVX2, which this machine lacks")]
    #[allow(unsafe_code)]
    fn paths_equal_the_portable_step() {
        assert!(crate::cpu::avx2(), "needs AVX2: this CPU has none");
        let mut rng = Rng::new(11);
        for (p1, p2) in [(8u8, 96u8), (30, 103), (1, 2)] {
            let pen = Penalties { p1, p2 };
            for nd in [32, 64] {
                for round in 0..100 {
                    let high = 48 + p2;
                    let source = |rng: &mut Rng| {
                        let mut v = vec![<u8 as Lane>::PAD; nd + 2];
                        for x in &mut v[1..=nd] {
                            *x = match rng.uniform() {
                                u if u < 0.2 => high,
                                u if u < 0.4 => 0,
                                u => (u * f64::from(high)) as u8,
                            };
                        }
                        let min = v[1..=nd].iter().copied().min().unwrap();
                        (v, min)
                    };
                    let sources: Vec<(Vec<u8>, u8)> = (0..4).map(|_| source(&mut rng)).collect();
                    let cost: Vec<u8> = (0..nd).map(|_| (rng.uniform() * 49.0) as u8).collect();
                    let start: Vec<u16> = (0..nd).map(|k| (round * 7 + k) as u16).collect();
                    // The portable steps: the first path writes the sums (or adds), the
                    // others add.
                    let mut want_out = vec![vec![0u8; nd]; 4];
                    let mut want_sum = start.clone();
                    let mut want_min = [0u8; 4];
                    for r in 0..4 {
                        let step = if r == 0 && round % 2 == 0 {
                            step::<u8, true>
                        } else {
                            step::<u8, false>
                        };
                        let (prev, min) = (&sources[r].0, sources[r].1);
                        want_min[r] = step(&cost, prev, min, pen, &mut want_out[r], &mut want_sum);
                    }
                    let mut got_out = vec![vec![0u8; nd]; 4];
                    let mut got_sum = start.clone();
                    let from: [Source<'_>; 4] =
                        std::array::from_fn(|r| (&sources[r].0[..], sources[r].1));
                    let [a, b, c, d] = &mut got_out[..] else {
                        unreachable!()
                    };
                    let out = [&mut a[..], &mut b[..], &mut c[..], &mut d[..]];
                    // SAFETY: AVX2 was detected above.
                    let got_min = unsafe {
                        if round % 2 == 0 {
                            step_paths::<4, false>(&cost, from, p1, p2, out, &mut got_sum)
                        } else {
                            step_paths::<4, true>(&cost, from, p1, p2, out, &mut got_sum)
                        }
                    };
                    assert_eq!(got_min, want_min, "p2 {p2}, {nd} d, round {round}");
                    assert_eq!(got_out, want_out, "p2 {p2}, {nd} d, round {round}");
                    assert_eq!(got_sum, want_sum, "p2 {p2}, {nd} d, round {round}");
                }
            }
        }
    }
}
