//! Integrity settings (`[integrity]` in the configuration) and their validation.

use serde::{Deserialize, Serialize};

use crate::config::ConfigErrors;

/// Risk budgets and the rules that decide when an epoch can be tested and a plane excluded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IntegrityConfig {
    /// Chance that a fault-free odometry epoch is flagged (an upper bound: the tests are split
    /// Bonferroni-style, see `thresholds`).
    pub false_alarm_probability: f64,
    /// Chance that a fault of minimum-detectable-bias size goes undetected; also the chance a
    /// protection level is exceeded by an undetected fault of that size.
    pub missed_detection_probability: f64,
    /// Planes that may be excluded in one epoch before it is declared not isolable.
    pub max_exclusions: usize,
    /// Fewest planes for which the displacement solve is monitored (at least 4: one redundant
    /// row); fewer gives `UnderDetermined`.
    pub min_planes_displacement: usize,
    /// Fewest planes for which the rotation solve is monitored (at least 2: two rows a plane).
    pub min_planes_rotation: usize,
    /// Largest condition number of the whitened geometry matrix that is still tested; above it
    /// the epoch is `UnderDetermined` instead of inverting a near-singular geometry.
    pub max_condition_number: f64,
    /// A direction that one plane alone faces cannot be tested against the other planes, only
    /// against the filter's prediction of the epoch's relative pose. It is fused only while
    /// that prediction would detect the plane moving this fast along it (m/s: its minimum
    /// detectable bias over the epoch interval): after the filter has dead-reckoned along the
    /// direction, a person walking square on to the platform would otherwise tell it that
    /// direction.
    pub lone_plane_detect_mps: f64,
    /// As `lone_plane_detect_mps`, for a plane turning about a rotation direction, mrad/s.
    pub lone_plane_detect_mradps: f64,
    /// A lone plane with a line this long (m) is fused without that check: wider than a door,
    /// a person or a carried board, it is taken for a wall. So is a level one in a building
    /// (`[odometry] building_max_tilt_deg`).
    pub lone_plane_min_extent_m: f64,
}

impl Default for IntegrityConfig {
    fn default() -> Self {
        Self {
            false_alarm_probability: 1e-3,
            missed_detection_probability: 1e-3,
            max_exclusions: 1,
            min_planes_displacement: MIN_PLANES_DISPLACEMENT,
            min_planes_rotation: MIN_PLANES_ROTATION,
            max_condition_number: 1e4,
            lone_plane_detect_mps: 0.3,
            lone_plane_detect_mradps: 10.0,
            lone_plane_min_extent_m: 1.5,
        }
    }
}

/// Three unknowns plus one redundant row, one row a plane.
pub(crate) const MIN_PLANES_DISPLACEMENT: usize = 4;
/// Three unknowns plus one redundant row, two rows a plane.
pub(crate) const MIN_PLANES_ROTATION: usize = 2;

impl IntegrityConfig {
    /// Every problem of the table, one line each.
    pub fn validate(&self) -> Result<(), ConfigErrors> {
        ConfigErrors::collect(|errors| self.check(errors))
    }

    /// Adds every problem of the table to `errors`.
    pub(crate) fn check(&self, errors: &mut ConfigErrors) {
        let mut integrity = errors.table("integrity");
        for (key, value) in [
            ("false_alarm_probability", self.false_alarm_probability),
            (
                "missed_detection_probability",
                self.missed_detection_probability,
            ),
        ] {
            integrity.check(
                value > 0.0 && value < 1.0,
                key,
                value,
                "must be in (0, 1): use e.g. 1e-3",
            );
        }
        for (key, value, minimum) in [
            (
                "min_planes_displacement",
                self.min_planes_displacement,
                MIN_PLANES_DISPLACEMENT,
            ),
            (
                "min_planes_rotation",
                self.min_planes_rotation,
                MIN_PLANES_ROTATION,
            ),
        ] {
            integrity.check(
                value >= minimum,
                key,
                value,
                format!("leaves no redundant row to test: use {minimum} or more"),
            );
        }
        integrity.check(
            self.max_condition_number.is_finite() && self.max_condition_number > 1.0,
            "max_condition_number",
            self.max_condition_number,
            "must be a finite number above 1: use e.g. 1e4",
        );
        for (key, value) in [
            ("lone_plane_detect_mps", self.lone_plane_detect_mps),
            ("lone_plane_detect_mradps", self.lone_plane_detect_mradps),
            ("lone_plane_min_extent_m", self.lone_plane_min_extent_m),
        ] {
            integrity.check(
                value >= 0.0,
                key,
                value,
                "must be 0 or more: use e.g. 0.3 m/s, 10 mrad/s or 1.5 m",
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_an_empty_table_gives_them() {
        assert!(IntegrityConfig::default().validate().is_ok());
        let parsed: IntegrityConfig = toml::from_str("").unwrap();
        assert_eq!(parsed, IntegrityConfig::default());
    }

    #[test]
    fn a_probability_outside_the_unit_interval_names_the_key() {
        let config = IntegrityConfig {
            false_alarm_probability: 1.5,
            ..Default::default()
        };
        assert_eq!(
            config.validate().unwrap_err().to_string(),
            "integrity.false_alarm_probability = 1.5: must be in (0, 1): use e.g. 1e-3"
        );
        let config = IntegrityConfig {
            missed_detection_probability: 0.0,
            ..Default::default()
        };
        assert_eq!(
            config.validate().unwrap_err().to_string(),
            "integrity.missed_detection_probability = 0.0: must be in (0, 1): use e.g. 1e-3"
        );
        let config = IntegrityConfig {
            missed_detection_probability: f64::NAN,
            ..Default::default()
        };
        assert!(config.validate().is_err());
    }

    #[test]
    fn plane_minimums_and_condition_limit_are_checked() {
        let config = IntegrityConfig {
            min_planes_displacement: 3,
            ..Default::default()
        };
        assert_eq!(
            config.validate().unwrap_err().to_string(),
            "integrity.min_planes_displacement = 3: leaves no redundant row to test: use 4 or more"
        );
        let config = IntegrityConfig {
            max_condition_number: f64::INFINITY,
            ..Default::default()
        };
        assert_eq!(
            config.validate().unwrap_err().to_string(),
            "integrity.max_condition_number = inf: must be a finite number above 1: use e.g. 1e4"
        );
    }

    #[test]
    fn unknown_keys_are_rejected_by_name() {
        let err = toml::from_str::<IntegrityConfig>("false_alarm_probabilty = 0.01").unwrap_err();
        assert!(err.to_string().contains("false_alarm_probabilty"), "{err}");
    }
}
