//! Integrity work per odometry epoch for 9 matched planes: both solves tested, with no fault
//! and with one moving plane (detected, excluded, both solves re-solved and re-tested).
//! The re-solves are `LinearSystem::solve` on the reduced systems, so they are included.

use divan::Bencher;
use ladar_odometer::estimate::IntegrityStatus;
use ladar_odometer::integrity::{without_planes, IntegrityConfig, IntegrityMonitor, SolveKind};
use ladar_odometer::least_squares::{LinearSystem, Solution, SolveError};
use nalgebra::{DMatrix, DVector, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

fn main() {
    divan::main();
}

const PLANES: usize = 9;
const SIGMA_DISTANCE: f64 = 0.005;
const SIGMA_NORMAL: f64 = 1.7e-3;

/// A room-like set of normals: walls, floor, ceiling and some tilted surfaces.
fn normals() -> Vec<Vector3<f64>> {
    (0..PLANES)
        .map(|k| {
            let azimuth = k as f64 * 2.4;
            let elevation: f64 = [0.0, 1.4, -1.3, 0.3, -0.2][k % 5];
            Vector3::new(
                elevation.cos() * azimuth.cos(),
                elevation.cos() * azimuth.sin(),
                elevation.sin(),
            )
        })
        .collect()
}

fn systems(fault: bool) -> (LinearSystem, LinearSystem) {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut noise = |sigma: f64| -> f64 {
        let unit: f64 = StandardNormal.sample(&mut rng);
        sigma * unit
    };
    let n = normals();
    let m = n.len();
    let mut disp_y = DVector::from_fn(m, |k, _| n[k].dot(&Vector3::new(0.2, 0.1, 0.0)));
    disp_y.iter_mut().for_each(|y| *y += noise(SIGMA_DISTANCE));
    if fault {
        disp_y[4] += 0.3;
    }
    let displacement = LinearSystem {
        h: DMatrix::from_fn(m, 3, |k, j| n[k][j]),
        y: disp_y,
        r: DMatrix::identity(m, m) * SIGMA_DISTANCE.powi(2),
        plane_of_row: (0..m).collect(),
    };
    let mut h = DMatrix::zeros(2 * m, 3);
    let mut y = DVector::zeros(2 * m);
    for (k, normal) in n.iter().enumerate() {
        let t1 = Vector3::x()
            .cross(normal)
            .try_normalize(1e-6)
            .unwrap_or(Vector3::y());
        let t2 = normal.cross(&t1);
        for (a, t) in [t1, t2].iter().enumerate() {
            h.row_mut(2 * k + a).copy_from(&normal.cross(t).transpose());
            y[2 * k + a] = noise(SIGMA_NORMAL);
        }
    }
    if fault {
        y[8] += 0.05;
    }
    let rotation = LinearSystem {
        h,
        y,
        r: DMatrix::identity(2 * m, 2 * m) * SIGMA_NORMAL.powi(2),
        plane_of_row: (0..2 * m).map(|row| row / 2).collect(),
    };
    (rotation, displacement)
}

fn resolver(system: &LinearSystem) -> impl FnMut(&[usize]) -> Result<Solution, SolveError> + '_ {
    move |excluded| without_planes(system, excluded).solve()
}

fn epoch(bencher: Bencher, fault: bool) {
    let monitor = IntegrityMonitor::new(IntegrityConfig::default()).unwrap();
    let (rotation, displacement) = systems(fault);
    let solved = (rotation.clone().solve(), displacement.clone().solve());
    let expected = monitor
        .check_epoch(
            solved.0.clone(),
            solved.1.clone(),
            &mut resolver(&rotation),
            &mut resolver(&displacement),
        )
        .status;
    let wanted = if fault {
        IntegrityStatus::Excluded { planes: vec![4] }
    } else {
        IntegrityStatus::Ok
    };
    assert_eq!(expected, wanted);
    bencher
        .with_inputs(|| solved.clone())
        .bench_local_values(|(rot, disp)| {
            monitor.check_epoch(
                rot,
                disp,
                &mut resolver(&rotation),
                &mut resolver(&displacement),
            )
        });
}

#[divan::bench]
fn epoch_9_planes_no_fault(bencher: Bencher) {
    epoch(bencher, false);
}

#[divan::bench]
fn epoch_9_planes_one_fault(bencher: Bencher) {
    epoch(bencher, true);
}

/// One test of the rotation solve (18 rows), without exclusion.
#[divan::bench]
fn test_rotation_9_planes(bencher: Bencher) {
    let monitor = IntegrityMonitor::new(IntegrityConfig::default()).unwrap();
    let (rotation, _) = systems(false);
    bencher.bench_local(|| monitor.test(SolveKind::Rotation, &rotation));
}

/// One test of the displacement solve (9 rows), without exclusion.
#[divan::bench]
fn test_displacement_9_planes(bencher: Bencher) {
    let monitor = IntegrityMonitor::new(IntegrityConfig::default()).unwrap();
    let (_, displacement) = systems(false);
    bencher.bench_local(|| monitor.test(SolveKind::Displacement, &displacement));
}

/// For reference: the re-solve the fault case calls twice (not integrity work).
#[divan::bench]
fn reference_resolve_rotation_8_planes(bencher: Bencher) {
    let (rotation, _) = systems(false);
    bencher.bench_local(|| without_planes(&rotation, &[4]).solve());
}
