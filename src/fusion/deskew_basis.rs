//! The velocity an epoch's scans were deskewed with, and what a correction of it since does to
//! a relative pose.
//!
//! Deskewing places every beam at the epoch's reference time with the filter's motion, so a
//! velocity error `dv` moves a beam measured `tau` seconds off that time by `dv * tau`. Two
//! epochs deskewed with the same error share that shift and their relative pose keeps little
//! of it; but a correction of the filter's velocity between the two extractions leaves the
//! planes of one shifted against the other's by the correction times the scans' reach, which
//! no plane's covariance carried. After a restart (velocity set to zero while the platform
//! flew at 0.65 m/s) that made the next relative pose 0.11 m/s off at a 0.02 m/s sigma in
//! `random-room-89` at 10 Hz, and the restarted filter sent wrong velocities as usable. The
//! reference epoch's planes are widened by the shift instead; refusing the pair lost every
//! other epoch while a start in motion's large first corrections lasted (docs/autopilot.md).

use nalgebra::{UnitQuaternion, Vector3};

use crate::odometry::planes::Plane;
use crate::sensors::{Scan, ScannerGeometry};

/// What an epoch's planes were deskewed with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct DeskewBasis {
    /// The filter's running sum of velocity corrections when the scans were deskewed
    /// (`Eskf::velocity_corrections`), m/s.
    pub corrections: Vector3<f64>,
    /// How far from the reference time the scans' beams reach, s.
    pub reach_s: f64,
}

impl DeskewBasis {
    /// The basis of `scans` deskewed to `t_ref` after the filter's corrections summed to
    /// `corrections`.
    pub(super) fn of(
        scans: &[Scan; 2],
        geometries: [&ScannerGeometry; 2],
        t_ref: f64,
        corrections: Vector3<f64>,
    ) -> Self {
        let reach_s = scans
            .iter()
            .zip(geometries)
            .flat_map(|(scan, geometry)| {
                let last = scan.ranges_m.len().saturating_sub(1);
                [0, last].map(|index| (scan.time_of(index, geometry) - t_ref).abs())
            })
            .fold(0.0, f64::max);
        Self {
            corrections,
            reach_s,
        }
    }

    /// Widens each of `planes` (deskewed on `self`) by how far the velocity corrected before
    /// `later` (turned into body axes by `attitude`) moves it along its normal over the
    /// scans' reach, so that its distance sigma carries the two epochs' disagreement. A shift
    /// within a plane is harmless: along a corridor, where the speed prior corrects the
    /// velocity nothing observes, the walls and the floor do not move.
    pub(super) fn widen(&self, later: &Self, attitude: &UnitQuaternion<f64>, planes: &mut [Plane]) {
        let corrected = attitude.inverse_transform_vector(&(later.corrections - self.corrections));
        let reach_s = self.reach_s.max(later.reach_s);
        for plane in planes {
            let shift = plane.normal.dot(&corrected).abs() * reach_s;
            plane.uncertainty.sigma_rho = plane.uncertainty.sigma_rho.hypot(shift);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn basis(corrections: [f64; 3], reach_s: f64) -> DeskewBasis {
        DeskewBasis {
            corrections: corrections.into(),
            reach_s,
        }
    }

    fn wall(normal: Vector3<f64>) -> Plane {
        let line = crate::odometry::planes::LineRef {
            scanner: 0,
            segment: 0,
        };
        let uncertainty = crate::odometry::uncertainty::PlaneUncertainty {
            normal_covariance: nalgebra::Matrix3::zeros(),
            sigma_normal: 0.0,
            sigma_rho: 0.002,
        };
        Plane::through_one_line(line, normal, 2.0, uncertainty, 3.0)
    }

    #[test]
    fn a_correction_between_two_epochs_widens_the_planes_it_moves() {
        let level = UnitQuaternion::identity();
        let sigma_rho = |planes: &[Plane; 2]| planes.each_ref().map(|p| p.uncertainty.sigma_rho);
        let side_walls = || [wall(Vector3::y()), wall(-Vector3::y())];
        let before = basis([0.2, -0.1, 0.0], 0.06);
        // A restart's velocity reset of 0.65 m/s across the walls: 39 mm at 60 ms.
        let mut walls = side_walls();
        before.widen(&basis([0.2, -0.75, 0.0], 0.06), &level, &mut walls);
        for sigma in sigma_rho(&walls) {
            assert!((sigma - 0.002f64.hypot(0.039)).abs() < 1e-9, "{sigma}");
        }
        // Turned a quarter round, the same correction runs along the walls and moves none.
        let mut walls = side_walls();
        let turned = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        before.widen(&basis([0.2, -0.75, 0.0], 0.06), &turned, &mut walls);
        assert_eq!(sigma_rho(&walls), [0.002; 2]);
        // Over scans taken at the reference time it barely moves a beam.
        let mut walls = side_walls();
        let prompt = basis([0.2, -0.1, 0.0], 0.002);
        prompt.widen(&basis([0.2, -0.75, 0.0], 0.002), &level, &mut walls);
        assert!(sigma_rho(&walls).iter().all(|s| *s < 0.0025));
    }
}
