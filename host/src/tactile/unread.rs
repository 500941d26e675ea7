//! Slopes of touched pixels the colour filter could not read, filled from their
//! neighbours instead of set flat.
//!
//! The filter refuses a phase's pixel when a channel is saturated (the strip beside a
//! press overexposes the slope that faces it), when too little LED light is left (a wall
//! facing away from both strips) or when it is not the strips' colour. Such a pixel's
//! slope on that axis is unknown, not zero: a band of zero slopes across an imprint's
//! wall is read as a flat step and the whole imprint comes out shallow (on a tuning skin
//! whose blue strip saturated the wall of a ball at the frame's left edge, 0.89 of its
//! depth). Each unread slope takes the mean of its 4-neighbours known when its turn
//! comes, in breadth-first order from the read pixels (so the nearest come first, and a
//! pixel may also use a neighbour of its own layer filled before it), and a band is
//! bridged from both sides. Pixels outside the touched set are skin at rest and count as read
//! (slope 0). O(pixels of the region).

use std::collections::VecDeque;

/// Reused buffers.
#[derive(Debug, Default)]
pub struct UnreadFill {
    /// 0: read; 1: unread, not yet filled; 2: unread, queued.
    state: Vec<u8>,
    queue: VecDeque<usize>,
}

const READ: u8 = 0;
const UNREAD: u8 = 1;
const QUEUED: u8 = 2;

impl UnreadFill {
    /// Fills `values` (row-major, `width` wide) at the indices `unread`, each from the
    /// mean of its 4-neighbours known when its turn comes. Indices out of range are
    /// ignored; pixels with no read pixel anywhere in reach keep their value. Returns
    /// how many were filled.
    pub fn fill(&mut self, values: &mut [f32], width: usize, unread: &[usize]) -> usize {
        let n = values.len();
        if unread.is_empty() || width == 0 || n == 0 {
            return 0;
        }
        let height = n / width;
        let n = width * height;
        self.state.clear();
        self.state.resize(n, READ);
        for &i in unread {
            if i < n {
                self.state[i] = UNREAD;
            }
        }
        // Seed: unread pixels beside a read one, in index order (whatever the order of
        // `unread`).
        self.queue.clear();
        for i in 0..n {
            if self.state[i] == UNREAD
                && neighbours(i, width, height).any(|j| self.state[j] == READ)
            {
                self.state[i] = QUEUED;
                self.queue.push_back(i);
            }
        }
        let mut filled = 0;
        while let Some(i) = self.queue.pop_front() {
            let (mut sum, mut count) = (0.0f32, 0u32);
            for j in neighbours(i, width, height) {
                match self.state[j] {
                    READ => {
                        sum += values[j];
                        count += 1;
                    }
                    UNREAD => {
                        self.state[j] = QUEUED;
                        self.queue.push_back(j);
                    }
                    _ => {}
                }
            }
            // Every queued pixel has a read neighbour by the time it is taken: it was
            // queued by one (or seeded beside one).
            if count > 0 {
                values[i] = sum / count as f32;
                filled += 1;
            }
            self.state[i] = READ;
        }
        filled
    }
}

/// The in-grid 4-neighbours of pixel `i`.
#[inline]
fn neighbours(i: usize, width: usize, height: usize) -> impl Iterator<Item = usize> {
    let (x, y) = (i % width, i / width);
    [
        (x > 0).then(|| i - 1),
        (x + 1 < width).then(|| i + 1),
        (y > 0).then(|| i - width),
        (y + 1 < height).then(|| i + width),
    ]
    .into_iter()
    .flatten()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_band_across_a_linear_ramp_is_filled_exactly() {
        // A ramp along x; a vertical band of three columns unread, bridged from both
        // sides: each side column takes its read neighbour, the middle one the mean.
        let (w, h) = (12usize, 5usize);
        let truth: Vec<f32> = (0..w * h).map(|i| (i % w) as f32 * 0.1).collect();
        let mut values = truth.clone();
        let mut unread = Vec::new();
        for y in 0..h {
            for x in 5..8 {
                values[y * w + x] = 0.0;
                unread.push(y * w + x);
            }
        }
        let filled = UnreadFill::default().fill(&mut values, w, &unread);
        assert_eq!(filled, unread.len());
        for y in 0..h {
            for x in 4..9 {
                let (got, want) = (values[y * w + x], truth[y * w + x]);
                // Within a step of the ramp.
                assert!(
                    (got - want).abs() <= 0.1 + 1e-6,
                    "({x},{y}): {got} vs {want}"
                );
            }
        }
        // The middle column (0.6) from both sides: within 0.05.
        for y in 0..h {
            assert!(
                (values[y * w + 6] - 0.6).abs() < 0.05,
                "row {y}: {}",
                values[y * w + 6]
            );
        }
    }

    #[test]
    fn a_single_hole_takes_the_mean_of_its_neighbours() {
        let (w, h) = (3usize, 3usize);
        let mut values = vec![1.0, 2.0, 3.0, 4.0, 99.0, 6.0, 7.0, 8.0, 9.0];
        let filled = UnreadFill::default().fill(&mut values, w, &[4]);
        assert_eq!(filled, 1);
        assert_eq!(values[4], (2.0 + 4.0 + 6.0 + 8.0) / 4.0);
        assert_eq!(h, values.len() / w);
    }

    #[test]
    fn nothing_read_leaves_the_values_and_bad_indices_are_ignored() {
        let mut values = vec![0.5f32; 6];
        let all: Vec<usize> = (0..6).collect();
        assert_eq!(UnreadFill::default().fill(&mut values, 3, &all), 0);
        assert!(values.iter().all(|&v| v == 0.5));
        let mut values = vec![1.0f32; 4];
        assert_eq!(
            UnreadFill::default().fill(&mut values, 2, &[0, 1000, usize::MAX]),
            1
        );
        assert_eq!(values, vec![1.0; 4]);
        // Degenerate sizes.
        assert_eq!(UnreadFill::default().fill(&mut [], 3, &[0]), 0);
        assert_eq!(UnreadFill::default().fill(&mut [1.0], 0, &[0]), 0);
    }

    #[test]
    fn the_fill_is_the_same_whatever_the_order_of_the_unread_list() {
        let (w, h) = (9usize, 7usize);
        let base: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 11) as f32).collect();
        let mut unread: Vec<usize> = (0..w * h).filter(|i| (i * 5) % 7 < 3).collect();
        let mut a = base.clone();
        UnreadFill::default().fill(&mut a, w, &unread);
        unread.reverse();
        unread.push(unread[0]);
        let mut b = base.clone();
        UnreadFill::default().fill(&mut b, w, &unread);
        assert_eq!(a, b);
    }
}
