//! Bad input to `run`: a sensor answering garbage is counted and dropped while the others
//! stream on; a missing port or an unknown configuration key is one clear line.

use ladar_odometer::daemon::config::Config;
use ladar_odometer::daemon::pipeline::{EventTrace, Traced};
use ladar_odometer::daemon::run::{self, RunError, RunOptions};
use ladar_odometer::daemon::serve::{self, SharedScene, StillRoom};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

mod support;
use support::{free_port, rig_config as config_text};

fn scratch(name: &str) -> support::Scratch {
    support::scratch("bad", name)
}

/// Accepts connections and answers each with seeded random bytes, some of them line feeds.
async fn garbage_sensor(listener: TcpListener, cancel: CancellationToken) {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    loop {
        let (mut stream, _) = tokio::select! {
            () = cancel.cancelled() => return,
            accepted = listener.accept() => accepted.unwrap(),
        };
        loop {
            let bytes: Vec<u8> = (0..200)
                .map(|_| if rng.gen_bool(0.1) { b'\n' } else { rng.gen() })
                .collect();
            if stream.write_all(&bytes).await.is_err() {
                break;
            }
            tokio::select! {
                () = cancel.cancelled() => return,
                () = tokio::time::sleep(Duration::from_millis(20)) => {}
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sensor_answering_garbage_is_counted_and_the_others_stream_on() {
    let dir = scratch("garbage");
    let cancel_emulators = CancellationToken::new();
    let emulators = TaskTracker::new();
    let pitched_port = free_port();
    let emulator_path = dir.join("emulators.toml");
    std::fs::write(
        &emulator_path,
        config_text(
            &format!("tcp:127.0.0.1:{}", free_port()),
            &format!("tcp:127.0.0.1:{pitched_port}"),
            "serial:/dev/null",
        ),
    )
    .unwrap();
    let config = Config::load(&emulator_path).unwrap();
    let scene: SharedScene = Arc::new(Mutex::new(StillRoom::for_config(&config)));
    let models = serve::default_models(&config);
    let served = serve::serve(
        &config,
        &models,
        scene,
        &emulators,
        cancel_emulators.clone(),
    )
    .await
    .unwrap();
    let imu = served.iter().find(|s| s.sensor == "imu").unwrap();
    let garbage = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let garbage_port = garbage.local_addr().unwrap().port();
    emulators.spawn(garbage_sensor(garbage, cancel_emulators.clone()));

    let run_path = dir.join("run.toml");
    std::fs::write(
        &run_path,
        config_text(
            &format!("tcp:127.0.0.1:{garbage_port}"),
            &format!("tcp:127.0.0.1:{pitched_port}"),
            &imu.connection,
        ),
    )
    .unwrap();
    let cancel = CancellationToken::new();
    let daemon = tokio::spawn(run::run(
        RunOptions {
            config: run_path,
            ..RunOptions::default()
        },
        |_, _| EventTrace::default(),
        cancel.clone(),
    ));
    tokio::time::sleep(Duration::from_millis(2500)).await;
    cancel.cancel();
    let report = tokio::time::timeout(Duration::from_secs(10), daemon)
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    cancel_emulators.cancel();

    let counts = |name: &str| report.sensors.iter().find(|(n, _)| n == name).unwrap().1;
    assert!(counts("front").decode_errors > 10, "{:?}", counts("front"));
    assert_eq!(counts("front").scans, 0);
    assert!(counts("pitched").scans > 40, "{:?}", counts("pitched"));
    assert!(counts("imu").imu_samples > 100, "{:?}", counts("imu"));
    let geometries: Vec<usize> = report
        .estimator
        .calls
        .iter()
        .filter_map(|c| match c {
            Traced::Geometry(sensor, _) => Some(*sensor),
            _ => None,
        })
        .collect();
    assert_eq!(
        geometries,
        [1],
        "only the healthy scanner reported its geometry"
    );
}

/// Paused time: the 20 s that run waits for a late USB device pass at once.
#[tokio::test(start_paused = true)]
async fn a_missing_serial_port_is_one_line_naming_the_sensor_and_the_fix() {
    let dir = scratch("missing");
    let path = dir.join("run.toml");
    std::fs::write(
        &path,
        config_text(
            "serial:/dev/ladar-no-such-port",
            "tcp:127.0.0.1:10940",
            "serial:/dev/ladar-no-such-imu",
        ),
    )
    .unwrap();
    let error = run::run(
        RunOptions {
            config: path,
            ..RunOptions::default()
        },
        |_, _| EventTrace::default(),
        CancellationToken::new(),
    )
    .await
    .unwrap_err();
    let line = error.to_string();
    assert!(matches!(error, RunError::Port(_)), "{error:?}");
    assert!(
        line.contains("`front`")
            && line.contains("/dev/ladar-no-such-port")
            && !line.contains('\n'),
        "{line}"
    );
}

#[tokio::test]
async fn an_unknown_key_is_one_line_naming_it() {
    let dir = scratch("key");
    let path = dir.join("run.toml");
    let text = config_text("tcp:127.0.0.1:1", "tcp:127.0.0.1:2", "tcp:127.0.0.1:3")
        .replace("rate_hz = 100", "rate_hz = 100\nrate_hertz = 5");
    std::fs::write(&path, text).unwrap();
    let error = run::run(
        RunOptions {
            config: path,
            ..RunOptions::default()
        },
        |_, _| EventTrace::default(),
        CancellationToken::new(),
    )
    .await
    .unwrap_err();
    let line = error.to_string();
    assert!(
        line.contains("rate_hertz") && !line.contains('\n'),
        "{line}"
    );
}

#[tokio::test]
async fn a_mount_left_to_tf_static_is_refused_by_a_live_run_naming_the_sensor() {
    let dir = scratch("tf-static");
    let path = dir.join("run.toml");
    let text = config_text(
        "tcp:127.0.0.1:1",
        "tcp:127.0.0.1:2",
        "serial:/dev/ladar-no-such-imu",
    )
    .replacen(
        "rpy_deg = [0.0, 0.0, 0.0]\ntranslation_m = [0.1, 0.0, 0.0]\n",
        "topic = \"/horizontal_laser_2d\"\n",
        1,
    )
    .replace("rate_hz = 100", "rate_hz = 100\nrpy_deg = [0.0, 0.0, 0.0]")
        + "\n[ros]\nbody_frame = \"base_link\"\n";
    std::fs::write(&path, text).unwrap();
    let error = run::run(
        RunOptions {
            config: path,
            ..RunOptions::default()
        },
        |_, _| EventTrace::default(),
        CancellationToken::new(),
    )
    .await
    .unwrap_err();
    let line = error.to_string();
    assert!(matches!(error, RunError::MountFromTfStatic(_)), "{error:?}");
    assert!(
        line.contains("/tf_static") && line.contains("rpy_deg") && !line.contains('\n'),
        "{line}"
    );
}
