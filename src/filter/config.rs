//! Filter configuration (the `[filter]` table): noise model, initial uncertainty, stationary
//! start, bad-input limits and the relative-pose update mode. Every key has a default, so an
//! empty table is a working MTi-G-7x0 configuration.

use nalgebra::UnitQuaternion;
use serde::{Deserialize, Serialize};
use std::cmp::Ordering;

use crate::config::ConfigErrors;
use crate::sensors::Mount;

const DEG: f64 = std::f64::consts::PI / 180.0;
/// Standard gravity (CGPM 1901), the default magnitude of the gravity model.
pub(crate) const STANDARD_GRAVITY: f64 = 9.80665;
/// The paper's odometry epoch, s. Settings that count epochs (`converged_after_epochs`,
/// `divergence_window`) count these at faster epoch rates too: what they judge settles with
/// time, not with the number of epochs.
pub(crate) const PAPER_EPOCH_S: f64 = 1.0;

/// How an odometry epoch's relative pose enters the filter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RelativePoseUpdate {
    /// Displacement and rotation fused against a stochastic clone of the pose at the earlier
    /// epoch, so the correlation between the two epochs is kept (docs/design.md, 4.9 "Filter").
    Cloned,
    /// The paper's update (sec. 4.3): body velocity = displacement / interval, and the rotation
    /// fused on the current attitude with the earlier attitude taken as exact.
    Velocity,
}

/// Keys of the `[filter]` table. Units are SI unless the key says `_deg`; noise densities are per
/// square root of a hertz, random walks are the densities of the white noise driving the walk.
/// Defaults are the MTi-G-7x0 / MTi-300 datasheet figures (docs/protocols.md, 2.5 "Noise figures").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FilterConfig {
    /// Magnitude of gravity in m/s^2, pointing down in NED. Default: standard gravity
    /// 9.80665; set the local value (e.g. from a normal-gravity formula) for long dead reckoning.
    pub gravity_mps2: f64,
    /// Gyro angle random walk, rad/s/sqrt(Hz). Default 0.01 deg/s/sqrt(Hz).
    pub gyro_noise_density: f64,
    /// Accelerometer velocity random walk, m/s^2/sqrt(Hz). Default 60 ug/sqrt(Hz).
    pub accel_noise_density: f64,
    /// Gyro bias random walk, rad/s^2/sqrt(Hz). Default: the 10 deg/h in-run stability reached
    /// after 100 s.
    pub gyro_bias_random_walk: f64,
    /// Accelerometer bias random walk, m/s^3/sqrt(Hz). Default: the 15 ug in-run stability
    /// reached after 100 s.
    pub accel_bias_random_walk: f64,
    /// Gyro scale-factor random walk, 1/sqrt(s).
    pub gyro_scale_random_walk: f64,
    /// Accelerometer scale-factor random walk, 1/sqrt(s).
    pub accel_scale_random_walk: f64,
    /// Initial position sigma, m. The origin is defined at the start, so the position is exact
    /// there; the default only keeps the covariance positive definite.
    pub initial_sigma_position_m: f64,
    /// Initial velocity sigma, m/s.
    pub initial_sigma_velocity_mps: f64,
    /// Initial roll and pitch (ZYX Euler) sigma after gravity alignment, degrees.
    pub initial_sigma_tilt_deg: f64,
    /// Initial Euler yaw sigma, degrees. Yaw 0 defines the local north at the start, so it is
    /// exact there, like the position; the global yaw error still takes its share of the roll
    /// error at a pitch (`euler_attitude_covariance`).
    pub initial_sigma_yaw_deg: f64,
    /// Initial gyro bias sigma after the stationary mean rate was removed, rad/s.
    pub initial_sigma_gyro_bias: f64,
    /// Initial accelerometer bias sigma, m/s^2.
    pub initial_sigma_accel_bias: f64,
    /// Initial gyro scale-factor sigma (dimensionless, 0.001 = 1000 ppm).
    pub initial_sigma_gyro_scale: f64,
    /// Initial accelerometer scale-factor sigma (dimensionless).
    pub initial_sigma_accel_scale: f64,
    /// Averaging window for gravity alignment (roll, pitch) and the initial gyro bias, s.
    pub coarse_alignment_s: f64,
    /// Length of the stationary start, s, counted from the first IMU sample: zero-velocity and
    /// zero-rate updates run until then (the paper used 40 s). At least `coarse_alignment_s`.
    pub stationary_start_s: f64,
    /// A sample turning faster than this (rad/s, before bias removal) is motion: it restarts
    /// the gravity alignment, or ends the stationary start early.
    pub stationary_max_rate: f64,
    /// A sample whose specific-force magnitude differs from gravity by more than this (m/s^2)
    /// is motion, as above.
    pub stationary_max_force_error_mps2: f64,
    /// A `zupt_interval_s` window whose mean specific force departs from the alignment's by
    /// more than this (m/s^2) is motion, however gentle: it ends the stationary start (or,
    /// within the alignment window, makes the start one in motion).
    pub still_max_force_change_mps2: f64,
    /// Likewise for the mean rate, rad/s.
    pub still_max_rate_change: f64,
    /// Interval of the zero-velocity / zero-rate updates during the stationary start, s.
    pub zupt_interval_s: f64,
    /// Sigma of the zero-velocity pseudo-measurement, m/s (vibration, hand shake).
    pub zupt_velocity_sigma_mps: f64,
    /// Rotation rate a platform taken for still may keep up unseen, rad/s: a hand-held rig, a
    /// rocking vehicle, a lift-off gentler than the stillness test (`still_max_rate_change`
    /// per window) can see. When motion ends the stationary start it may have begun earlier,
    /// and the zero-rate updates since then took it for gyro bias, so the bias gets this much
    /// uncertainty back (a start that runs its full length saw no motion and keeps it all).
    /// The default is a third of `still_max_rate_change`, so that a rate just under what the
    /// test sees is 3 sigma. Without it a hover that began gently left the pitch-rate bias
    /// 1.5 mrad/s off, and where nothing observes the pitch, gravity turned that into an
    /// acceleration the velocity sigma did not cover (docs/accuracy.md, "The stationary
    /// start's gyro bias").
    pub still_sway_rate_sigma: f64,
    /// Acceleration a platform taken for still may build up unseen, m/s^2: a lift-off or a walk
    /// that starts gentler than the stillness test (`still_max_force_change_mps2` per window)
    /// can see. The zero-velocity updates until motion is seen took that acceleration for
    /// accelerometer bias and tilt, and held the velocity it built at zero: when motion ends
    /// the stationary start, the accelerometer bias gets this much uncertainty back, and the
    /// velocity `zupt_velocity_sigma_mps`; 0 gives nothing back. Unset, it is a third of
    /// `still_max_force_change_mps2` with the pairs and 0 with the plane map, whose lone floor
    /// cannot yet survive it (docs/autopilot.md, "A walk that starts unseen"). Without it a
    /// corridor walk that began at 0.04 m/s^2 left the velocity 1 cm/s off at a 3 mm/s sigma
    /// and the sum of the accelerometer's x bias and the pitch 6 mm/s^2 off, and along the
    /// corridor, where nothing observes them, the velocity error grew three times as fast as
    /// its sigma.
    pub still_sway_force_sigma_mps2: Option<f64>,
    /// Longest IMU interval integrated normally, s; a longer gap marks the filter degraded.
    pub max_imu_gap_s: f64,
    /// Probability of the chi-square innovation gate on the NIS; 1.0 disables the gate.
    pub gate_probability: f64,
    /// `"cloned"` (default) or `"velocity"`.
    pub relative_pose_update: RelativePoseUpdate,
    /// Largest difference between a measurement's epoch times and the clone / filter times
    /// when the epoch is ahead of the filter (its newest IMU sample), s; the difference is
    /// bridged by extrapolating the newest pose.
    pub epoch_time_tolerance_s: f64,
    /// Largest delay of a measurement's epoch times behind the clone / filter times, s; the
    /// delay is bridged with the recorded poses of the history. A scan pair closes only once
    /// its scans have been sent, when the IMU has run on past the reference scanner's mid-scan
    /// time by the rest of its revolution: 62 ms for a 10 Hz URG-04LX, plus up to one IMU
    /// interval and the link's latency. At most `pose_history_s`.
    pub epoch_max_delay_s: f64,
    /// IMU mount: rotation of the IMU frame into body FRD, `[roll, pitch, yaw]` in degrees,
    /// composed as in docs/design.md, "Frames". The lever arm is neglected (body origin at the
    /// IMU). Not a key of `[filter]`: the file sets the mount once, in `[imu] rpy_deg`, and
    /// `Config::fusion_settings` copies it here.
    #[serde(skip)]
    pub imu_mount_rpy_deg: [f64; 3],
    /// Length of the pose history kept for deskewing and odometer priors, s.
    pub pose_history_s: f64,
    /// Highest IMU rate expected, Hz; sizes the pose history once, at construction.
    pub max_imu_rate_hz: f64,
    /// Velocity sigma of a start in motion (an alignment window that was not still) and of a
    /// restart, m/s: the odometry measures the velocity within an epoch or two.
    pub moving_start_sigma_velocity_mps: f64,
    /// Roll and pitch sigma of a start in motion, degrees: the mean specific force over the
    /// alignment window then holds the mean acceleration too (3 deg covers 0.5 m/s^2).
    pub moving_start_sigma_tilt_deg: f64,
    /// Gyro bias sigma of a start in motion, rad/s: the mean rate is motion, not bias.
    pub moving_start_sigma_gyro_bias: f64,
    /// The estimate counts as converged, and may go to the autopilot with a quality above 0,
    /// once this many relative poses have been fused since the start or a restart, spanning
    /// as many of the paper's 1 s epochs at faster rates: the first ones linearise about a
    /// guessed velocity and tilt, and their covariance is not yet to be believed. An axis no
    /// surface observes stays uncertain after that, and says so.
    pub converged_after_epochs: u32,
    /// A speed above this (m/s) is taken as a diverged filter, which then restarts: set it
    /// above the platform's top speed. A velocity no surface observes runs off, honestly
    /// uncertain, until it gets here; the default keeps what it moves the position between two
    /// 30 Hz messages below 0.2 m, which an autopilot would otherwise take for a jump.
    pub max_speed_mps: f64,
    /// The platform's speed envelope, m/s: a prior on the velocity, N(0, sigma^2), fused every
    /// `speed_prior_interval_s` along the directions whose velocity sigma exceeds it, and only
    /// those. Where no surface observes the motion (a bare corridor's length, a room whose end
    /// walls are out of reach) the IMU alone would let the velocity error grow without bound,
    /// and the position error with its square; the prior holds the estimate to the speeds the
    /// platform flies. A direction only the prior holds keeps a sigma of at least 0.7 times
    /// it, so from `MIN_SPEED_PRIOR_SIGMA_MPS` up it stays above the 0.5 m/s at which ODOMETRY's
    /// quality falls to 0: the autopilot never uses what the prior alone says. Set it to the
    /// speed the platform keeps up for `speed_prior_interval_s` and more, or 0 to turn it off.
    pub speed_prior_sigma_mps: f64,
    /// How often the speed prior is fused, s: about the time over which the platform's
    /// velocity changes by its envelope (a hover's drift, a walk's turn).
    pub speed_prior_interval_s: f64,
    /// Fused relative poses over which the divergence guard sums the NIS, spanning as many
    /// seconds at faster epoch rates.
    pub divergence_window: u32,
    /// Relative poses refused by the gate in a row that count as divergence.
    pub divergence_refused_in_row: u32,
    /// A correction that moves the position by more than this (m) increments `reset_counter`,
    /// so that the autopilot re-anchors instead of fusing the step as motion.
    pub max_position_step_m: f64,
    /// An IMU gap longer than this (s) restarts the filter: it aligns again, keeping its
    /// position and heading, since the attitude and velocity could have become anything.
    pub max_coast_s: f64,
}

/// The smallest speed prior that cannot by itself make a velocity look usable
/// (`speed_prior_sigma_mps`).
const MIN_SPEED_PRIOR_SIGMA_MPS: f64 = 0.75;

impl Default for FilterConfig {
    fn default() -> Self {
        let bias_settling_s: f64 = 100.0;
        Self {
            gravity_mps2: STANDARD_GRAVITY,
            gyro_noise_density: 0.01 * DEG,
            accel_noise_density: 60e-6 * STANDARD_GRAVITY,
            gyro_bias_random_walk: 10.0 * DEG / 3600.0 / bias_settling_s.sqrt(),
            accel_bias_random_walk: 15e-6 * STANDARD_GRAVITY / bias_settling_s.sqrt(),
            gyro_scale_random_walk: 1e-6,
            accel_scale_random_walk: 1e-6,
            initial_sigma_position_m: 1e-4,
            initial_sigma_velocity_mps: 0.1,
            initial_sigma_tilt_deg: 2.0,
            initial_sigma_yaw_deg: 1e-3,
            initial_sigma_gyro_bias: 0.1 * DEG,
            initial_sigma_accel_bias: 0.05,
            initial_sigma_gyro_scale: 0.005,
            initial_sigma_accel_scale: 0.005,
            coarse_alignment_s: 1.0,
            stationary_start_s: 40.0,
            stationary_max_rate: 0.05,
            stationary_max_force_error_mps2: 0.5,
            still_max_force_change_mps2: 0.05,
            still_max_rate_change: 0.005,
            zupt_interval_s: 0.1,
            zupt_velocity_sigma_mps: 0.01,
            still_sway_rate_sigma: 1.7e-3,
            still_sway_force_sigma_mps2: None,
            max_imu_gap_s: 0.05,
            gate_probability: 0.9999,
            relative_pose_update: RelativePoseUpdate::Cloned,
            epoch_time_tolerance_s: 0.05,
            epoch_max_delay_s: 0.2,
            imu_mount_rpy_deg: [0.0; 3],
            pose_history_s: 2.0,
            max_imu_rate_hz: 1000.0,
            moving_start_sigma_velocity_mps: 1.0,
            moving_start_sigma_tilt_deg: 3.0,
            moving_start_sigma_gyro_bias: 0.3 * DEG,
            converged_after_epochs: 3,
            max_speed_mps: 6.0,
            speed_prior_sigma_mps: MIN_SPEED_PRIOR_SIGMA_MPS,
            speed_prior_interval_s: 10.0,
            divergence_window: 10,
            divergence_refused_in_row: 5,
            max_position_step_m: 0.1,
            max_coast_s: 1.0,
        }
    }
}

impl FilterConfig {
    /// `still_sway_force_sigma_mps2` as set, or a third of the stillness test's threshold: an
    /// acceleration that stays under the test's change per window for a whole window.
    pub(crate) fn unseen_start_force_sigma(&self) -> f64 {
        self.still_sway_force_sigma_mps2
            .unwrap_or(self.still_max_force_change_mps2 / 3.0)
    }

    /// Every problem of the table, one line each.
    pub(crate) fn validate(&self) -> Result<(), ConfigErrors> {
        ConfigErrors::collect(|errors| self.check(errors))
    }

    /// Adds every problem of the table to `errors`.
    pub(crate) fn check(&self, errors: &mut ConfigErrors) {
        let mut filter = errors.table("filter");
        let positive = [
            ("gravity_mps2", self.gravity_mps2),
            ("gyro_noise_density", self.gyro_noise_density),
            ("accel_noise_density", self.accel_noise_density),
            ("initial_sigma_position_m", self.initial_sigma_position_m),
            (
                "initial_sigma_velocity_mps",
                self.initial_sigma_velocity_mps,
            ),
            ("initial_sigma_tilt_deg", self.initial_sigma_tilt_deg),
            ("initial_sigma_yaw_deg", self.initial_sigma_yaw_deg),
            ("initial_sigma_gyro_bias", self.initial_sigma_gyro_bias),
            ("initial_sigma_accel_bias", self.initial_sigma_accel_bias),
            ("initial_sigma_gyro_scale", self.initial_sigma_gyro_scale),
            ("initial_sigma_accel_scale", self.initial_sigma_accel_scale),
            ("coarse_alignment_s", self.coarse_alignment_s),
            ("stationary_max_rate", self.stationary_max_rate),
            (
                "stationary_max_force_error_mps2",
                self.stationary_max_force_error_mps2,
            ),
            (
                "still_max_force_change_mps2",
                self.still_max_force_change_mps2,
            ),
            ("still_max_rate_change", self.still_max_rate_change),
            ("zupt_interval_s", self.zupt_interval_s),
            ("zupt_velocity_sigma_mps", self.zupt_velocity_sigma_mps),
            ("still_sway_rate_sigma", self.still_sway_rate_sigma),
            ("max_imu_gap_s", self.max_imu_gap_s),
            ("epoch_time_tolerance_s", self.epoch_time_tolerance_s),
            ("epoch_max_delay_s", self.epoch_max_delay_s),
            ("pose_history_s", self.pose_history_s),
            ("max_imu_rate_hz", self.max_imu_rate_hz),
            (
                "moving_start_sigma_velocity_mps",
                self.moving_start_sigma_velocity_mps,
            ),
            (
                "moving_start_sigma_tilt_deg",
                self.moving_start_sigma_tilt_deg,
            ),
            (
                "moving_start_sigma_gyro_bias",
                self.moving_start_sigma_gyro_bias,
            ),
            ("max_speed_mps", self.max_speed_mps),
            ("max_position_step_m", self.max_position_step_m),
            ("max_coast_s", self.max_coast_s),
            ("speed_prior_interval_s", self.speed_prior_interval_s),
        ];
        for (key, value) in positive {
            filter.check(
                value.is_finite() && value > 0.0,
                key,
                value,
                "set a finite value greater than zero",
            );
        }
        let counts = [
            ("converged_after_epochs", self.converged_after_epochs),
            ("divergence_window", self.divergence_window),
            ("divergence_refused_in_row", self.divergence_refused_in_row),
        ];
        for (key, value) in counts {
            filter.check(value > 0, key, value, "set 1 or more");
        }
        let non_negative = [
            ("gyro_bias_random_walk", self.gyro_bias_random_walk),
            ("accel_bias_random_walk", self.accel_bias_random_walk),
            ("gyro_scale_random_walk", self.gyro_scale_random_walk),
            ("accel_scale_random_walk", self.accel_scale_random_walk),
            ("stationary_start_s", self.stationary_start_s),
        ];
        let set_non_negative = self
            .still_sway_force_sigma_mps2
            .map(|value| ("still_sway_force_sigma_mps2", value));
        for (key, value) in non_negative.into_iter().chain(set_non_negative) {
            filter.check(
                value.is_finite() && value >= 0.0,
                key,
                value,
                "set a finite value of zero or more",
            );
        }
        filter.check(
            self.speed_prior_sigma_mps == 0.0
                || self.speed_prior_sigma_mps >= MIN_SPEED_PRIOR_SIGMA_MPS,
            "speed_prior_sigma_mps",
            self.speed_prior_sigma_mps,
            format!(
                "set 0 (off) or at least {MIN_SPEED_PRIOR_SIGMA_MPS}: below it the prior alone \
                 could make an unobserved velocity look usable"
            ),
        );
        filter.check(
            self.gate_probability > 0.0 && self.gate_probability <= 1.0,
            "gate_probability",
            self.gate_probability,
            "set a probability in (0, 1], 1 disables the gate",
        );
        // A NaN on either side compares as neither and passes: its own line names it.
        filter.check(
            self.stationary_start_s
                .partial_cmp(&self.coarse_alignment_s)
                != Some(Ordering::Less),
            "stationary_start_s",
            self.stationary_start_s,
            format!(
                "shorter than filter.coarse_alignment_s = {:?}: make it at least as long",
                self.coarse_alignment_s
            ),
        );
        filter.check(
            self.imu_mount_rpy_deg.iter().all(|a| a.is_finite()),
            "imu_mount_rpy_deg",
            self.imu_mount_rpy_deg,
            "set three finite angles in degrees (in the configuration file: [imu] rpy_deg)",
        );
        filter.check(
            self.epoch_max_delay_s.partial_cmp(&self.pose_history_s) != Some(Ordering::Greater),
            "epoch_max_delay_s",
            self.epoch_max_delay_s,
            format!(
                "longer than filter.pose_history_s = {:?}: the delay is bridged from the pose history, so keep it within it",
                self.pose_history_s
            ),
        );
    }

    /// Rotation of IMU-frame vectors into the body frame.
    pub(crate) fn imu_to_body(&self) -> UnitQuaternion<f64> {
        Mount::from_rpy_deg(self.imu_mount_rpy_deg, [0.0; 3]).rotation
    }

    pub(crate) fn pose_history_capacity(&self) -> usize {
        (self.pose_history_s * self.max_imu_rate_hz).ceil().max(2.0) as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_an_empty_table_gives_the_defaults() {
        FilterConfig::default().validate().unwrap();
        let parsed: FilterConfig = toml::from_str("").unwrap();
        assert_eq!(parsed, FilterConfig::default());
        assert_eq!(parsed.stationary_start_s, 40.0);
    }

    #[test]
    fn keys_parse_and_unknown_keys_are_refused() {
        let parsed: FilterConfig = toml::from_str("relative_pose_update = \"velocity\"").unwrap();
        assert_eq!(parsed.relative_pose_update, RelativePoseUpdate::Velocity);
        assert!(toml::from_str::<FilterConfig>("gyro_noise = 1.0").is_err());
        // The mount is [imu] rpy_deg in the file; only code sets it here.
        assert!(toml::from_str::<FilterConfig>("imu_mount_rpy_deg = [0, 0, 90]").is_err());
        let rotated = FilterConfig {
            imu_mount_rpy_deg: [0.0, 0.0, 90.0],
            ..FilterConfig::default()
        }
        .imu_to_body()
            * nalgebra::Vector3::x();
        assert!((rotated - nalgebra::Vector3::y()).norm() < 1e-12);
    }

    #[test]
    fn every_bad_value_is_its_own_line_naming_the_key() {
        let config = FilterConfig {
            max_imu_gap_s: -1.0,
            gate_probability: 1.5,
            stationary_start_s: 0.5,
            divergence_window: 0,
            speed_prior_sigma_mps: 0.3,
            ..FilterConfig::default()
        };
        let message = config.validate().unwrap_err().to_string();
        let lines: Vec<&str> = message.lines().collect();
        assert_eq!(
            lines,
            [
                "filter.max_imu_gap_s = -1.0: set a finite value greater than zero",
                "filter.divergence_window = 0: set 1 or more",
                "filter.speed_prior_sigma_mps = 0.3: set 0 (off) or at least 0.75: below it the \
                 prior alone could make an unobserved velocity look usable",
                "filter.gate_probability = 1.5: set a probability in (0, 1], 1 disables the gate",
                "filter.stationary_start_s = 0.5: shorter than filter.coarse_alignment_s = 1.0: \
                 make it at least as long",
            ]
        );
    }
}
