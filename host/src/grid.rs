//! A dense row-major 2-D array: the one container for images of numbers (slopes,
//! depth, colour ratios) that the tactile pipeline passes between its stages.

/// A `width × height` array stored row by row.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid<T> {
    width: usize,
    height: usize,
    data: Vec<T>,
}

impl<T: Copy> Grid<T> {
    /// A grid filled with `value`.
    pub fn filled(width: usize, height: usize, value: T) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// Wraps `data` (row-major); `None` if its length is not `width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Option<Self> {
        (width.checked_mul(height) == Some(data.len())).then_some(Self {
            width,
            height,
            data,
        })
    }

    /// A grid whose value at `(x, y)` is `f(x, y)`.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> T) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Self {
            width,
            height,
            data,
        }
    }

    /// Number of columns.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Number of rows.
    pub fn height(&self) -> usize {
        self.height
    }

    /// `true` when the grid holds no element.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// The value at column `x`, row `y` (panics when out of range, like slice indexing).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> T {
        self.data[y * self.width + x]
    }

    /// Sets the value at column `x`, row `y`.
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, value: T) {
        self.data[y * self.width + x] = value;
    }

    /// Row `y` as a slice.
    #[inline]
    pub fn row(&self, y: usize) -> &[T] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// Row `y` as a mutable slice.
    #[inline]
    pub fn row_mut(&mut self, y: usize) -> &mut [T] {
        &mut self.data[y * self.width..(y + 1) * self.width]
    }

    /// All values, row-major.
    pub fn as_slice(&self) -> &[T] {
        &self.data
    }

    /// All values, row-major, mutable.
    pub fn as_mut_slice(&mut self) -> &mut [T] {
        &mut self.data
    }

    /// Gives the values back, row-major.
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// The sub-rectangle starting at `(x0, y0)` of size `w × h` (must lie inside).
    pub fn crop(&self, x0: usize, y0: usize, w: usize, h: usize) -> Self {
        assert!(
            x0 + w <= self.width && y0 + h <= self.height,
            "crop out of range"
        );
        let mut data = Vec::with_capacity(w * h);
        for y in y0..y0 + h {
            data.extend_from_slice(&self.row(y)[x0..x0 + w]);
        }
        Self {
            width: w,
            height: h,
            data,
        }
    }

    /// Applies `f` to every value.
    pub fn map<U: Copy>(&self, f: impl FnMut(T) -> U) -> Grid<U> {
        Grid {
            width: self.width,
            height: self.height,
            data: self.data.iter().copied().map(f).collect(),
        }
    }
}

/// Writes the transpose of `src` (`width × height`, row-major) into `dst`
/// (`height × width`). Works in tiles so both sides stay in cache.
pub fn transpose<T: Copy>(src: &[T], dst: &mut [T], width: usize, height: usize) {
    assert_eq!(src.len(), width * height);
    assert_eq!(dst.len(), width * height);
    const TILE: usize = 32;
    const BLOCK: usize = 8;
    for y0 in (0..height).step_by(TILE) {
        let y1 = (y0 + TILE).min(height);
        for x0 in (0..width).step_by(TILE) {
            let x1 = (x0 + TILE).min(width);
            // Whole 8 × 8 blocks go through registers: eight rows read, eight columns
            // written; the tile's ragged edges element by element.
            let (bx1, by1) = (
                x0 + (x1 - x0) / BLOCK * BLOCK,
                y0 + (y1 - y0) / BLOCK * BLOCK,
            );
            for by in (y0..by1).step_by(BLOCK) {
                for bx in (x0..bx1).step_by(BLOCK) {
                    let block: [[T; BLOCK]; BLOCK] = std::array::from_fn(|r| {
                        let row = &src[(by + r) * width + bx..][..BLOCK];
                        std::array::from_fn(|c| row[c])
                    });
                    for c in 0..BLOCK {
                        let out = &mut dst[(bx + c) * height + by..][..BLOCK];
                        for (r, o) in out.iter_mut().enumerate() {
                            *o = block[r][c];
                        }
                    }
                }
            }
            for y in y0..y1 {
                let row = &src[y * width..];
                let xs = if y < by1 { bx1..x1 } else { x0..x1 };
                for x in xs {
                    dst[x * height + y] = row[x];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transpose_odd_sizes() {
        for (w, h) in [(1, 1), (1, 7), (7, 1), (33, 65), (70, 3)] {
            let src: Vec<u32> = (0..(w * h) as u32).collect();
            let mut dst = vec![0; w * h];
            transpose(&src, &mut dst, w, h);
            for y in 0..h {
                for x in 0..w {
                    assert_eq!(dst[x * h + y], src[y * w + x]);
                }
            }
        }
    }

    #[test]
    fn crop_takes_the_right_window() {
        let g = Grid::from_fn(5, 4, |x, y| (x, y));
        let c = g.crop(1, 2, 3, 2);
        assert_eq!(c.get(0, 0), (1, 2));
        assert_eq!(c.get(2, 1), (3, 3));
        assert!(Grid::from_vec(2, 2, vec![0; 3]).is_none());
    }
}
