//! A departure from the references that (nearly) every press shows at the same place,
//! away from the press itself: the reference frames show something the presses do not
//! (a press, debris, a mark, a light), or every press was made there. Calibrated on such
//! references, a model reads a phantom contact there in every frame; so calibration
//! refuses them, naming the place.
//!
//! Each press votes only for the blocks outside its own fitted circle (with a clearance),
//! so presses made again and again at one spot do not count against references that are
//! right. The flat skin departs above the detection threshold in about one block in
//! 10 000 ([`super::threshold`]), so a block that departs in most presses is no noise.

use super::circle::Circle;
use crate::tactile::contact::label_components;

/// Least share of the presses that may vote on a block (its press elsewhere) in which it
/// departs for it to count as shared.
pub const MIN_SHARE: f64 = 0.6;
/// Least number of presses voting on a block for a verdict.
pub const MIN_VOTERS: usize = 5;
/// A press's own zone, as a multiple of its fitted radius (its faint outer slopes lie
/// just outside the outline).
pub const OWN_ZONE: f64 = 1.3;

/// A region that departs in most presses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SharedDeparture {
    /// Its bounding box's centre, in blocks (column, row).
    pub centre: (f64, f64),
    /// Its size, in blocks.
    pub cells: usize,
    /// Presses in which its most shared block departs, and presses that voted on it.
    pub departs_in: (usize, usize),
}

/// The largest region of at least `min_cells` blocks (8-connected) that departs above
/// `threshold` in at least [`MIN_SHARE`] of the presses voting on it; `None` when there
/// is none. `maps[k]` is press `k`'s departure per block (`w × h`, NaN: unknown),
/// `circles[k]` its fitted circle in blocks (`None`: not found, the press does not vote;
/// its own zone: [`OWN_ZONE`] times the radius, plus a block). A region over half the
/// frame is no object on the skin (a threshold within the noise, light that changed) and
/// is left to the threshold's and the light's own checks.
pub fn find(
    maps: &[Vec<f32>],
    circles: &[Option<Circle>],
    w: usize,
    h: usize,
    threshold: f32,
    min_cells: usize,
) -> Option<SharedDeparture> {
    let n = w * h;
    let (mut departs, mut voters) = (vec![0usize; n], vec![0usize; n]);
    for (map, circle) in maps.iter().zip(circles) {
        let Some(c) = circle else { continue };
        let own = (OWN_ZONE * c.r + 1.0).powi(2);
        for (i, &d) in map.iter().enumerate().take(n) {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            if (x - c.cx).powi(2) + (y - c.cy).powi(2) <= own || d.is_nan() {
                continue;
            }
            voters[i] += 1;
            departs[i] += usize::from(d > threshold);
        }
    }
    let shared: Vec<bool> = (0..n)
        .map(|i| voters[i] >= MIN_VOTERS && departs[i] as f64 >= MIN_SHARE * voters[i] as f64)
        .collect();
    if !shared.iter().any(|&s| s) {
        return None;
    }
    let (labels, components) = label_components(&shared, w, h);
    let (k, c) = components
        .iter()
        .enumerate()
        .filter(|(_, c)| c.cells >= min_cells.max(1) && 2 * c.cells <= n)
        .max_by_key(|(_, c)| c.cells)?;
    let most = (0..n)
        .filter(|&i| labels[i] as usize == k + 1)
        .max_by_key(|&i| (departs[i], voters[i]))?;
    Some(SharedDeparture {
        centre: ((c.x0 + c.x1) as f64 / 2.0, (c.y0 + c.y1) as f64 / 2.0),
        cells: c.cells,
        departs_in: (departs[most], voters[most]),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Ten presses at ten places on flat skin with a few noisy blocks: nothing shared.
    /// The same with a spot departing in eight of them (the references show a press
    /// there): found, with its place and the vote. Presses all made at one place, each
    /// covering it: nothing shared (each press's own circle does not vote).
    #[test]
    fn a_spot_in_most_presses_is_found_and_repeated_presses_are_not() {
        let (w, h) = (40, 30);
        let circle = |k: usize| {
            Some(Circle {
                cx: 3.0 + 2.0 * k as f64,
                cy: 5.0 + (k % 3) as f64 * 6.0,
                r: 2.0,
            })
        };
        let press = |k: usize, spot: bool| -> Vec<f32> {
            let c = circle(k).unwrap();
            (0..w * h)
                .map(|i| {
                    let (x, y) = ((i % w) as f64, (i / w) as f64);
                    let inside = (x - c.cx).hypot(y - c.cy) <= c.r;
                    let at_spot =
                        spot && (30..33).contains(&(i % w)) && (20..23).contains(&(i / w));
                    if inside || at_spot {
                        1.0
                    } else if (i * 7 + k * 13).is_multiple_of(997) {
                        0.9 // a noisy block, in one press only
                    } else {
                        0.05
                    }
                })
                .collect()
        };
        let circles: Vec<_> = (0..10).map(circle).collect();
        let clean: Vec<_> = (0..10).map(|k| press(k, false)).collect();
        assert_eq!(find(&clean, &circles, w, h, 0.3, 3), None);
        let spotted: Vec<_> = (0..10).map(|k| press(k, k < 8)).collect();
        let found = find(&spotted, &circles, w, h, 0.3, 3).expect("the spot");
        assert_eq!(found.cells, 9);
        assert_eq!(found.centre, (31.0, 21.0));
        assert_eq!(found.departs_in, (8, 10));
        // Every press at the spot: each covers it, none votes there.
        let at_spot = Some(Circle {
            cx: 31.0,
            cy: 21.0,
            r: 2.0,
        });
        let only_there: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                if (x - 31.0).hypot(y - 21.0) <= 2.0 {
                    1.0
                } else {
                    0.05
                }
            })
            .collect();
        let repeated = vec![only_there; 10];
        assert_eq!(find(&repeated, &[at_spot; 10], w, h, 0.3, 3), None);
        // Everything departing everywhere (a threshold within the noise): not an object.
        let everywhere: Vec<_> = (0..10).map(|_| vec![1.0f32; w * h]).collect();
        assert_eq!(find(&everywhere, &circles, w, h, 0.3, 3), None);
        // Too few voters for a verdict.
        assert_eq!(find(&spotted[..4], &circles[..4], w, h, 0.3, 3), None);
    }
}
