//! Timing helpers the benchmarks share (tactile and stereo): the median of repeated runs.

use std::time::Instant;

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
