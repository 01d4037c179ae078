//! Strapdown mechanisation and the error-state EKF (section 4.3, DESIGN.md 4.9).

pub mod alignment;
pub mod config;
pub mod consistency;
pub mod covariance;
pub mod eskf;
pub mod history;
pub mod relative_pose;
pub mod state;
pub mod strapdown;
#[cfg(test)]
pub(crate) mod testkit;
pub mod update;

pub use config::{ConfigError, FilterConfig, RelativePoseUpdate};
pub use consistency::{chi_square_quantile, nees, nis, Normalised};
pub use eskf::{
    Degradation, DropReason, Eskf, FilterCounters, FilterPhase, ImuOutcome, PosePrior, ResetReason,
    UpdateError, UpdateKind, UpdateReport,
};
pub use history::Pose;
pub use relative_pose::{RelativePose, RelativeRotation, RelativeTranslation};
pub use state::NominalState;
pub use update::Observability;

#[cfg(test)]
mod eskf_tests;
