//! How the odometer's fused relative poses err against truth over a chain of epochs
//! (docs/accuracy.md, "NEES"): each one alone is consistent with its covariance, but
//! consecutive ones share the planes of the epoch between them with opposite signs, so their
//! errors are negatively correlated and their sums grow far slower than the filter, which fuses
//! them as independent, assumes.
//!
//! `cargo test --release --test odometry_noise -- --ignored --nocapture`

use ladar_odometer::fusion::evaluate::{run_scenario_with, AccuracyReport};
use ladar_odometer::fusion::record::{EpochOutcome, EpochRecord};
use ladar_odometer::fusion::FusionSettings;
use ladar_odometer::sim::{Scenario, Trajectory};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};

/// One fused relative pose's errors against truth, with the covariances it was fused with.
struct Fused {
    t: f64,
    t_previous: f64,
    rotation_error: Vector3<f64>,
    rotation_covariance: Matrix3<f64>,
    displacement_error: Vector3<f64>,
    displacement_covariance: Matrix3<f64>,
}

impl Fused {
    fn new(record: &EpochRecord, trajectory: &Trajectory) -> Option<Self> {
        let (rotation, displacement) = (record.rotation?, record.displacement?);
        let t_previous = record.t_previous?;
        let fully_observed = record.unobservable_displacement.is_empty();
        if record.outcome != EpochOutcome::Fused || !fully_observed {
            return None;
        }
        let (i, j) = (
            trajectory.kinematics(t_previous),
            trajectory.kinematics(record.t),
        );
        let true_rotation = i.q.inverse() * j.q;
        let measured = UnitQuaternion::from_scaled_axis(Vector3::from(rotation.value));
        Some(Self {
            t: record.t,
            t_previous,
            rotation_error: (true_rotation.inverse() * measured).scaled_axis(),
            rotation_covariance: Matrix3::from(rotation.covariance),
            displacement_error: Vector3::from(displacement.value) - i.q.inverse() * (j.p - i.p),
            displacement_covariance: Matrix3::from(displacement.covariance),
        })
    }

    fn part(&self, rotation: bool) -> (Vector3<f64>, Matrix3<f64>) {
        if rotation {
            (self.rotation_error, self.rotation_covariance)
        } else {
            (self.displacement_error, self.displacement_covariance)
        }
    }
}

/// Per part (rotation, displacement), per body axis.
#[derive(Debug)]
struct NoiseFigures {
    /// Mean 3-dof NEES of one relative pose (3 if its covariance is honest).
    nees: [f64; 2],
    /// Correlation of the normalised errors of two consecutive relative poses.
    lag_one_correlation: [[f64; 3]; 2],
    /// Mean of (sum of the errors of `WINDOW` consecutive poses)^2 over the sum of their
    /// variances: 1 if they were independent, as the filter fuses them.
    window_ratio: [[f64; 3]; 2],
    filter: AccuracyReport,
}

const WINDOW: usize = 5;

fn chained(poses: &[Fused]) -> bool {
    poses
        .windows(2)
        .all(|pair| (pair[1].t_previous - pair[0].t).abs() < 1e-9)
}

fn nees(poses: &[Fused], rotation: bool) -> f64 {
    let values: Vec<f64> = poses
        .iter()
        .filter_map(|pose| {
            let (error, covariance) = pose.part(rotation);
            Some(covariance.cholesky()?.solve(&error).dot(&error))
        })
        .collect();
    values.iter().sum::<f64>() / values.len() as f64
}

fn lag_one_correlation(poses: &[Fused], rotation: bool) -> [f64; 3] {
    std::array::from_fn(|axis| {
        let normalised = |pose: &Fused| {
            let (error, covariance) = pose.part(rotation);
            error[axis] / covariance[(axis, axis)].sqrt()
        };
        let (mut product, mut first, mut second) = (0.0, 0.0, 0.0);
        for pair in poses.windows(2).filter(|pair| chained(pair)) {
            let (a, b) = (normalised(&pair[0]), normalised(&pair[1]));
            product += a * b;
            first += a * a;
            second += b * b;
        }
        product / (first * second).sqrt()
    })
}

fn window_ratio(poses: &[Fused], rotation: bool) -> [f64; 3] {
    let windows: Vec<&[Fused]> = poses.chunks_exact(WINDOW).filter(|w| chained(w)).collect();
    std::array::from_fn(|axis| {
        let ratio = |window: &&[Fused]| {
            let (error, variance) = window.iter().fold((0.0, 0.0), |(e, v), pose| {
                let (error, covariance) = pose.part(rotation);
                (e + error[axis], v + covariance[(axis, axis)])
            });
            error * error / variance
        };
        windows.iter().map(ratio).sum::<f64>() / windows.len() as f64
    })
}

fn measure(rate_hz: f64, moving_objects: bool) -> NoiseFigures {
    let mut scenario = Scenario::builtin("hallway-hover").unwrap();
    if rate_hz > 4.0 {
        for scanner in &mut scenario.scanners {
            scanner.skip = 3;
        }
    }
    if !moving_objects {
        for patch in &mut scenario.scene.patches {
            patch.motion = Default::default();
        }
    }
    let mut settings = FusionSettings::default();
    settings.filter.stationary_start_s = 40.0;
    settings.fusion.epoch_rate_hz = rate_hz;
    let trajectory = scenario.trajectory.clone();
    let mut poses = Vec::new();
    let filter = run_scenario_with(&scenario, &settings, &mut |record, _| {
        poses.extend(Fused::new(record, &trajectory).filter(|pose| pose.t >= 45.0));
    })
    .unwrap();
    let both = |f: &dyn Fn(bool) -> [f64; 3]| [f(true), f(false)];
    NoiseFigures {
        nees: [nees(&poses, true), nees(&poses, false)],
        lag_one_correlation: both(&|rotation| lag_one_correlation(&poses, rotation)),
        window_ratio: both(&|rotation| window_ratio(&poses, rotation)),
        filter,
    }
}

fn print(label: &str, figures: &NoiseFigures) {
    let round = |v: [f64; 3]| v.map(|x| (x * 100.0).round() / 100.0);
    for (k, part) in ["rotation", "displacement"].iter().enumerate() {
        println!(
            "{label} {part}: NEES {:.2}, lag-one correlation {:?}, {WINDOW}-pose window ratio {:?}",
            figures.nees[k],
            round(figures.lag_one_correlation[k]),
            round(figures.window_ratio[k]),
        );
    }
    let report = &figures.filter;
    println!(
        "{label} filter: attitude std {:?} mrad, NEES blocks pos/vel/att {:?}",
        round(report.attitude_error_std_mrad),
        round(report.nees_block_means),
    );
}

#[test]
#[ignore = "release-mode study of the hallway-hover, about 10 s: run with --ignored --nocapture"]
fn consecutive_relative_poses_are_negatively_correlated() {
    for rate_hz in [1.0, 10.0] {
        for moving_objects in [true, false] {
            let label = format!(
                "hallway-hover {rate_hz} Hz{}",
                if moving_objects {
                    ""
                } else {
                    ", door and board still"
                }
            );
            let figures = measure(rate_hz, moving_objects);
            print(&label, &figures);
            assert!(
                (2.4..3.9).contains(&figures.nees[0]) && (2.4..3.9).contains(&figures.nees[1]),
                "{label}: one relative pose is no longer consistent: {:?}",
                figures.nees
            );
            for part in 0..2 {
                for axis in 0..3 {
                    assert!(
                        figures.lag_one_correlation[part][axis] < -0.15,
                        "{label}: consecutive poses no longer anticorrelated: {figures:?}"
                    );
                    assert!(
                        figures.window_ratio[part][axis] < 0.8,
                        "{label}: sums no longer telescope: {figures:?}"
                    );
                }
            }
        }
    }
}
