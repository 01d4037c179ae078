//! Settings of the fusion (`[fusion]`) and the four tables it is built from, with validation.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::config::ConfigErrors;
use crate::filter::FilterConfig;
use crate::integrity::IntegrityConfig;
use crate::odometry::{OdometryConfig, OdometryMethod};

/// Keys of the `[fusion]` table. Every key has a default; unknown keys are refused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FusionConfig {
    /// Odometry epochs per second, Hz. Default 1.0, as the paper; at most the scan rate (a pair
    /// of scans makes at most one epoch). Between epochs the scans are not processed.
    pub epoch_rate_hz: f64,
    /// `true` (default): planes the integrity monitor isolates are excluded and epochs it cannot
    /// clear are not fused. `false`: integrity still tests and reports, but every solved epoch is
    /// fused with all its matched planes (only for comparing with and without exclusion).
    pub exclusion: bool,
    /// Largest difference, s, between the mid-scan times of the two scanners' scans paired into
    /// one epoch. Default 0.05 s; pairs further apart wait for the next scan.
    pub max_scan_skew_s: f64,
    /// Every how many propagated IMU samples `push_imu` returns an `Estimate` (1 = each).
    pub estimate_decimation: u32,
    /// A scanner whose newest scan is older than this, s, on the IMU's host time, marks the
    /// estimates degraded. Default 1.0 s.
    pub scan_stale_s: f64,
    /// Factor on the odometer's rotation and displacement covariances before they are fused.
    pub measurement_covariance_scale: f64,
    /// Whether the filter models the noise consecutive relative poses share through the planes
    /// of their common epoch (`shared_noise`). Without it, their telescoping errors are fused
    /// as independent and the filter is conservative. Default true; at 10 Hz with a swinging
    /// door in view, whose slow ends integrity cannot see in 0.1 s, the model is still somewhat
    /// optimistic on position and velocity (docs/accuracy.md, "What remains"), and false is the
    /// conservative choice there.
    pub shared_plane_noise: bool,
    /// Baseline, s, of the plane confirmation (`confirmation`): above 1 Hz a plane enters the
    /// solve only if it also matches a plane of the epoch this far back, where a fictitious
    /// plane (two lines of different surfaces) or a slowly turning door has left the match gate.
    /// On the plane map, a surface alone in facing a direction younger than this is checked by
    /// the prediction more strictly, in proportion to its age, as a carried board has gone less
    /// far. Default 1.0 s; 0 turns it off. No effect when epochs are at least this far apart.
    pub plane_confirmation_s: f64,
}

impl Default for FusionConfig {
    fn default() -> Self {
        Self {
            epoch_rate_hz: 1.0,
            exclusion: true,
            max_scan_skew_s: 0.05,
            estimate_decimation: 1,
            scan_stale_s: 1.0,
            measurement_covariance_scale: 1.0,
            shared_plane_noise: true,
            plane_confirmation_s: 1.0,
        }
    }
}

/// Everything a `Fusion` is built from: the `[fusion]`, `[odometry]`, `[integrity]` and
/// `[filter]` tables.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FusionSettings {
    pub fusion: FusionConfig,
    pub odometry: OdometryConfig,
    pub integrity: IntegrityConfig,
    pub filter: FilterConfig,
}

/// Time the pose history must cover beyond one epoch interval: the scans arrive after their
/// reference time and the solve uses the pose at the previous epoch.
const HISTORY_MARGIN_S: f64 = 0.25;

/// What keeps a `Fusion` from being built: its settings, or a scanner index.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum FusionError {
    #[error("{0}")]
    Config(#[from] ConfigErrors),
    #[error("scanner index {0} does not exist: the fusion takes scanners 0 and 1")]
    NoSuchScanner(usize),
}

impl FusionConfig {
    /// Adds every problem of the table to `errors`.
    pub(crate) fn check(&self, errors: &mut ConfigErrors) {
        let mut fusion = errors.table("fusion");
        let positive = "set a finite number above 0";
        let checks = [
            (
                "measurement_covariance_scale",
                self.measurement_covariance_scale,
                self.measurement_covariance_scale >= 1.0,
                "set a finite number of 1 or more",
            ),
            (
                "epoch_rate_hz",
                self.epoch_rate_hz,
                self.epoch_rate_hz > 0.0,
                positive,
            ),
            (
                "max_scan_skew_s",
                self.max_scan_skew_s,
                self.max_scan_skew_s >= 0.0,
                "set a finite number of 0 or more",
            ),
            (
                "scan_stale_s",
                self.scan_stale_s,
                self.scan_stale_s > 0.0,
                positive,
            ),
            (
                "plane_confirmation_s",
                self.plane_confirmation_s,
                self.plane_confirmation_s >= 0.0,
                "set a finite number of 0 (off) or more",
            ),
        ];
        for (key, value, ok, fix) in checks {
            fusion.check(ok && value.is_finite(), key, value, fix);
        }
        fusion.check(
            self.estimate_decimation >= 1,
            "estimate_decimation",
            self.estimate_decimation,
            "set 1 or more",
        );
    }

    /// Seconds between epochs.
    pub(crate) fn epoch_interval_s(&self) -> f64 {
        1.0 / self.epoch_rate_hz
    }

    /// Whether epochs come often enough for the plane confirmation to apply: it is on and the
    /// previous epoch is less than its baseline back (`confirmation_tolerance_s` early counts).
    pub(super) fn confirms_planes(&self) -> bool {
        self.confirmation_baseline_s().is_some()
    }

    /// The shortest span, s, that counts as the plane confirmation's baseline (its length less
    /// `confirmation_tolerance_s`), where the confirmation applies.
    pub(super) fn confirmation_baseline_s(&self) -> Option<f64> {
        let shortest_s = self.plane_confirmation_s - self.confirmation_tolerance_s();
        (self.plane_confirmation_s > 0.0 && self.epoch_interval_s() < shortest_s)
            .then_some(shortest_s)
    }

    /// How early an epoch may come against the confirmation's baseline: half an interval.
    pub(super) fn confirmation_tolerance_s(&self) -> f64 {
        0.5 * self.epoch_interval_s()
    }

    /// How far back the filter's pose history must reach: the previous epoch, or the plane
    /// confirmation's keyframe.
    fn lookback_s(&self) -> f64 {
        self.epoch_interval_s().max(self.plane_confirmation_s)
    }
}

impl FusionSettings {
    /// Every problem of the four tables, one line each.
    pub fn validate(&self) -> Result<(), ConfigErrors> {
        ConfigErrors::collect(|errors| self.check(errors))
    }

    /// The filter's settings as the fusion runs them: with the plane map, an unset
    /// `still_sway_force_sigma_mps2` is 0. There a floor seen from one level line is often the
    /// only surface facing up, and is fused alone only while the prediction knows its offset to
    /// 2 cm: the wider start took that past it within a second on the hall walk, and a floor
    /// left out cannot be checked again (docs/autopilot.md, "A walk that starts unseen").
    pub(crate) fn filter_config(&self) -> FilterConfig {
        let mut filter = self.filter.clone();
        if self.odometry.method == OdometryMethod::Map {
            filter.still_sway_force_sigma_mps2.get_or_insert(0.0);
        }
        filter
    }

    /// Adds every problem of the four tables to `errors`.
    pub(crate) fn check(&self, errors: &mut ConfigErrors) {
        self.fusion.check(errors);
        self.odometry.check(errors);
        self.integrity.check(errors);
        self.filter.check(errors);
        self.check_history(errors);
    }

    /// Adds a problem if the filter's pose history does not span an epoch interval: the one
    /// check that needs two tables.
    pub(crate) fn check_history(&self, errors: &mut ConfigErrors) {
        let needed = self.fusion.lookback_s() + self.fusion.max_scan_skew_s + HISTORY_MARGIN_S;
        errors.table("fusion").check(
            // An infinite need is an epoch rate of 0, which its own line already names.
            !(needed.is_finite() && needed > self.filter.pose_history_s),
            "epoch_rate_hz",
            self.fusion.epoch_rate_hz,
            format!(
                "with fusion.plane_confirmation_s = {:?} needs {needed:.2} s of pose history but filter.pose_history_s = {:?}: raise filter.pose_history_s, or the epoch rate, or lower the confirmation",
                self.fusion.plane_confirmation_s, self.filter.pose_history_s
            ),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(method: OdometryMethod, sway: Option<f64>) -> FusionSettings {
        let mut settings = FusionSettings::default();
        settings.odometry.method = method;
        settings.filter.still_sway_force_sigma_mps2 = sway;
        settings
    }

    #[test]
    fn an_unseen_start_sways_on_the_pairs_and_not_on_the_map_unless_set() {
        let third = FilterConfig::default().still_max_force_change_mps2 / 3.0;
        let pairs = settings(OdometryMethod::Pairs, None)
            .filter_config()
            .unseen_start_force_sigma();
        assert!((pairs - third).abs() < 1e-12, "{pairs}");
        assert_eq!(
            settings(OdometryMethod::Map, None)
                .filter_config()
                .unseen_start_force_sigma(),
            0.0
        );
        for method in [OdometryMethod::Pairs, OdometryMethod::Map] {
            assert_eq!(
                settings(method, Some(0.03))
                    .filter_config()
                    .unseen_start_force_sigma(),
                0.03
            );
        }
    }
}
