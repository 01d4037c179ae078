//! Drawing `report.html` for a 500 s run: estimates kept at 20 Hz, truth at 100 Hz and epochs
//! at 10 Hz, as `replay --report` has them for a long flight. `cargo bench --bench report`

use divan::black_box;
use ladar_odometer::daemon::mavlink_out::QualityPolicy;
use ladar_odometer::daemon::replay::ReplaySummary;
use ladar_odometer::daemon::sink::Tally;
use ladar_odometer::estimate::{Estimate, IntegrityStatus};
use ladar_odometer::report::RunReport;
use ladar_odometer::sensors::TruthSample;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use serde_json::json;

fn main() {
    divan::main();
}

const SECONDS: f64 = 500.0;

fn estimate(t: f64) -> Estimate {
    Estimate {
        t,
        position: Vector3::new(t.sin(), 0.01 * t, -1.0),
        velocity: Vector3::new(t.cos(), 0.01, 0.001 * (3.0 * t).sin()),
        attitude: UnitQuaternion::from_euler_angles(0.01 * t.sin(), -0.17, 0.001 * t),
        angular_rate: Vector3::zeros(),
        position_covariance: Matrix3::identity() * 1e-4,
        velocity_covariance: Matrix3::identity() * (1e-4 + 1e-5 * (t / 7.0).sin().abs()),
        velocity_attitude_covariance: Matrix3::zeros(),
        attitude_covariance: Matrix3::identity() * 1e-6,
        gyro_bias: Vector3::zeros(),
        accel_bias: Vector3::zeros(),
        reset_counter: 0,
        last_reset: None,
        integrity: Some(IntegrityStatus::Ok),
        since_last_fused: 0.05,
        degraded: false,
        converged: true,
    }
}

fn truth(t: f64) -> TruthSample {
    let e = estimate(t);
    TruthSample {
        t,
        p: e.position,
        q: e.attitude,
        v: e.velocity * 1.001,
    }
}

fn epoch(t: f64) -> serde_json::Value {
    let test =
        |chi: f64| json!({"chi_square": chi, "chi_square_threshold": 16.6, "detected": chi > 16.6});
    json!({
        "t": t, "outcome": "fused", "planes": 6, "matched": 5, "used": 5, "excluded_planes": [],
        "integrity": {
            "rotation": {"test": test(3.0 + 2.0 * (7.0 * t).sin())},
            "displacement": {"test": test(2.0 + (5.0 * t).cos())}
        },
        "plane_geometry": (0..6).map(|k| {
            let a = f64::from(k);
            json!({"normal": [a.cos(), a.sin(), 0.0], "rho": 1.0 + a})
        }).collect::<Vec<_>>()
    })
}

fn times(rate_hz: f64) -> impl Iterator<Item = f64> {
    (0..(SECONDS * rate_hz) as usize).map(move |k| k as f64 / rate_hz)
}

#[divan::bench(sample_count = 5, sample_size = 1)]
fn render_500_s(bencher: divan::Bencher) {
    let estimates: Vec<Estimate> = times(20.0).map(estimate).collect();
    let truth: Vec<TruthSample> = times(100.0).map(truth).collect();
    let epochs: Vec<serde_json::Value> = times(10.0).map(epoch).collect();
    let policy = QualityPolicy::default();
    let summary = ReplaySummary {
        duration_s: SECONDS,
        chunks: 0,
        bytes: 0,
        sensors: Vec::new(),
        outputs: Tally {
            estimates: estimates.len() as u64,
            epochs: epochs.len() as u64,
            planes: 6 * epochs.len() as u64,
            ..Tally::default()
        },
        truth: None,
        autopilot: None,
        loss: None,
    };
    let report = RunReport {
        title: "bench",
        estimates: &estimates,
        truth: &truth,
        epochs: &epochs,
        policy: &policy,
        summary: &summary,
        shares_truth_frame: true,
    };
    bencher.bench_local(|| black_box(report.render().unwrap()).len());
}
