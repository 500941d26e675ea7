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

/// Replaces non-finite slopes by 0 and clamps the rest to `±max_slope`.
pub fn sanitize(slopes: &mut [f32], max_slope: f32) -> SanitizeReport {
    let mut report = SanitizeReport::default();
    for v in slopes {
        if !v.is_finite() {
            *v = 0.0;
            report.non_finite += 1;
        } else if v.abs() > max_slope {
            *v = v.signum() * max_slope;
            report.clamped += 1;
        }
    }
    report
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_and_clamps() {
        let mut v = [0.5, f32::NAN, f32::INFINITY, -1e3, 2.0, f32::NEG_INFINITY];
        let r = sanitize(&mut v, 1.0);
        assert_eq!(v, [0.5, 0.0, 0.0, -1.0, 1.0, 0.0]);
        assert_eq!(
            r,
            SanitizeReport {
                non_finite: 3,
                clamped: 2
            }
        );
    }
}
