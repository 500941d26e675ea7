//! Which vector instructions this CPU has. Builds target plain x86-64 so the binary runs
//! anywhere; the hot kernels of the tactile and stereo pipelines are compiled a second
//! time with AVX2 enabled and pick that copy at run time when the CPU has it (semi-global
//! matching's census costs a third time, with AVX-512's byte population count). The
//! checks are cached by the standard library, so asking per call is cheap.

/// AVX2: 256-bit integer and float lanes (the tactile block sums).
#[cfg(target_arch = "x86_64")]
pub fn avx2() -> bool {
    std::is_x86_feature_detected!("avx2")
}

/// AVX2: 256-bit integer and float lanes (the tactile block sums).
#[cfg(not(target_arch = "x86_64"))]
pub fn avx2() -> bool {
    false
}

/// AVX2 with fused multiply-add (the perceptron's layers).
#[cfg(target_arch = "x86_64")]
pub fn avx2_fma() -> bool {
    avx2() && std::is_x86_feature_detected!("fma")
}

/// AVX2 with fused multiply-add (never on other architectures).
#[cfg(not(target_arch = "x86_64"))]
pub fn avx2_fma() -> bool {
    false
}

/// AVX2 with the bit-manipulation and counting instructions the stereo matchers' census
/// and cost kernels use (BMI1/2, POPCNT, LZCNT).
#[cfg(target_arch = "x86_64")]
pub fn avx2_bmi() -> bool {
    avx2()
        && std::is_x86_feature_detected!("bmi1")
        && std::is_x86_feature_detected!("bmi2")
        && std::is_x86_feature_detected!("popcnt")
        && std::is_x86_feature_detected!("lzcnt")
}

/// AVX2 with BMI1/2, POPCNT and LZCNT (never on other architectures).
#[cfg(not(target_arch = "x86_64"))]
pub fn avx2_bmi() -> bool {
    false
}

/// AVX2 with BMI as [`avx2_bmi`], and AVX-512's byte population count (BITALG with
/// F, BW and VL): the census costs of semi-global matching take it when the CPU has it,
/// unless the environment sets `STEREOTAC_NO_AVX512` (to any value, even 0 or empty:
/// to compare, or where AVX-512 slows the clock), read once.
#[cfg(target_arch = "x86_64")]
pub fn avx512_popcnt() -> bool {
    static USE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *USE.get_or_init(|| std::env::var_os("STEREOTAC_NO_AVX512").is_none() && has_avx512_popcnt())
}

/// Whether the CPU has what [`avx512_popcnt`] asks for, whatever the environment says.
#[cfg(target_arch = "x86_64")]
pub fn has_avx512_popcnt() -> bool {
    avx2_bmi()
        && std::is_x86_feature_detected!("avx512f")
        && std::is_x86_feature_detected!("avx512bw")
        && std::is_x86_feature_detected!("avx512vl")
        && std::is_x86_feature_detected!("avx512bitalg")
}

/// Never on other architectures.
#[cfg(not(target_arch = "x86_64"))]
pub fn avx512_popcnt() -> bool {
    false
}

/// Asks the CPU to bring the cache line holding `bytes[at]` into its caches ahead of use
/// (nothing when `at` is past the end, or on other architectures). A kernel that streams
/// a frame written by another core or long ago computes too slowly per byte for the
/// hardware's own prefetching to keep ahead: detection on a skin at rest took 0.24 ms on
/// such frames and 0.115 ms on the same frames read once before.
#[inline(always)]
#[allow(unsafe_code)]
pub fn prefetch(bytes: &[u8], at: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(byte) = bytes.get(at) {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: SSE is part of x86-64, and a prefetch reads nothing the program sees
        // (it cannot fault); the address is a byte of a live slice anyway.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(std::ptr::from_ref(byte).cast()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (bytes, at);
}

#[cfg(test)]
mod tests {
    #[test]
    fn prefetch_past_the_end_or_of_nothing_is_harmless() {
        let bytes = [1u8, 2, 3];
        for at in [0, 2, 3, usize::MAX] {
            super::prefetch(&bytes, at);
        }
        super::prefetch(&[], 0);
        assert_eq!(bytes, [1, 2, 3]);
    }
}
