//! Strapdown mechanisation and the error-state EKF (paper sec. 4.3; docs/design.md, 4.9 "Filter").
//!
//! How the fusion drives it (all times on the host clock, in time order):
//! 1. `Eskf::new(config)`, then `push_imu(&sample)` for every IMU sample. The first
//!    `coarse_alignment_s` align roll, pitch and gyro bias; zero-motion updates run until
//!    `stationary_start_s`; `phase()` says where it is.
//! 2. Deskew each beam with `pose_at(beam_time)`; give the odometer
//!    `relative_pose(t_ref, t)` as its prior.
//! 3. At every odometry epoch's reference time call `clone_pose()` (after feeding the IMU up
//!    to about that time); when the epoch's solution arrives, feed the IMU up to its time and
//!    call `update_relative_pose(&RelativePoseMeasurement { .. })`: it reports the NIS and whether the
//!    gate accepted it, and consumes the clone. Missing parts are `None`; unobservable
//!    directions come in as `Observability::from_unobservable(&directions)`.
//! 4. `estimate()` fills the shared `Estimate` (the fusion sets `integrity`).

pub(crate) mod alignment;
pub(crate) mod config;
pub(crate) mod consistency;
pub(crate) mod covariance;
pub(crate) mod divergence;
pub(crate) mod eskf;
pub(crate) mod history;
pub(crate) mod imu_noise;
pub(crate) mod map_states;
pub(crate) mod relative_pose;
pub mod state;
pub(crate) mod strapdown;
#[cfg(test)]
pub(crate) mod testkit;
pub(crate) mod update;

pub use config::{FilterConfig, RelativePoseUpdate};
pub use consistency::mean_nees_interval;
pub(crate) use consistency::{chi_square_quantile, surprises_one_of};
pub use eskf::{
    Eskf, LevelDirection, LineOnSurface, LineStack, MapLine, SurfaceAllowance, SurfacePlacement,
};
pub(crate) use eskf::{FilterPhase, ImuOutcome, ResetReason, UpdateReport};
pub(crate) use history::Pose;
pub use relative_pose::{
    RelativePoseMeasurement, RelativeRotation, RelativeTranslation, SharedNoise,
};
pub use state::NominalState;
pub use update::Observability;

#[cfg(test)]
mod eskf_tests;
