//! Timing helpers the benchmarks, the pipelines' stage timings and the live reports
//! share: milliseconds between two instants, the median of repeated runs, percentiles of
//! latencies.

use std::time::Instant;

/// Milliseconds from `a` to `b`: the stage timings of the pipelines.
pub fn ms_between(a: Instant, b: Instant) -> f64 {
    (b - a).as_secs_f64() * 1e3
}

/// Median wall time in ms of `repeats` runs of `f`, after one warm-up run.
pub fn median_ms(repeats: usize, mut f: impl FnMut()) -> f64 {
    f(); // warm-up: plans, caches
    median(
        (0..repeats.max(1))
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect(),
    )
}

/// The median of `v` (the upper one of an even count); 0 when empty.
pub fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The `q` quantile (0..1) of `v`, nearest rank: (p50, p99) of latencies. `None` when
/// empty.
pub fn quantiles<const N: usize>(mut v: Vec<f64>, q: [f64; N]) -> Option<[f64; N]> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let last = (v.len() - 1) as f64;
    Some(q.map(|q| v[(last * q.clamp(0.0, 1.0)).round() as usize]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_take_the_nearest_rank() {
        let v: Vec<f64> = (1..=101).rev().map(f64::from).collect();
        assert_eq!(
            quantiles(v, [0.0, 0.5, 0.99, 1.0]),
            Some([1.0, 51.0, 100.0, 101.0])
        );
        assert_eq!(quantiles(Vec::new(), [0.5]), None);
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
    }
}
