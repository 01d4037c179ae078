//! The error-state EKF: IMU samples drive the nominal state and the covariance; odometry
//! epochs and the stationary start correct them. Naming after PX4 EKF2 and Sola (2017).
//! Propagation, cloning and resets are here; each measurement's update, and the odometer's
//! prior, has a file of its own in `eskf/`, as in EKF2's `aid_sources/`, so that an aid is read
//! (or added) in one place.

use nalgebra::{Matrix3, Rotation3, SMatrix, UnitQuaternion, Vector3};
use thiserror::Error;

use super::alignment::{looks_stationary, RecentForce, StationaryMeans};
use super::config::FilterConfig;
use super::covariance::{ErrorDynamics, ProcessNoise};
use super::divergence::{Divergence, DivergenceGuard};
use super::history::{Pose, PoseHistory};
use super::imu_noise::ImuNoiseMeter;
use super::map_states::{put_place, JointRows, MapStates};
use super::relative_pose::CarriedNoise;
use super::state::{
    Covariance, NominalState, ACCEL_BIAS, ACCEL_SCALE, ATT, AUGMENTED, CARRIED, CLONE_ATT,
    CLONE_POS, ERROR_STATES, GYRO_BIAS, GYRO_SCALE, POS, VEL,
};
use super::strapdown::{mechanise, ImuIncrement};
use super::update::{self, GateThresholds, Gated, Stacked};
use crate::config::ConfigErrors;
use crate::estimate::Estimate;
use crate::sensors::ImuSample;

mod level_update;
mod map_update;
mod pose_prior;
mod relative_pose_update;
mod speed_prior;
mod zero_motion_update;

pub use level_update::LevelDirection;
pub use map_update::{LineOnSurface, LineStack, MapLine, SurfaceAllowance, SurfacePlacement};

/// Most covariance steps taken to bridge one IMU gap.
const MAX_GAP_STEPS: f64 = 1000.0;

/// Where the filter is in its start-up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum FilterPhase {
    /// Averaging the first `coarse_alignment_s` of IMU data; no estimate yet.
    Aligning,
    /// Aligned; zero-velocity and zero-rate updates run until the end of the stationary start.
    StationaryStart,
    /// Free navigation.
    Navigating,
}

/// What one IMU sample did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ImuOutcome {
    /// Integrated into the state.
    Propagated,
    /// First `Rate` sample at the start time: kept to pair with the next one.
    Started,
    /// Taken into the gravity-alignment average.
    Aligning,
    /// Completed the gravity alignment: the state is initialised.
    Aligned,
    /// Not used, and counted.
    Dropped(DropReason),
    /// More than `max_imu_gap_s` since the previous sample: not integrated; the covariance
    /// was grown over the gap and the filter is degraded until the next fused epoch.
    Gap { seconds: f64 },
    /// The sample would have put a non-finite value into the state, or showed the filter
    /// diverged: the filter reset or restarted.
    Reset(ResetReason),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DropReason {
    /// Time not after the previous sample's.
    NonMonotonic,
    /// NaN or infinity in the time or the values, or a `Delta` interval that is not positive.
    NonFinite,
    /// A `Delta` sample claiming an interval longer than `max_imu_gap_s`.
    BadInterval,
}

/// Why `reset_counter` moved: the filter restarted, or its published pose jumped.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum ResetReason {
    #[error("IMU propagation produced a non-finite state (absurd IMU sample)")]
    NonFinitePropagation,
    #[error("a measurement update produced a non-finite state")]
    NonFiniteUpdate,
    #[error("filter diverged: {0}; navigation state restarted")]
    Diverged(Divergence),
    #[error("no IMU data for {seconds:.1} s: realigning, keeping position and heading")]
    ImuGap { seconds: f64 },
    #[error("a correction moved the position by {metres:.2} m at once")]
    PositionStep { metres: f64 },
}

/// Why the estimate should not be trusted as a full IMU/odometry solution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Degradation {
    ImuGap { seconds: f64 },
}

/// Counts of bad input, for logs and the summary.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct FilterCounters {
    pub non_monotonic: u64,
    pub non_finite: u64,
    pub bad_interval: u64,
    pub imu_gaps: u64,
    pub rejected_updates: u64,
    pub resets: u64,
    /// Samples that looked like motion in the alignment window (it then starts in motion)
    /// or during the stationary start, and relative poses that showed motion there (either
    /// ends the stationary start early).
    pub motion_during_start: u64,
}

/// Which measurement an update report is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UpdateKind {
    RelativePoseCloned,
    RelativePoseVelocity,
    ZeroMotion,
    SpeedPrior,
    LevelDirections,
    MapLines,
}

/// A building's floor is level by assumption, and a plane that only looks like one (a wall line
/// and a box-top line at the same height, 1.5 deg off the filter's level) is a wrong model, not
/// noise: in `random-room-59` such a floor passed the measurements' 99.99 % gate with an NIS of
/// 16.9 on its two rows and set the pitch-rate bias 12 mrad/s off. An assumption the filter's
/// tilt disputes at 99 % is not taken. A disabled gate (1.0) stays disabled.
const ASSUMPTION_GATE_PROBABILITY: f64 = 0.99;

fn assumption_gate_probability(gate_probability: f64) -> f64 {
    if gate_probability >= 1.0 {
        gate_probability
    } else {
        gate_probability.min(ASSUMPTION_GATE_PROBABILITY)
    }
}

/// Outcome of one measurement update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpdateReport {
    pub kind: UpdateKind,
    pub t: f64,
    /// Normalised innovation squared over the observable rows.
    pub nis: f64,
    /// Observable rows fused (0: nothing was observable, nothing changed).
    pub dof: usize,
    /// Gate threshold on the NIS.
    pub threshold: f64,
    /// False when the gate rejected the measurement.
    pub accepted: bool,
}

/// A measurement the filter could not use.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum UpdateError {
    #[error("filter not aligned yet: wait for the end of filter.coarse_alignment_s")]
    NotAligned,
    #[error("relative pose has NaN or infinite values: the odometer must not report it")]
    NonFinite,
    #[error("relative pose epoch t = {t} s is too far from the filter time {filter_t} s: feed the IMU up to the epoch (at most filter.epoch_time_tolerance_s short of it) and fuse it within filter.epoch_max_delay_s")]
    TimeMismatch { t: f64, filter_t: f64 },
    #[error("no cloned pose at t_ref = {t_ref} s: call clone_pose() at every odometry epoch")]
    NoClone { t_ref: f64 },
    #[error("reference epoch t_ref = {t_ref} s is outside the pose history: raise filter.pose_history_s")]
    OutsideHistory { t_ref: f64 },
    #[error("measurement covariance is not positive definite: check the odometer's covariance")]
    BadCovariance,
    #[error("surface {id} is not in the map: it was dropped or the filter restarted")]
    NoSurface { id: u64 },
}

#[derive(Debug, Clone, Copy)]
struct ZeroMotionWindow {
    start: f64,
    means: StationaryMeans,
}

/// Error-state Kalman filter over the 21 error states of `state.rs`, plus the 6 states of a
/// cloned reference pose while an odometry epoch is open.
#[derive(Debug, Clone)]
pub struct Eskf {
    config: FilterConfig,
    imu_to_body: UnitQuaternion<f64>,
    gravity: Vector3<f64>,
    noise: ProcessNoise,
    /// Measures the IMU's white noise, which the process noise takes where it is worse than
    /// configured.
    imu_noise: ImuNoiseMeter,
    gate: GateThresholds,
    /// The gate of updates that fuse an assumption rather than a measurement
    /// (`update_level_directions`).
    assumption_gate: GateThresholds,
    phase: FilterPhase,
    state: NominalState,
    covariance: Covariance,
    clone: Option<Pose>,
    /// The reference epoch's noise in the last fused relative pose, while it is a state.
    carried: Option<CarriedNoise>,
    t: Option<f64>,
    t_start: Option<f64>,
    previous: Option<ImuSample>,
    dynamics: Option<ErrorDynamics>,
    angular_rate: Vector3<f64>,
    means: StationaryMeans,
    zero_motion: Option<ZeroMotionWindow>,
    history: PoseHistory,
    counters: FilterCounters,
    reset_counter: u8,
    last_reset: Option<ResetReason>,
    degraded: Option<Degradation>,
    last_fused: Option<f64>,
    guard: DivergenceGuard,
    /// Set once the estimate has converged after the last (re)start
    /// (`FilterConfig::converged_after_epochs`).
    converged: bool,
    /// The gate refused the last relative pose that measured anything: the filter's prediction
    /// and the odometry disagree beyond its covariance, so the estimate is not to be used
    /// until a relative pose is fused again.
    disputed: bool,
    /// Relative poses fused since the last (re)start.
    fused_since_start: u32,
    /// The reference time of the first of them.
    first_fused_ref: Option<f64>,
    /// Every sample and every `zupt_interval_s` part of the current alignment window looked
    /// still.
    window_still: bool,
    /// The first `zupt_interval_s` part of the alignment window, which the others must match.
    first_part: Option<StationaryMeans>,
    /// Position and heading kept through a realignment after a long IMU gap.
    resume: Option<Resume>,
    /// When the speed prior was last fused (`apply_speed_prior`).
    last_speed_prior: Option<f64>,
    /// What a restart levels its tilt by.
    recent_force: RecentForce,
    /// Every change of the velocity that was not the IMU's, summed (navigation axes, m/s):
    /// updates and restarts. Scans deskewed before and after such a change disagree by it.
    velocity_corrections: Vector3<f64>,
    /// The plane map's surfaces, carried with the state (`odometry.method = "map"`).
    map: MapStates,
    /// The gate's chi-square thresholds by rows of lines on the map, filled as counts occur.
    map_gates: Vec<f64>,
}

/// What a restart keeps: the local frame's origin and heading stay, with their uncertainty,
/// so that the autopilot's frame does not move.
#[derive(Debug, Clone, Copy)]
struct Resume {
    position: Vector3<f64>,
    yaw: f64,
    position_covariance: Matrix3<f64>,
    yaw_variance: f64,
}

impl Resume {
    fn of(state: &NominalState, covariance: &Covariance) -> Self {
        let attitude = covariance.fixed_view::<3, 3>(ATT, ATT);
        Self {
            position: state.p,
            yaw: state.q.euler_angles().2,
            position_covariance: covariance.fixed_view::<3, 3>(POS, POS).into(),
            yaw_variance: attitude[(2, 2)],
        }
    }

    /// Puts the kept position and heading into a freshly started state and covariance; the
    /// kept covariance grows by `extra_position_variance` (motion the filter did not see).
    fn apply(
        &self,
        state: &mut NominalState,
        covariance: &mut Covariance,
        extra_position_variance: f64,
    ) {
        let (roll, pitch, _) = state.q.euler_angles();
        state.p = self.position;
        state.q = UnitQuaternion::from_euler_angles(roll, pitch, self.yaw);
        let position = self.position_covariance + Matrix3::identity() * extra_position_variance;
        covariance
            .fixed_view_mut::<3, 3>(POS, POS)
            .copy_from(&position);
        covariance[(ATT + 2, ATT + 2)] = covariance[(ATT + 2, ATT + 2)].max(self.yaw_variance);
    }
}

impl Eskf {
    /// A filter that aligns itself from the stationary start.
    pub(crate) fn new(config: FilterConfig) -> Result<Self, ConfigErrors> {
        config.validate()?;
        let state = NominalState::at_rest(UnitQuaternion::identity(), Vector3::zeros());
        let covariance = initial_covariance(&config, &state.q, StartSigmas::still(&config));
        Ok(Self {
            imu_to_body: config.imu_to_body(),
            gravity: Vector3::new(0.0, 0.0, config.gravity_mps2),
            noise: ProcessNoise::new(&config),
            imu_noise: ImuNoiseMeter::default(),
            gate: GateThresholds::new(config.gate_probability),
            assumption_gate: GateThresholds::new(assumption_gate_probability(
                config.gate_probability,
            )),
            phase: FilterPhase::Aligning,
            state,
            covariance,
            clone: None,
            carried: None,
            t: None,
            t_start: None,
            previous: None,
            dynamics: None,
            angular_rate: Vector3::zeros(),
            means: StationaryMeans::default(),
            zero_motion: None,
            history: PoseHistory::with_capacity(config.pose_history_capacity()),
            counters: FilterCounters::default(),
            reset_counter: 0,
            last_reset: None,
            degraded: None,
            last_fused: None,
            guard: DivergenceGuard::new(&config),
            converged: false,
            disputed: false,
            fused_since_start: 0,
            first_fused_ref: None,
            window_still: true,
            first_part: None,
            resume: None,
            last_speed_prior: None,
            recent_force: RecentForce::default(),
            velocity_corrections: Vector3::zeros(),
            map: MapStates::default(),
            map_gates: Vec::new(),
            config,
        })
    }

    /// A filter already navigating from a known state at time `t` (simulation, warm restart),
    /// with the configured initial sigmas.
    pub fn with_initial_state(
        config: FilterConfig,
        t: f64,
        state: NominalState,
    ) -> Result<Self, ConfigErrors> {
        let mut filter = Self::new(config)?;
        filter.covariance =
            initial_covariance(&filter.config, &state.q, StartSigmas::still(&filter.config));
        filter.state = state;
        filter.phase = FilterPhase::Navigating;
        filter.converged = true;
        filter.t = Some(t);
        filter.t_start = Some(t);
        filter.record_pose(t);
        Ok(filter)
    }

    /// Feeds one IMU sample (times strictly increasing, host clock).
    pub fn push_imu(&mut self, sample: &ImuSample) -> ImuOutcome {
        if !sample_is_finite(sample) {
            self.counters.non_finite += 1;
            return ImuOutcome::Dropped(DropReason::NonFinite);
        }
        let t = sample.time();
        let interval = match (self.t, sample) {
            (Some(last), ImuSample::Rate { .. }) if t == last && self.previous.is_none() => {
                self.previous = Some(*sample);
                return ImuOutcome::Started;
            }
            (Some(last), _) if t <= last => {
                self.counters.non_monotonic += 1;
                return ImuOutcome::Dropped(DropReason::NonMonotonic);
            }
            (_, ImuSample::Delta { dt, .. }) if *dt > self.config.max_imu_gap_s => {
                self.counters.bad_interval += 1;
                return ImuOutcome::Dropped(DropReason::BadInterval);
            }
            (_, ImuSample::Delta { dt, .. }) => *dt,
            (Some(last), ImuSample::Rate { .. }) => t - last,
            (None, ImuSample::Rate { .. }) => 0.0,
        };
        let since_last = self.t.map_or(0.0, |last| t - last);
        let previous = self.previous.replace(*sample).or(match (self.t, sample) {
            // No earlier sample to pair with (started from a given state): hold this one.
            (Some(last), ImuSample::Rate { gyro, accel, .. }) => Some(ImuSample::Rate {
                t: last,
                gyro: *gyro,
                accel: *accel,
            }),
            _ => None,
        });
        self.t = Some(t);
        if since_last > self.config.max_imu_gap_s {
            self.imu_noise.restart();
            return self.bridge_gap(t, since_last);
        }
        if let Some(measured) = self.imu_noise.observe(sample, interval) {
            self.noise = ProcessNoise::at_least_measured(&self.config, &measured);
        }
        match self.phase {
            FilterPhase::Aligning => self.align(t, sample, interval),
            FilterPhase::StationaryStart | FilterPhase::Navigating => {
                let Some(increment) = ImuIncrement::from_samples(previous.as_ref(), sample) else {
                    return ImuOutcome::Started;
                };
                if let Some(reason) = self.propagate(&increment) {
                    return ImuOutcome::Reset(reason);
                }
                if self.phase == FilterPhase::StationaryStart {
                    self.stationary_updates(t, sample, interval);
                } else {
                    self.apply_speed_prior(t);
                }
                ImuOutcome::Propagated
            }
        }
    }

    /// Averages the alignment window, still or not: a still window is the fast path (the mean
    /// rate is the gyro bias, and zero-motion updates follow); a moving one starts in motion,
    /// with the wide priors the odometry then narrows.
    fn align(&mut self, t: f64, sample: &ImuSample, interval: f64) -> ImuOutcome {
        if !self.looks_stationary(sample) {
            self.counters.motion_during_start += 1;
            self.window_still = false;
        }
        let start = *self.t_start.get_or_insert(t);
        self.means.add(sample, interval);
        if let Some(part) = self.completed_window(t, sample, interval) {
            match &self.first_part {
                None => self.first_part = Some(part),
                Some(first) => self.window_still &= !self.departs(&part, first),
            }
        }
        if t - start < self.config.coarse_alignment_s {
            return ImuOutcome::Aligning;
        }
        self.first_part = None;
        let still = self.window_still;
        self.state = self.means.aligned_state(&self.imu_to_body, still);
        let sigmas = if still {
            StartSigmas::still(&self.config)
        } else {
            StartSigmas::moving(&self.config)
        };
        self.covariance = initial_covariance(&self.config, &self.state.q, sigmas);
        if let Some(resume) = self.resume.take() {
            let unseen = self.config.moving_start_sigma_velocity_mps * (t - start);
            resume.apply(&mut self.state, &mut self.covariance, unseen * unseen);
        }
        self.zero_motion = None;
        self.phase = if still && t - start < self.config.stationary_start_s {
            FilterPhase::StationaryStart
        } else {
            FilterPhase::Navigating
        };
        self.record_pose(t);
        ImuOutcome::Aligned
    }

    /// Strapdown step plus covariance propagation; commits only a finite result.
    fn propagate(&mut self, increment: &ImuIncrement) -> Option<ResetReason> {
        let corrected = increment.corrected(&self.state, &self.imu_to_body);
        let next = mechanise(&self.state, &corrected, &self.gravity);
        let dynamics = ErrorDynamics::new(
            &self.state.q,
            &self.imu_to_body,
            &corrected,
            &self.state.gyro_scale,
            &self.state.accel_scale,
        );
        // In place: a non-finite result is discarded by the reset anyway.
        let covariance_finite = dynamics.propagate(
            &mut self.covariance,
            &self.noise,
            corrected.dt,
            self.clone.is_some(),
        );
        self.map.advance(&dynamics, corrected.dt);
        if !next.is_finite() || !covariance_finite {
            self.reset(ResetReason::NonFinitePropagation);
            return Some(ResetReason::NonFinitePropagation);
        }
        // The specific force the step applied in navigation axes, read back from its velocity
        // change rather than rotated again.
        let force = (next.v - self.state.v) / corrected.dt - self.gravity;
        self.recent_force
            .add(&force, corrected.dt, self.config.coarse_alignment_s);
        self.state = next;
        self.dynamics = Some(dynamics);
        self.angular_rate = corrected.dtheta / corrected.dt;
        self.record_pose(increment.t);
        let divergence = self.guard.check_speed(self.state.v.norm())?;
        let reason = ResetReason::Diverged(divergence);
        self.reinitialise(reason);
        Some(reason)
    }

    /// Over a gap the IMU is unknown: the state coasts at constant velocity and the covariance
    /// grows as the last dynamics and the process noise say, in steps of the allowed interval.
    fn bridge_gap(&mut self, t: f64, seconds: f64) -> ImuOutcome {
        self.counters.imu_gaps += 1;
        self.degraded = Some(Degradation::ImuGap { seconds });
        if self.phase == FilterPhase::Aligning {
            self.restart_alignment(t);
            return ImuOutcome::Gap { seconds };
        }
        if seconds > self.config.max_coast_s {
            self.dissolve_map();
            self.resume = Some(Resume::of(&self.state, &self.covariance));
            self.restart_alignment(t);
            self.count_reset(ResetReason::ImuGap { seconds });
            return ImuOutcome::Gap { seconds };
        }
        // Bounded work for any gap: past MAX_GAP_STEPS the steps get longer.
        let steps = (seconds / self.config.max_imu_gap_s)
            .ceil()
            .min(MAX_GAP_STEPS);
        let step = seconds / steps;
        for _ in 0..steps as usize {
            let dynamics = self.dynamics.unwrap_or_else(|| self.rest_dynamics());
            dynamics.propagate(
                &mut self.covariance,
                &self.noise,
                step,
                self.clone.is_some(),
            );
            self.map.advance(&dynamics, step);
        }
        self.state.p += self.state.v * seconds;
        self.zero_motion = None;
        self.record_pose(t);
        ImuOutcome::Gap { seconds }
    }

    /// Error dynamics of a body at rest in its current attitude.
    fn rest_dynamics(&self) -> ErrorDynamics {
        let dt = self.config.max_imu_gap_s;
        let force_imu = self
            .imu_to_body
            .inverse_transform_vector(&self.state.q.inverse_transform_vector(&-self.gravity));
        let at_rest = super::strapdown::Corrected {
            dt,
            dtheta_imu: Vector3::zeros(),
            dv_imu: force_imu * dt,
            dtheta: Vector3::zeros(),
            dv: Vector3::zeros(),
        };
        ErrorDynamics::new(
            &self.state.q,
            &self.imu_to_body,
            &at_rest,
            &self.state.gyro_scale,
            &self.state.accel_scale,
        )
    }

    fn looks_stationary(&self, sample: &ImuSample) -> bool {
        looks_stationary(
            sample,
            self.config.gravity_mps2,
            self.config.stationary_max_rate,
            self.config.stationary_max_force_error_mps2,
        )
    }

    /// Adds the sample to the current `zupt_interval_s` window and returns the window's means
    /// when it is complete.
    fn completed_window(
        &mut self,
        t: f64,
        sample: &ImuSample,
        interval: f64,
    ) -> Option<StationaryMeans> {
        let window = self.zero_motion.get_or_insert(ZeroMotionWindow {
            start: t - interval,
            means: StationaryMeans::default(),
        });
        window.means.add(sample, interval);
        let complete = t - window.start >= self.config.zupt_interval_s;
        complete.then(|| self.zero_motion.take().map(|w| w.means))?
    }

    fn departs(&self, window: &StationaryMeans, reference: &StationaryMeans) -> bool {
        window.departs_from(
            reference,
            self.config.still_max_force_change_mps2,
            self.config.still_max_rate_change,
        )
    }

    /// Clones the current pose as the reference of the next odometry epoch (replacing any
    /// open clone). Returns the clone's time.
    pub fn clone_pose(&mut self) -> Result<f64, UpdateError> {
        let t = self.aligned_time()?;
        let p = &mut self.covariance;
        for (clone_at, source) in [(CLONE_POS, POS), (CLONE_ATT, ATT)] {
            for k in 0..3 {
                for column in (0..ERROR_STATES).chain(CARRIED..AUGMENTED) {
                    let value = p[(source + k, column)];
                    p[(clone_at + k, column)] = value;
                    p[(column, clone_at + k)] = value;
                }
            }
        }
        for (a, source_a) in [(CLONE_POS, POS), (CLONE_ATT, ATT)] {
            for (b, source_b) in [(CLONE_POS, POS), (CLONE_ATT, ATT)] {
                for i in 0..3 {
                    for j in 0..3 {
                        p[(a + i, b + j)] = p[(source_a + i, source_b + j)];
                    }
                }
            }
        }
        self.clone = Some(Pose {
            t,
            p: self.state.p,
            q: self.state.q,
        });
        Ok(t)
    }

    fn fuse(
        &mut self,
        rows: &Stacked,
        kind: UpdateKind,
        t: f64,
    ) -> Result<UpdateReport, UpdateError> {
        if !rows.is_finite() {
            return Err(UpdateError::NonFinite);
        }
        let gate = match kind {
            UpdateKind::LevelDirections => &self.assumption_gate,
            _ => &self.gate,
        };
        if !self.map.is_empty() {
            // The map is built only by `odometry.method = "map"`, which fuses no relative
            // poses, so nothing here carries noise out to a next measurement.
            let threshold = gate.threshold(rows.dof());
            let joint = rows.joint(self.map.states());
            return self.fuse_joint(&joint, (rows.dof(), threshold), None, kind, t);
        }
        let mut covariance = self.covariance;
        let gated =
            update::apply(&mut covariance, rows, gate).map_err(|_| UpdateError::BadCovariance)?;
        let carried_out = rows.carried_out_covariance();
        self.commit(gated, covariance, carried_out, Vector3::zeros(), kind, t)
    }

    /// Fuses rows over the state and the mapped surfaces together, the state's directions
    /// `held` projects onto left where they were (`MapStates::update`).
    fn fuse_joint(
        &mut self,
        rows: &JointRows,
        (dof, threshold): (usize, f64),
        held: Option<&Matrix3<f64>>,
        kind: UpdateKind,
        t: f64,
    ) -> Result<UpdateReport, UpdateError> {
        if !rows.is_finite() {
            return Err(UpdateError::NonFinite);
        }
        let mut covariance = self.covariance;
        let joint = self
            .map
            .update(&mut covariance, rows, threshold, held)
            .map_err(|_| UpdateError::BadCovariance)?;
        let gated = Gated {
            nis: joint.nis,
            dof,
            threshold,
            correction: joint.correction,
            carried: None,
        };
        self.commit(gated, covariance, None, joint.origin_moved, kind, t)
    }

    /// Applies a gated update's correction and covariance (or counts its refusal);
    /// `origin_moved` is how far the same update moved the map's origin, which the reported
    /// position moves with.
    fn commit(
        &mut self,
        gated: Gated,
        covariance: Covariance,
        carried_out: Option<SMatrix<f64, 6, 6>>,
        origin_moved: Vector3<f64>,
        kind: UpdateKind,
        t: f64,
    ) -> Result<UpdateReport, UpdateError> {
        let report = UpdateReport {
            kind,
            t,
            nis: gated.nis,
            dof: gated.dof,
            threshold: gated.threshold,
            accepted: gated.correction.is_some(),
        };
        let Some(correction) = gated.correction else {
            if gated.dof > 0 {
                self.counters.rejected_updates += 1;
            }
            return Ok(report);
        };
        let block =
            |at: usize| Vector3::new(correction[at], correction[at + 1], correction[at + 2]);
        let next = self.state.inject(&correction);
        if !next.is_finite() || !covariance.iter().all(|x| x.is_finite()) || !self.map.is_finite() {
            self.reset(ResetReason::NonFiniteUpdate);
            return Ok(UpdateReport {
                accepted: false,
                ..report
            });
        }
        self.velocity_corrections += next.v - self.state.v;
        let step = (next.p - self.state.p + origin_moved).norm();
        if step > self.config.max_position_step_m {
            self.count_reset(ResetReason::PositionStep { metres: step });
        }
        // The stored poses were propagated from the state before the correction: move them
        // with it, so motion read from the history (deskew, priors, epoch bridges) is the
        // IMU's alone and never contains the correction itself.
        self.history
            .correct(&(next.p - self.state.p), &(next.q * self.state.q.inverse()));
        // An open clone is corrected too (a zero-velocity update moves it through its
        // correlation with the current pose): its covariance now describes errors about the
        // corrected pose, and the next relative pose must be compared with that pose.
        if let Some(clone) = &mut self.clone {
            clone.p += block(CLONE_POS);
            clone.q = UnitQuaternion::from_scaled_axis(block(CLONE_ATT)) * clone.q;
        }
        match (gated.carried, carried_out) {
            (Some(mean), Some(prior)) => {
                let part = |k: usize| Vector3::new(mean[k], mean[k + 1], mean[k + 2]);
                self.carried = Some(CarriedNoise {
                    prior: [0, 3].map(|k| prior.fixed_view::<3, 3>(k, k).into()),
                    mean: [part(0), part(3)],
                });
            }
            _ => {
                if let Some(carried) = &mut self.carried {
                    carried.mean[0] += block(CARRIED);
                    carried.mean[1] += block(CARRIED + 3);
                }
            }
        }
        self.state = next;
        self.covariance = covariance;
        self.replace_latest_pose(t);
        Ok(report)
    }

    fn aligned_time(&self) -> Result<f64, UpdateError> {
        match (self.phase, self.t) {
            (FilterPhase::Aligning, _) | (_, None) => Err(UpdateError::NotAligned),
            (_, Some(t)) => Ok(t),
        }
    }

    /// Keeps the last finite state, restarts the covariance from the initial sigmas and drops
    /// the clone; the estimate jumps, so `reset_counter` moves.
    fn reset(&mut self, reason: ResetReason) {
        self.dissolve_map();
        self.covariance = initial_covariance(
            &self.config,
            &self.state.q,
            StartSigmas::still(&self.config),
        );
        self.clone = None;
        self.carried = None;
        self.count_reset(reason);
    }

    /// Restarts the navigation state where it stands: position and heading stay, so that the
    /// autopilot's frame does not move; the velocity restarts at zero, the biases at their
    /// priors and the covariance from the start-in-motion sigmas, so that the odometry
    /// measures them again. The tilt is levelled on the last second's specific force, as a
    /// start in motion levels it: a divergence often is a wrong tilt, which gravity turned into
    /// the runaway velocity (100 mrad in `open-room` started in motion, twice the start's
    /// sigma). Until the estimate converges again it is not to be trusted.
    fn reinitialise(&mut self, reason: ResetReason) {
        self.dissolve_map();
        let resume = Resume::of(&self.state, &self.covariance);
        let attitude = self
            .recent_force
            .levelled(&self.state.q, self.config.coarse_alignment_s)
            .unwrap_or(self.state.q);
        self.velocity_corrections -= self.state.v;
        let diverged_attitude = self.state.q;
        self.state = NominalState::at_rest(attitude, Vector3::zeros());
        self.covariance = initial_covariance(
            &self.config,
            &self.state.q,
            StartSigmas::moving(&self.config),
        );
        resume.apply(&mut self.state, &mut self.covariance, 0.0);
        // The levelling turned the attitude without a turn of the body: the stored poses turn
        // with it, or the first relative pose after the restart reads the turn as motion and
        // puts it into the gyro bias, its prior sigma wide open. In `random-corridor-49` the
        // first epoch after a restart taught the gyro's x bias 1.8 mrad/s off, and the
        // velocity across the body ran 2.9 m/s off as the roll error grew at that rate,
        // usable all the while.
        self.history.correct(
            &Vector3::zeros(),
            &(self.state.q * diverged_attitude.inverse()),
        );
        self.phase = FilterPhase::Navigating;
        self.forget_epochs();
        self.count_reset(reason);
    }

    /// Starts a new alignment window at `t` (after an IMU gap).
    fn restart_alignment(&mut self, t: f64) {
        self.phase = FilterPhase::Aligning;
        self.means = StationaryMeans::default();
        self.window_still = true;
        self.t_start = Some(t);
        self.forget_epochs();
    }

    /// Drops what ties the filter to earlier epochs: the clone, the carried noise, the
    /// zero-motion window, the divergence guard's history, the convergence, and the recent
    /// specific force, which the attitude before a restart put into navigation axes.
    pub(super) fn forget_epochs(&mut self) {
        self.recent_force.clear();
        self.clone = None;
        self.carried = None;
        self.dissolve_map();
        self.zero_motion = None;
        self.guard.clear();
        self.converged = false;
        self.disputed = false;
        self.fused_since_start = 0;
        self.first_fused_ref = None;
    }

    fn count_reset(&mut self, reason: ResetReason) {
        self.reset_counter = self.reset_counter.wrapping_add(1);
        self.counters.resets += 1;
        self.last_reset = Some(reason);
    }

    fn record_pose(&mut self, t: f64) {
        self.history.push(Pose {
            t,
            p: self.state.p,
            q: self.state.q,
        });
    }

    fn replace_latest_pose(&mut self, t: f64) {
        if self.history.span().is_some_and(|(_, newest)| newest == t) {
            self.history.pop_newest();
        }
        self.record_pose(t);
    }

    /// Propagated pose at `t` within the pose history (deskewing a beam measured at `t`).
    #[cfg(test)]
    pub(crate) fn pose_at(&self, t: f64) -> Option<Pose> {
        self.history.pose_at(t)
    }

    /// The pose at `t` from the history or, for a `t` after the newest IMU sample, the newest
    /// pose carried on with the current velocity and body rate (what deskew uses for beams read
    /// after the IMU). `None` before the history or before any IMU sample.
    pub(crate) fn pose_at_or_after(&self, t: f64) -> Option<Pose> {
        if let Some(pose) = self.history.pose_at(t) {
            return Some(pose);
        }
        let ahead = t - self.t?;
        (ahead > 0.0).then(|| Pose {
            t,
            p: self.state.p + self.state.v * ahead,
            q: self.state.q * UnitQuaternion::from_scaled_axis(self.angular_rate * ahead),
        })
    }

    /// Whether an epoch time `t` can be bridged to the filter's pose at `at` (the clone's or
    /// the current time): from the history up to `epoch_max_delay_s` before it (a pair closes
    /// the rest of a revolution after its reference time), by extrapolation up to
    /// `epoch_time_tolerance_s` after it (the IMU's bytes read after the scans').
    fn bridgeable(&self, t: f64, at: f64) -> bool {
        let behind = at - t;
        behind <= self.config.epoch_max_delay_s && -behind <= self.config.epoch_time_tolerance_s
    }

    /// `pose_at_or_after`, at most `epoch_time_tolerance_s` ahead: a scan pair can be complete
    /// before the IMU sample that covers its reference time has been read.
    fn pose_or_ahead(&self, t: f64) -> Option<Pose> {
        let ahead = t - self.t?;
        (ahead <= self.config.epoch_time_tolerance_s)
            .then(|| self.pose_at_or_after(t))
            .flatten()
    }

    pub(crate) fn estimate(&self) -> Estimate {
        let t = self.t.unwrap_or(0.0);
        let block =
            |at: usize| -> Matrix3<f64> { self.covariance.fixed_view::<3, 3>(at, at).into() };
        Estimate {
            t,
            position: self.position(),
            velocity: self.state.v,
            attitude: self.state.q,
            angular_rate: self.angular_rate,
            position_covariance: self.position_covariance(),
            velocity_covariance: block(VEL),
            velocity_attitude_covariance: self.covariance.fixed_view::<3, 3>(VEL, ATT).into(),
            attitude_covariance: block(ATT),
            gyro_bias: self.imu_to_body * self.state.gyro_bias,
            accel_bias: self.imu_to_body * self.state.accel_bias,
            reset_counter: self.reset_counter,
            last_reset: self.last_reset,
            integrity: None,
            since_last_fused: self.last_fused.map_or(f64::INFINITY, |last| t - last),
            degraded: self.degraded.is_some() || self.phase == FilterPhase::Aligning,
            converged: self.converged && !self.disputed,
        }
    }

    /// NEES of position, velocity and attitude against truth at the filter time.
    #[cfg(test)]
    pub(crate) fn nees(
        &self,
        truth: &crate::sensors::TruthSample,
    ) -> Option<super::consistency::Normalised> {
        let covariance: nalgebra::SMatrix<f64, 9, 9> =
            self.covariance().fixed_view::<9, 9>(POS, POS).into();
        super::consistency::nees(
            &self.position(),
            &self.state.v,
            &self.state.q,
            &covariance,
            truth,
        )
    }

    /// Whether enough relative poses were fused since the last (re)start for the estimate to be
    /// trusted (`FilterConfig::converged_after_epochs`).
    pub(crate) fn converged(&self) -> bool {
        self.converged
    }

    pub(crate) fn phase(&self) -> FilterPhase {
        self.phase
    }

    pub fn state(&self) -> &NominalState {
        &self.state
    }
    /// The 33x33 covariance; rows and columns 21.. are the clone's and the carried noise's,
    /// meaningful only while a clone is open. The position's rows and columns are those of
    /// the body's place in the navigation frame, as the estimate reports it
    /// (`Eskf::position`).
    pub fn covariance(&self) -> Covariance {
        let mut covariance = self.covariance;
        put_place(&mut covariance, &self.with_position());
        covariance
    }
    pub fn time(&self) -> Option<f64> {
        self.t
    }
    #[cfg(test)]
    pub(crate) fn counters(&self) -> FilterCounters {
        self.counters
    }
    #[cfg(test)]
    pub(crate) fn last_reset(&self) -> Option<ResetReason> {
        self.last_reset
    }
    /// Standard deviations of the 21 error states, in `state.rs` order.
    #[cfg(test)]
    pub(crate) fn sigmas(&self) -> [f64; ERROR_STATES] {
        std::array::from_fn(|i| self.covariance[(i, i)].sqrt())
    }
    /// The sum of the velocity's changes that were not the IMU's (`velocity_corrections`).
    pub(crate) fn velocity_corrections(&self) -> Vector3<f64> {
        self.velocity_corrections
    }

    /// The larger of the roll and pitch sigmas (global attitude error), rad.
    pub(crate) fn tilt_sigma(&self) -> f64 {
        let c = &self.covariance;
        c[(ATT, ATT)].max(c[(ATT + 1, ATT + 1)]).sqrt()
    }

    /// Gyro bias in the IMU frame, rad/s.
    #[cfg(test)]
    pub(crate) fn gyro_bias(&self) -> Vector3<f64> {
        self.state.gyro_bias
    }
}

fn sample_is_finite(sample: &ImuSample) -> bool {
    let finite = |v: &Vector3<f64>| v.iter().all(|x| x.is_finite());
    match sample {
        ImuSample::Rate { t, gyro, accel } => t.is_finite() && finite(gyro) && finite(accel),
        ImuSample::Delta { t, dt, dq, dv } => {
            t.is_finite()
                && dt.is_finite()
                && *dt > 0.0
                && dq.coords.iter().all(|x| x.is_finite())
                && finite(dv)
        }
    }
}

/// The priors that differ between a still start and a start in motion.
#[derive(Debug, Clone, Copy)]
struct StartSigmas {
    velocity_mps: f64,
    tilt_deg: f64,
    gyro_bias: f64,
}

impl StartSigmas {
    fn still(config: &FilterConfig) -> Self {
        Self {
            velocity_mps: config.initial_sigma_velocity_mps,
            tilt_deg: config.initial_sigma_tilt_deg,
            gyro_bias: config.initial_sigma_gyro_bias,
        }
    }

    fn moving(config: &FilterConfig) -> Self {
        Self {
            velocity_mps: config.moving_start_sigma_velocity_mps,
            tilt_deg: config.moving_start_sigma_tilt_deg,
            gyro_bias: config.moving_start_sigma_gyro_bias,
        }
    }
}

fn initial_covariance(
    config: &FilterConfig,
    attitude: &UnitQuaternion<f64>,
    start: StartSigmas,
) -> Covariance {
    let deg = std::f64::consts::PI / 180.0;
    let tilt = start.tilt_deg * deg;
    let euler_sigmas = Vector3::new(tilt, tilt, config.initial_sigma_yaw_deg * deg);
    let sigmas = [
        (POS, Vector3::repeat(config.initial_sigma_position_m)),
        (VEL, Vector3::repeat(start.velocity_mps)),
        (GYRO_BIAS, Vector3::repeat(start.gyro_bias)),
        (ACCEL_BIAS, Vector3::repeat(config.initial_sigma_accel_bias)),
        (GYRO_SCALE, Vector3::repeat(config.initial_sigma_gyro_scale)),
        (
            ACCEL_SCALE,
            Vector3::repeat(config.initial_sigma_accel_scale),
        ),
    ];
    let mut p = Covariance::zeros();
    for (at, sigma) in sigmas {
        for k in 0..3 {
            p[(at + k, at + k)] = sigma[k] * sigma[k];
        }
    }
    p.fixed_view_mut::<3, 3>(ATT, ATT)
        .copy_from(&euler_attitude_covariance(attitude, &euler_sigmas));
    p
}

/// The global attitude-error covariance of independent roll, pitch and yaw (ZYX Euler) errors
/// at `attitude`. Gravity alignment fixes roll and pitch and the start convention fixes the
/// Euler yaw; at a pitch, a roll error turns the body about an axis out of the horizontal, so
/// the global yaw error carries part of it (sin(pitch) of it), which a diagonal prior would
/// miss whenever the yaw sigma is small.
pub(super) fn euler_attitude_covariance(
    attitude: &UnitQuaternion<f64>,
    sigmas: &Vector3<f64>,
) -> Matrix3<f64> {
    let (_, pitch, yaw) = attitude.euler_angles();
    let yawed = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw);
    let pitched = yawed * Rotation3::from_axis_angle(&Vector3::y_axis(), pitch);
    let jacobian =
        Matrix3::from_columns(&[pitched * Vector3::x(), yawed * Vector3::y(), Vector3::z()]);
    jacobian * Matrix3::from_diagonal(&sigmas.component_mul(sigmas)) * jacobian.transpose()
}
