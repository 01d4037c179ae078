//! The ranging noise a scanner's lines show, so that the lines' and planes' covariances hold
//! when the scanner ranges worse than its configured `range_sigma_m`. A UTM-30LX is specified
//! at +-30 mm, and dark, glossy or dusty surfaces scatter more; a configuration that says
//! 10 mm then makes every plane three times surer than it is. With the simulated ranges three
//! times noisier than the configuration said, the hall walk sent a velocity 3.1 m/s off as
//! usable and the open room's cross-track NEES was 3.4 (docs/accuracy.md, "Noisier sensors
//! than configured"). The configuration stays the floor: a scanner is never taken for better
//! than its configured sigma.
//!
//! Each line's readings lie off its fitted line along their beams by the ranging error (the
//! fit takes two degrees of freedom), so a line of n readings estimates the ranging variance
//! by its residual sum of squares over n - 2. Lines that are no plane's (a person's legs, a
//! curtain, a corner the split missed) scatter more, so the estimate is the median over the
//! recent lines, not their pooled mean.

use super::lines::Segment;

/// Lines remembered per scanner: at 1 Hz epochs the last few epochs' worth, enough for a
/// median within a few percent.
const REMEMBERED_LINES: usize = 64;
/// Fewer readings than this leave too few degrees of freedom for a line's own estimate to
/// help the median.
const MIN_READINGS: usize = 10;

/// The recent lines' ranging variances of one scanner.
#[derive(Debug, Clone)]
pub(crate) struct RangingNoise {
    variances: [f64; REMEMBERED_LINES],
    remembered: usize,
    next: usize,
}

impl Default for RangingNoise {
    fn default() -> Self {
        Self {
            variances: [0.0; REMEMBERED_LINES],
            remembered: 0,
            next: 0,
        }
    }
}

impl RangingNoise {
    /// Remembers the ranging variance each of one scan's `lines` shows.
    pub(crate) fn observe(&mut self, lines: &[Segment]) {
        let estimates = lines
            .iter()
            .filter(|line| line.points() >= MIN_READINGS)
            .map(|line| line.range_residual_ss / (line.points() - 2) as f64)
            .filter(|variance| variance.is_finite());
        for variance in estimates {
            self.variances[self.next] = variance;
            self.next = (self.next + 1) % REMEMBERED_LINES;
            self.remembered = (self.remembered + 1).min(REMEMBERED_LINES);
        }
    }

    /// The ranging sigma the recent lines show, m; `None` before any line was long enough.
    pub(crate) fn sigma_m(&self) -> Option<f64> {
        if self.remembered == 0 {
            return None;
        }
        let mut recent = self.variances;
        let recent = &mut recent[..self.remembered];
        let middle = recent.len() / 2;
        let (_, median, _) = recent.select_nth_unstable_by(middle, f64::total_cmp);
        Some(median.sqrt())
    }

    /// `configured` unless the lines show the scanner ranging worse.
    pub(crate) fn sigma_at_least(&self, configured: f64) -> f64 {
        self.sigma_m()
            .map_or(configured, |measured| measured.max(configured))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::odometry::deskew::Beam;
    use crate::odometry::lines::{LineExtractor, LineParameters};
    use nalgebra::{Vector2, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// A wall 3 m ahead seen over +-45 degrees, each range off by `sigma` (Gaussian, seeded).
    fn wall_scan(sigma: f64, rng: &mut ChaCha8Rng) -> Vec<Beam> {
        (0..361)
            .map(|k| {
                let bearing = (f64::from(k) * 0.25 - 45.0).to_radians();
                let noise: f64 = rng.sample(StandardNormal);
                let range = 3.0 / bearing.cos() + sigma * noise;
                let planar = Vector2::new(bearing.cos(), bearing.sin()) * range;
                let body = Vector3::new(planar.x, planar.y, 0.0);
                Beam {
                    planar,
                    body,
                    direction: body.normalize(),
                    azimuth: bearing,
                    range,
                    time: 0.0,
                }
            })
            .collect()
    }

    /// What five scans of the wall with ranges off by `sigma` teach a fresh estimate.
    fn measured_on_walls(sigma: f64) -> RangingNoise {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let parameters = LineParameters {
            breakpoint_lambda_rad: 10f64.to_radians(),
            breakpoint_noise_m: 3.0 * sigma.max(0.01),
            split_distance_m: 0.2,
            min_points: 10,
            min_length_m: 0.3,
        };
        let (mut extractor, mut lines, mut noise) = (
            LineExtractor::default(),
            Vec::new(),
            RangingNoise::default(),
        );
        for _ in 0..5 {
            extractor.extract(&wall_scan(sigma, &mut rng), &parameters, &mut lines);
            noise.observe(&lines);
        }
        noise
    }

    #[test]
    fn the_lines_show_the_ranging_noise_the_scanner_has() {
        for sigma in [0.01, 0.03] {
            let measured = measured_on_walls(sigma)
                .sigma_m()
                .expect("the wall is a line");
            assert!(
                (measured / sigma - 1.0).abs() < 0.15,
                "ranges off by {sigma} m measured as {measured} m"
            );
        }
    }

    #[test]
    fn a_scanner_is_never_taken_for_better_than_configured() {
        assert_eq!(RangingNoise::default().sigma_at_least(0.01), 0.01);
        let quiet = measured_on_walls(0.002);
        assert_eq!(quiet.sigma_at_least(0.01), 0.01);
        assert!((quiet.sigma_at_least(0.001) / 0.002 - 1.0).abs() < 0.15);
    }
}
