//! Protection levels: the largest error on each axis of a solve that a fault in any one plane,
//! just large enough to be detected with probability `1 - Pmd`, can cause without being caught.
//!
//! Slope method: a bias `b` on plane `k` moves the estimate by `S_k b` (`S = P H^T R^-1`) and
//! the plane's test by noncentrality `sqrt(b^T N_k b)`. Over the biases at the detection limit
//! `b^T N_k b = (gamma_k + z_(1-Pmd))^2`, the largest error on axis `a` is that noncentrality
//! times the slope `sqrt(e_a^T S_k N_k^-1 S_k^T e_a)` (for one row a plane this is the familiar
//! `|S_ak| * MDB_k`). The fault part is the maximum over planes; the estimate's own noise,
//! independent of the parity vector and so of detection, adds `z_(1-Pmd/2) sigma_a`, so an
//! undetected fault of that size leaves the error inside the level with probability at least
//! `1 - Pmd`.

use super::parity::PlaneTest;
use super::thresholds::Thresholds;
use serde::Serialize;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProtectionLevels {
    /// `from_fault + from_noise`, per axis, in the solve's units (m or rad).
    pub level: [f64; 3],
    /// Largest error a fault at the detection limit in one plane causes; infinite when some
    /// plane's bias can hide from every test.
    pub from_fault: [f64; 3],
    pub from_noise: [f64; 3],
    /// The plane whose fault gives `from_fault` on each axis.
    pub worst_plane: [Option<usize>; 3],
}

pub(crate) fn protection_levels(
    planes: &[PlaneTest],
    estimate_sigmas: &[f64; 3],
    thresholds: &Thresholds,
) -> ProtectionLevels {
    let mut from_fault = [0.0; 3];
    let mut worst_plane = [None; 3];
    for plane in planes {
        let noncentrality = plane.threshold + thresholds.missed_detection_quantile;
        for axis in 0..3 {
            let error = plane.slope[axis] * noncentrality;
            if worst_plane[axis].is_none() || error > from_fault[axis] {
                from_fault[axis] = error;
                worst_plane[axis] = Some(plane.plane);
            }
        }
    }
    let from_noise = estimate_sigmas.map(|sigma| thresholds.noise_quantile * sigma);
    ProtectionLevels {
        level: [0, 1, 2].map(|axis| from_fault[axis] + from_noise[axis]),
        from_fault,
        from_noise,
        worst_plane,
    }
}
