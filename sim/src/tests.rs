//! Whole-simulator tests: geometry against hand-computed ranges, per-beam timing, IMU against
//! truth, noise statistics, determinism and the built-in scenarios' plane counts.

use super::*;
use ladar_sensors::ScannerGeometry;
use nalgebra::{UnitQuaternion, Vector3};

/// A 6 m x 4 m room around the origin (walls at x = 3, x = -3, y = -2, y = 2), floor and ceiling
/// 1 m away, one level UTM-30LX at the body origin, no noise.
fn room(trajectory: Trajectory) -> Scenario {
    let wall = |name: &str, centre: [f64; 3], u: [f64; 3], half: f64| {
        Patch::new(name, centre, u, [0.0, 0.0, 1.0], [half, 1.0])
    };
    Scenario {
        name: "room".into(),
        seed: 7,
        duration_s: 1.0,
        truth_rate_hz: 50.0,
        trajectory,
        scanners: vec![ScannerConfig::new(
            "utm",
            ScannerModel::Utm30lx,
            [0.0; 3],
            0.0,
        )],
        imu: None,
        scene: Scene {
            patches: vec![
                wall("front", [3.0, 0.0, 0.0], [0.0, 1.0, 0.0], 2.0),
                wall("back", [-3.0, 0.0, 0.0], [0.0, 1.0, 0.0], 2.0),
                wall("left", [0.0, -2.0, 0.0], [1.0, 0.0, 0.0], 3.0),
                wall("right", [0.0, 2.0, 0.0], [1.0, 0.0, 0.0], 3.0),
            ],
        },
    }
}

fn still() -> Trajectory {
    Trajectory::Stationary {
        position_m: [0.0; 3],
        rpy_deg: [0.0; 3],
    }
}

#[test]
fn level_beams_hit_the_expected_walls_at_exact_ranges() {
    let mut sim = Simulator::new(&room(still())).unwrap();
    let (scan, hits) = sim.scan_labelled(0, 0.0);
    let g = ScannerGeometry::UTM_30LX;
    assert_eq!(scan.ranges_m.len(), 1081);
    for (i, (&range, hit)) in scan.ranges_m.iter().zip(&hits).enumerate() {
        let psi = g.step_azimuth(scan.step_of(i));
        let (s, c) = psi.sin_cos();
        // Candidate distances to each wall along the beam; the smallest positive one wins.
        let candidates = [(3.0 / c, 0), (-3.0 / c, 1), (-2.0 / s, 2), (2.0 / s, 3)];
        let (expected, wall) = candidates
            .into_iter()
            .filter(|(d, _)| *d > 0.0 && d.is_finite())
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap();
        assert!(
            (range - expected).abs() <= 0.0005 + 1e-12,
            "beam {i}: {range} vs {expected}"
        );
        assert_eq!(*hit, Some(wall), "beam {i}");
    }
    // The front step sees the front wall straight on; 90 deg later in step order is the left.
    assert_eq!(scan.ranges_m[540], 3.0);
    assert_eq!(scan.ranges_m[900], 2.0);
    assert_eq!(hits[900], Some(2));
}

#[test]
fn mount_pitch_and_offset_are_applied() {
    let mut scenario = room(still());
    scenario.scanners[0].mount_rpy_deg = [0.0, 10.0, 0.0];
    scenario.scanners[0].mount_translation_m = [0.5, 0.0, 0.0];
    let mut sim = Simulator::new(&scenario).unwrap();
    let scan = sim.scan(0, 0.0);
    let expected = 2.5 / 10f64.to_radians().cos();
    assert!((scan.ranges_m[540] - expected).abs() <= 0.0005);
}

#[test]
fn beams_beyond_the_scene_report_the_device_no_return_code() {
    let mut scenario = room(still());
    scenario.scene.patches.truncate(1);
    let mut urg = scenario.clone();
    urg.scanners[0].model = ScannerModel::Urg04lx;
    let utm_scan = Simulator::new(&scenario).unwrap().scan(0, 0.0);
    assert_eq!(
        utm_scan.ranges_m[0], 0.001,
        "UTM code 1: no object in range"
    );
    let urg_scan = Simulator::new(&urg).unwrap().scan(0, 0.0);
    assert_eq!(urg_scan.ranges_m[0], 0.0, "URG code 0");
    assert_eq!(urg_scan.first_step, 44);
    assert_eq!(urg_scan.ranges_m.len(), 682);
}

#[test]
fn readings_lie_on_the_true_planes() {
    let scenario = Scenario::builtin("hallway-flight").unwrap().without_noise();
    let mut sim = Simulator::new(&scenario).unwrap();
    for t0 in [0.0, 15.0, 23.1] {
        for sensor in 0..2 {
            let (scan, hits) = sim.scan_labelled(sensor, t0);
            let scanner = sim.scanners()[sensor].clone();
            let mut checked = 0;
            for (i, hit) in hits.iter().enumerate() {
                let Some(patch) = hit else { continue };
                let t = scan.time_of(i, scanner.geometry());
                let point_sensor =
                    scanner.geometry().step_direction(scan.step_of(i)) * scan.ranges_m[i];
                let point_body = scanner.mount().to_body(&point_sensor);
                let plane = sim.true_planes_in_body(t)[*patch];
                assert!(
                    (plane.normal.dot(&point_body) - plane.distance).abs() < 1e-3,
                    "t0 {t0} sensor {sensor} beam {i}"
                );
                checked += 1;
            }
            assert!(checked > 500, "{checked}");
        }
    }
}

#[test]
fn each_beam_sees_the_wall_from_the_pose_at_its_own_time() {
    // Fly at up to 1.9 m/s towards a wall 15 m ahead; the wall is much wider than the FOV reach.
    let flight = Trajectory::Flight {
        position_m: [0.0; 3],
        rpy_deg: [0.0; 3],
        start_s: 0.0,
        leg_length_m: 4.0,
        leg_duration_s: 4.0,
        return_leg: false,
        turn_duration_s: 0.0,
        oscillation: Oscillation::default(),
    };
    let mut scenario = room(flight);
    scenario.scene.patches = vec![Patch::new(
        "wall",
        [15.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [100.0, 10.0],
    )];
    let mut sim = Simulator::new(&scenario).unwrap();
    let t0 = 2.0;
    let scan = sim.scan(0, t0);
    let g = *sim.scanners()[0].geometry();
    let mut largest_skew: f64 = 0.0;
    for (i, &range) in scan.ranges_m.iter().enumerate() {
        let psi = g.step_azimuth(scan.step_of(i));
        if psi.cos() < 0.5 {
            continue;
        }
        let x_at_beam = sim.truth_at(scan.time_of(i, &g)).p.x;
        let expected = (15.0 - x_at_beam) / psi.cos();
        assert!((range - expected).abs() <= 0.0005 + 1e-9, "beam {i}");
        let x_at_t0 = sim.truth_at(t0).p.x;
        largest_skew = largest_skew.max(((15.0 - x_at_t0) / psi.cos() - expected).abs());
    }
    assert!(
        largest_skew > 0.02,
        "motion during the scan must matter: {largest_skew}"
    );
}

/// Strapdown integration of exact increments: q_k = q_{k-1} dq, v_k = v_{k-1} + C dv + g dt.
#[test]
fn integrating_ideal_imu_increments_reproduces_the_truth() {
    let mut scenario = Scenario::builtin("hallway-flight").unwrap().without_noise();
    // Scans are irrelevant here and slow in debug builds.
    scenario.scanners.clear();
    let imu = scenario.imu.as_mut().unwrap();
    imu.mount_rpy_deg = [180.0, 0.0, 90.0];
    let mount = imu.mount_rotation();
    let mut sim = Simulator::new(&scenario).unwrap();
    let (start, end) = (10.0, 16.0);
    let truth0 = sim.truth_at(start);
    let mut q = truth0.q * mount;
    let mut v = truth0.v;
    let mut p = truth0.p;
    let gravity = Vector3::new(0.0, 0.0, GRAVITY);
    let mut last_t = start;
    for event in sim.events() {
        let SimEvent::Imu(ImuSample::Delta { t, dt, dq, dv }) = event else {
            continue;
        };
        if t <= start + 1e-9 {
            continue;
        }
        if t > end + 1e-9 {
            break;
        }
        let v_next = v + q * dv + gravity * dt;
        p += (v + v_next) * (dt / 2.0);
        v = v_next;
        q *= dq;
        last_t = t;
    }
    assert!((last_t - end).abs() < 1e-9);
    let truth = Simulator::new(&scenario).unwrap().truth_at(end);
    let attitude_error = (truth.q * mount).angle_to(&q);
    assert!(attitude_error < 1e-9, "{attitude_error}");
    assert!((truth.v - v).norm() < 1e-9, "{}", (truth.v - v).norm());
    let travelled = (truth.p - truth0.p).norm();
    assert!(travelled > 3.0);
    assert!(
        (truth.p - p).norm() < 1e-6 * travelled,
        "{}",
        (truth.p - p).norm()
    );
}

#[test]
fn ideal_rate_output_is_the_truth_in_the_imu_frame() {
    let mut scenario = Scenario::builtin("hallway-flight").unwrap().without_noise();
    // Scans are irrelevant here and slow in debug builds.
    scenario.scanners.clear();
    let imu = scenario.imu.as_mut().unwrap();
    imu.output = ImuOutput::Rate;
    imu.mount_rpy_deg = [0.0, 90.0, 0.0];
    let mount = imu.mount_rotation();
    let sim = Simulator::new(&scenario).unwrap();
    let h = 1e-5;
    let rates: Vec<ImuSample> = Simulator::new(&scenario)
        .unwrap()
        .events()
        .filter_map(|e| match e {
            SimEvent::Imu(s) if s.time() > 12.0 => Some(s),
            _ => None,
        })
        .take(400)
        .collect();
    for sample in rates {
        let ImuSample::Rate { t, gyro, accel } = sample else {
            panic!("rate output expected")
        };
        let (before, after) = (sim.truth_at(t - h), sim.truth_at(t + h));
        let omega_body = (before.q.inverse() * after.q).scaled_axis() / (2.0 * h);
        let a = (after.v - before.v) / (2.0 * h);
        let f_body = sim
            .truth_at(t)
            .q
            .inverse_transform_vector(&(a - Vector3::new(0.0, 0.0, GRAVITY)));
        assert!((mount.inverse_transform_vector(&omega_body) - gyro).norm() < 1e-8);
        assert!((mount.inverse_transform_vector(&f_body) - accel).norm() < 1e-6);
    }
}

fn still_imu(output: ImuOutput, gyro: TriadErrors, accel: TriadErrors) -> Simulator {
    let mut scenario = room(still());
    scenario.duration_s = 10.0;
    scenario.scanners.clear();
    scenario.imu = Some(ImuConfig {
        rate_hz: 400.0,
        output,
        mount_rpy_deg: [0.0; 3],
        gyro,
        accel,
    });
    Simulator::new(&scenario).unwrap()
}

fn imu_samples(mut sim: Simulator) -> Vec<ImuSample> {
    sim.events()
        .filter_map(|e| match e {
            SimEvent::Imu(s) => Some(s),
            _ => None,
        })
        .collect()
}

fn std_dev(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

#[test]
fn imu_white_noise_has_the_configured_density() {
    let noisy = |density| TriadErrors {
        noise_density: density,
        ..TriadErrors::NONE
    };
    let (gyro_nd, accel_nd) = (
        TriadErrors::mti_gyro().noise_density,
        TriadErrors::mti_accel().noise_density,
    );
    let rate = imu_samples(still_imu(ImuOutput::Rate, noisy(gyro_nd), noisy(accel_nd)));
    assert_eq!(rate.len(), 4000);
    let mut gyro = Vec::new();
    let mut accel_z = Vec::new();
    for s in &rate {
        let ImuSample::Rate {
            gyro: g, accel: a, ..
        } = s
        else {
            unreachable!()
        };
        gyro.extend(g.iter());
        accel_z.push(a.z);
    }
    let (mean, sd) = std_dev(&gyro);
    assert!(mean.abs() < 3.0 * gyro_nd * 20.0 / 109.0, "{mean}");
    assert!((sd / (gyro_nd * 20.0) - 1.0).abs() < 0.03, "{sd}");
    let (mean, sd) = std_dev(&accel_z);
    assert!((mean + GRAVITY).abs() < 1e-3);
    assert!((sd / (accel_nd * 20.0) - 1.0).abs() < 0.03, "{sd}");

    let delta = imu_samples(still_imu(ImuOutput::Delta, noisy(gyro_nd), noisy(accel_nd)));
    let angles: Vec<f64> = delta
        .iter()
        .flat_map(|s| {
            let ImuSample::Delta { dq, .. } = s else {
                unreachable!()
            };
            let a = dq.scaled_axis();
            [a.x, a.y, a.z]
        })
        .collect();
    let (_, sd) = std_dev(&angles);
    assert!((sd / (gyro_nd * 0.05) - 1.0).abs() < 0.03, "{sd}");
}

#[test]
fn turn_on_bias_and_scale_factor_shift_the_still_output() {
    let gyro = TriadErrors {
        turn_on_bias: [0.001, -0.002, 0.003],
        ..TriadErrors::NONE
    };
    let accel = TriadErrors {
        turn_on_bias: [0.01, 0.02, -0.03],
        scale_factor: [0.0, 0.0, 0.001],
        ..TriadErrors::NONE
    };
    let samples = imu_samples(still_imu(ImuOutput::Rate, gyro, accel));
    let ImuSample::Rate {
        gyro: g, accel: a, ..
    } = samples[100]
    else {
        unreachable!()
    };
    assert!((g - Vector3::new(0.001, -0.002, 0.003)).norm() < 1e-15);
    let expected_z = -GRAVITY * 1.001 - 0.03;
    assert!((a - Vector3::new(0.01, 0.02, expected_z)).norm() < 1e-12);
}

#[test]
fn drawn_imu_errors_follow_their_spread_and_their_seed() {
    let spread = ImuSpread {
        gyro_bias: 0.005,
        accel_bias: 0.05,
        gyro_scale_factor: 0.002,
        accel_scale_factor: 0.003,
    };
    let units: Vec<ImuConfig> = (0..200)
        .map(|seed| ImuConfig::default().with_drawn_errors(&spread, seed))
        .collect();
    assert_eq!(units[7], ImuConfig::default().with_drawn_errors(&spread, 7));
    assert_ne!(units[7].gyro.turn_on_bias, units[8].gyro.turn_on_bias);
    let spread_of = |values: Vec<f64>, sigma: f64| {
        let (mean, sd) = std_dev(&values);
        // 600 draws: the sample sigma within 10 % (3.5 of its sigmas), the mean within 4 of its.
        assert!((sd / sigma - 1.0).abs() < 0.1, "{sd} against {sigma}");
        assert!(mean.abs() < 4.0 * sigma / 600f64.sqrt(), "{mean}");
    };
    let all = |f: fn(&ImuConfig) -> [f64; 3]| units.iter().flat_map(f).collect::<Vec<f64>>();
    spread_of(all(|u| u.gyro.turn_on_bias), spread.gyro_bias);
    spread_of(all(|u| u.accel.turn_on_bias), spread.accel_bias);
    spread_of(all(|u| u.gyro.scale_factor), spread.gyro_scale_factor);
    spread_of(all(|u| u.accel.scale_factor), spread.accel_scale_factor);
    // Noise and drift stay the unit type's.
    assert_eq!(
        units[0].gyro.noise_density,
        TriadErrors::mti_gyro().noise_density
    );
}

#[test]
fn bias_random_walk_grows_with_the_square_root_of_time() {
    let walk = TriadErrors {
        bias_random_walk: 1e-3,
        ..TriadErrors::NONE
    };
    // Over 10 s the three gyro axes of 40 seeds give 120 walks with sigma 1e-3 * sqrt(10).
    let mut finals: Vec<f64> = Vec::new();
    for seed in 0..40 {
        let mut scenario = room(still());
        scenario.duration_s = 10.0;
        scenario.scanners.clear();
        scenario.imu = Some(ImuConfig {
            rate_hz: 100.0,
            output: ImuOutput::Rate,
            mount_rpy_deg: [0.0; 3],
            gyro: walk,
            accel: TriadErrors::NONE,
        });
        let samples = imu_samples(Simulator::with_seed(&scenario, seed).unwrap());
        let ImuSample::Rate { gyro, .. } = samples.last().unwrap() else {
            unreachable!()
        };
        finals.extend(gyro.iter());
    }
    let rms = (finals.iter().map(|v| v * v).sum::<f64>() / finals.len() as f64).sqrt();
    let expected = 1e-3 * 10f64.sqrt();
    // 120 samples: the RMS is within about 20 % at 3 sigma.
    assert!((rms / expected - 1.0).abs() < 0.2, "{rms} vs {expected}");
}

#[test]
fn range_noise_has_the_configured_sigma_and_no_bias() {
    let mut scenario = room(still());
    scenario.scanners[0].range_sigma_m = 0.01;
    let mut noisy = Simulator::new(&scenario).unwrap();
    let exact = Simulator::new(&scenario.clone().without_noise())
        .unwrap()
        .scan(0, 0.0);
    let mut errors = Vec::new();
    for k in 0..20 {
        let scan = noisy.scan(0, f64::from(k) * 0.025);
        errors.extend(
            scan.ranges_m
                .iter()
                .zip(&exact.ranges_m)
                .map(|(r, e)| r - e),
        );
    }
    assert_eq!(errors.len(), 21620);
    let (mean, sd) = std_dev(&errors);
    // The 1 mm quantisation of both adds sqrt(2/12) mm in quadrature: negligible here.
    assert!((sd / 0.01 - 1.0).abs() < 0.03, "{sd}");
    assert!(
        mean.abs() < 3.0 * 0.01 / (errors.len() as f64).sqrt(),
        "{mean}"
    );
}

#[test]
fn dropouts_happen_at_the_configured_rate_with_the_device_code() {
    let mut scenario = room(still());
    scenario.scanners[0].dropout_probability = 0.05;
    let mut sim = Simulator::new(&scenario).unwrap();
    let mut dropped = 0;
    for k in 0..10 {
        dropped += sim
            .scan(0, f64::from(k))
            .ranges_m
            .iter()
            .filter(|r| **r == 0.005)
            .count();
    }
    let rate = dropped as f64 / 10810.0;
    // Binomial sigma 0.0021.
    assert!((rate - 0.05).abs() < 0.0065, "{rate}");
}

#[test]
fn same_seed_same_events_other_seed_other_noise() {
    let scenario = Scenario::builtin("hallway-flight").unwrap();
    let first: Vec<SimEvent> = Simulator::new(&scenario)
        .unwrap()
        .events()
        .take(3000)
        .collect();
    let second: Vec<SimEvent> = Simulator::new(&scenario)
        .unwrap()
        .events()
        .take(3000)
        .collect();
    assert_eq!(format!("{first:?}"), format!("{second:?}"));
    let other: Vec<SimEvent> = Simulator::with_seed(&scenario, 99)
        .unwrap()
        .events()
        .take(3000)
        .collect();
    assert_ne!(first, other);
    assert!(first.iter().any(|e| matches!(e, SimEvent::Scan { .. })));
}

#[test]
fn events_stream_in_time_order_until_the_duration() {
    let mut scenario = Scenario::builtin("hallway-flight").unwrap();
    scenario.duration_s = 2.0;
    let mut sim = Simulator::new(&scenario).unwrap();
    let mut times = Vec::new();
    let mut counts = [0usize; 3];
    for event in sim.events() {
        times.push(event.time());
        counts[match event {
            SimEvent::Truth(_) => 0,
            SimEvent::Imu(_) => 1,
            SimEvent::Scan { .. } => 2,
        }] += 1;
    }
    assert!(times.windows(2).all(|w| w[0] <= w[1]));
    assert!(*times.last().unwrap() <= 2.0);
    // Truth at 0, 0.02, ..., 2.0; IMU at 400 Hz; two scanners at 4 Hz, each scan complete 25 ms
    // (plus 12.3 ms for the second) after its step 0.
    assert_eq!(counts, [101, 800, 8 + 8]);
    assert!(sim.next_event().is_none(), "exhausted after the duration");
}

/// Patches seen by at least `min_points` beams of every scanner at the epoch starting at `t0`.
fn planes_seen(sim: &mut Simulator, t0: f64, min_points: usize) -> Vec<usize> {
    let mut per_scanner = Vec::new();
    for sensor in 0..sim.scanners().len() {
        let (_, hits) = sim.scan_labelled(sensor, t0);
        let mut counts = vec![0usize; sim.scene.patches.len()];
        for patch in hits.into_iter().flatten() {
            counts[patch] += 1;
        }
        per_scanner.push(counts);
    }
    (0..sim.scene.patches.len())
        .filter(|&p| per_scanner.iter().all(|c| c[p] >= min_points))
        .collect()
}

#[test]
fn paper_sim_gives_four_planes_of_about_fifty_points_per_line() {
    let scenario = Scenario::builtin("paper-sim").unwrap();
    let mut sim = Simulator::new(&scenario).unwrap();
    for t0 in [0.0, 1.0] {
        for sensor in 0..2 {
            let (_, hits) = sim.scan_labelled(sensor, t0);
            for patch in 0..4 {
                let n = hits.iter().filter(|h| **h == Some(patch)).count();
                assert!(
                    (35..=65).contains(&n),
                    "t0 {t0} sensor {sensor} plane {patch}: {n}"
                );
            }
        }
    }
    let events: Vec<SimEvent> = Simulator::new(&scenario).unwrap().events().collect();
    let scans: Vec<f64> = events
        .iter()
        .filter_map(|e| match e {
            SimEvent::Scan { scan, .. } => Some(scan.t0),
            _ => None,
        })
        .collect();
    assert_eq!(scans, [0.0, 0.0, 1.0, 1.0]);
    let moved = sim.truth_at(1.0).p;
    assert_eq!(moved, Vector3::new(0.6, 0.4, 0.0));
}

#[test]
fn paper_bias_experiments_move_plane_two_only() {
    let plain = Simulator::new(&Scenario::paper_sim(PaperBias::None))
        .unwrap()
        .true_planes_in_body(1.0);
    let shifted = Simulator::new(&Scenario::paper_sim(PaperBias::Translated))
        .unwrap()
        .true_planes_in_body(1.0);
    assert!((shifted[1].distance - plain[1].distance - 0.1).abs() < 1e-12);
    for i in [0, 2, 3] {
        assert_eq!(shifted[i], plain[i]);
    }
    let turned = Simulator::new(&Scenario::paper_sim(PaperBias::Rotated)).unwrap();
    let (before, after) = (
        turned.true_planes_in_body(0.0),
        turned.true_planes_in_body(1.0),
    );
    let yaw_5 = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 5f64.to_radians());
    let yaw_extra = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.7f64.to_radians());
    assert!((after[0].normal - yaw_5.inverse() * before[0].normal).norm() < 1e-12);
    assert!((after[1].normal - yaw_extra * before[1].normal).norm() < 1e-12);
    assert!((after[1].distance - before[1].distance).abs() < 1e-12);
}

#[test]
fn a_study_can_move_a_plane_between_epochs() {
    let scenario = Scenario::builtin("paper-sim").unwrap().without_noise();
    let mut sim = Simulator::new(&scenario).unwrap();
    let (before, hits) = sim.scan_labelled(0, 0.0);
    let centre = sim.scene.patches[1].centre_m;
    sim.scene.patches[1].centre_m = (Vector3::from(centre) * 1.1).into();
    let after = sim.scan(0, 0.0);
    for (i, hit) in hits.iter().enumerate() {
        if *hit == Some(1) {
            // Farther away, or off the edge of the (same size) patch: no object in range.
            let moved = after.ranges_m[i] > before.ranges_m[i] + 0.4;
            assert!(moved || after.ranges_m[i] == 0.001, "beam {i}");
        } else {
            assert_eq!(after.ranges_m[i], before.ranges_m[i]);
        }
    }
}

#[test]
fn office_door_offers_three_independent_surfaces_and_a_swinging_door() {
    let scenario = Scenario::builtin("office-door").unwrap();
    let mut sim = Simulator::new(&scenario).unwrap();
    let door = sim
        .scene
        .patches
        .iter()
        .position(|p| p.name == "door")
        .unwrap();
    let closed = planes_seen(&mut sim, 0.0, 10);
    assert!(closed.contains(&door), "{closed:?}");
    assert!((4..=9).contains(&closed.len()), "{closed:?}");
    let names: Vec<&str> = closed
        .iter()
        .map(|&i| sim.scene.patches[i].name.as_str())
        .collect();
    for surface in ["floor", "left-wall", "front-wall"] {
        assert!(names.contains(&surface), "{names:?}");
    }
    // Fully open at 2 + 4.5 s: its normal has turned from the y axis to the x axis.
    let open = sim.true_planes_in_body(6.5)[door];
    assert!(open.normal.x.abs() > 1.0 - 1e-12, "{open:?}");
    assert!(sim.true_planes_in_body(0.0)[door].normal.y > 1.0 - 1e-12);
}

#[test]
fn hallway_hover_offers_four_to_nine_planes_at_every_epoch() {
    let scenario = Scenario::builtin("hallway-hover").unwrap();
    let mut sim = Simulator::new(&scenario).unwrap();
    let board = sim
        .scene
        .patches
        .iter()
        .position(|p| p.name == "board")
        .unwrap();
    for k in 0..50 {
        let t0 = 0.2 + f64::from(k) * 9.97;
        let seen = planes_seen(&mut sim, t0, 10);
        assert!((4..=9).contains(&seen.len()), "t0 {t0}: {seen:?}");
    }
    // The board is only within reach of the steeper scanner near the end of each approach.
    assert!(planes_seen(&mut sim, 309.5, 10).contains(&board));
    assert!(!planes_seen(&mut sim, 299.0, 10).contains(&board));
}

#[test]
fn a_hand_edited_invalid_scenario_is_refused_not_panicked_on() {
    let mut scenario = Scenario::builtin("paper-sim").unwrap();
    scenario.scanners[1].geometry = None;
    let err = Simulator::new(&scenario).err().unwrap().to_string();
    assert_eq!(
        err,
        "scenario \"paper-sim\" is invalid: scanner \"raised\": model custom needs a [scanners.geometry] table"
    );
}
