//! The disparity matcher a pipeline runs: block matching (fast, the default) or
//! semi-global matching (fills weak texture and slanted surfaces, slower), behind one
//! `compute`.

use serde::Serialize;

use super::block_match::{BlockMatchParams, BlockMatcher, DisparityMap, Kernel, MatchError};
use super::prefilter;
use super::sgm::{Paths, SemiGlobalMatcher, SgmParams};
use crate::grid::Grid;

/// Which matcher.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MatcherKind {
    /// Block matching ([`super::block_match`]).
    #[default]
    Bm,
    /// Semi-global matching ([`super::sgm`]).
    Sgm,
}

impl MatcherKind {
    /// Every matcher, the default first.
    pub const ALL: [MatcherKind; 2] = [MatcherKind::Bm, MatcherKind::Sgm];

    /// The name options, files and Python take: "bm" or "sgm".
    pub fn name(self) -> &'static str {
        match self {
            MatcherKind::Bm => "bm",
            MatcherKind::Sgm => "sgm",
        }
    }

    /// The matching window (side, px) this matcher takes when none is given: block
    /// matching's blocks (9, as OpenCV's StereoBM sample) or semi-global matching's
    /// refinement window ([`SgmParams::refine_window`], 11).
    pub fn default_window(self) -> u32 {
        match self {
            MatcherKind::Bm => BlockMatchParams::default().block_size,
            MatcherKind::Sgm => SgmParams::default().refine_window,
        }
    }
}

/// "bm" or "sgm" ([`MatcherKind::name`]).
impl std::str::FromStr for MatcherKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s.trim())
            .ok_or_else(|| {
                format!("matcher {s:?}: not bm (block matching) or sgm (semi-global matching)")
            })
    }
}

/// A matcher, built once and reused for every frame.
#[derive(Debug, Clone)]
pub enum Matcher {
    /// Block matching.
    Block(BlockMatcher),
    /// Semi-global matching (boxed: its parameters and kept volumes are several times
    /// a block matcher's size).
    SemiGlobal(Box<SemiGlobalMatcher>),
}

impl Matcher {
    /// A matcher of `kind` over the disparities of `range` (its other block-matching
    /// settings are used by `bm` only, except the block size, which is `sgm`'s
    /// refinement window); `sgm` aggregates along `sgm_paths` and takes its defaults
    /// otherwise.
    pub fn new(
        kind: MatcherKind,
        range: BlockMatchParams,
        sgm_paths: Paths,
    ) -> Result<Self, MatchError> {
        Ok(match kind {
            MatcherKind::Bm => Self::Block(BlockMatcher::new(range)?),
            MatcherKind::Sgm => Self::SemiGlobal(Box::new(
                SemiGlobalMatcher::new(SgmParams {
                    min_disparity: range.min_disparity,
                    num_disparities: range.num_disparities,
                    paths: sgm_paths,
                    refine_window: range.block_size,
                    ..SgmParams::default()
                })
                // The window came as the block size: name it so.
                .map_err(|e| match e {
                    MatchError::InvalidParam {
                        name: "refine_window",
                        value,
                        why,
                    } => MatchError::InvalidParam {
                        name: "block size (semi-global matching's refinement window)",
                        value,
                        why,
                    },
                    e => e,
                })?,
            )),
        })
    }

    /// Matches a rectified pair.
    pub fn compute(&self, left: &Grid<u8>, right: &Grid<u8>) -> Result<DisparityMap, MatchError> {
        match self {
            Self::Block(m) => {
                let mut out = m.compute(left, right)?;
                out.stats.flat = out.stats.low_texture;
                Ok(out)
            }
            Self::SemiGlobal(m) => m.compute(left, right),
        }
    }

    /// Which matcher this is.
    pub fn kind(&self) -> MatcherKind {
        match self {
            Self::Block(_) => MatcherKind::Bm,
            Self::SemiGlobal(_) => MatcherKind::Sgm,
        }
    }

    /// Paths semi-global matching aggregates along (`None` for block matching).
    pub fn sgm_paths(&self) -> Option<Paths> {
        match self {
            Self::Block(_) => None,
            Self::SemiGlobal(m) => Some(m.params().paths),
        }
    }

    /// Side of the matching window (px): block matching's blocks, semi-global
    /// matching's sub-pixel refinement window.
    pub fn window(&self) -> u32 {
        match self {
            Self::Block(m) => m.params().block_size,
            Self::SemiGlobal(m) => m.params().refine_window,
        }
    }

    /// The compiled variant in use.
    pub fn kernel(&self) -> Kernel {
        match self {
            Self::Block(m) => m.kernel(),
            Self::SemiGlobal(m) => m.kernel(),
        }
    }

    /// Smallest and largest disparity searched (px).
    pub fn disparity_range(&self) -> (u32, u32) {
        match self {
            Self::Block(m) => (m.params().min_disparity, m.params().max_disparity()),
            Self::SemiGlobal(m) => (m.params().min_disparity, m.params().max_disparity()),
        }
    }

    /// Number of disparities searched.
    pub fn num_disparities(&self) -> u32 {
        let (lo, hi) = self.disparity_range();
        hi - lo + 1
    }
}

/// Pixels of `image` whose window has less texture than block matching's default
/// threshold (its default prefilter, window and texture measure: the threshold is a sum
/// over that window, so the window is block matching's whatever the matcher's is).
pub(super) fn flat_pixels(image: &Grid<u8>) -> usize {
    let d = BlockMatchParams::default();
    let response = prefilter::x_sobel(image, d.prefilter_cap);
    let texture = prefilter::texture(&response, d.prefilter_cap, d.block_size as usize);
    texture
        .as_slice()
        .iter()
        .filter(|&&t| t < d.texture_threshold)
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_read_back_and_match_the_summary() {
        for kind in MatcherKind::ALL {
            assert_eq!(kind.name().parse::<MatcherKind>(), Ok(kind));
            // summary.json writes the kind through serde: the same name.
            let json = serde_json::to_string(&kind).unwrap();
            assert_eq!(json, format!("\"{}\"", kind.name()));
        }
        let e = "census".parse::<MatcherKind>().unwrap_err();
        assert!(e.contains("\"census\": not bm"), "{e}");
    }

    /// With semi-global matching the block size is the refinement window, and a bad one
    /// is named as the block size the user set.
    #[test]
    fn the_block_size_is_the_refinement_window() {
        let range = BlockMatchParams {
            block_size: 13,
            ..BlockMatchParams::default()
        };
        let m = Matcher::new(MatcherKind::Sgm, range, Paths::Three).unwrap();
        assert_eq!(m.window(), 13);
        let bm = Matcher::new(MatcherKind::Bm, range, Paths::Three).unwrap();
        assert_eq!(bm.window(), 13);
        let even = BlockMatchParams {
            block_size: 8,
            ..range
        };
        let e = Matcher::new(MatcherKind::Sgm, even, Paths::Three)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("block size") && e.contains("= 8: an odd window side"),
            "{e}"
        );
    }

    #[test]
    fn path_counts_read_back() {
        for paths in Paths::ALL {
            assert_eq!(Paths::with_count(paths.count()), Some(paths));
            assert_eq!(paths.count().to_string().parse::<Paths>(), Ok(paths));
        }
        for bad in ["0", "6", "eight", "", "-3"] {
            let e = bad.parse::<Paths>().unwrap_err();
            assert!(e.contains("not 3, 4, 5 or 8"), "{e}");
        }
        assert_eq!(Paths::with_count(7), None);
    }
}
