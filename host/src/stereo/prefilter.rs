//! The matcher's input stage, as OpenCV's StereoBM: an x-Sobel response clamped to
//! `±cap` and shifted to `0..=2·cap`, which removes brightness differences between the
//! cameras (and the skin's haze, which is smooth) before pixels are compared; and the
//! texture measure, the window sum of `|response − cap|`, below which a window has too
//! little structure to match.

use crate::grid::Grid;

/// The x-Sobel response of `image`, clamped to `±cap` and offset by `cap`.
///
/// Boundary: rows above and below the image repeat the edge row; the first and last
/// column have no horizontal neighbour on one side and are set to `cap` (no gradient).
pub fn x_sobel(image: &Grid<u8>, cap: u8) -> Grid<u8> {
    let (w, h) = (image.width(), image.height());
    let mut out = Grid::filled(w, h, cap);
    if w < 3 || h == 0 {
        return out;
    }
    let cap_i = i32::from(cap);
    for y in 0..h {
        let above = image.row(y.saturating_sub(1));
        let centre = image.row(y);
        let below = image.row((y + 1).min(h - 1));
        let row = out.row_mut(y);
        for x in 1..w - 1 {
            let dx = |r: &[u8]| i32::from(r[x + 1]) - i32::from(r[x - 1]);
            let v = dx(above) + 2 * dx(centre) + dx(below);
            row[x] = (v.clamp(-cap_i, cap_i) + cap_i) as u8;
        }
    }
    out
}

/// For every pixel, the sum of `|v − cap|` over the `block × block` window centred on
/// it (windows reaching past the image are summed over the part inside).
pub fn texture(prefiltered: &Grid<u8>, cap: u8, block: usize) -> Grid<u32> {
    let (w, h) = (prefiltered.width(), prefiltered.height());
    let r = block / 2;
    let mut out = Grid::filled(w, h, 0u32);
    // Column sums over the rows of the current window, updated as it moves down.
    let mut column = vec![0u32; w];
    let add_row = |column: &mut [u32], y: usize, sign: bool| {
        for (c, &v) in column.iter_mut().zip(prefiltered.row(y)) {
            let t = u32::from(v.abs_diff(cap));
            *c = if sign { *c + t } else { *c - t };
        }
    };
    for y in 0..r.min(h) {
        add_row(&mut column, y, true);
    }
    for y in 0..h {
        if y + r < h {
            add_row(&mut column, y + r, true);
        }
        if y > r {
            add_row(&mut column, y - r - 1, false);
        }
        let row = out.row_mut(y);
        let mut run: u32 = column[..r.min(w)].iter().sum();
        for x in 0..w {
            if x + r < w {
                run += column[x + r];
            }
            if x > r {
                run -= column[x - r - 1];
            }
            row[x] = run;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sobel_of_a_ramp_is_eight_times_its_slope() {
        // I = 3x: each of the three rows gives 2·3 = 6, weighted 1 + 2 + 1.
        let img = Grid::from_fn(8, 5, |x, _| (3 * x) as u8);
        let out = x_sobel(&img, 63);
        for y in 0..5 {
            assert_eq!(out.get(0, y), 63);
            assert_eq!(out.get(7, y), 63);
            for x in 1..7 {
                assert_eq!(out.get(x, y), 63 + 24, "({x}, {y})");
            }
        }
        // Clamped at the cap.
        assert!(
            x_sobel(&img, 10)
                .as_slice()
                .iter()
                .all(|&v| v == 10 || v == 20)
        );
    }

    #[test]
    fn texture_sums_the_window() {
        let pre = Grid::from_fn(6, 4, |x, y| (10 + x + y) as u8);
        let t = texture(&pre, 10, 3);
        // Centre (2, 1): x in 1..=3, y in 0..=2, values 1+x+y-1 … sum of (x + y).
        let expect: u32 = (1..=3).flat_map(|x| (0..=2).map(move |y| x + y)).sum();
        assert_eq!(t.get(2, 1), expect);
        // Corner (0, 0): x, y in 0..=1.
        assert_eq!(t.get(0, 0), 1 + 1 + 2); // 0 + 1 + 1 + 2
        assert!(
            x_sobel(&Grid::filled(2, 2, 9u8), 5)
                .as_slice()
                .iter()
                .all(|&v| v == 5)
        );
    }
}
