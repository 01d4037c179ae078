//! Seeded statistical and structural tests of the integrity layer on synthetic solves.

use super::parity::{parity_space, Untestable};
use super::thresholds::normal_upper_quantile;
use super::*;
use crate::estimate::IntegrityStatus;
use crate::least_squares::{LinearSystem, Solution, SolveError};
use nalgebra::{DMatrix, DVector, Vector3};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal, UnitSphere};

/// Sigma of a plane distance difference, m, and of a normal difference per tangent row, rad.
const SIGMA_DISTANCE: f64 = 0.005;
const SIGMA_NORMAL: f64 = 1.2e-3 * std::f64::consts::SQRT_2;

fn normals(rng: &mut ChaCha8Rng, planes: usize) -> Vec<Vector3<f64>> {
    (0..planes)
        .map(|_| Vector3::from(UnitSphere.sample(rng)))
        .collect()
}

fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

/// Eq 2 with noise: `y_k = n_k . d + e_k`, plus `bias` on the listed planes.
fn displacement(
    normals: &[Vector3<f64>],
    rng: &mut ChaCha8Rng,
    bias: &[(usize, f64)],
) -> LinearSystem {
    let m = normals.len();
    let truth = Vector3::new(0.3, -0.2, 0.05);
    let y = DVector::from_fn(m, |k, _| {
        let fault: f64 = bias.iter().filter(|(p, _)| *p == k).map(|(_, b)| b).sum();
        normals[k].dot(&truth) + SIGMA_DISTANCE * gaussian(rng) + fault
    });
    LinearSystem {
        h: DMatrix::from_fn(m, 3, |k, j| normals[k][j]),
        y,
        r: DMatrix::identity(m, m) * SIGMA_DISTANCE.powi(2),
        plane_of_row: (0..m).collect(),
    }
}

/// Orthonormal tangent basis `(t1, t2)` with `t1 x t2 = n`.
fn tangents(n: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let t1 = helper.cross(n).normalize();
    (t1, n.cross(&t1))
}

/// Rotation rows in the tangent space of each normal at the converged linearisation point:
/// `t_a . (n_i - n_j) = (n_j x t_a) . dtheta`, noise per row, and plane `k` of `tilt` turned by
/// `tilt.1` radians about a random axis of its tangent plane.
fn rotation(
    normals: &[Vector3<f64>],
    rng: &mut ChaCha8Rng,
    tilt: Option<(usize, f64)>,
) -> LinearSystem {
    let m = 2 * normals.len();
    let mut h = DMatrix::zeros(m, 3);
    let mut y = DVector::zeros(m);
    for (k, n) in normals.iter().enumerate() {
        let (t1, t2) = tangents(n);
        let turned = match tilt {
            Some((plane, angle)) if plane == k => {
                let phi = rng.gen_range(0.0..std::f64::consts::TAU);
                let axis = t1 * phi.cos() + t2 * phi.sin();
                nalgebra::Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle)
                    * n
            }
            _ => *n,
        };
        for (a, t) in [t1, t2].iter().enumerate() {
            h.row_mut(2 * k + a).copy_from(&n.cross(t).transpose());
            y[2 * k + a] = t.dot(&(turned - n)) + SIGMA_NORMAL * gaussian(rng);
        }
    }
    LinearSystem {
        h,
        y,
        r: DMatrix::identity(m, m) * SIGMA_NORMAL.powi(2),
        plane_of_row: (0..m).map(|row| row / 2).collect(),
    }
}

fn monitor(pfa: f64, pmd: f64) -> IntegrityMonitor {
    IntegrityMonitor::new(IntegrityConfig {
        false_alarm_probability: pfa,
        missed_detection_probability: pmd,
        ..Default::default()
    })
    .unwrap()
}

fn resolver(system: &LinearSystem) -> impl FnMut(&[usize]) -> Result<Solution, SolveError> + '_ {
    move |excluded| without_planes(system, excluded).solve()
}

fn check_displacement(monitor: &IntegrityMonitor, system: &LinearSystem) -> SolveReport {
    monitor.check_solve(
        SolveKind::Displacement,
        system.clone().solve(),
        &mut resolver(system),
    )
}

fn check_epoch(monitor: &IntegrityMonitor, rot: &LinearSystem, disp: &LinearSystem) -> EpochReport {
    monitor.check_epoch(
        rot.clone().solve(),
        disp.clone().solve(),
        &mut resolver(rot),
        &mut resolver(disp),
    )
}

/// Random geometry good enough to test (the tests below are about statistics, not geometry).
fn testable_normals(
    rng: &mut ChaCha8Rng,
    planes: usize,
    monitor: &IntegrityMonitor,
) -> Vec<Vector3<f64>> {
    loop {
        let n = normals(rng, planes);
        let probe = displacement(&n, rng, &[]);
        if let Ok(test) = monitor.test(SolveKind::Displacement, &probe) {
            if test
                .planes
                .iter()
                .all(|p| p.mdb < 10.0 * SIGMA_DISTANCE * 10.0)
            {
                return n;
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn parity_basis_is_orthonormal_and_blind_to_the_state(
        seed in any::<u64>(),
        planes in 4usize..12,
        rotational in any::<bool>(),
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let n = normals(&mut rng, planes);
        let system = if rotational {
            rotation(&n, &mut rng, None)
        } else {
            displacement(&n, &mut rng, &[])
        };
        // Random normals are now and then too close to parallel for the solve, whose test of
        // degeneracy is stricter than the parity space's condition number (seed
        // 6136834641882083998: four planes, a displacement no row pins along one direction).
        let (Ok(space), Ok(solution)) = (parity_space(&system, 1e6), system.clone().solve()) else {
            return Ok(());
        };
        let m = system.rows();
        let v = space.basis();
        prop_assert_eq!(v.nrows(), m - 3);
        let whitened_h = space.square_root.clone().solve_lower_triangular(&system.h).unwrap();
        prop_assert!((&v * &whitened_h).norm() < 1e-9 * whitened_h.norm());
        prop_assert!((&v * v.transpose() - DMatrix::identity(m - 3, m - 3)).norm() < 1e-9);
        // Eq 38: the parity vector's covariance is the identity.
        let cov_p = &space.parity_map * &system.r * space.parity_map.transpose();
        prop_assert!((cov_p - DMatrix::identity(m - 3, m - 3)).norm() < 1e-9);
        // |p|^2 is the weighted residual sum of squares.
        let r_chol = system.r.clone().cholesky().unwrap();
        let weighted = solution.residuals.dot(&r_chol.solve(&solution.residuals));
        prop_assert!((space.parity.norm_squared() - weighted).abs() < 1e-8 * (1.0 + weighted));
    }
}

#[test]
fn one_row_normalised_residual_is_residual_over_its_sigma() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let n = normals(&mut rng, 7);
    let system = displacement(&n, &mut rng, &[]);
    let test = monitor(1e-3, 1e-3)
        .test(SolveKind::Displacement, &system)
        .unwrap();
    let solution = system.clone().solve().unwrap();
    for (k, plane) in test.planes.iter().enumerate() {
        assert!((test.residuals[k] - solution.residuals[k]).abs() < 1e-12);
        let w = test.residuals[k] / test.residual_sigmas[k];
        assert!(
            (plane.normalised_residual - w).abs() < 1e-8,
            "{} vs {w}",
            plane.normalised_residual
        );
    }
}

/// Fraction of fault-free displacement solves whose global test fires, and whose any test fires.
fn solve_false_alarms(pfa: f64, trials: usize) -> (f64, f64) {
    let monitor = monitor(pfa, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let (mut global, mut any) = (0, 0);
    for _ in 0..trials {
        let n = normals(&mut rng, 6);
        let Ok(test) = monitor.test(SolveKind::Displacement, &displacement(&n, &mut rng, &[]))
        else {
            continue;
        };
        global += test.global_fired() as usize;
        any += test.detected as usize;
    }
    (global as f64 / trials as f64, any as f64 / trials as f64)
}

/// Fraction of fault-free epochs (6 planes, both solves) not reported `Ok`.
fn epoch_false_alarms(pfa: f64, trials: usize) -> f64 {
    let monitor = monitor(pfa, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(2025);
    let mut flagged = 0;
    for _ in 0..trials {
        let n = testable_normals(&mut rng, 6, &monitor);
        let report = check_epoch(
            &monitor,
            &rotation(&n, &mut rng, None),
            &displacement(&n, &mut rng, &[]),
        );
        flagged += (report.status != IntegrityStatus::Ok) as usize;
    }
    flagged as f64 / trials as f64
}

// The global test has half the budget; a solve or an epoch is flagged at most at the budget
// and, the tests being strongly correlated, at least at half of it.

#[test]
fn fault_free_solves_raise_false_alarms_at_the_budget() {
    let pfa = 1e-2;
    let (global, any) = solve_false_alarms(pfa, 20_000);
    assert!(
        (0.5..=2.0).contains(&(global / (pfa / 2.0))),
        "global {global}"
    );
    assert!((0.5..=1.15).contains(&(any / pfa)), "any test {any}");
}

#[test]
fn fault_free_epochs_raise_false_alarms_at_the_budget() {
    // A larger budget keeps the count of alarms, and so the tolerance, meaningful in debug.
    let pfa = 0.05;
    let trials = if cfg!(debug_assertions) { 3000 } else { 20_000 };
    let epoch = epoch_false_alarms(pfa, trials);
    assert!((0.5..=1.15).contains(&(epoch / pfa)), "epoch {epoch}");
}

#[test]
#[ignore = "Monte Carlo at the default 1e-3: run with --release -- --ignored"]
fn fault_free_false_alarm_rates_match_the_default_budget() {
    let pfa = 1e-3;
    let (global, any) = solve_false_alarms(pfa, 400_000);
    assert!(
        (0.5..=2.0).contains(&(global / (pfa / 2.0))),
        "global {global}"
    );
    assert!((0.5..=1.1).contains(&(any / pfa)), "any test {any}");
    let epoch = epoch_false_alarms(pfa, 200_000);
    assert!((0.5..=1.1).contains(&(epoch / pfa)), "epoch {epoch}");
}

#[test]
fn twice_the_mdb_on_one_of_six_planes_is_detected_and_excluded() {
    let monitor = monitor(1e-3, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let trials = 2000;
    let (mut detected, mut right) = (0, 0);
    for _ in 0..trials {
        let n = testable_normals(&mut rng, 6, &monitor);
        let k = rng.gen_range(0..6);
        let clean = monitor
            .test(SolveKind::Displacement, &displacement(&n, &mut rng, &[]))
            .unwrap();
        let sign = if rng.gen::<bool>() { 1.0 } else { -1.0 };
        let bias = 2.0 * clean.planes[k].mdb * sign;
        let report = check_displacement(&monitor, &displacement(&n, &mut rng, &[(k, bias)]));
        detected += (report.status != IntegrityStatus::Ok) as usize;
        right += (report.status == IntegrityStatus::Excluded { planes: vec![k] }) as usize;
    }
    assert!(
        detected as f64 >= 0.99 * trials as f64,
        "detected {detected}/{trials}"
    );
    assert!(
        right as f64 >= 0.99 * trials as f64,
        "right plane {right}/{trials}"
    );
}

#[test]
fn a_bias_of_one_mdb_is_caught_by_its_plane_test_with_one_minus_pmd() {
    let pmd = 0.1;
    let monitor = monitor(1e-3, pmd);
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let n = testable_normals(&mut rng, 8, &monitor);
    let trials = 5000;
    let mut caught = 0;
    for trial in 0..trials {
        let k = trial % 8;
        let clean = monitor
            .test(SolveKind::Displacement, &displacement(&n, &mut rng, &[]))
            .unwrap();
        let faulty = displacement(&n, &mut rng, &[(k, clean.planes[k].mdb)]);
        let test = monitor.test(SolveKind::Displacement, &faulty).unwrap();
        caught += test.planes[k].fired() as usize;
    }
    let rate = caught as f64 / trials as f64;
    assert!((rate - (1.0 - pmd)).abs() < 0.02, "caught {rate}");
}

#[test]
fn a_normal_turned_by_three_degrees_is_detected_and_excluded() {
    let monitor = monitor(1e-3, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let trials = 1000;
    let (mut detected, mut right) = (0, 0);
    let mut mdb_deg = 0.0_f64;
    for _ in 0..trials {
        let n = testable_normals(&mut rng, 6, &monitor);
        let k = rng.gen_range(0..6);
        let system = rotation(&n, &mut rng, Some((k, 3f64.to_radians())));
        let report = monitor.check_solve(
            SolveKind::Rotation,
            system.clone().solve(),
            &mut resolver(&system),
        );
        detected += (report.status != IntegrityStatus::Ok) as usize;
        right += (report.status == IntegrityStatus::Excluded { planes: vec![k] }) as usize;
        let clean = monitor
            .test(SolveKind::Rotation, &rotation(&n, &mut rng, None))
            .unwrap();
        mdb_deg = mdb_deg.max(clean.planes[k].mdb.to_degrees());
    }
    assert!(
        detected as f64 >= 0.99 * trials as f64,
        "detected {detected}/{trials}"
    );
    assert!(
        right as f64 >= 0.97 * trials as f64,
        "right plane {right}/{trials}"
    );
    // Sanity of the angle units: with 1.2 mrad normals the MDB is about a degree, not 1e-3 or 1e3.
    assert!(
        (0.2..3.0).contains(&mdb_deg),
        "largest rotation MDB {mdb_deg} deg"
    );
}

/// Bias on plane `k` at the detection limit in the direction that hurts `axis` most.
fn worst_bias(
    system: &LinearSystem,
    test: &SolveTest,
    k: usize,
    axis: usize,
    config_pmd_quantile: f64,
) -> DVector<f64> {
    let space = parity_space(system, 1e6).unwrap();
    let rows: Vec<usize> = (0..system.rows())
        .filter(|&r| system.plane_of_row[r] == k)
        .collect();
    let g = space.parity_map.select_columns(&rows);
    let info = g.tr_mul(&g);
    let s = space.gain.select_columns(&rows).row(axis).transpose();
    let info_inv = info.try_inverse().unwrap();
    let plane = test.plane(k).unwrap();
    let noncentrality = plane.threshold + config_pmd_quantile;
    let direction = &info_inv * &s;
    let scale = noncentrality / (s.dot(&direction)).sqrt();
    let mut bias = DVector::zeros(system.rows());
    for (i, &row) in rows.iter().enumerate() {
        bias[row] = direction[i] * scale;
    }
    bias
}

#[test]
fn protection_level_is_the_error_of_the_worst_fault_at_the_detection_limit() {
    let monitor = monitor(1e-3, 1e-3);
    let z_md = normal_upper_quantile(1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    for rotational in [false, true] {
        let n = testable_normals(&mut rng, 7, &monitor);
        let system = if rotational {
            rotation(&n, &mut rng, None)
        } else {
            displacement(&n, &mut rng, &[])
        };
        let kind = if rotational {
            SolveKind::Rotation
        } else {
            SolveKind::Displacement
        };
        let test = monitor.test(kind, &system).unwrap();
        let space = parity_space(&system, 1e6).unwrap();
        for axis in 0..3 {
            let mut largest = 0.0_f64;
            for k in 0..7 {
                let bias = worst_bias(&system, &test, k, axis, z_md);
                let error = (&space.gain * &bias)[axis].abs();
                // The fault sits exactly at the detection limit of its own test.
                let shift = (&space.parity_map * &bias).norm_squared();
                let plane = test.plane(k).unwrap();
                assert!((shift.sqrt() - (plane.threshold + z_md)).abs() < 1e-9 * shift.sqrt());
                assert!(error <= test.protection.from_fault[axis] * (1.0 + 1e-9));
                largest = largest.max(error);
            }
            assert!(
                (largest - test.protection.from_fault[axis]).abs() < 1e-9 * largest,
                "axis {axis}"
            );
        }
    }
}

#[test]
fn protection_level_bounds_the_error_of_undetected_mdb_faults() {
    let pmd = 0.2;
    let monitor = monitor(1e-3, pmd);
    let z_md = normal_upper_quantile(pmd);
    let mut rng = ChaCha8Rng::seed_from_u64(22);
    let n = testable_normals(&mut rng, 6, &monitor);
    let truth = Vector3::new(0.3, -0.2, 0.05);
    let clean_system = displacement(&n, &mut rng, &[]);
    let clean = monitor
        .test(SolveKind::Displacement, &clean_system)
        .unwrap();
    let axis = 0;
    let k = clean.protection.worst_plane[axis].unwrap();
    let bias = worst_bias(&clean_system, &clean, k, axis, z_md);
    let (mut undetected, mut outside, mut beyond_fault_part) = (0, 0, 0);
    for _ in 0..4000 {
        let mut system = displacement(&n, &mut rng, &[]);
        system.y += &bias;
        let test = monitor.test(SolveKind::Displacement, &system).unwrap();
        if test.detected {
            continue;
        }
        undetected += 1;
        let error = (system.clone().solve().unwrap().x - truth)[axis].abs();
        outside += (error > test.protection.level[axis]) as usize;
        beyond_fault_part += (error > test.protection.from_fault[axis]) as usize;
    }
    let missed = undetected as f64 / 4000.0;
    assert!(missed > 0.5 * pmd && missed < pmd * 1.1, "missed {missed}");
    let outside = outside as f64 / undetected as f64;
    assert!(outside < pmd, "outside the level {outside}");
    // The fault part alone is not a bound: the level is not needlessly loose either.
    assert!(beyond_fault_part as f64 / undetected as f64 > 0.3);
}

#[test]
fn four_planes_detect_but_cannot_isolate_five_can() {
    let monitor = monitor(1e-3, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    for planes in [4, 5] {
        // With five planes the parity space has two dimensions, and random normals can put two
        // planes' tests almost in line (correlation above 0.999): those are told apart by
        // noise, and `planes_a_solve_cannot_tell_apart_are_not_excluded_on_a_coin_flip`
        // covers them. Here the five are separable.
        let faulty = loop {
            let n = testable_normals(&mut rng, planes, &monitor);
            let clean = monitor
                .test(SolveKind::Displacement, &displacement(&n, &mut rng, &[]))
                .unwrap();
            let faulty = displacement(&n, &mut rng, &[(1, 4.0 * clean.planes[1].mdb)]);
            let test = monitor.test(SolveKind::Displacement, &faulty).unwrap();
            let separable = test.detected
                && (0..planes).all(|a| (0..a).all(|b| test.correlation(a, b).unwrap() < 0.999));
            if planes == 4 || separable {
                break faulty;
            }
        };
        let report = check_displacement(&monitor, &faulty);
        let expected = if planes == 4 {
            IntegrityStatus::DetectedNotIsolable
        } else {
            IntegrityStatus::Excluded { planes: vec![1] }
        };
        assert_eq!(report.status, expected, "{planes} planes");
    }
}

#[test]
fn a_plane_excluded_from_displacement_leaves_rotation_too() {
    let monitor = monitor(1e-3, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(41);
    let n = testable_normals(&mut rng, 7, &monitor);
    let rot = rotation(&n, &mut rng, None);
    let disp = displacement(&n, &mut rng, &[(2, 0.3)]);
    let report = check_epoch(&monitor, &rot, &disp);
    assert_eq!(report.status, IntegrityStatus::Excluded { planes: vec![2] });
    for solve in [&report.rotation, &report.displacement] {
        assert_eq!(solve.excluded, vec![2]);
        let system = &solve.solution.as_ref().unwrap().system;
        assert!(!system.plane_of_row.contains(&2));
        assert!(!solve.test.as_ref().unwrap().detected);
    }
    assert_eq!(report.rotation.test.as_ref().unwrap().redundancy, 2 * 6 - 3);
}

#[test]
fn two_faults_need_two_exclusions() {
    let mut rng = ChaCha8Rng::seed_from_u64(51);
    for max_exclusions in [1, 2] {
        let monitor = IntegrityMonitor::new(IntegrityConfig {
            max_exclusions,
            ..Default::default()
        })
        .unwrap();
        let n = testable_normals(&mut rng, 9, &monitor);
        let report = check_displacement(
            &monitor,
            &displacement(&n, &mut rng, &[(3, 0.5), (6, -0.8)]),
        );
        if max_exclusions == 1 {
            assert_eq!(report.status, IntegrityStatus::DetectedNotIsolable);
        } else {
            let IntegrityStatus::Excluded { mut planes } = report.status else {
                panic!("{:?}", report.status)
            };
            planes.sort();
            assert_eq!(planes, vec![3, 6]);
        }
    }
}

#[test]
fn bad_geometry_and_bad_input_are_under_determined_not_panics() {
    let monitor = monitor(1e-3, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(61);
    // Five walls within 0.01 deg of vertical: the vertical is barely observed.
    let tilt = 1e-4;
    let n: Vec<Vector3<f64>> = (0..5)
        .map(|k| {
            let a = k as f64 * 1.2;
            Vector3::new(a.cos(), a.sin(), if k == 0 { tilt } else { 0.0 }).normalize()
        })
        .collect();
    let system = displacement(&n, &mut rng, &[]);
    let report = monitor.check_solve(
        SolveKind::Displacement,
        Ok(solution_without_checks(&system)),
        &mut resolver(&system),
    );
    assert_eq!(report.status, IntegrityStatus::UnderDetermined);
    assert!(matches!(
        report.untestable,
        Some(Untestable::IllConditioned { .. })
    ));

    let err = SolveError::UnderDetermined {
        unobservable: vec![Vector3::z()],
    };
    let report = monitor.check_solve(
        SolveKind::Displacement,
        Err(err),
        &mut |_: &[usize]| unreachable!(),
    );
    assert_eq!(report.status, IntegrityStatus::UnderDetermined);

    let mut poisoned = displacement(&normals(&mut rng, 6), &mut rng, &[]);
    poisoned.y[3] = f64::NAN;
    assert!(matches!(
        monitor.test(SolveKind::Displacement, &poisoned),
        Err(Untestable::Malformed(_))
    ));
    poisoned.y[3] = 0.0;
    poisoned.r[(2, 2)] = -1.0;
    assert_eq!(
        monitor.test(SolveKind::Displacement, &poisoned),
        Err(Untestable::BadCovariance)
    );
    poisoned.plane_of_row.pop();
    assert!(matches!(
        monitor.test(SolveKind::Displacement, &poisoned),
        Err(Untestable::Malformed(_))
    ));

    let three = displacement(&normals(&mut rng, 3), &mut rng, &[]);
    assert_eq!(
        monitor.test(SolveKind::Displacement, &three),
        Err(Untestable::TooFewPlanes {
            planes: 3,
            minimum: 4
        })
    );
}

/// A Solution whose system the core would have refused: integrity must still not invert it.
fn solution_without_checks(system: &LinearSystem) -> Solution {
    Solution {
        x: Vector3::zeros(),
        covariance: nalgebra::Matrix3::identity(),
        residuals: system.y.clone(),
        system: system.clone(),
        dilution: crate::least_squares::Dilution {
            per_axis: Vector3::zeros(),
            condition: f64::INFINITY,
        },
    }
}

#[test]
fn an_exclusion_that_would_leave_a_solve_unsolvable_is_not_made() {
    let monitor = monitor(1e-3, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(71);
    let n = testable_normals(&mut rng, 6, &monitor);
    let system = displacement(&n, &mut rng, &[(0, 0.5)]);
    let report = monitor.check_solve(
        SolveKind::Displacement,
        system.clone().solve(),
        &mut |_: &[usize]| Err(SolveError::BadCovariance),
    );
    assert_eq!(report.status, IntegrityStatus::DetectedNotIsolable);
    assert!(report.excluded.is_empty());
    assert!(report.test.unwrap().detected);
}

#[test]
fn reports_serialise_for_the_epoch_log() {
    let monitor = monitor(1e-3, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(81);
    let n = testable_normals(&mut rng, 6, &monitor);
    let report = check_epoch(
        &monitor,
        &rotation(&n, &mut rng, None),
        &displacement(&n, &mut rng, &[(4, 0.4)]),
    );
    let json = serde_json::to_value(&report).unwrap();
    assert_eq!(json["status"]["status"], "excluded");
    assert_eq!(json["status"]["planes"][0], 4);
    let displacement = &json["displacement"];
    assert_eq!(displacement["kind"], "displacement");
    assert_eq!(displacement["test"]["planes"].as_array().unwrap().len(), 5);
    assert!(
        displacement["test"]["chi_square_threshold"]
            .as_f64()
            .unwrap()
            > 0.0
    );
    assert!(
        displacement["test"]["protection"]["level"][2]
            .as_f64()
            .unwrap()
            > 0.0
    );
    assert_eq!(displacement["solution"]["x"].as_array().unwrap().len(), 3);
    assert!(displacement["untestable"].is_null());
}

#[test]
fn an_invalid_configuration_is_refused() {
    let config = IntegrityConfig {
        false_alarm_probability: -0.1,
        ..Default::default()
    };
    assert_eq!(
        IntegrityMonitor::new(config).unwrap_err().to_string(),
        "integrity.false_alarm_probability = -0.1: must be in (0, 1): use e.g. 1e-3"
    );
}

#[test]
fn a_turned_plane_is_excluded_from_the_displacement_too() {
    let monitor = monitor(1e-3, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(91);
    let n = testable_normals(&mut rng, 6, &monitor);
    let rot = rotation(&n, &mut rng, Some((5, 4f64.to_radians())));
    let report = check_epoch(&monitor, &rot, &displacement(&n, &mut rng, &[]));
    assert_eq!(report.status, IntegrityStatus::Excluded { planes: vec![5] });
    assert_eq!(report.displacement.test.as_ref().unwrap().planes.len(), 5);
    assert_eq!(report.displacement.status, report.status);
}

#[test]
fn two_planes_test_rotation_but_cannot_protect_it() {
    let monitor = monitor(1e-3, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(92);
    let n = [Vector3::x(), Vector3::new(0.0, 0.6, 0.8)];
    let test = monitor
        .test(SolveKind::Rotation, &rotation(&n, &mut rng, None))
        .unwrap();
    assert_eq!(test.redundancy, 1);
    // One parity dimension: each plane has one testable direction of its two.
    assert!(test.planes.iter().all(|plane| plane.dof == 1));
    assert!(test.planes.iter().all(|plane| plane.mdb.is_infinite()));
    assert!(test
        .protection
        .level
        .iter()
        .all(|level| level.is_infinite()));
    let turned = rotation(&n, &mut rng, Some((0, 0.2)));
    let report = monitor.check_solve(
        SolveKind::Rotation,
        turned.clone().solve(),
        &mut resolver(&turned),
    );
    // The turn shows in the one parity dimension (or hides in the untestable one); either way
    // one redundant row cannot say which plane turned.
    assert!(matches!(
        report.status,
        IntegrityStatus::DetectedNotIsolable | IntegrityStatus::Ok
    ));
    assert!(report.excluded.is_empty());
}

/// An office with a door: only the front wall and the door (turned 3 deg from it) see x in the
/// displacement solve, so their tests there are correlated above 0.999 and the larger residual
/// is a coin flip; the rotation solve tells them apart.
fn front_wall_and_door() -> Vec<Vector3<f64>> {
    vec![
        Vector3::new(0.0, -1.0, 0.0),
        Vector3::new(0.0, 1.0, 0.0),
        Vector3::new(0.0, 0.0, 1.0),
        Vector3::new(0.0, 1.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(1.0, 0.05, 0.0).normalize(),
    ]
}

#[test]
fn planes_a_solve_cannot_tell_apart_are_not_excluded_on_a_coin_flip() {
    let monitor = monitor(1e-3, 1e-3);
    let (front, door) = (4, 5);
    let n = front_wall_and_door();
    let mut rng = ChaCha8Rng::seed_from_u64(101);
    for _ in 0..20 {
        let disp = displacement(&n, &mut rng, &[(door, 0.3)]);
        let test = monitor.test(SolveKind::Displacement, &disp).unwrap();
        assert!(test.detected);
        assert!(test.correlation(front, door).unwrap() > 0.999);
        let report = check_displacement(&monitor, &disp);
        assert_eq!(report.status, IntegrityStatus::DetectedNotIsolable);

        let rot = rotation(&n, &mut rng, Some((door, 4f64.to_radians())));
        let rotation_test = monitor.test(SolveKind::Rotation, &rot).unwrap();
        assert!(rotation_test.correlation(front, door).unwrap() < 0.999);
        let report = check_epoch(&monitor, &rot, &disp);
        assert_eq!(
            report.status,
            IntegrityStatus::Excluded { planes: vec![door] }
        );
    }
}

#[test]
fn test_correlation_is_one_with_itself_and_symmetric() {
    let monitor = monitor(1e-3, 1e-3);
    let mut rng = ChaCha8Rng::seed_from_u64(102);
    let n = testable_normals(&mut rng, 6, &monitor);
    // Faults large enough to fire: the correlations are kept for exclusion only.
    let turned = rotation(&n, &mut rng, Some((0, 30f64.to_radians())));
    for system in [turned, displacement(&n, &mut rng, &[(0, 2.0)])] {
        let kind = if system.rows() == n.len() {
            SolveKind::Displacement
        } else {
            SolveKind::Rotation
        };
        let test = monitor.test(kind, &system).unwrap();
        assert!(test.detected, "{kind:?}");
        for a in 0..n.len() {
            assert!((test.correlation(a, a).unwrap() - 1.0).abs() < 1e-9);
            for b in 0..n.len() {
                let c = test.correlation(a, b).unwrap();
                assert!((c - test.correlation(b, a).unwrap()).abs() < 1e-9);
                assert!((0.0..=1.0).contains(&c));
            }
        }
    }
}
