//! Local means of the phase images. A single pixel's colour is too noisy to say whether
//! the skin is touched (a cheap camera's shot noise and MJPG chroma noise reach several
//! percent per channel); the mean over a small neighbourhood is not. Detection works on
//! the means of `step × step` blocks ([`BlockMeans`], one read of each pixel, integer
//! sums); calibration finds press outlines on box means around every pixel
//! ([`box_means`]).

use image::RgbImage;

/// Mean RGB of each `step × step` block of an image (partial blocks at the right and
/// bottom edges average the pixels they have), one plane per channel so loops over the
/// blocks run in vector lanes.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockMeans {
    /// Block size (px).
    pub step: usize,
    /// Blocks across.
    pub width: usize,
    /// Blocks down.
    pub height: usize,
    /// Mean red per block, row by row.
    pub red: Vec<f32>,
    /// Mean green per block.
    pub green: Vec<f32>,
    /// Mean blue per block.
    pub blue: Vec<f32>,
    /// Per block, how many of its pixel columns' channels reach 255 in some row
    /// (clipped: the light there is unknown); 0 when nothing is clipped.
    pub clipped: Vec<u32>,
}

impl BlockMeans {
    /// No blocks yet, with room for `width × height` of `step` px.
    fn with_room(step: usize, width: usize, height: usize) -> Self {
        let n = width * height;
        Self {
            step,
            width,
            height,
            red: Vec::with_capacity(n),
            green: Vec::with_capacity(n),
            blue: Vec::with_capacity(n),
            clipped: Vec::with_capacity(n),
        }
    }

    /// Block means of `image`. For the default step of 4 on a CPU with AVX2, each band
    /// of four rows is summed block by block straight from its bytes
    /// ([`sum_clean_band`]); otherwise, and in a band with a clipped value, the rows of a
    /// block are first summed channel by channel ([`sum_rows`]), then the columns of
    /// every block at once ([`sum_blocks_of_four`] for the step of 4), both in vector
    /// lanes. Both give the same integer sums.
    pub fn of(image: &RgbImage, step: usize) -> Self {
        // u16 row sums hold up to 257 rows of 255.
        let step = step.clamp(1, 256);
        let (w, h) = (image.width() as usize, image.height() as usize);
        let (bw, bh) = (w.div_ceil(step), h.div_ceil(step));
        let mut sums = BandSums::new(w);
        let mut out = Self::with_room(step, bw, bh);
        for (n_rows, band, ahead) in bands(image, step) {
            // Four whole rows of whole blocks: the block sums straight from the bytes, in
            // vector lanes. A band with a clipped value is summed again below, where the
            // clipped values are counted (rare: a bright spot).
            let full = 1.0 / (n_rows * step) as f32;
            let lanes = step == 4 && n_rows == 4 && w % 4 == 0 && w > 0;
            if !(lanes && sum_clean_band(band, ahead, w * 3, [0, 1, 2, 3], full, &mut out)) {
                sums.push_band(band, ahead, step, &mut out);
            }
        }
        out
    }

    /// Block means over the middle half of each block's rows (rows 1 and 2 of the
    /// default step of 4; of a block `n` rows tall, its `⌈n/2⌉` middle ones): half the
    /// bytes of [`BlockMeans::of`], centred where its means are, so the light's slow
    /// gradients across flat skin give the same means. Detection's first look at a pair
    /// ([`crate::tactile::contact::find_regions`]). `clipped` counts the values of the
    /// rows read.
    pub fn of_middle_rows(image: &RgbImage, step: usize) -> Self {
        let step = step.clamp(1, 256);
        let (w, h) = (image.width() as usize, image.height() as usize);
        let (bw, bh) = (w.div_ceil(step), h.div_ceil(step));
        let stride = w * 3;
        let mut sums = BandSums::new(w);
        let mut out = Self::with_room(step, bw, bh);
        for (n_rows, band, ahead) in bands(image, step) {
            let count = n_rows.div_ceil(2);
            let first = (n_rows - count) / 2;
            let scale = 1.0 / (count * step) as f32;
            let lanes = step == 4 && n_rows == 4 && w % 4 == 0 && w > 0;
            if !(lanes && sum_clean_band(band, ahead, stride, [1, 2], scale, &mut out)) {
                let rows = &band[first * stride..(first + count) * stride];
                sums.push_band(rows, ahead, step, &mut out);
            }
        }
        out
    }

    /// [`Self::of`] given `middle`, the means of the same image's middle rows
    /// ([`Self::of_middle_rows`]): for the default step of 4 on a frame of whole blocks
    /// only the other two rows of each band are read, and their sums added to the middle
    /// rows' (whole numbers over a power-of-two count of pixels, so the means are bit for
    /// bit [`Self::of`]'s). A band with a clipped value, other sizes and other CPUs are
    /// read whole.
    pub fn of_given_middle_rows(image: &RgbImage, middle: &Self) -> Self {
        let (w, h) = (image.width() as usize, image.height() as usize);
        let step = middle.step;
        let (bw, bh) = (w / 4, h / 4);
        let shaped = (middle.width, middle.height, middle.len()) == (bw, bh, bw * bh);
        if step != 4 || w % 4 != 0 || h % 4 != 0 || w == 0 || !shaped {
            return Self::of(image, step);
        }
        let mut sums = BandSums::new(w);
        let mut out = Self::with_room(step, bw, bh);
        for (_, band, ahead) in bands(image, step) {
            let blocks = out.red.len()..out.red.len() + bw;
            if middle.clipped[blocks.clone()].iter().all(|&c| c == 0)
                && sum_clean_band(band, ahead, w * 3, [0, 3], 0.125, &mut out)
            {
                // Both halves' means are sums over 8 pixels, exact multiples of 1/8.
                for (plane, half) in [
                    (&mut out.red, &middle.red),
                    (&mut out.green, &middle.green),
                    (&mut out.blue, &middle.blue),
                ] {
                    for (o, m) in plane[blocks.clone()].iter_mut().zip(&half[blocks.clone()]) {
                        *o = (*o + *m) * 0.5;
                    }
                }
            } else {
                sums.push_band(band, ahead, step, &mut out);
            }
        }
        out
    }

    /// Number of blocks.
    pub fn len(&self) -> usize {
        self.red.len()
    }

    /// `true` for an image with no pixels.
    pub fn is_empty(&self) -> bool {
        self.red.is_empty()
    }

    /// Mean `[R, G, B]` of block `i`.
    pub fn mean(&self, i: usize) -> [f32; 3] {
        [self.red[i], self.green[i], self.blue[i]]
    }

    /// Every block's mean `[R, G, B]`, row by row.
    pub fn means(&self) -> Vec<[f32; 3]> {
        (0..self.len()).map(|i| self.mean(i)).collect()
    }
}

/// The red, green and blue sums (exact whole numbers as `f32`) of each block of 4×4 px
/// in band `by` (block row) of `image` over the block's row `row` (0–3) alone, into
/// `out`'s planes (emptied first; one value per block of the band), in vector lanes
/// ([`band_sums_avx2`]; the same rows of the next band are asked for ahead of use), and
/// whether a value read there is 255 (`out.clipped` is left empty). `None`, with `out`
/// empty, where the frame is not whole blocks of four, `row` is not one of a block's
/// or the CPU lacks AVX2. For [`crate::tactile::quiet`], which screens each block by one
/// of its rows while they are in the cache.
#[allow(unsafe_code)]
pub(crate) fn row_sums(
    image: &RgbImage,
    by: usize,
    row: usize,
    out: &mut BlockMeans,
) -> Option<bool> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    for plane in [&mut out.red, &mut out.green, &mut out.blue] {
        plane.clear();
    }
    out.clipped.clear();
    if w == 0 || w % 4 != 0 || h % 4 != 0 || (by + 1) * 4 > h || row >= 4 {
        return None;
    }
    let (raw, stride) = (image.as_raw(), w * 3);
    let band = &raw[by * 4 * stride..(by + 1) * 4 * stride];
    let next = ((by + 1) * 4 * stride).min(raw.len());
    let ahead = &raw[next..(next + 4 * stride).min(raw.len())];
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::avx2() {
        // SAFETY: `band_sums_avx2` only needs AVX2, detected just above.
        return Some(unsafe { band_sums_avx2(band, ahead, stride, [row], 1.0, out) });
    }
    let _ = (band, ahead);
    None
}

/// No blocks yet, with room for one band of `blocks` blocks of four: the scratch of
/// [`row_sums`].
pub(crate) fn band_scratch(blocks: usize) -> BlockMeans {
    BlockMeans::with_room(4, blocks, 1)
}

/// Buffers of the band-by-band path of [`BlockMeans::of`] and
/// [`BlockMeans::of_middle_rows`] for a frame `width` px wide.
struct BandSums {
    /// Channel sums down the rows of a band, per pixel column.
    rows: Vec<u16>,
    /// Channel maxima down the rows (written only when something reached 255).
    row_max: Vec<u8>,
    /// Sums of blocks of four pixels ([`sum_blocks_of_four`]).
    quads: Vec<u16>,
}

impl BandSums {
    fn new(width: usize) -> Self {
        Self {
            rows: vec![0u16; width * 3],
            row_max: vec![0u8; width * 3],
            quads: vec![0u16; width * 3],
        }
    }

    /// Appends the means and clipped counts of the blocks (`step` px wide) over the rows
    /// of `band` (at most 257, whole rows of the frame) to `out`: the rows summed channel by
    /// channel ([`sum_rows`]), then the columns of every block (of four pixels at once), in
    /// vector lanes. `ahead` holds the rows that come next ([`sum_rows`]).
    fn push_band(&mut self, band: &[u8], ahead: &[u8], step: usize, out: &mut BlockMeans) {
        let (rows, row_max, quads) = (&mut self.rows, &mut self.row_max, &mut self.quads);
        let stride = rows.len();
        let w = stride / 3;
        let bw = w.div_ceil(step);
        let n_rows = band.len() / stride.max(1);
        let full = 1.0 / (n_rows * step) as f32;
        // Whole blocks of four pixels (the default step) in vector lanes.
        let whole = if step == 4 { w / 4 } else { 0 };
        let any_clipped = sum_rows(
            band,
            ahead,
            w * 3,
            rows,
            row_max,
            &mut quads[..(whole * 12).saturating_sub(9)],
        );
        if whole > 0 {
            let at = out.red.len();
            // Block j's sums are quads[12j..12j + 3] (all written: the last block's
            // end 9 values before the sums do). Appended, not zero-filled first: the
            // planes of a 640×480 frame are 230 kB.
            let blocks = || quads.chunks_exact(12).take(whole);
            out.red.extend(blocks().map(|q| f32::from(q[0]) * full));
            out.green.extend(blocks().map(|q| f32::from(q[1]) * full));
            out.blue.extend(blocks().map(|q| f32::from(q[2]) * full));
            if any_clipped {
                out.clipped
                    .extend(row_max[..whole * 12].chunks_exact(12).map(count_clipped));
            } else {
                out.clipped.resize(at + whole, 0);
            }
        }
        // Sums of at most 256 × 256 values of 255 fit a u32: wrapping adds keep the
        // loops free of overflow checks.
        for bx in whole..bw {
            let x0 = bx * step;
            let n_cols = step.min(w - x0);
            let inv = if n_cols == step {
                full
            } else {
                1.0 / (n_rows * n_cols) as f32
            };
            let span = x0 * 3..(x0 + n_cols) * 3;
            let mut s = [0u32; 3];
            for px in rows[span.clone()].chunks_exact(3) {
                for c in 0..3 {
                    s[c] = s[c].wrapping_add(u32::from(px[c]));
                }
            }
            out.red.push(s[0] as f32 * inv);
            out.green.push(s[1] as f32 * inv);
            out.blue.push(s[2] as f32 * inv);
            out.clipped.push(if any_clipped {
                count_clipped(&row_max[span])
            } else {
                0
            });
        }
    }
}

/// Channel values at 255 among `maxes`.
#[inline]
fn count_clipped(maxes: &[u8]) -> u32 {
    maxes.iter().map(|&c| u32::from(c == u8::MAX)).sum()
}

/// The bands of `step` pixel rows of `image`, top to bottom (the last may have fewer):
/// each as its number of rows, its bytes and the bytes of the rows after it (asked for
/// ahead of use).
fn bands(image: &RgbImage, step: usize) -> impl Iterator<Item = (usize, &[u8], &[u8])> {
    let (raw, stride) = (image.as_raw(), image.width() as usize * 3);
    let h = image.height() as usize;
    (0..h.div_ceil(step)).map(move |by| {
        let y0 = by * step;
        let n_rows = step.min(h - y0);
        let next = (y0 + n_rows) * stride;
        let ahead = &raw[next..(next + step * stride).min(raw.len())];
        (n_rows, &raw[y0 * stride..next], ahead)
    })
}

/// The mean red, green and blue (sum × `scale`) of every block of four pixels over rows
/// `pick` of `band` (four rows of whole blocks, `stride` bytes each), appended to `out`'s
/// planes in vector lanes ([`band_sums_avx2`]) and kept only where nothing read reached
/// 255 (its blocks then count no clipped value): `true` then; `false`, with `out` as it
/// was, where something did or the CPU lacks AVX2 (the caller sums the band another way,
/// counting clipped values). `ahead` holds the next band's rows, whose rows `pick` are
/// asked for ahead of use ([`crate::cpu::prefetch`]).
#[allow(unsafe_code)]
fn sum_clean_band<const N: usize>(
    band: &[u8],
    ahead: &[u8],
    stride: usize,
    pick: [usize; N],
    scale: f32,
    out: &mut BlockMeans,
) -> bool {
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::avx2() {
        let at = out.red.len();
        // SAFETY: `band_sums_avx2` only needs AVX2, detected just above.
        if !unsafe { band_sums_avx2(band, ahead, stride, pick, scale, out) } {
            out.clipped.resize(at + stride / 12, 0);
            return true;
        }
        out.red.truncate(at);
        out.green.truncate(at);
        out.blue.truncate(at);
        return false;
    }
    let _ = (band, ahead, stride, pick, scale, out);
    false
}

/// Blocks per group of [`band_sums_avx2`]: eight, one per 128-bit lane of four
/// registers.
const GROUP: usize = 8;

/// [`sum_clean_band`]'s sums in AVX2 (the return value says whether a value read reached
/// 255), one block of four pixels (12 bytes of each row) per 128-bit
/// lane: a byte shuffle orders a row's 12 bytes by channel, a multiply-add of byte pairs
/// sums them two by two (16-bit), the rows are added, and a multiply-add of 16-bit pairs
/// gives the block's red, green and blue sums (32-bit). The two lanes of a register hold
/// blocks four apart, so a 4×4 transpose of four registers puts eight blocks' red
/// (green, blue) sums in order. Integer sums, as the rows-then-columns path: the means
/// are bit for bit the same. A lane loads the 16 bytes from its block's start (the first
/// lane) or ending at its end (the second), so no load leaves its group of blocks.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
fn band_sums_avx2<const N: usize>(
    band: &[u8],
    ahead: &[u8],
    stride: usize,
    pick: [usize; N],
    scale: f32,
    out: &mut BlockMeans,
) -> bool {
    use std::arch::x86_64::*;
    let blocks = stride / 12;
    // Bytes of a row's block by channel, in pairs for the multiply-add; -1 (high bit set)
    // gives 0. The second lane's block starts 4 bytes into its load.
    let order = |o: i8| {
        [
            o,
            o + 3,
            o + 6,
            o + 9,
            o + 1,
            o + 4,
            o + 7,
            o + 10,
            o + 2,
            o + 5,
            o + 8,
            o + 11,
            -1,
            -1,
            -1,
            -1,
        ]
    };
    let mut pattern = [0i8; 32];
    pattern[..16].copy_from_slice(&order(0));
    pattern[16..].copy_from_slice(&order(4));
    // SAFETY: 32 bytes; unaligned load.
    let shuffle = unsafe { _mm256_loadu_si256(pattern.as_ptr().cast()) };
    let ones8 = _mm256_set1_epi8(1);
    let ones16 = _mm256_set1_epi16(1);
    let scale_one = scale;
    let scale = _mm256_set1_ps(scale);
    let mut top = _mm256_setzero_si256();
    let groups = blocks / GROUP;
    let rows: [&[u8]; N] = pick.map(|r| &band[r * stride..(r + 1) * stride]);
    let at = out.red.len();
    for plane in [&mut out.red, &mut out.green, &mut out.blue] {
        plane.reserve(blocks);
    }
    let planes = [&mut out.red, &mut out.green, &mut out.blue].map(|p| p.as_mut_ptr());
    for g in 0..groups {
        let start = g * GROUP * 12;
        for row in pick {
            crate::cpu::prefetch(ahead, row * stride + start);
            crate::cpu::prefetch(ahead, row * stride + start + 64);
        }
        let group: [&[u8; GROUP * 12]; N] = rows.map(|r| {
            r[start..start + GROUP * 12]
                .try_into()
                .expect("a group's bytes")
        });
        let mut lanes = [_mm256_setzero_si256(); 4];
        for (k, lane) in lanes.iter_mut().enumerate() {
            let mut pairs = _mm256_setzero_si256();
            for bytes in group {
                // SAFETY: block k's 16 bytes from its start and block k + 4's 16 bytes
                // ending at its end, `12k + 60 ≤ 96`: inside the group; unaligned loads.
                let v = unsafe {
                    let p = bytes.as_ptr().add(12 * k);
                    _mm256_loadu2_m128i(p.add(44).cast(), p.cast())
                };
                let v = _mm256_shuffle_epi8(v, shuffle);
                top = _mm256_max_epu8(top, v);
                pairs = _mm256_add_epi16(pairs, _mm256_maddubs_epi16(v, ones8));
            }
            *lane = _mm256_madd_epi16(pairs, ones16);
        }
        let [a, b, c, d] = lanes;
        let (ab_lo, cd_lo) = (_mm256_unpacklo_epi32(a, b), _mm256_unpacklo_epi32(c, d));
        let (ab_hi, cd_hi) = (_mm256_unpackhi_epi32(a, b), _mm256_unpackhi_epi32(c, d));
        let sums = [
            _mm256_unpacklo_epi64(ab_lo, cd_lo),
            _mm256_unpackhi_epi64(ab_lo, cd_lo),
            _mm256_unpacklo_epi64(ab_hi, cd_hi),
        ];
        for (plane, s) in planes.iter().zip(sums) {
            // SAFETY: each plane has room for `blocks` more values (reserved above), and
            // this group's eight end at `at + 8g + 8 ≤ at + blocks`; unaligned store.
            unsafe {
                _mm256_storeu_ps(
                    plane.add(at + g * GROUP),
                    _mm256_mul_ps(_mm256_cvtepi32_ps(s), scale),
                );
            }
        }
    }
    for plane in [&mut out.red, &mut out.green, &mut out.blue] {
        // SAFETY: the groups wrote every value up to here (above); capacity reserved.
        unsafe { plane.set_len(at + groups * GROUP) };
    }
    let mut top = {
        let mut bytes = [0u8; 32];
        // SAFETY: 32 bytes; unaligned store.
        unsafe { _mm256_storeu_si256(bytes.as_mut_ptr().cast(), top) };
        bytes.into_iter().max().unwrap_or(0)
    };
    // The blocks after the last group, one by one.
    for j in groups * GROUP..blocks {
        let mut s = [0u32; 3];
        for row in pick {
            let at = row * stride + 12 * j;
            for px in band[at..at + 12].chunks_exact(3) {
                for c in 0..3 {
                    s[c] += u32::from(px[c]);
                    top = top.max(px[c]);
                }
            }
        }
        out.red.push(s[0] as f32 * scale_one);
        out.green.push(s[1] as f32 * scale_one);
        out.blue.push(s[2] as f32 * scale_one);
    }
    top == u8::MAX
}

/// Bytes of a cache line.
const LINE: usize = 64;
/// Columns of the four-row sums between requests for the next block's rows: four cache
/// lines of each (one at a time made the loop 10 % slower on frames already cached).
const CHUNK: usize = 4 * LINE;

/// `quads[k] = rows[k] + rows[k + 3] + rows[k + 6] + rows[k + 9]`: at `k = 12·j + c` the
/// sum of channel `c` over the four pixels of block `j` (at most 4 × 1020, a u16).
#[inline(always)]
fn sum_blocks_of_four(rows: &[u16], quads: &mut [u16]) {
    let n = quads.len();
    let (a, b, c, d) = (
        &rows[..n],
        &rows[3..n + 3],
        &rows[6..n + 6],
        &rows[9..n + 9],
    );
    for k in 0..n {
        quads[k] = a[k]
            .wrapping_add(b[k])
            .wrapping_add(c[k])
            .wrapping_add(d[k]);
    }
}

/// Channel-by-channel sums (`sums`) and maxima (`maxes`, written only when some value
/// reached 255) over the rows of `rows` (each
/// `stride` bytes, at most 257 of them so the u16 sums cannot overflow), then the sums of
/// blocks of four pixels into `quads` ([`sum_blocks_of_four`]; pass an empty slice for
/// other block sizes). Says whether any value reached 255. `next` holds the rows that come
/// after (the next block's): the four-row path asks for them ahead of use
/// ([`crate::cpu::prefetch`]). Runs the AVX2 copy of the loops when the CPU has it.
#[allow(unsafe_code)]
fn sum_rows(
    rows: &[u8],
    next: &[u8],
    stride: usize,
    sums: &mut [u16],
    maxes: &mut [u8],
    quads: &mut [u16],
) -> bool {
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::avx2() {
        // SAFETY: `sum_rows_avx2` only needs AVX2, detected just above.
        return unsafe { sum_rows_avx2(rows, next, stride, sums, maxes, quads) };
    }
    sum_rows_portable(rows, next, stride, sums, maxes, quads)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn sum_rows_avx2(
    rows: &[u8],
    next: &[u8],
    stride: usize,
    sums: &mut [u16],
    maxes: &mut [u8],
    quads: &mut [u16],
) -> bool {
    sum_rows_portable(rows, next, stride, sums, maxes, quads)
}

#[inline(always)]
fn sum_rows_portable(
    rows: &[u8],
    next: &[u8],
    stride: usize,
    sums: &mut [u16],
    maxes: &mut [u8],
    quads: &mut [u16],
) -> bool {
    let (sums, maxes) = (&mut sums[..stride], &mut maxes[..stride]);
    let mut top = 0u8;
    if rows.len() == 4 * stride {
        // Four rows (the default block) at once: each sum is written once instead of read
        // and written per row (with the planes appended below: detection at rest 198 →
        // 150 µs at 640×480); the maxima only when something clipped (below).
        let (a, rest) = rows.split_at(stride);
        let (b, rest) = rest.split_at(stride);
        let (c, d) = rest.split_at(stride);
        // A few cache lines' worth of columns at a time, the same columns of the next
        // block's rows asked for first.
        for start in (0..stride).step_by(CHUNK) {
            for row in 0..4 {
                for line in (0..CHUNK).step_by(LINE) {
                    crate::cpu::prefetch(next, row * stride + start + line);
                }
            }
            let cols = start..(start + CHUNK).min(stride);
            for ((((s, &a), &b), &c), &d) in sums[cols.clone()]
                .iter_mut()
                .zip(&a[cols.clone()])
                .zip(&b[cols.clone()])
                .zip(&c[cols.clone()])
                .zip(&d[cols])
            {
                *s = u16::from(a) + u16::from(b) + u16::from(c) + u16::from(d);
                top = top.max(a.max(b).max(c.max(d)));
            }
        }
        // The maxima per column only where something clipped (rare: a bright spot).
        if top == u8::MAX {
            for ((((m, &a), &b), &c), &d) in maxes.iter_mut().zip(a).zip(b).zip(c).zip(d) {
                *m = a.max(b).max(c.max(d));
            }
        }
    } else {
        sums.fill(0);
        maxes.fill(0);
        for row in rows.chunks_exact(stride) {
            // Cannot overflow (at most 257 rows of 255); wrapping keeps the loop free of
            // overflow checks so it vectorises in every profile.
            for ((s, m), &v) in sums.iter_mut().zip(maxes.iter_mut()).zip(row) {
                *s = s.wrapping_add(u16::from(v));
                *m = (*m).max(v);
            }
        }
        top = maxes.iter().fold(0, |a, &m| a.max(m));
    }
    if !quads.is_empty() {
        sum_blocks_of_four(sums, quads);
    }
    top == u8::MAX
}

/// Bilinear interpolation of per-block values (`width × height` blocks of `step` px, row
/// by row) at pixel position `(x, y)` (pixel centres at `+0.5`); beyond the outer block
/// centres the nearest block's value holds.
pub fn bilinear(
    blocks: &[[f32; 3]],
    width: usize,
    height: usize,
    step: usize,
    x: f32,
    y: f32,
) -> [f32; 3] {
    let f = step.max(1) as f32;
    let u = (x / f - 0.5).clamp(0.0, width.saturating_sub(1) as f32);
    let v = (y / f - 0.5).clamp(0.0, height.saturating_sub(1) as f32);
    let (i, j) = (u as usize, v as usize);
    let (i1, j1) = (
        (i + 1).min(width.saturating_sub(1)),
        (j + 1).min(height.saturating_sub(1)),
    );
    let (fu, fv) = (u - i as f32, v - j as f32);
    let at = |i: usize, j: usize| blocks[j * width + i];
    let mut out = [0.0; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let top = at(i, j)[c] * (1.0 - fu) + at(i1, j)[c] * fu;
        let bottom = at(i, j1)[c] * (1.0 - fu) + at(i1, j1)[c] * fu;
        *o = top * (1.0 - fv) + bottom * fv;
    }
    out
}

/// Mean RGB over the `(2r + 1)²` box around every pixel (clipped at the frame's edges),
/// row by row.
pub fn box_means(image: &RgbImage, r: usize) -> Vec<[f32; 3]> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    // Horizontal running sums, then vertical.
    let mut horizontal = vec![[0u32; 3]; w * h];
    for y in 0..h {
        let mut acc = [0u32; 3];
        let px = |x: usize| image.get_pixel(x as u32, y as u32).0;
        for x in 0..(w + r) {
            if x < w {
                let p = px(x);
                for c in 0..3 {
                    acc[c] += u32::from(p[c]);
                }
            }
            if x > 2 * r {
                let p = px(x - 2 * r - 1);
                for c in 0..3 {
                    acc[c] -= u32::from(p[c]);
                }
            }
            if x >= r {
                horizontal[y * w + x - r] = acc;
            }
        }
    }
    let mut out = vec![[0f32; 3]; w * h];
    for x in 0..w {
        let cols = (x + r + 1).min(w) - x.saturating_sub(r);
        let mut acc = [0u32; 3];
        for y in 0..(h + r) {
            if y < h {
                for c in 0..3 {
                    acc[c] += horizontal[y * w + x][c];
                }
            }
            if y > 2 * r {
                for c in 0..3 {
                    acc[c] -= horizontal[(y - 2 * r - 1) * w + x][c];
                }
            }
            if y >= r {
                let yy = y - r;
                let rows = (yy + r + 1).min(h) - yy.saturating_sub(r);
                let n = (rows * cols) as f32;
                out[yy * w + x] = acc.map(|v| v as f32 / n);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| image::Rgb([x as u8, y as u8, (x + y) as u8]))
    }

    /// Block `(bx, by)` of `img` summed pixel by pixel: its channel sums, how many of its
    /// pixel columns' channels reach 255 in some row ([`BlockMeans::clipped`]) and its
    /// number of pixels.
    fn direct_block(img: &RgbImage, step: usize, bx: usize, by: usize) -> ([u32; 3], u32, usize) {
        let h = img.height() as usize;
        direct_rows(img, step, bx, by * step..((by + 1) * step).min(h))
    }

    /// [`direct_block`] over the block's middle rows ([`BlockMeans::of_middle_rows`]).
    fn direct_middle(img: &RgbImage, step: usize, bx: usize, by: usize) -> ([u32; 3], u32, usize) {
        let h = img.height() as usize;
        let n = step.min(h - by * step);
        let first = by * step + (n - n.div_ceil(2)) / 2;
        direct_rows(img, step, bx, first..first + n.div_ceil(2))
    }

    fn direct_rows(
        img: &RgbImage,
        step: usize,
        bx: usize,
        ys: std::ops::Range<usize>,
    ) -> ([u32; 3], u32, usize) {
        let w = img.width() as usize;
        let xs = bx * step..((bx + 1) * step).min(w);
        let mut sum = [0u32; 3];
        let mut clipped = vec![[false; 3]; xs.len()];
        for y in ys.clone() {
            for (i, x) in xs.clone().enumerate() {
                let p = img.get_pixel(x as u32, y as u32).0;
                for c in 0..3 {
                    sum[c] += u32::from(p[c]);
                    clipped[i][c] |= p[c] == 255;
                }
            }
        }
        let clipped = clipped.iter().flatten().filter(|&&c| c).count() as u32;
        (sum, clipped, xs.len() * ys.len())
    }

    #[test]
    fn block_means_average_whole_and_partial_blocks() {
        let img = ramp(10, 6);
        let b = BlockMeans::of(&img, 4);
        assert_eq!((b.width, b.height), (3, 2));
        assert_eq!(b.mean(0), [1.5, 1.5, 3.0]);
        assert!(b.clipped.iter().all(|&c| c == 0));
        let mut bright = img.clone();
        bright.put_pixel(9, 5, image::Rgb([255, 255, 7]));
        assert_eq!(BlockMeans::of(&bright, 4).clipped, [0, 0, 0, 0, 0, 2]);
        // The last column of blocks holds x = 8, 9; the last row y = 4, 5.
        assert_eq!(b.mean(5), [8.5, 4.5, 13.0]);
        assert_eq!(BlockMeans::of(&img, 0).len(), 60);
        // Blocks larger than the image: one block, the image's mean.
        let whole = BlockMeans::of(&img, 1000);
        assert_eq!((whole.width, whole.height), (1, 1));
        for (got, want) in whole.mean(0).iter().zip([4.5, 2.5, 7.0]) {
            assert!((got - want).abs() < 1e-5, "{:?}", whole.mean(0));
        }
    }

    #[test]
    fn block_means_match_a_direct_sum() {
        // Random pixels with some saturated channels; whole and partial blocks, the
        // four-row path (step 4) and the general one (steps 3 and 5).
        let mut rng = crate::rng::Rng::new(11);
        let (w, h) = (37usize, 23usize);
        let img = RgbImage::from_fn(w as u32, h as u32, |_, _| {
            image::Rgb(std::array::from_fn(|_| {
                if rng.uniform() < 0.05 {
                    255
                } else {
                    (rng.next_u64() % 256) as u8
                }
            }))
        });
        for step in [3usize, 4, 5] {
            let b = BlockMeans::of(&img, step);
            for by in 0..h.div_ceil(step) {
                for bx in 0..w.div_ceil(step) {
                    let (sum, clipped, n) = direct_block(&img, step, bx, by);
                    let i = by * b.width + bx;
                    for (got, want) in b.mean(i).iter().zip(sum) {
                        assert!(
                            (got - want as f32 / n as f32).abs() < 1e-4,
                            "step {step} block ({bx}, {by})"
                        );
                    }
                    assert_eq!(
                        b.clipped[i], clipped,
                        "step {step} block ({bx}, {by}) clipped"
                    );
                }
            }
        }
    }

    #[test]
    fn four_pixel_blocks_read_in_lanes_equal_a_direct_sum_bit_for_bit() {
        // Widths of whole blocks of four pixels: the band path in vector lanes, groups
        // of eight blocks and the blocks after them; a partial band below; bands with a
        // clipped value (summed again) and without.
        let mut rng = crate::rng::Rng::new(5);
        for blocks in [1usize, 7, 8, 9, 16, 17, 23, 160] {
            let (w, h) = (4 * blocks, 14usize);
            let mut img = RgbImage::from_fn(w as u32, h as u32, |_, _| {
                image::Rgb(std::array::from_fn(|_| (rng.next_u64() % 255) as u8))
            });
            // A clipped value in the second band only.
            img.put_pixel((w - 1) as u32, 5, image::Rgb([9, 255, 9]));
            let b = BlockMeans::of(&img, 4);
            assert_eq!((b.width, b.height, b.len()), (blocks, 4, blocks * 4));
            for by in 0..4 {
                for bx in 0..blocks {
                    let (sum, clipped, n) = direct_block(&img, 4, bx, by);
                    // The one clipped value, counted where it was put.
                    assert_eq!(clipped, u32::from((by, bx) == (1, blocks - 1)));
                    let inv = 1.0 / n as f32;
                    let i = by * blocks + bx;
                    assert_eq!(
                        b.mean(i),
                        sum.map(|v| v as f32 * inv),
                        "{blocks} ({bx}, {by})"
                    );
                    assert_eq!(b.clipped[i], clipped, "{blocks} ({bx}, {by})");
                }
            }
        }
    }

    #[test]
    fn middle_rows_equal_a_direct_sum_bit_for_bit() {
        // Whole blocks of four pixels (vector lanes, groups of eight and the blocks
        // after them) and partial ones (steps 3 and 5, widths not a multiple of four), a
        // partial band below; a clipped value in a row read (counted) and in one not read
        // (not counted: the means of the rows read are exact).
        let mut rng = crate::rng::Rng::new(7);
        for (w, step) in [
            (4usize, 4usize),
            (28, 4),
            (32, 4),
            (36, 4),
            (68, 4),
            (640, 4),
            (37, 3),
            (37, 5),
            (38, 4),
        ] {
            let h = 14usize;
            let mut img = RgbImage::from_fn(w as u32, h as u32, |_, _| {
                image::Rgb(std::array::from_fn(|_| (rng.next_u64() % 255) as u8))
            });
            img.put_pixel((w - 1) as u32, 5, image::Rgb([9, 255, 9]));
            img.put_pixel(0, 4, image::Rgb([255, 9, 9]));
            let b = BlockMeans::of_middle_rows(&img, step);
            let (bw, bh) = (w.div_ceil(step), h.div_ceil(step));
            assert_eq!((b.width, b.height, b.len()), (bw, bh, bw * bh));
            for by in 0..bh {
                for bx in 0..bw {
                    let (sum, clipped, n) = direct_middle(&img, step, bx, by);
                    let i = by * bw + bx;
                    let inv = 1.0 / n as f32;
                    let at = format!("width {w} step {step} ({bx}, {by})");
                    assert_eq!(b.mean(i), sum.map(|v| v as f32 * inv), "{at}");
                    assert_eq!(b.clipped[i], clipped, "{at}");
                }
            }
            if step == 4 {
                // y = 5 is row 1 of the second band (read), y = 4 its row 0 (not read).
                assert_eq!(b.clipped.iter().sum::<u32>(), 1, "width {w}");
            }
        }
    }

    #[test]
    fn the_other_rows_added_to_the_middle_ones_equal_block_means_bit_for_bit() {
        // Whole blocks of four (vector lanes), clipped values in a middle row and in an
        // outer one (bands read whole), and sizes the shortcut does not take.
        let mut rng = crate::rng::Rng::new(9);
        for (w, h) in [(640usize, 16usize), (36, 12), (4, 8), (37, 12), (36, 14)] {
            let mut img = RgbImage::from_fn(w as u32, h as u32, |_, _| {
                image::Rgb(std::array::from_fn(|_| (rng.next_u64() % 255) as u8))
            });
            img.put_pixel(0, 5, image::Rgb([9, 255, 9]));
            img.put_pixel((w - 1) as u32, h as u32 - 4, image::Rgb([255, 9, 9]));
            let middle = BlockMeans::of_middle_rows(&img, 4);
            let all = BlockMeans::of_given_middle_rows(&img, &middle);
            assert_eq!(all, BlockMeans::of(&img, 4), "{w}×{h}");
        }
    }

    #[test]
    fn box_means_match_a_direct_sum() {
        let img = ramp(9, 7);
        let r = 2;
        let fast = box_means(&img, r);
        for y in 0..7usize {
            for x in 0..9usize {
                let mut s = [0f32; 3];
                let mut n = 0.0;
                for yy in y.saturating_sub(r)..(y + r + 1).min(7) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(9) {
                        let p = img.get_pixel(xx as u32, yy as u32).0;
                        for c in 0..3 {
                            s[c] += p[c] as f32;
                        }
                        n += 1.0;
                    }
                }
                let want = s.map(|v| v / n);
                let got = fast[y * 9 + x];
                for c in 0..3 {
                    assert!(
                        (got[c] - want[c]).abs() < 1e-4,
                        "({x},{y}) {got:?} {want:?}"
                    );
                }
            }
        }
        assert!(box_means(&RgbImage::new(0, 0), 2).is_empty());
    }
}
