//! Parity-space fault detection and exclusion with protection levels (sections 3.3 to 3.5,
//! eqs 29-44): each odometry solve is tested for a moving plane, the culprit is excluded when
//! the redundancy allows it, and the largest error an undetected fault could cause is reported.
//!
//! Stages, one a file: `thresholds` (risk budgets to gamma and chi-square thresholds),
//! `parity` (parity space, per-plane w-tests, minimum detectable biases), `protection`
//! (protection levels), `exclusion` (the detect-exclude-retest loop over one solve or an
//! epoch); `blocks`, the same test with a mapped surface's rows in the role of a plane
//! (`odometry.method = "map"`).

pub mod blocks;
mod config;
mod exclusion;
mod parity;
mod protection;
mod thresholds;

pub use config::IntegrityConfig;
pub use exclusion::{without_planes, IntegrityMonitor, SolveKind};
pub(crate) use exclusion::{EpochReport, SolveReport};
pub use parity::SolveTest;
pub use thresholds::{chi_square_upper_quantile, Thresholds};

#[cfg(test)]
mod tests;
