//! What a stereo result should make its user look twice at: almost nothing matched (and
//! whether the view is blank, when nothing else is worth saying), many
//! best matches at the ends of the disparity range (the scene is nearer than `--near-mm`
//! or beyond `--far-mm`) or past them (dropped: outside the working range), depths
//! crowding the range's ends. Each warning says what was
//! seen, with the numbers, and what to try; `stereo --strict` turns them into failure.

use super::block_match::MatchStats;

/// Share of valid pixels below which a result is almost empty.
pub const MIN_VALID_FRACTION: f64 = 0.05;
/// Share of the searched pixels whose best match lay at the range's end, above which the
/// scene likely lies outside the working range.
pub const MAX_RANGE_EDGE_FRACTION: f64 = 0.10;
/// Share of pixels with a flat matching window from which an almost empty result is put
/// down to a blank view (and only that is said).
pub const MIN_FLAT_FRACTION: f64 = 0.5;
/// Share of valid depths within 2 % of the range's ends above which the range likely
/// cuts the scene.
pub const MAX_AT_LIMIT_FRACTION: f64 = 0.20;

/// The warnings of one result: `stats` of the matcher, `depths` the valid depths in any
/// order (mm), over `pixels` pixels, searched between `near_mm` and `far_mm`.
pub fn of(
    stats: &MatchStats,
    depths: &[f32],
    pixels: usize,
    near_mm: f64,
    far_mm: f64,
) -> Vec<String> {
    let mut out = Vec::new();
    let pixels = pixels.max(1) as f64;
    let valid = depths.len() as f64 / pixels;
    let flat = stats.flat as f64 / pixels;
    if valid < MIN_VALID_FRACTION && flat >= MIN_FLAT_FRACTION {
        // A blank view: every other hint (the range, the calibration) would mislead.
        out.push(format!(
            "only {:.1}% of pixels have a depth: the left view has almost no texture ({:.0}% \
             of its pixels have a flat matching window): a blank, uniform or out-of-focus \
             view, a covered lens or no light; a wider --near-mm/--far-mm will not help",
            100.0 * valid,
            100.0 * flat
        ));
        return out;
    }
    if valid < MIN_VALID_FRACTION {
        out.push(format!(
            "only {:.1}% of pixels have a depth (below {:.0}%): too little texture ({} pixels), \
             a scene outside --near-mm {near_mm}..--far-mm {far_mm}, or a calibration of \
             another rig",
            100.0 * valid,
            100.0 * MIN_VALID_FRACTION,
            stats.flat
        ));
    }
    let edge = stats.range_edge as f64 / pixels;
    if edge > MAX_RANGE_EDGE_FRACTION {
        out.push(format!(
            "{:.0}% of pixels matched best at an end of the disparity range: part of the \
             scene is nearer than --near-mm {near_mm} or beyond --far-mm {far_mm}; widen the \
             range",
            100.0 * edge
        ));
    }
    let outside = stats.outside_range as f64 / pixels;
    if outside > MAX_RANGE_EDGE_FRACTION {
        out.push(format!(
            "{:.0}% of pixels matched at depths outside --near-mm {near_mm}..--far-mm \
             {far_mm} and were left without one: part of the scene lies outside the working \
             range; widen it (in Python, near_mm and far_mm)",
            100.0 * outside
        ));
    }
    if !depths.is_empty() {
        let (lo, hi) = (near_mm * 1.02, far_mm * 0.98);
        let at_limit = depths
            .iter()
            .filter(|&&d| f64::from(d) <= lo || f64::from(d) >= hi)
            .count() as f64
            / depths.len() as f64;
        if at_limit > MAX_AT_LIMIT_FRACTION {
            out.push(format!(
                "{:.0}% of depths lie at the ends of the working range {near_mm}..{far_mm} mm: \
                 the range likely cuts the scene; widen --near-mm/--far-mm",
                100.0 * at_limit
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_cut_and_healthy_results() {
        let stats = MatchStats {
            low_texture: 400,
            flat: 400,
            range_edge: 5,
            ..Default::default()
        };
        let healthy: Vec<f32> = (0..600).map(|i| 120.0 + i as f32 * 0.05).collect();
        assert!(of(&stats, &healthy, 1000, 50.0, 400.0).is_empty());
        let w = of(&stats, &healthy[..20], 1000, 50.0, 400.0);
        assert_eq!(w.len(), 1);
        assert!(
            w[0].contains("only 2.0%") && w[0].contains("(400 pixels)"),
            "{w:?}"
        );
        let cut = MatchStats {
            range_edge: 300,
            ..stats
        };
        let w = of(&cut, &healthy, 1000, 50.0, 400.0);
        assert!(
            w.iter().any(|w| w.contains("30% of pixels matched best")),
            "{w:?}"
        );
        let crowded: Vec<f32> = (0..600)
            .map(|i| if i < 300 { 395.0 } else { 200.0 })
            .collect();
        let w = of(&stats, &crowded, 1000, 50.0, 400.0);
        assert!(w.iter().any(|w| w.contains("50% of depths")), "{w:?}");
        let outside = MatchStats {
            outside_range: 150,
            ..stats
        };
        let w = of(&outside, &healthy, 1000, 50.0, 400.0);
        assert!(
            w.len() == 1 && w[0].contains("15% of pixels matched at depths outside"),
            "{w:?}"
        );
        assert!(
            !of(&stats, &[], 0, 50.0, 400.0).is_empty(),
            "nothing at all warns"
        );
        // A blank pair under semi-global matching: best matches at the range's end, but
        // the view is flat, and only that is said.
        let blank = MatchStats {
            range_edge: 850,
            flat: 990,
            ..Default::default()
        };
        let w = of(&blank, &[], 1000, 50.0, 400.0);
        assert!(
            w.len() == 1 && w[0].contains("no texture (99%") && w[0].contains("will not help"),
            "{w:?}"
        );
        // Texture there, nothing matched: the range and the calibration are the suspects.
        let w = of(&MatchStats { flat: 100, ..blank }, &[], 1000, 50.0, 400.0);
        assert!(w.iter().any(|w| w.contains("widen the range")), "{w:?}");
    }
}
