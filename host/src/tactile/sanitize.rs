//! Slope sanitising before integration: one NaN or infinity makes a Poisson solve's whole
//! output non-finite, and one huge spike bends the surface hundreds of pixels away. Both
//! are cut here: non-finite slopes become 0 (no information) and the rest are clamped to
//! the steepest slope the sensor can report.

/// Default bound on `|slope|`: beyond ~3 (72°) photometric stereo has no signal left.
pub const DEFAULT_MAX_SLOPE: f32 = 3.0;

/// What [`sanitize`] changed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SanitizeReport {
    /// NaN or infinite values replaced by 0.
    pub non_finite: usize,
    /// Values clamped to ±max.
    pub clamped: usize,
}

/// Replaces non-finite slopes by 0 and clamps the rest to `±max_slope`. Branch-free, so
/// it runs in vector lanes (AVX2 when the CPU has it).
#[allow(unsafe_code)]
pub fn sanitize(slopes: &mut [f32], max_slope: f32) -> SanitizeReport {
    let mut report = SanitizeReport::default();
    // 32-bit counts fill twice the lanes of 64-bit ones; a chunk cannot overflow them.
    for chunk in slopes.chunks_mut(1 << 24) {
        #[cfg(target_arch = "x86_64")]
        let [non_finite, clamped] = if crate::cpu::avx2() {
            // SAFETY: `sanitize_avx2` only needs AVX2, detected just above.
            unsafe { sanitize_avx2(chunk, max_slope) }
        } else {
            sanitize_portable(chunk, max_slope)
        };
        #[cfg(not(target_arch = "x86_64"))]
        let [non_finite, clamped] = sanitize_portable(chunk, max_slope);
        report.non_finite += non_finite as usize;
        report.clamped += clamped as usize;
    }
    report
}

/// [`sanitize_portable`] in 8-wide lanes (comparisons and selects: the same values).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn sanitize_avx2(slopes: &mut [f32], max_slope: f32) -> [u32; 2] {
    sanitize_portable(slopes, max_slope)
}

/// Counts of non-finite and clamped slopes of at most `u32::MAX` slopes.
#[inline(always)]
fn sanitize_portable(slopes: &mut [f32], max_slope: f32) -> [u32; 2] {
    let (mut non_finite, mut clamped) = (0u32, 0u32);
    for v in slopes {
        let finite = v.is_finite();
        let steep = v.abs() > max_slope;
        non_finite += u32::from(!finite);
        clamped += u32::from(finite & steep);
        let bounded = if steep { max_slope.copysign(*v) } else { *v };
        *v = if finite { bounded } else { 0.0 };
    }
    [non_finite, clamped]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_and_clamps() {
        let mut v = [
            0.5,
            f32::NAN,
            f32::INFINITY,
            -1e3,
            2.0,
            f32::NEG_INFINITY,
            -0.25,
        ];
        let r = sanitize(&mut v, 1.0);
        assert_eq!(v, [0.5, 0.0, 0.0, -1.0, 1.0, 0.0, -0.25]);
        assert_eq!(
            r,
            SanitizeReport {
                non_finite: 3,
                clamped: 2
            }
        );
    }

    /// In lanes as one value at a time: every lane and the tail, values at the bound,
    /// signed zeros and infinities.
    #[test]
    fn lanes_give_the_values_and_counts_of_one_at_a_time() {
        let special = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            f32::NAN,
            f32::INFINITY,
            -7.5,
            1.0 + 1e-7,
        ];
        let mut rng = crate::rng::Rng::new(5);
        for n in [0usize, 3, 8, 13, 100] {
            let v: Vec<f32> = (0..n)
                .map(|k| {
                    if k % 3 == 0 {
                        special[k / 3 % special.len()]
                    } else {
                        rng.range(-2.0, 2.0) as f32
                    }
                })
                .collect();
            let (mut want, mut counts) = (v.clone(), SanitizeReport::default());
            for w in &mut want {
                if !w.is_finite() {
                    *w = 0.0;
                    counts.non_finite += 1;
                } else if w.abs() > 1.0 {
                    *w = 1.0f32.copysign(*w);
                    counts.clamped += 1;
                }
            }
            let mut got = v.clone();
            assert_eq!(sanitize(&mut got, 1.0), counts, "{n} values");
            let bits = |x: &[f32]| x.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&want), "{n} values");
        }
    }
}
