//! ladar-odometer: six-degree-of-freedom odometry from two 2D laser scanners and an IMU, after
//! Zhu and Uijt de Haag, "A Robust and Efficient 3D LADAR Odometer with Outlier Detection".
//!
//! Dependency direction: `sensors`, `least_squares`, `odometry`, `integrity` and `filter` are
//! pure and synchronous; `fusion` wires them without I/O; only `daemon` touches tokio, ports and
//! files.

pub mod config;
pub mod daemon;
pub mod estimate;
pub mod filter;
pub mod fusion;
pub mod integrity;
pub mod integrity_check;
pub mod least_squares;
pub mod odometry;
pub mod report;

pub use ladar_sensors as sensors;
