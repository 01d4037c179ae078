//! Hot-path costs of the error-state EKF: one IMU sample (strapdown + 33x33 covariance
//! propagation) and one relative-pose update (6 rows against the cloned pose).
//! Run: `cargo bench --bench filter`.

use divan::Bencher;
use ladar_odometer::filter::{
    Eskf, FilterConfig, NominalState, Observability, RelativePoseMeasurement, RelativeRotation,
    RelativeTranslation, SharedNoise,
};
use ladar_odometer::sensors::ImuSample;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};

fn main() {
    divan::main();
}

const RATE_HZ: f64 = 400.0;

fn moving_filter() -> Eskf {
    let state = NominalState {
        v: Vector3::new(1.0, 0.2, 0.0),
        ..NominalState::at_rest(
            UnitQuaternion::from_euler_angles(0.05, -0.1, 0.3),
            Vector3::zeros(),
        )
    };
    Eskf::with_initial_state(FilterConfig::default(), 0.0, state).unwrap()
}

fn sample(k: u64, delta: bool) -> ImuSample {
    let t = k as f64 / RATE_HZ;
    let gyro = Vector3::new(0.01, -0.02, 0.3 + 0.1 * t.sin());
    let accel = Vector3::new(0.3, 0.1, -9.8);
    if delta {
        ImuSample::Delta {
            t,
            dt: 1.0 / RATE_HZ,
            dq: UnitQuaternion::from_scaled_axis(gyro / RATE_HZ),
            dv: accel / RATE_HZ,
        }
    } else {
        ImuSample::Rate { t, gyro, accel }
    }
}

#[divan::bench(args = [false, true])]
fn propagate_one_imu_sample(bencher: Bencher, delta: bool) {
    let mut filter = moving_filter();
    let mut k = 1;
    bencher
        .with_inputs(|| {
            k += 1;
            sample(k, delta)
        })
        .bench_local_refs(|sample| filter.push_imu(sample));
}

/// Same, while an odometry epoch is open (33 states propagated instead of 21).
#[divan::bench]
fn propagate_with_open_clone(bencher: Bencher) {
    let mut filter = moving_filter();
    filter.push_imu(&sample(1, true));
    filter.clone_pose().unwrap();
    let mut k = 1;
    bencher
        .with_inputs(|| {
            k += 1;
            sample(k, true)
        })
        .bench_local_refs(|sample| filter.push_imu(sample));
}

#[divan::bench]
fn relative_pose_update(bencher: Bencher) {
    let mut filter = moving_filter();
    let mut k = 0;
    // A first epoch leaves its noise carried, so the measured update takes the carried
    // noise in as well as carrying its own out, as every update of a chain of epochs does.
    for _ in 0..2 {
        let t_ref = filter.clone_pose().unwrap_or(0.0);
        for _ in 0..40 {
            k += 1;
            filter.push_imu(&sample(k, false));
        }
        if k > 40 {
            filter
                .update_relative_pose(&measurement(&filter, t_ref))
                .unwrap();
        }
    }
    let t_ref = filter.clone_pose().unwrap();
    for _ in 0..40 {
        k += 1;
        filter.push_imu(&sample(k, false));
    }
    let measurement = measurement(&filter, t_ref);
    bencher
        .with_inputs(|| filter.clone())
        .bench_local_values(|mut filter| {
            let report = filter.update_relative_pose(divan::black_box(&measurement));
            (report, filter)
        });
}

/// A relative pose from `t_ref` to the filter time, a little off the filter's prediction, with
/// the displacement under-determined along x and half of each covariance shared.
fn measurement(filter: &Eskf, t_ref: f64) -> RelativePoseMeasurement {
    let t = filter.time().unwrap();
    let prior = filter.relative_pose(t_ref, t).unwrap();
    let (rotation, displacement) = (Matrix3::identity() * 1e-6, Matrix3::identity() * 1e-4);
    RelativePoseMeasurement {
        t_ref,
        t,
        rotation: Some(RelativeRotation {
            rotation_vector: prior.rotation.scaled_axis() + Vector3::repeat(1e-3),
            covariance: rotation,
            observability: Observability::full(),
        }),
        translation: Some(RelativeTranslation {
            displacement: prior.translation + Vector3::repeat(5e-3),
            covariance: displacement,
            observability: Observability::from_unobservable(&[Vector3::x()]),
        }),
        shared: Some(SharedNoise {
            with_previous: [rotation * -0.4, displacement * -0.4],
            current: [rotation * 0.5, displacement * 0.5],
        }),
    }
}
