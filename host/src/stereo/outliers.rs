//! Statistical outlier removal, as Open3D's `remove_statistical_outlier`: for every
//! point, the mean distance to its `k` nearest neighbours; points whose mean is more
//! than `std_ratio` standard deviations above the cloud's average are dropped (by
//! default with each mean divided by the point's depth, see [`OutlierParams`]). Nearest
//! neighbours come from a k-d tree (`kiddo`), queried in parallel.

use std::num::NonZeroUsize;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use serde::Serialize;

/// Outlier removal settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct OutlierParams {
    /// Neighbours per point (Open3D's `nb_neighbors`).
    pub neighbours: usize,
    /// Threshold in standard deviations above the mean.
    pub std_ratio: f64,
    /// Divide each point's mean neighbour distance by its depth (Z) before the
    /// statistics. Points of a depth image are spaced in proportion to their depth, so
    /// without this the far part of any slanted surface is "sparse" and goes; Open3D's
    /// filter does not do this (set `false` to match it).
    pub per_depth: bool,
}

impl Default for OutlierParams {
    fn default() -> Self {
        Self {
            neighbours: 20,
            std_ratio: 2.0,
            per_depth: true,
        }
    }
}

/// Which points to keep (`true`), one entry per point. Clouds with at most `neighbours`
/// points are kept whole (no statistics to judge by); non-finite points are dropped.
pub fn statistical_inliers(points: &[[f32; 3]], params: &OutlierParams) -> Vec<bool> {
    let finite: Vec<bool> = points
        .iter()
        .map(|p| p.iter().all(|c| c.is_finite()))
        .collect();
    let Some(k) = NonZeroUsize::new(params.neighbours) else {
        return finite;
    };
    let usable: Vec<[f32; 3]> = points
        .iter()
        .zip(&finite)
        .filter(|&(_, &ok)| ok)
        .map(|(p, _)| *p)
        .collect();
    if usable.len() <= k.get() || !params.std_ratio.is_finite() {
        return finite;
    }
    let Ok(tree) = ImmutableKdTree::<f32, 3>::new_from_slice(&usable) else {
        return finite;
    };
    // k + 1: the nearest is the point itself.
    let query_k = NonZeroUsize::new(k.get() + 1).expect("k + 1 > 0");
    let mean_distance: Vec<f64> = usable
        .par_iter()
        .map(|p| {
            let found = tree
                .query(p)
                .nearest_n::<SquaredEuclidean<f32>>(query_k)
                .execute();
            let sum: f64 = found
                .iter()
                .skip(1)
                .map(|n| f64::from(n.distance).sqrt())
                .sum();
            let mean = sum / (found.len().saturating_sub(1)).max(1) as f64;
            let z = f64::from(p[2]);
            if params.per_depth && z > 0.0 {
                mean / z
            } else {
                mean
            }
        })
        .collect();
    let n = mean_distance.len() as f64;
    let mean = mean_distance.iter().sum::<f64>() / n;
    let var = mean_distance
        .iter()
        .map(|m| (m - mean) * (m - mean))
        .sum::<f64>()
        / (n - 1.0);
    let limit = mean + params.std_ratio * var.sqrt();
    let mut verdict = mean_distance.into_iter().map(|m| m <= limit);
    finite
        .into_iter()
        .map(|ok| ok && verdict.next().unwrap_or(false))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn far_points_go_a_dense_grid_stays() {
        // A 30×30 grid at 1 mm spacing on the plane z = 100, plus three strays.
        let mut pts: Vec<[f32; 3]> = (0..900)
            .map(|i| [(i % 30) as f32, (i / 30) as f32, 100.0])
            .collect();
        pts.push([15.0, 15.0, 140.0]);
        pts.push([-40.0, 0.0, 100.0]);
        pts.push([f32::NAN, 0.0, 0.0]);
        pts.push([200.0, 200.0, 200.0]);
        let keep = statistical_inliers(&pts, &OutlierParams::default());
        assert_eq!(keep.len(), 904);
        assert!(keep[..900].iter().all(|&k| k), "grid points dropped");
        assert_eq!(&keep[900..], &[false, false, false, false]);
        // Too few points: kept whole (but NaN still goes).
        // Pixel grids of a depth camera: a 60×60 patch at 100 mm (0.33 mm apart) and a
        // 20×20 patch at 300 mm (1 mm apart). Judged per depth, both are the same
        // density and stay; by Open3D's rule the far patch is "sparse" and goes.
        let grid = |n: usize, z: f32| {
            (0..n * n).map(move |i| {
                let (u, v) = ((i % n) as f32, (i / n) as f32);
                [u * z / 300.0, v * z / 300.0 + 100.0, z]
            })
        };
        let two: Vec<[f32; 3]> = grid(60, 100.0).chain(grid(20, 300.0)).collect();
        let kept = |per_depth| {
            let p = OutlierParams {
                per_depth,
                ..OutlierParams::default()
            };
            statistical_inliers(&two, &p)[3600..]
                .iter()
                .filter(|&&k| k)
                .count()
        };
        // (The rims of a patch have fewer neighbours on one side: SOR drops some of them
        // whenever the cloud is this uniform, here 76 of the far patch's 400.)
        assert!(kept(true) >= 18 * 18, "{}", kept(true));
        assert_eq!(kept(false), 0);
        let few = [
            [0.0, 0.0, 0.0],
            [100.0, 0.0, 0.0],
            [f32::INFINITY, 0.0, 0.0],
        ];
        assert_eq!(
            statistical_inliers(&few, &OutlierParams::default()),
            vec![true, true, false]
        );
    }
}
