//! `run` against emulated sensors (two SCIP scanners on TCP behind an unpluggable proxy, an
//! Xbus IMU on a pty), MAVLink out over UDP to a receiver here; then the recording is checked
//! byte for byte against what the emulators sent, and replayed to the same calls and estimates
//! bit for bit.

use ladar_odometer::daemon::config::Config;
use ladar_odometer::daemon::fusion_estimator::FusionEstimator;
use ladar_odometer::daemon::pipeline::{EpochCounts, Estimator, EventTrace, Traced};
use ladar_odometer::daemon::recording::{Direction, ReadMode, Recording};
use ladar_odometer::daemon::replay::{self, ReplayOptions};
use ladar_odometer::daemon::run::{self, RunOptions};
use ladar_odometer::daemon::serve::{self, SharedScene, StillRoom};
use ladar_odometer::estimate::{Estimate, IntegrityStatus};
use ladar_odometer::sensors::{ImuSample, Scan, ScannerGeometry};
use mavlink::dialects::ardupilotmega::{MavMessage, ODOMETRY_DATA};
use mavlink::{MavlinkReader, MavlinkVersion};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream, UdpSocket};
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

/// Scans of the pitched scanner (40 Hz) per echoed epoch: 2 Hz.
const SCANS_PER_EPOCH: usize = 20;

/// Records every call like [`EventTrace`] and answers each IMU sample with an estimate at its
/// time, so that the MAVLink path and the bit-for-bit comparison have estimates to carry. Every
/// `SCANS_PER_EPOCH` pitched scans close an epoch, whose estimate is the newest IMU one marked
/// with y = 1 m.
#[derive(Debug, Default)]
struct Echo {
    trace: EventTrace,
    estimates: Vec<Estimate>,
    epoch_estimates: Vec<Estimate>,
    pitched_scans: usize,
}

fn echoed(t: f64) -> Estimate {
    Estimate {
        t,
        position: Vector3::new(t, 0.0, -1.0),
        velocity: Vector3::new(0.5, 0.0, 0.0),
        attitude: UnitQuaternion::identity(),
        angular_rate: Vector3::zeros(),
        position_covariance: Matrix3::identity() * 0.01,
        velocity_covariance: Matrix3::identity() * 0.0025,
        velocity_attitude_covariance: Matrix3::zeros(),
        attitude_covariance: Matrix3::identity() * 1e-4,
        gyro_bias: Vector3::zeros(),
        accel_bias: Vector3::zeros(),
        reset_counter: 0,
        last_reset: None,
        integrity: Some(IntegrityStatus::Ok),
        since_last_fused: 0.0,
        degraded: false,
        converged: true,
    }
}

impl Estimator for Echo {
    type Epoch = ();
    fn geometry(&mut self, scanner: usize, geometry: ScannerGeometry) {
        self.trace.geometry(scanner, geometry);
    }
    fn imu(&mut self, sample: ImuSample) -> Option<Estimate> {
        self.trace.imu(sample);
        let estimate = echoed(sample.time());
        self.estimates.push(estimate.clone());
        Some(estimate)
    }
    fn scan(&mut self, scan: Scan) -> Option<()> {
        let pitched = scan.sensor == 1;
        self.trace.scan(scan);
        self.pitched_scans += usize::from(pitched);
        let last = self.estimates.last()?;
        if !pitched || !self.pitched_scans.is_multiple_of(SCANS_PER_EPOCH) {
            return None;
        }
        let mut estimate = last.clone();
        estimate.position.y = 1.0;
        self.epoch_estimates.push(estimate);
        Some(())
    }
    fn epoch_estimate(&self) -> Option<Estimate> {
        self.epoch_estimates.last().cloned()
    }
    fn sensor_stale(&mut self, sensor: usize, stale: bool, t: f64) {
        self.trace.sensor_stale(sensor, stale, t);
    }
    fn epoch_counts(_: &()) -> EpochCounts {
        EpochCounts::default()
    }
}

/// A TCP hop between the daemon and an emulator that can be unplugged, keeping every byte it
/// delivered to the daemon.
struct Proxy {
    delivered: Arc<Mutex<Vec<u8>>>,
    plugged: watch::Sender<bool>,
    port: u16,
}

impl Proxy {
    async fn start(upstream: u16, tracker: &TaskTracker, cancel: CancellationToken) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let port = listener.local_addr().unwrap().port();
        let delivered = Arc::new(Mutex::new(Vec::new()));
        let (plugged, plugged_rx) = watch::channel(true);
        tracker.spawn(forward(
            listener,
            upstream,
            delivered.clone(),
            plugged_rx,
            cancel,
        ));
        Self {
            delivered,
            plugged,
            port,
        }
    }
}

async fn forward(
    listener: TcpListener,
    upstream: u16,
    delivered: Arc<Mutex<Vec<u8>>>,
    mut plugged: watch::Receiver<bool>,
    cancel: CancellationToken,
) {
    loop {
        let accepted = tokio::select! {
            () = cancel.cancelled() => return,
            accepted = listener.accept() => accepted,
        };
        let Ok((mut client, _)) = accepted else {
            continue;
        };
        if !*plugged.borrow_and_update() {
            // Unplugged: the connection goes nowhere and says nothing.
            drop(client);
            continue;
        }
        let mut device = TcpStream::connect(("127.0.0.1", upstream)).await.unwrap();
        let (mut from_device, mut to_device) = device.split();
        let (mut from_client, mut to_client) = client.split();
        let mut up = [0u8; 4096];
        let mut down = [0u8; 8192];
        loop {
            tokio::select! {
                () = cancel.cancelled() => return,
                _ = plugged.changed() => {
                    if !*plugged.borrow_and_update() {
                        // FIN after the last delivered byte: the daemon reads all of it, then EOF.
                        let _ = to_client.shutdown().await;
                        break;
                    }
                }
                read = from_client.read(&mut up) => match read {
                    Ok(0) | Err(_) => break,
                    Ok(n) => if to_device.write_all(&up[..n]).await.is_err() { break },
                },
                read = from_device.read(&mut down) => match read {
                    Ok(0) | Err(_) => break,
                    Ok(n) => {
                        if to_client.write_all(&down[..n]).await.is_err() {
                            break;
                        }
                        delivered.lock().unwrap().extend_from_slice(&down[..n]);
                    }
                },
            }
        }
    }
}

mod support;
use support::free_port;

fn config_text(front: &str, pitched: &str, imu: &str, mavlink: Option<u16>) -> String {
    let mut text = support::rig_config(front, pitched, imu);
    if let Some(port) = mavlink {
        text.push_str(&format!(
            "\n[mavlink]\nprofile = \"px4\"\nconnection = \"udpout:127.0.0.1:{port}\"\nrate_hz = 30\n"
        ));
    }
    text
}

fn scratch(name: &str) -> support::Scratch {
    support::scratch("live", name)
}

fn concatenated_rx(recording: &Recording, sensor: &str) -> Vec<u8> {
    recording
        .messages
        .iter()
        .filter(|m| m.sensor == sensor && m.direction == Direction::Rx)
        .flat_map(|m| m.data.iter().copied())
        .collect()
}

async fn receive_mavlink(socket: UdpSocket, frames: Arc<Mutex<Vec<MavMessage>>>) {
    let mut buffer = [0u8; 512];
    while let Ok((n, _)) = socket.recv_from(&mut buffer).await {
        if let Ok((_, message)) =
            MavlinkReader::new(&buffer[..n]).read_message::<MavMessage>(MavlinkVersion::V2)
        {
            frames.lock().unwrap().push(message);
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn live_run_survives_an_unplug_records_every_byte_and_replays_bit_for_bit() {
    let dir = scratch("run");
    let cancel_emulators = CancellationToken::new();
    let emulators = TaskTracker::new();
    let (front_port, pitched_port) = (free_port(), free_port());
    let emulator_config = config_text(
        &format!("tcp:127.0.0.1:{front_port}"),
        &format!("tcp:127.0.0.1:{pitched_port}"),
        "serial:/dev/null",
        None,
    );
    let emulator_path = dir.join("emulators.toml");
    std::fs::write(&emulator_path, &emulator_config).unwrap();
    let config = ladar_odometer::daemon::config::Config::load(&emulator_path).unwrap();
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
    let front = Proxy::start(front_port, &emulators, cancel_emulators.clone()).await;
    let pitched = Proxy::start(pitched_port, &emulators, cancel_emulators.clone()).await;

    let autopilot = UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let autopilot_port = autopilot.local_addr().unwrap().port();
    let received = Arc::new(Mutex::new(Vec::new()));
    let receiver = tokio::spawn(receive_mavlink(autopilot, received.clone()));

    let run_path = dir.join("run.toml");
    std::fs::write(
        &run_path,
        config_text(
            &format!("tcp:127.0.0.1:{}", front.port),
            &format!("tcp:127.0.0.1:{}", pitched.port),
            &imu.connection,
            Some(autopilot_port),
        ),
    )
    .unwrap();
    let recording_path = dir.join("live.mcap");
    let out = dir.join("out");
    let cancel = CancellationToken::new();
    let daemon = tokio::spawn(run::run(
        RunOptions {
            config: run_path,
            record: Some(recording_path.clone()),
            out: Some(out.clone()),
        },
        |_, _| Echo::default(),
        cancel.clone(),
    ));

    tokio::time::sleep(Duration::from_millis(2000)).await;
    front.plugged.send_replace(false);
    tokio::time::sleep(Duration::from_millis(1500)).await;
    front.plugged.send_replace(true);
    tokio::time::sleep(Duration::from_millis(2500)).await;
    // Unplug both before stopping, so that every byte delivered was also read.
    front.plugged.send_replace(false);
    pitched.plugged.send_replace(false);
    tokio::time::sleep(Duration::from_millis(300)).await;
    cancel.cancel();
    let report = tokio::time::timeout(Duration::from_secs(10), daemon)
        .await
        .expect("shutdown is prompt")
        .unwrap()
        .unwrap();
    cancel_emulators.cancel();
    receiver.abort();

    // The unplugged scanner was marked stale and came back without a restart.
    let calls = &report.estimator.trace.calls;
    let stale_front: Vec<bool> = calls
        .iter()
        .filter_map(|c| match c {
            Traced::Stale {
                sensor: 0, stale, ..
            } => Some(*stale),
            _ => None,
        })
        .collect();
    assert!(
        stale_front.starts_with(&[true, false, true]),
        "{stale_front:?}"
    );
    let front_geometries = calls
        .iter()
        .filter(|c| matches!(c, Traced::Geometry(0, _)))
        .count();
    assert_eq!(front_geometries, 2, "re-initialised after the replug");
    let scans_of = |sensor| {
        calls
            .iter()
            .filter(|c| matches!(c, Traced::Scan(s) if s.sensor == sensor))
            .count()
    };
    // URG-04LX at 10 Hz for about 4.5 s of the 6.3 s, UTM-30LX at 40 Hz for about 6 s.
    assert!((30..=60).contains(&scans_of(0)), "{}", scans_of(0));
    assert!((180..=260).contains(&scans_of(1)), "{}", scans_of(1));
    let imu_samples = report.estimator.estimates.len();
    assert!((450..=700).contains(&imu_samples), "{imu_samples}");
    assert_eq!(report.dropped_chunks, 0);
    assert_eq!(report.unrecorded_chunks, 0);
    for (name, counts) in &report.sensors {
        assert_eq!(counts.decode_errors, 0, "{name}");
    }

    // Every byte the scanners sent is in the recording, in order.
    let recording = Recording::open(&recording_path, ReadMode::Strict).unwrap();
    assert_eq!(
        concatenated_rx(&recording, "front"),
        *front.delivered.lock().unwrap()
    );
    assert_eq!(
        concatenated_rx(&recording, "pitched"),
        *pitched.delivered.lock().unwrap()
    );

    // MAVLink: heartbeats at 1 Hz and ODOMETRY at the configured 30 Hz, plus the epochs' (each
    // takes the place of the next slot, so at 2 Hz epochs a little over 30 Hz on average).
    let messages = received.lock().unwrap().clone();
    let heartbeats = messages
        .iter()
        .filter(|m| matches!(m, MavMessage::HEARTBEAT(_)))
        .count();
    let odometry: Vec<_> = messages
        .iter()
        .filter_map(|m| match m {
            MavMessage::ODOMETRY(o) => Some(o.clone()),
            _ => None,
        })
        .collect();
    assert!((4..=8).contains(&heartbeats), "{heartbeats}");
    let span = odometry.last().unwrap().time_usec - odometry[0].time_usec;
    let rate = (odometry.len() - 1) as f64 / (span as f64 * 1e-6);
    assert!((25.0..=32.0).contains(&rate), "{rate} Hz");
    assert!(odometry.iter().all(|o| o.vx == 0.5 && o.quality > 0));
    assert_epochs_reached_the_autopilot(
        &report.estimator.epoch_estimates,
        &report.estimator.estimates,
        &odometry,
    );

    // Replay: the same calls and the same estimates, bit for bit.
    let (summary, replayed) = replay::replay(
        &ReplayOptions {
            recording: recording_path,
            out: Some(dir.join("replay-out")),
            ..ReplayOptions::default()
        },
        |_, _| Echo::default(),
    )
    .unwrap();
    assert_eq!(
        format!("{:?}", replayed.trace),
        format!("{:?}", report.estimator.trace)
    );
    assert_eq!(
        format!("{:?}", replayed.estimates),
        format!("{:?}", report.estimator.estimates)
    );
    assert_eq!(
        format!("{:?}", replayed.epoch_estimates),
        format!("{:?}", report.estimator.epoch_estimates)
    );
    assert_eq!(summary.outputs.estimates as usize, imu_samples);
    // The replay decides the same ODOMETRY messages: the live ones are its beginning (the
    // MAVLink task stops before the fusion has drained its last chunks).
    let replayed_odometry = tlog_odometry(&dir.join("replay-out").join("mavlink.tlog"));
    assert!(odometry.len() <= replayed_odometry.len());
    assert_eq!(
        format!("{odometry:?}"),
        format!("{:?}", &replayed_odometry[..odometry.len()])
    );
    assert_eq!(
        std::fs::read(out.join("trajectory.tum")).unwrap(),
        std::fs::read(dir.join("replay-out").join("trajectory.tum")).unwrap()
    );
    assert_replay_output_exists(&dir.join("replay-out"));
}

/// Serves `config`'s sensors in `scene`, runs the daemon on them for `seconds` with the
/// configuration `serve-emulators --write-config` would write (connections to the emulators,
/// MAVLink to a receiver here, outputs in `dir/out`) and returns what the autopilot received.
async fn run_against_emulators(
    dir: &Path,
    config: &Config,
    text: &str,
    models: &[scip::Model],
    scene: SharedScene,
    seconds: u64,
) -> Vec<MavMessage> {
    let emulators = TaskTracker::new();
    let cancel_emulators = CancellationToken::new();
    let served = serve::serve(config, models, scene, &emulators, cancel_emulators.clone())
        .await
        .unwrap();
    let autopilot = UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let autopilot_port = autopilot.local_addr().unwrap().port();
    let received = Arc::new(Mutex::new(Vec::new()));
    let receiver = tokio::spawn(receive_mavlink(autopilot, received.clone()));
    let to_autopilot = format!("connection = \"udpout:127.0.0.1:{autopilot_port}\"");
    let mut runnable = match &config.mavlink {
        Some(m) => text.replace(&format!("connection = \"{}\"", m.connection), &to_autopilot),
        None => format!("{text}\n[mavlink]\nprofile = \"px4\"\n{to_autopilot}\n"),
    };
    let sensors = config.scanners.iter().map(|s| &s.connection);
    for (emulator, original) in served.iter().zip(sensors.chain([&config.imu.connection])) {
        runnable = runnable.replace(
            &format!("connection = \"{original}\""),
            &format!("connection = \"{}\"", emulator.connection),
        );
    }
    let run_path = dir.join("run.toml");
    std::fs::write(&run_path, runnable).unwrap();
    let cancel = CancellationToken::new();
    let daemon = tokio::spawn(run::run(
        RunOptions {
            config: run_path,
            record: Some(dir.join("live.mcap")),
            out: Some(dir.join("out")),
        },
        |config, _| FusionEstimator::new(Some(config)),
        cancel.clone(),
    ));
    tokio::time::sleep(Duration::from_secs(seconds)).await;
    cancel.cancel();
    tokio::time::timeout(Duration::from_secs(10), daemon)
        .await
        .expect("shutdown is prompt")
        .unwrap()
        .unwrap();
    cancel_emulators.cancel();
    receiver.abort();
    let messages = received.lock().unwrap().clone();
    messages
}

/// `run` with the real fusion on what `serve-emulators --config` serves for the two-scanner PX4
/// example (issue situation 4): the still box room, the first scanner a 10 Hz URG-04LX whose
/// pairs close 52-63 ms after their mid-scan reference time. Every solved epoch must reach the
/// filter, and the autopilot must hear that the odometry is usable.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_px4_example_standing_in_the_box_room_fuses_its_epochs_live() {
    let dir = scratch("box-room");
    let example =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("config/examples/px4-two-utm30lx-usb.toml");
    let (config, text) = Config::load_with_text(&example).unwrap();
    let scene: SharedScene = Arc::new(Mutex::new(StillRoom::for_config(&config)));
    let models = serve::default_models(&config);
    // The filter aligns in the first second; epochs come at 1 Hz.
    let messages = run_against_emulators(&dir, &config, &text, &models, scene, 7).await;
    let out = dir.join("out");
    let epochs: Vec<serde_json::Value> = std::fs::read_to_string(out.join("epochs.jsonl"))
        .unwrap()
        .lines()
        .map(|line| serde_json::from_str(line).unwrap())
        .collect();
    let failed: Vec<_> = epochs
        .iter()
        .filter(|e| e["outcome"] == "update_failed")
        .map(|e| &e["reason"])
        .collect();
    assert!(failed.is_empty(), "{failed:?}");
    let fused = epochs.iter().filter(|e| e["outcome"] == "fused").count();
    assert!(fused >= 3, "{fused} of {} epochs fused", epochs.len());
    assert!(
        messages
            .iter()
            .any(|m| matches!(m, MavMessage::ODOMETRY(o) if o.quality > 0)),
        "ODOMETRY quality stayed -1"
    );
}

/// Each epoch's estimate went out at once (its ODOMETRY is the marked one at the epoch's time)
/// or, when the previous message was under 10 ms before, the next message is the first IMU
/// estimate 10 ms after that one, out of its 30 Hz slot.
fn assert_epochs_reached_the_autopilot(
    epochs: &[Estimate],
    estimates: &[Estimate],
    odometry: &[ODOMETRY_DATA],
) {
    let micros = |e: &Estimate| (e.t * 1e6).round() as u64;
    let mut at_once = 0;
    for epoch in epochs {
        let t_us = micros(epoch);
        if odometry.iter().any(|o| o.time_usec == t_us && o.y == 1.0) {
            at_once += 1;
            continue;
        }
        let previous = odometry.iter().rev().find(|o| o.time_usec <= t_us);
        let next = odometry.iter().find(|o| o.time_usec > t_us);
        let (Some(previous), Some(next)) = (previous, next) else {
            panic!("the epoch at {t_us} us was neither sent nor waiting behind a message");
        };
        let carrier = estimates
            .iter()
            .map(micros)
            .find(|&t| t > t_us && t >= previous.time_usec + 9_999);
        assert_eq!(
            Some(next.time_usec),
            carrier,
            "the epoch at {t_us} us (previous message at {} us)",
            previous.time_usec
        );
    }
    assert!(epochs.len() >= 5, "{} epochs", epochs.len());
    // How many went out at once depends on where the host's timing puts each epoch against the
    // 10 ms spacing, so it is reported, not asserted (the mavlink_out unit tests pin that path).
    println!(
        "{at_once} of {} epochs sent at once, the rest carried 10 ms on",
        epochs.len()
    );
}

/// ODOMETRY messages of a `mavlink.tlog` (8-byte time, then a MAVLink 2 frame, repeated).
fn tlog_odometry(path: &Path) -> Vec<ODOMETRY_DATA> {
    let bytes = std::fs::read(path).unwrap();
    let mut odometry = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        let frame = &bytes[at + 8..];
        let signed = frame[2] & 1 == 1;
        let length = 12 + usize::from(frame[1]) + if signed { 13 } else { 0 };
        let (_, message) = MavlinkReader::new(&frame[..length])
            .read_message::<MavMessage>(MavlinkVersion::V2)
            .unwrap();
        if let MavMessage::ODOMETRY(o) = message {
            odometry.push(o);
        }
        at += 8 + length;
    }
    odometry
}

fn assert_replay_output_exists(dir: &Path) {
    for file in ["trajectory.tum", "epochs.jsonl", "mavlink.tlog"] {
        assert!(dir.join(file).exists(), "{file}");
    }
    assert!(std::fs::metadata(dir.join("mavlink.tlog")).unwrap().len() > 0);
}

/// Situation 1 of the honest-velocity issue: the daemon started while the platform already
/// hovers (a systemd restart in flight). Every ODOMETRY the autopilot may use carries a hover's
/// velocity, and the estimate becomes usable within seconds, not never.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_daemon_started_45_s_into_the_hover_tells_the_autopilot_only_what_it_knows() {
    let dir = scratch("late-start");
    let scenario = ladar_sim::Scenario::builtin("hallway-hover").unwrap();
    let text = ladar_odometer::daemon::simulate::rig_config(&scenario).unwrap();
    let config = Config::parse(&text, Path::new("hallway-hover")).unwrap();
    let scene = serve::SimulatedScene::starting_at(&scenario, 45.0).unwrap();
    let models = ladar_odometer::daemon::simulate::emulated_models(&scenario);
    let messages = run_against_emulators(
        &dir,
        &config,
        &text,
        &models,
        Arc::new(Mutex::new(scene)),
        20,
    )
    .await;
    let odometry: Vec<&ODOMETRY_DATA> = messages
        .iter()
        .filter_map(|m| match m {
            MavMessage::ODOMETRY(o) => Some(o),
            _ => None,
        })
        .collect();
    let speed = |o: &ODOMETRY_DATA| (o.vx.powi(2) + o.vy.powi(2) + o.vz.powi(2)).sqrt();
    let valid: Vec<_> = odometry.iter().filter(|o| o.quality >= 1).collect();
    let fastest = valid.iter().map(|o| speed(o)).fold(0.0f32, f32::max);
    assert!(
        fastest < 0.3,
        "a valid ODOMETRY said {fastest} m/s in a hover"
    );
    let end = odometry.last().map_or(0, |o| o.time_usec);
    let last_10_s: Vec<_> = odometry
        .iter()
        .filter(|o| o.time_usec + 10_000_000 >= end)
        .collect();
    let usable = last_10_s.iter().filter(|o| o.quality >= 1).count();
    assert!(
        2 * usable >= last_10_s.len() && !last_10_s.is_empty(),
        "{usable} of the last {} ODOMETRY usable",
        last_10_s.len()
    );
}
