//! The whole stereo frame: rectify both views (maps built once), match, post-filter,
//! reproject, and optionally drop outlying points. One [`StereoPipeline`] per sensor
//! and stream; it keeps the temporal filter's state between frames.

use std::time::Instant;

use serde::Serialize;

use super::block_match::{BlockMatchParams, MatchError, MatchStats};
use super::calibration::StereoCalibration;
use super::matcher::{Matcher, MatcherKind, flat_pixels};
use super::outliers::{OutlierParams, grid_inliers};
use super::postfilter::{HoleFill, SpatialFilter, TemporalFilter, TemporalParams};
use super::rectify::{Rectification, RectifyError, RemapSizeError, RemapTable};
use super::reproject::{PointCloud, depth_from_disparity, reproject};
use super::sgm::{Paths, SgmParams};
use super::warnings::MIN_VALID_FRACTION;
use crate::grid::Grid;

/// How the pipeline runs. [`Default`] suits the sensor: depths 5–60 cm, the matcher's
/// defaults, the spatial filter on, the rest off.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StereoConfig {
    /// Rectified focal length as a share of the cameras' (smaller shows more of a wide
    /// lens at lower resolution).
    pub rectify_scale: f64,
    /// Nearest depth searched, mm.
    pub near_mm: f64,
    /// Farthest depth searched, mm.
    pub far_mm: f64,
    /// Which matcher: block matching (default) or semi-global.
    pub matcher: MatcherKind,
    /// Paths semi-global matching aggregates along (`sgm` only).
    pub sgm_paths: Paths,
    /// Matching window side (odd): block matching's blocks (3..=31 with the default
    /// pre-filter), semi-global matching's refinement window (3..=31; larger averages
    /// more noise on smooth surfaces and blurs small depth steps over more columns).
    /// `None`: the matcher's own ([`MatcherKind::default_window`]: 9 for `bm`, 11 for
    /// `sgm`).
    pub block_size: Option<u32>,
    /// Matcher uniqueness ratio, percent.
    pub uniqueness_ratio: u32,
    /// Matcher texture threshold.
    pub texture_threshold: u32,
    /// Edge-preserving spatial filter.
    pub spatial: Option<SpatialFilter>,
    /// Temporal filter (for streams).
    pub temporal: Option<TemporalParams>,
    /// Hole filling.
    pub hole_fill: Option<HoleFill>,
    /// Statistical outlier removal on the point cloud.
    pub outliers: Option<OutlierParams>,
}

impl StereoConfig {
    /// The matching window side this configuration gives: `block_size`, or the matcher's
    /// own when none is given.
    pub fn window(&self) -> u32 {
        self.block_size.unwrap_or(self.matcher.default_window())
    }
}

impl Default for StereoConfig {
    fn default() -> Self {
        let m = BlockMatchParams::default();
        Self {
            rectify_scale: 1.0,
            near_mm: 50.0,
            far_mm: 600.0,
            matcher: MatcherKind::Bm,
            sgm_paths: SgmParams::default().paths,
            block_size: None,
            uniqueness_ratio: m.uniqueness_ratio,
            texture_threshold: m.texture_threshold,
            spatial: Some(SpatialFilter::default()),
            temporal: None,
            hole_fill: None,
            outliers: None,
        }
    }
}

/// Why the pipeline could not be built or run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StereoError {
    /// Rectification failed.
    #[error(transparent)]
    Rectify(#[from] RectifyError),
    /// Matcher parameters or inputs.
    #[error(transparent)]
    Match(#[from] MatchError),
    /// A frame whose sides differ from the calibration's (a transposed array, another
    /// camera mode), even when it has as many pixels.
    #[error(
        "{camera} frame is {got:?} (width, height) but the calibration is {want:?}: give \
         frames of the calibrated size (an array is (height, width))"
    )]
    FrameDims {
        /// "left" or "right".
        camera: &'static str,
        /// The frame's size.
        got: (u32, u32),
        /// The calibration's.
        want: (u32, u32),
    },
    /// The disparities the working range asks for reach past the image: no pixel could
    /// be matched.
    #[error(
        "the working range needs disparities up to {max} px but the rectified image is \
         {width} px wide: nothing could match; raise --near-mm to about {nearest_mm:.0} mm \
         (the nearest depth this rig sees at this scale), or lower --scale"
    )]
    RangeBeyondImage {
        /// Largest disparity searched (px).
        max: u32,
        /// Rectified width (px).
        width: u32,
        /// The nearest depth whose disparity fits the image (mm).
        nearest_mm: f64,
    },
    /// The rectified image is narrower than the fewest disparities searched beside the
    /// matching window, or lower than the window: no working range fits it.
    #[error(
        "the rectified image is {}×{} px: too small to match whatever the working range \
         (16 disparities beside the {}-px matching window need at least {}×{} px); give \
         larger frames (and their calibration), or raise --scale",
        size.0,
        size.1,
        least.1 - 2,
        least.0,
        least.1
    )]
    TooSmall {
        /// Rectified size (px).
        size: (u32, u32),
        /// The least size that can match (px).
        least: (u32, u32),
    },
    /// A frame of the wrong size.
    #[error("{camera} frame: {source}")]
    FrameSize {
        /// "left" or "right".
        camera: &'static str,
        /// Details.
        source: RemapSizeError,
    },
}

/// Milliseconds per stage of one frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct StereoTimings {
    /// Rectifying both views.
    pub rectify_ms: f64,
    /// Matching (costs, checks, speckles).
    pub match_ms: f64,
    /// Post-filters.
    pub filter_ms: f64,
    /// Depth and point cloud.
    pub reproject_ms: f64,
    /// Outlier removal.
    pub outliers_ms: f64,
    /// The whole frame.
    pub total_ms: f64,
}

/// One processed frame.
#[derive(Debug, Clone)]
pub struct StereoFrame {
    /// The rectified left view (what the maps below line up with).
    pub left: Grid<u8>,
    /// The rectified right view.
    pub right: Grid<u8>,
    /// Disparity (px, NaN invalid), after the filters and outlier removal.
    pub disparity: Grid<f32>,
    /// Depth along the rectified optical axis, mm (NaN invalid).
    pub depth_mm: Grid<f32>,
    /// Points in the rectified left camera's frame, mm.
    pub cloud: PointCloud,
    /// The matcher's counts.
    pub stats: MatchStats,
    /// Pixels filled by hole filling.
    pub holes_filled: usize,
    /// Points removed as outliers.
    pub outliers_removed: usize,
    /// Time per stage.
    pub timings: StereoTimings,
}

impl StereoFrame {
    /// The valid depths (mm), in pixel order: for counts and fill rates (a median needs
    /// only `select_nth_unstable_by`, not a sort).
    pub fn valid_depths(&self) -> Vec<f32> {
        self.depth_mm
            .as_slice()
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .collect()
    }

    /// The valid depths (mm), sorted: for percentiles.
    pub fn sorted_valid_depths(&self) -> Vec<f32> {
        let mut v = self.valid_depths();
        v.sort_by(f32::total_cmp);
        v
    }

    /// What this result should make its user look twice at (see [`super::warnings`]),
    /// for the `config` it was processed with.
    pub fn warnings(&self, config: &StereoConfig) -> Vec<String> {
        let pixels = self.disparity.width() * self.disparity.height();
        let depths = self.valid_depths();
        super::warnings::of(&self.stats, &depths, pixels, config.near_mm, config.far_mm)
    }
}

/// Rectification maps, matcher and filter state for one calibrated pair.
#[derive(Debug, Clone)]
pub struct StereoPipeline {
    config: StereoConfig,
    rectification: Rectification,
    maps: (RemapTable, RemapTable),
    matcher: Matcher,
    temporal: Option<TemporalFilter>,
}

impl StereoPipeline {
    /// Builds the maps and the matcher for `calib`.
    pub fn new(calib: &StereoCalibration, config: StereoConfig) -> Result<Self, StereoError> {
        let rectification = Rectification::bouguet(calib, config.rectify_scale)?;
        let params = BlockMatchParams {
            block_size: config.window(),
            uniqueness_ratio: config.uniqueness_ratio,
            texture_threshold: config.texture_threshold,
            ..BlockMatchParams::for_depth_range(
                rectification.focal(),
                rectification.baseline(),
                config.near_mm,
                config.far_mm,
            )?
        };
        let width = rectification.width;
        // The fewest disparities searched (16) and the matching window's margins must fit
        // beside each other whatever the range: narrower, no --near-mm helps.
        // (And the window must fit the height.)
        let least = (16 + params.block_size + 2, params.block_size + 2);
        let height = rectification.height;
        if width < least.0 || height < least.1 {
            return Err(StereoError::TooSmall {
                size: (width, height),
                least,
            });
        }
        if params.max_disparity() + 2 > width {
            let fb = rectification.focal() * rectification.baseline();
            return Err(StereoError::RangeBeyondImage {
                max: params.max_disparity(),
                width,
                // (The range is rounded up to 16 disparities: 16 px of margin.)
                nearest_mm: (fb / (f64::from(width) - 19.0).max(1.0)).ceil(),
            });
        }
        let matcher = Matcher::new(config.matcher, params, config.sgm_paths)?;
        Ok(Self {
            // The window resolved: what the configuration reads back (and serialises)
            // is the one in use.
            config: StereoConfig {
                block_size: Some(params.block_size),
                ..config
            },
            maps: rectification.maps(calib),
            rectification,
            matcher,
            temporal: config.temporal.map(TemporalFilter::new),
        })
    }

    /// The rectification in use.
    pub fn rectification(&self) -> &Rectification {
        &self.rectification
    }

    /// The matcher in use.
    pub fn matcher(&self) -> &Matcher {
        &self.matcher
    }

    /// The configuration.
    pub fn config(&self) -> &StereoConfig {
        &self.config
    }

    /// Processes one raw frame pair (8-bit grey, the calibration's size).
    pub fn process(
        &mut self,
        left: &Grid<u8>,
        right: &Grid<u8>,
    ) -> Result<StereoFrame, StereoError> {
        let start = Instant::now();
        let (w, h) = (
            self.rectification.width as usize,
            self.rectification.height as usize,
        );
        let remap = |table: &RemapTable, src: &Grid<u8>, camera| {
            let got = (src.width() as u32, src.height() as u32);
            if got != table.source_size() {
                return Err(StereoError::FrameDims {
                    camera,
                    got,
                    want: table.source_size(),
                });
            }
            let mut out = vec![0u8; w * h];
            table
                .remap(src.as_slice(), &mut out)
                .map_err(|source| StereoError::FrameSize { camera, source })?;
            Ok::<_, StereoError>(Grid::from_vec(w, h, out).expect("size matches"))
        };
        let (l, r) = rayon::join(
            || remap(&self.maps.0, left, "left"),
            || remap(&self.maps.1, right, "right"),
        );
        let (left, right) = (l?, r?);
        let t_rect = Instant::now();
        let matched = self.matcher.compute(&left, &right)?;
        let t_match = Instant::now();
        let mut disparity = matched.disparity;
        let (focal, baseline) = (self.rectification.focal(), self.rectification.baseline());
        // Before the filters, which then only combine depths within the range.
        let mut stats = matched.stats;
        stats.outside_range = keep_within_range(
            &mut disparity,
            focal * baseline,
            self.config.near_mm,
            self.config.far_mm,
        );
        stats.valid = stats.valid.saturating_sub(stats.outside_range);
        if let Some(s) = &self.config.spatial {
            s.apply(&mut disparity);
        }
        if let Some(t) = &mut self.temporal {
            t.apply(&mut disparity);
        }
        let holes_filled = self.config.hole_fill.map_or(0, |f| f.apply(&mut disparity));
        let t_filter = Instant::now();
        let (mut cloud, mut depth_mm) = rayon::join(
            || reproject(&disparity, &self.rectification.q),
            || depth_from_disparity(&disparity, focal, baseline),
        );
        let t_reproject = Instant::now();
        let mut outliers_removed = 0;
        if let Some(p) = &self.config.outliers {
            let keep = grid_inliers(&cloud, disparity.width(), disparity.height(), p);
            for (&pixel, _) in cloud.pixels.iter().zip(&keep).filter(|(_, k)| !**k) {
                disparity.as_mut_slice()[pixel as usize] = f32::NAN;
                depth_mm.as_mut_slice()[pixel as usize] = f32::NAN;
                outliers_removed += 1;
            }
            cloud.retain(&keep);
        }
        // Aggregation gives even a blank pair a best match (at a range's end), so only the
        // texture can tell a blank view from a scene out of range: semi-global matching's
        // flat pixels are counted (one pass over the left view) when almost no depth is
        // left, counted as the warnings count it, after the range and the filters.
        if self.matcher.kind() == MatcherKind::Sgm {
            let valid = depth_mm.as_slice().iter().filter(|v| v.is_finite()).count();
            if (valid as f64) < MIN_VALID_FRACTION * depth_mm.as_slice().len() as f64 {
                stats.flat = flat_pixels(&left);
            }
        }
        let t_outliers = Instant::now();
        let ms = crate::timing::ms_between;
        let timings = StereoTimings {
            rectify_ms: ms(start, t_rect),
            match_ms: ms(t_rect, t_match),
            filter_ms: ms(t_match, t_filter),
            reproject_ms: ms(t_filter, t_reproject),
            outliers_ms: ms(t_reproject, t_outliers),
            total_ms: ms(start, Instant::now()),
        };
        Ok(StereoFrame {
            left,
            right,
            disparity,
            depth_mm,
            cloud,
            stats,
            holes_filled,
            outliers_removed,
            timings,
        })
    }
}

/// Drops the disparities whose depth `f·B / d` (computed as [`depth_from_disparity`]
/// does, in f32) lies outside `near_mm..=far_mm`: the matcher searches whole blocks of 16
/// disparities, a little past the range asked for. Returns how many it dropped.
fn keep_within_range(disparity: &mut Grid<f32>, fb: f64, near_mm: f64, far_mm: f64) -> usize {
    let (fb, near, far) = (fb as f32, near_mm as f32, far_mm as f32);
    let mut dropped = 0;
    for d in disparity.as_mut_slice() {
        if d.is_finite() && !(*d > 0.0 && (near..=far).contains(&(fb / *d))) {
            *d = f32::NAN;
            dropped += 1;
        }
    }
    dropped
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::synthetic::{Membrane, Plane, StereoRig, render_pair};

    /// One lens covered (a blank left view, the right one faint noise) under semi-global
    /// matching: the pipeline counts the flat pixels (the matcher alone does not) once
    /// almost no depth is left, and the result is said to be a blank view, not a range
    /// to widen.
    #[test]
    fn a_covered_lens_is_said_to_be_blank_under_semi_global_matching() {
        let rig = StereoRig::sensor();
        let mut rng = crate::rng::Rng::new(5);
        let mut noisy = || {
            Grid::from_fn(rig.width, rig.height, |_, _| {
                (128.0 + (rng.uniform() - 0.5) * 6.0).round() as u8
            })
        };
        let (l, r) = (Grid::filled(rig.width, rig.height, 128u8), noisy());
        let config = StereoConfig {
            matcher: MatcherKind::Sgm,
            ..StereoConfig::default()
        };
        let mut p = StereoPipeline::new(&rig.calibration(), config).unwrap();
        let f = p.process(&l, &r).unwrap();
        let w = f.warnings(&config);
        assert!(
            w.len() == 1 && w[0].contains("almost no texture") && !w[0].contains("widen"),
            "{w:?} (stats {:?})",
            f.stats
        );
    }

    /// No block size given: each matcher takes its own window (block matching 9,
    /// semi-global matching's refinement 11); one given is taken by either.
    #[test]
    fn each_matcher_takes_its_own_window_unless_one_is_given() {
        let calib = StereoRig::sensor().calibration();
        let window = |matcher, block_size| {
            let config = StereoConfig {
                matcher,
                block_size,
                ..StereoConfig::default()
            };
            StereoPipeline::new(&calib, config)
                .unwrap()
                .matcher()
                .window()
        };
        assert_eq!(window(MatcherKind::Bm, None), 9);
        assert_eq!(window(MatcherKind::Sgm, None), 11);
        assert_eq!(window(MatcherKind::Bm, Some(13)), 13);
        assert_eq!(window(MatcherKind::Sgm, Some(7)), 7);
    }

    #[test]
    fn a_plane_comes_out_at_its_depth() {
        let rig = StereoRig::sensor();
        let mut p = StereoPipeline::new(&rig.calibration(), StereoConfig::default()).unwrap();
        let (l, r) = render_pair(&rig, &Plane::facing(200.0), &Membrane::sensor(), 1);
        let f = p.process(&l, &r).unwrap();
        let centre: Vec<f32> = (200..280)
            .flat_map(|y| (250..390).map(move |x| (x, y)))
            .map(|(x, y)| f.depth_mm.get(x, y))
            .collect();
        let valid: Vec<f32> = centre.iter().copied().filter(|v| v.is_finite()).collect();
        assert!(
            valid.len() * 100 >= centre.len() * 95,
            "fill {}",
            valid.len()
        );
        let mut sorted = valid.clone();
        sorted.sort_by(f32::total_cmp);
        let median = sorted[sorted.len() / 2];
        assert!((median - 200.0).abs() < 1.0, "median {median}");
        assert_eq!(
            f.cloud.len(),
            f.depth_mm
                .as_slice()
                .iter()
                .filter(|v| v.is_finite())
                .count()
        );
        // Wrong frame size: a typed error naming the camera; a transposed frame (as many
        // pixels) too.
        let small = Grid::filled(10, 10, 0u8);
        assert!(matches!(
            p.process(&small, &r),
            Err(StereoError::FrameDims { camera: "left", .. })
        ));
        let transposed = Grid::filled(r.height(), r.width(), 0u8);
        assert!(matches!(
            p.process(&l, &transposed),
            Err(StereoError::FrameDims {
                camera: "right",
                ..
            })
        ));
    }

    /// Images too small for any working range are refused as such (raising --near-mm,
    /// which the range error advises, cannot help them), and an impossible range names
    /// the flags and the nearest depth the rig allows.
    #[test]
    fn images_too_small_and_impossible_ranges_are_named() {
        for (w, h) in [(8, 8), (64, 8), (26, 40)] {
            let rig = StereoRig {
                width: w,
                height: h,
                focal_px: 0.5 * w as f64,
                baseline_mm: 14.0,
            };
            let e = StereoPipeline::new(&rig.calibration(), StereoConfig::default())
                .unwrap_err()
                .to_string();
            assert!(e.contains(&format!("{w}×{h} px: too small")), "{e}");
        }
        let rig = StereoRig::sensor();
        let config = StereoConfig {
            near_mm: -10.0,
            ..StereoConfig::default()
        };
        let e = StereoPipeline::new(&rig.calibration(), config)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--near-mm -10 and --far-mm 600") && e.contains("at least 1.1 mm"),
            "{e}"
        );
    }

    /// Outlier removal drops a point from the cloud, the disparity and the depth map
    /// alike (depth is computed beside the cloud, before the removal).
    #[test]
    fn removed_outliers_leave_no_depth() {
        let rig = StereoRig::sensor();
        let config = StereoConfig {
            outliers: Some(crate::stereo::outliers::OutlierParams {
                std_ratio: 0.5,
                ..Default::default()
            }),
            ..StereoConfig::default()
        };
        let mut p = StereoPipeline::new(&rig.calibration(), config).unwrap();
        let (l, r) = render_pair(&rig, &Plane::facing(200.0), &Membrane::sensor(), 1);
        let f = p.process(&l, &r).unwrap();
        assert!(f.outliers_removed > 0, "a tight ratio removes some points");
        let finite = |g: &Grid<f32>| {
            g.as_slice()
                .iter()
                .map(|v| v.is_finite())
                .collect::<Vec<_>>()
        };
        assert_eq!(finite(&f.depth_mm), finite(&f.disparity));
        assert_eq!(
            f.cloud.len(),
            finite(&f.depth_mm).iter().filter(|v| **v).count()
        );
    }
}
