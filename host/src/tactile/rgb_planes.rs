//! Interleaved 8-bit RGB pixels into three `f32` planes: the first step of reading a
//! run of touched pixels' colours ([`super::features`]). One byte at a time the loads
//! and inserts were about a third of the colour stage; in AVX2, eight pixels are two
//! loads, six byte shuffles and three widening conversions. Every value is exact either
//! way (a byte is a whole number an `f32` holds), so both give the same planes.

/// Splits `raw` (`[r, g, b, r, g, b, …]`) into `r`, `g` and `b`, as many pixels as the
/// shortest of them holds; the rest of the planes is left as it was.
#[allow(unsafe_code)]
pub fn deinterleave(raw: &[u8], r: &mut [f32], g: &mut [f32], b: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::avx2() {
        // SAFETY: `deinterleave_avx2` only needs AVX2, detected just above.
        return unsafe { deinterleave_avx2(raw, r, g, b) };
    }
    deinterleave_portable(raw, r, g, b);
}

/// [`deinterleave`] one pixel at a time.
fn deinterleave_portable(raw: &[u8], r: &mut [f32], g: &mut [f32], b: &mut [f32]) {
    let pixels = raw
        .chunks_exact(3)
        .zip(r.iter_mut().zip(g.iter_mut()).zip(b.iter_mut()));
    for (px, ((r, g), b)) in pixels {
        (*r, *g, *b) = (f32::from(px[0]), f32::from(px[1]), f32::from(px[2]));
    }
}

/// [`deinterleave`] eight pixels (24 bytes) at a time: bytes 0–15 hold pixels 0–4 and
/// bytes 8–23 pixels 3–7, so two 16-byte loads that stay inside the eight pixels give
/// every channel's eight bytes through one shuffle of each and an OR.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
fn deinterleave_avx2(raw: &[u8], r: &mut [f32], g: &mut [f32], b: &mut [f32]) {
    use std::arch::x86_64::*;
    let n = (raw.len() / 3).min(r.len()).min(g.len()).min(b.len());
    // For channel `c`: bytes `c, c + 3, …` of the low load (pixels 0–4, those whose byte
    // lies in 0–15) and of the high load (its byte `j` is byte `8 + j` of the pixels),
    // the rest zeroed (-1 is 0x80: the shuffle writes 0 there).
    let shuffles = |c: i8| {
        let mut low = [-1i8; 16];
        let mut high = [-1i8; 16];
        for px in 0..8i8 {
            let byte = 3 * px + c;
            if byte < 16 {
                low[px as usize] = byte;
            } else {
                high[px as usize] = byte - 8;
            }
        }
        // SAFETY: both arrays are 16 bytes, read unaligned.
        unsafe {
            (
                _mm_loadu_si128(low.as_ptr().cast()),
                _mm_loadu_si128(high.as_ptr().cast()),
            )
        }
    };
    let channels = [shuffles(0), shuffles(1), shuffles(2)];
    let mut i = 0;
    while i + 8 <= n {
        // SAFETY: pixels i..i + 8 lie in `raw` (bytes 3i..3i + 24, the loads read
        // 3i..3i + 16 and 3i + 8..3i + 24) and in every plane (i + 8 <= n).
        unsafe {
            let at = raw.as_ptr().add(3 * i);
            let low = _mm_loadu_si128(at.cast());
            let high = _mm_loadu_si128(at.add(8).cast());
            for (plane, (s_low, s_high)) in [&mut *r, &mut *g, &mut *b].into_iter().zip(channels) {
                let bytes =
                    _mm_or_si128(_mm_shuffle_epi8(low, s_low), _mm_shuffle_epi8(high, s_high));
                let values = _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(bytes));
                _mm256_storeu_ps(plane.as_mut_ptr().add(i), values);
            }
        }
        i += 8;
    }
    // The last pixels (fewer than eight) one at a time; `i <= n` lies in every slice.
    deinterleave_portable(&raw[3 * i..], &mut r[i..], &mut g[i..], &mut b[i..]);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every length from 0 to 40 pixels, from every start in a row of bytes that takes
    /// every value: the planes are the pixels' bytes, and nothing past them is written.
    #[test]
    fn planes_hold_each_pixels_bytes_at_every_length_and_offset() {
        let bytes: Vec<u8> = (0..200u32).map(|k| (k * 97 + 13) as u8).collect();
        let mut every = bytes.clone();
        every.extend(0..=255u8);
        for start in 0..3 {
            for n in 0..=40usize {
                let raw = &bytes[start..start + 3 * n];
                let mut planes = [vec![-1.0f32; n + 3], vec![-1.0; n + 3], vec![-1.0; n + 3]];
                let [r, g, b] = &mut planes;
                deinterleave(raw, &mut r[..n], &mut g[..n], b);
                for (c, plane) in planes.iter().enumerate() {
                    for (k, &v) in plane.iter().enumerate() {
                        let want = if k < n {
                            f32::from(raw[3 * k + c])
                        } else {
                            -1.0
                        };
                        assert_eq!(v, want, "start {start}, {n} pixels, channel {c}, pixel {k}");
                    }
                }
            }
        }
        // Every byte value, through the lanes.
        let n = every.len() / 3;
        let mut planes = [vec![0.0f32; n], vec![0.0; n], vec![0.0; n]];
        let [r, g, b] = &mut planes;
        deinterleave(&every, r, g, b);
        for k in 0..n {
            for (c, plane) in planes.iter().enumerate() {
                assert_eq!(plane[k], f32::from(every[3 * k + c]));
            }
        }
        // Planes shorter than the pixels: only what they hold is written.
        let (mut r, mut g, mut b) = (vec![0.0f32; 9], vec![0.0f32; 5], vec![0.0f32; 9]);
        deinterleave(&bytes[..30], &mut r, &mut g, &mut b);
        assert_eq!(
            g,
            bytes[..15]
                .chunks(3)
                .map(|p| f32::from(p[1]))
                .collect::<Vec<_>>()
        );
        assert_eq!(r[4], f32::from(bytes[12]));
        assert_eq!(r[5], 0.0, "past the shortest plane");
    }
}
