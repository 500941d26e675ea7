//! What semi-global matching is asked to do: the paths it aggregates along and its
//! parameters, checked before a matcher is made; and the sizes every stage shares.

use serde::Serialize;

use crate::stereo::block_match::{MatchError, SubpixelFit};

/// Image paths the costs are aggregated along.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Paths {
    /// Along the row both ways and straight down from the row above: the paths of
    /// OpenCV's `StereoSGBM` in its 3-way mode, one sweep and no volume like
    /// [`Paths::Five`]. Fastest; streaks along rows and columns where texture is weak.
    Three,
    /// Horizontal and vertical, in two sweeps over the rows.
    Four,
    /// Along the row both ways and the three paths from the row above (straight down
    /// and the two downward diagonals): one sweep, each row matched as soon as the
    /// sweep has passed it, no cost or sum volume.
    Five,
    /// Every direction and diagonal, in two sweeps: fewest streaks along rows and
    /// columns.
    Eight,
}

impl Paths {
    /// Every choice, fewest paths first.
    pub const ALL: [Paths; 4] = [Paths::Three, Paths::Four, Paths::Five, Paths::Eight];

    /// How many.
    pub fn count(self) -> usize {
        match self {
            Paths::Three => 3,
            Paths::Four => 4,
            Paths::Five => 5,
            Paths::Eight => 8,
        }
    }

    /// The choice of `count` paths, if there is one.
    pub fn with_count(count: usize) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.count() == count)
    }
}

/// A number of paths: "3", "4", "5" or "8".
impl std::str::FromStr for Paths {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        s.trim()
            .parse()
            .ok()
            .and_then(Self::with_count)
            .ok_or_else(|| {
                format!(
                    "{s:?} is not 3, 4, 5 or 8 paths (8: every direction, the default; 3: \
                     along the row both ways and down, the fastest)"
                )
            })
    }
}

/// Semi-global matching parameters. [`Default`]: 64 disparities, 8 paths, penalties
/// for the 48-bit census cost.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SgmParams {
    /// Smallest disparity searched (pixels).
    pub min_disparity: u32,
    /// Number of disparities searched: a positive multiple of 16.
    pub num_disparities: u32,
    /// Penalty for a disparity step of one pixel between neighbours along a path.
    pub p1: u16,
    /// Penalty for a larger step (> `p1`).
    pub p2: u16,
    /// Paths aggregated.
    pub paths: Paths,
    /// Percent by which the best aggregated cost must beat every other (not adjacent)
    /// candidate.
    pub uniqueness_ratio: u32,
    /// Largest disagreement (pixels) between the left→right and right→left matches;
    /// `None` turns the check off.
    pub lr_max_diff: Option<u32>,
    /// Regions of at most this many pixels are removed as speckles (0: off).
    pub speckle_window: u32,
    /// Largest disparity step (pixels) inside one speckle region.
    pub speckle_range: f32,
    /// Sub-pixel fit on the aggregated costs.
    pub subpixel: SubpixelFit,
    /// Then refine each disparity on the images themselves: the least-squares shift
    /// that lines up a window of the left view with the right view (two Gauss–Newton
    /// steps from the aggregated-cost estimate). Aggregated census costs place the
    /// minimum only to about 0.15 px.
    pub refine: bool,
    /// Side of the refinement's square window (odd, 3..=31; default 11). Larger windows
    /// average more noise on smooth surfaces and blur small depth steps over more
    /// columns. The default is the smallest that keeps `stereo-eval`'s unfiltered RMS
    /// error under 0.3 % from 100 to 300 mm behind the hazy skin (ten frames a
    /// distance, 2026-11-28: 9×9 up to 0.346 %, 11×11 up to 0.279 %, 13×13 up to
    /// 0.236 %); a 0.5 px depth step spreads over about as many columns as the window.
    pub refine_window: u32,
}

impl Default for SgmParams {
    fn default() -> Self {
        Self {
            min_disparity: 0,
            num_disparities: 64,
            p1: 8,
            p2: 96,
            paths: Paths::Eight,
            uniqueness_ratio: 10,
            lr_max_diff: Some(1),
            speckle_window: 100,
            speckle_range: 1.0,
            subpixel: SubpixelFit::Equiangular,
            refine: true,
            refine_window: 11,
        }
    }
}

impl SgmParams {
    /// The largest disparity searched.
    pub fn max_disparity(&self) -> u32 {
        self.min_disparity + self.num_disparities - 1
    }

    /// Checks every field; the matcher refuses parameters that fail.
    pub fn validate(&self) -> Result<(), MatchError> {
        let bad = |name, value: String, why| Err(MatchError::InvalidParam { name, value, why });
        let n = self.num_disparities;
        if n == 0 || !n.is_multiple_of(16) || n > 1024 {
            return bad(
                "num_disparities",
                n.to_string(),
                "a multiple of 16, 16..=1024",
            );
        }
        if u64::from(self.min_disparity) + u64::from(n) > 4096 {
            return bad(
                "min_disparity",
                self.min_disparity.to_string(),
                "the largest disparity searched must be below 4096",
            );
        }
        if self.p1 == 0 || self.p2 <= self.p1 || self.p2 > 1024 {
            return bad(
                "p2",
                format!("{} (p1 = {})", self.p2, self.p1),
                "penalties 0 < p1 < p2 <= 1024",
            );
        }
        if self.uniqueness_ratio >= 100 {
            return bad(
                "uniqueness_ratio",
                self.uniqueness_ratio.to_string(),
                "a percentage below 100",
            );
        }
        let side = self.refine_window;
        if side.is_multiple_of(2) || !(3..=31).contains(&side) {
            return bad(
                "refine_window",
                side.to_string(),
                "an odd window side, 3..=31 (9 is the default)",
            );
        }
        if !(self.speckle_range.is_finite() && self.speckle_range >= 0.0) {
            return bad(
                "speckle_range",
                self.speckle_range.to_string(),
                "a finite, non-negative number of pixels",
            );
        }
        Ok(())
    }
}

/// Sizes every stage shares.
pub(super) struct Shape {
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) nd: usize,
    pub(super) d_min: usize,
}
