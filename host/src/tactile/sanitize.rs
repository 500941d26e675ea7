//! Slope sanitising before integration: one NaN or infinity makes a Poisson solve's whole
//! output non-finite, and one huge spike bends the surface hundreds of pixels away. Both
//! are cut here: non-finite slopes become 0 (no information) and the rest are clamped to
//! the steepest slope the sensor can report.

/// Default bound on `|slope|`: beyond ~3 (72°) photometric stereo has no signal left.
pub const DEFAULT_MAX_SLOPE: f32 = 3.0;

/// What [`sanitize`] changed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SanitizeReport {
    /// NaN or infinite values replaced by 0.
    pub non_finite: usize,
    /// Values clamped to ±max.
    pub clamped: usize,
}

/// Replaces non-finite slopes by 0 and clamps the rest to `±max_slope`. Branch-free, so
/// it runs in vector lanes.
pub fn sanitize(slopes: &mut [f32], max_slope: f32) -> SanitizeReport {
    let (mut non_finite, mut clamped) = (0usize, 0usize);
    for v in slopes {
        let finite = v.is_finite();
        let steep = v.abs() > max_slope;
        non_finite += usize::from(!finite);
        clamped += usize::from(finite & steep);
        let bounded = if steep { max_slope.copysign(*v) } else { *v };
        *v = if finite { bounded } else { 0.0 };
    }
    SanitizeReport {
        non_finite,
        clamped,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_and_clamps() {
        let mut v = [
            0.5,
            f32::NAN,
            f32::INFINITY,
            -1e3,
            2.0,
            f32::NEG_INFINITY,
            -0.25,
        ];
        let r = sanitize(&mut v, 1.0);
        assert_eq!(v, [0.5, 0.0, 0.0, -1.0, 1.0, 0.0, -0.25]);
        assert_eq!(
            r,
            SanitizeReport {
                non_finite: 3,
                clamped: 2
            }
        );
    }
}
