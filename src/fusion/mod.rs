//! Pure wiring of IMU samples and scans, in time order, through the core and the filter.

pub mod clock;
pub mod sources;
