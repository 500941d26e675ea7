//! Local means of the phase images. A single pixel's colour is too noisy to say whether
//! the skin is touched (a cheap camera's shot noise and MJPG chroma noise reach several
//! percent per channel); the mean over a small neighbourhood is not. Detection works on
//! the means of `step × step` blocks ([`BlockMeans`], one read of each pixel, integer
//! sums); calibration finds press outlines on box means around every pixel
//! ([`box_means`]).

use image::RgbImage;

/// Mean RGB of each `step × step` block of an image (partial blocks at the right and
/// bottom edges average the pixels they have).
#[derive(Debug, Clone, PartialEq)]
pub struct BlockMeans {
    /// Block size (px).
    pub step: usize,
    /// Blocks across.
    pub width: usize,
    /// Blocks down.
    pub height: usize,
    /// Mean `[R, G, B]` per block, row by row.
    pub means: Vec<[f32; 3]>,
    /// Per block, how many of its pixel columns' channels reach 255 in some row
    /// (clipped: the light there is unknown); 0 when nothing is clipped.
    pub clipped: Vec<u32>,
}

impl BlockMeans {
    /// Block means of `image`. The rows of a block are first summed channel by channel
    /// (a loop the compiler vectorises), then each block's columns.
    pub fn of(image: &RgbImage, step: usize) -> Self {
        // u16 row sums hold up to 257 rows of 255.
        let step = step.clamp(1, 256);
        let (w, h) = (image.width() as usize, image.height() as usize);
        let (bw, bh) = (w.div_ceil(step), h.div_ceil(step));
        let raw = image.as_raw();
        let mut rows = vec![0u16; w * 3];
        let mut clipped_rows = vec![0u8; w * 3];
        let mut means = Vec::with_capacity(bw * bh);
        let mut clipped = Vec::with_capacity(bw * bh);
        for by in 0..bh {
            let y0 = by * step;
            let n_rows = step.min(h - y0);
            rows.fill(0);
            clipped_rows.fill(0);
            for y in y0..y0 + n_rows {
                // Cannot overflow (at most 256 rows of 255); wrapping keeps the loop free
                // of overflow checks so it vectorises in every profile.
                let row = &raw[y * w * 3..(y + 1) * w * 3];
                let (sums, clips) = (&mut rows[..row.len()], &mut clipped_rows[..row.len()]);
                for i in 0..row.len() {
                    sums[i] = sums[i].wrapping_add(u16::from(row[i]));
                    clips[i] = clips[i].max(row[i]);
                }
            }
            // Sums of at most 256 × 256 values of 255 fit a u32: wrapping adds keep the
            // loops free of overflow checks.
            let full = 1.0 / (n_rows * step) as f32;
            for bx in 0..bw {
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
                let mut clips = 0u32;
                for &c in &clipped_rows[span] {
                    clips += u32::from(c == u8::MAX);
                }
                means.push(s.map(|v| v as f32 * inv));
                clipped.push(clips);
            }
        }
        Self {
            step,
            width: bw,
            height: bh,
            means,
            clipped,
        }
    }
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

    #[test]
    fn block_means_average_whole_and_partial_blocks() {
        let img = ramp(10, 6);
        let b = BlockMeans::of(&img, 4);
        assert_eq!((b.width, b.height), (3, 2));
        assert_eq!(b.means[0], [1.5, 1.5, 3.0]);
        assert!(b.clipped.iter().all(|&c| c == 0));
        let mut bright = img.clone();
        bright.put_pixel(9, 5, image::Rgb([255, 255, 7]));
        assert_eq!(BlockMeans::of(&bright, 4).clipped, [0, 0, 0, 0, 0, 2]);
        // The last column of blocks holds x = 8, 9; the last row y = 4, 5.
        assert_eq!(b.means[5], [8.5, 4.5, 13.0]);
        assert_eq!(BlockMeans::of(&img, 0).means.len(), 60);
        // Blocks larger than the image: one block, the image's mean.
        let whole = BlockMeans::of(&img, 1000);
        assert_eq!((whole.width, whole.height), (1, 1));
        for (got, want) in whole.means[0].iter().zip([4.5, 2.5, 7.0]) {
            assert!((got - want).abs() < 1e-5, "{:?}", whole.means[0]);
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
