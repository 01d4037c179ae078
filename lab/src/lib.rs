//! The lab: seeded, deterministic studies that run ladar-odometer on its simulator (ladar-sim)
//! and produce the figures in docs/. None of it ships in the daemon; the `integrity-check` command's own
//! study stays in the library, and the studies here build on its harness.
//!
//! - `evaluate`: accuracy and NEES of the fusion on one scenario against truth;
//! - `monte_carlo`: the same over many seeded runs (docs/accuracy.md);
//! - `sigma`, `paper`, `door`: the plane sigmas (Table 1), detection, false alarms and exclusion
//!   (sec. 4.1) and the office door (sec. 4.2) against the paper's figures (docs/figures.md).

pub mod door;
pub mod evaluate;
pub mod monte_carlo;
pub mod paper;
pub mod sigma;
