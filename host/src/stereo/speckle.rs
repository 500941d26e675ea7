//! Speckle removal (as OpenCV's `filterSpeckles`): connected regions of a disparity map
//! whose neighbours differ by at most `max_diff` are found by flood fill; regions of at
//! most `max_size` pixels are mismatches on repeated texture or noise and are
//! invalidated (set to NaN). One pass over the image, O(pixels).

use crate::grid::Grid;

/// Invalidates small regions in `disparity` (NaN = invalid, 4-connected); returns how
/// many pixels it invalidated. `max_size = 0` does nothing.
pub fn filter_speckles(disparity: &mut Grid<f32>, max_size: usize, max_diff: f32) -> usize {
    if max_size == 0 || disparity.is_empty() {
        return 0;
    }
    let (w, h) = (disparity.width(), disparity.height());
    let data = disparity.as_mut_slice();
    let mut seen = vec![false; w * h];
    let mut region: Vec<usize> = Vec::new();
    let mut stack: Vec<usize> = Vec::new();
    let mut removed = 0;
    for start in 0..w * h {
        if seen[start] || !data[start].is_finite() {
            continue;
        }
        seen[start] = true;
        region.clear();
        stack.push(start);
        while let Some(i) = stack.pop() {
            region.push(i);
            let v = data[i];
            let (x, y) = (i % w, i / w);
            let neighbours = [
                (x > 0).then(|| i - 1),
                (x + 1 < w).then(|| i + 1),
                (y > 0).then(|| i - w),
                (y + 1 < h).then(|| i + w),
            ];
            for j in neighbours.into_iter().flatten() {
                if !seen[j] && data[j].is_finite() && (data[j] - v).abs() <= max_diff {
                    seen[j] = true;
                    stack.push(j);
                }
            }
        }
        if region.len() <= max_size {
            for &i in &region {
                data[i] = f32::NAN;
            }
            removed += region.len();
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_islands_go_large_regions_stay() {
        // A 10×10 plane at 20 with a 2×2 island at 40 and one lone pixel at 5.
        let mut d = Grid::from_fn(10, 10, |x, y| match (x, y) {
            (3..=4, 3..=4) => 40.0,
            (8, 8) => 5.0,
            _ => 20.0 + 0.1 * (x + y) as f32,
        });
        d.set(0, 9, f32::NAN);
        let removed = filter_speckles(&mut d, 4, 1.0);
        assert_eq!(removed, 5);
        assert!(d.get(3, 3).is_nan() && d.get(4, 4).is_nan() && d.get(8, 8).is_nan());
        assert_eq!(d.get(0, 0), 20.0);
        let valid = d.as_slice().iter().filter(|v| v.is_finite()).count();
        assert_eq!(valid, 100 - 5 - 1);
        // A gentle slope is one region however long: nothing more goes.
        assert_eq!(filter_speckles(&mut d, 50, 1.0), 0);
        // But with a step threshold below the slope, every pixel is its own region.
        assert_eq!(filter_speckles(&mut d, 1, 0.05), 94);
    }
}
