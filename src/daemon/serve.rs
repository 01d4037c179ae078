//! Emulated sensors served in real time on ptys and TCP, so that `run` can be exercised end to
//! end with no hardware: the drivers' emulators answer the daemon's handshake and stream what a
//! [`Scene`] says the sensors measure.

use super::config::{Config, ConfigErrors, SensorConnection};
use crate::sensors::{Mount, ScannerGeometry};
use nalgebra::Vector3;
use std::io;
use std::path::Path;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

/// What the emulated sensors measure at a host time (seconds since serving started).
pub trait Scene: Send {
    /// One range per step AMIN..=AMAX of scanner `scanner`, in mm, for the revolution whose
    /// step 0 is at `step0_s`.
    fn ranges_mm(&mut self, scanner: usize, geometry: &ScannerGeometry, step0_s: f64) -> Vec<u32>;
    /// Specific force (m/s^2) and angular rate (rad/s) in the IMU frame (NED-flagged) at `t`.
    fn imu(&mut self, t: f64) -> ([f64; 3], [f64; 3]);
}

pub type SharedScene = Arc<Mutex<dyn Scene>>;

/// A rig standing still in a closed box room: each beam's range is the distance to the wall,
/// floor or ceiling it meets. Good for exercising the daemon; the simulator makes real flights.
#[derive(Debug, Clone)]
pub struct StillRoom {
    /// Room from `min` to `max` around the body origin, NED-aligned body, metres.
    pub min: Vector3<f64>,
    pub max: Vector3<f64>,
    pub mounts: Vec<Mount>,
}

impl StillRoom {
    /// An 8 x 6 m room, 3 m high, the body 1.2 m above the floor and off-centre so that
    /// opposite walls differ.
    pub fn for_config(config: &Config) -> Self {
        Self {
            min: Vector3::new(-3.0, -2.5, -1.8),
            max: Vector3::new(5.0, 3.5, 1.2),
            mounts: config.scanners.iter().map(|s| s.mount()).collect(),
        }
    }

    fn range_m(&self, origin: &Vector3<f64>, direction: &Vector3<f64>) -> f64 {
        (0..3)
            .filter_map(|axis| {
                let d = direction[axis];
                let wall = if d > 0.0 {
                    self.max[axis]
                } else if d < 0.0 {
                    self.min[axis]
                } else {
                    return None;
                };
                Some((wall - origin[axis]) / d)
            })
            .filter(|t| *t >= 0.0)
            .fold(f64::INFINITY, f64::min)
    }
}

impl Scene for StillRoom {
    fn ranges_mm(&mut self, scanner: usize, geometry: &ScannerGeometry, _: f64) -> Vec<u32> {
        let mount = self
            .mounts
            .get(scanner)
            .copied()
            .unwrap_or_else(Mount::identity);
        (geometry.amin..=geometry.amax)
            .map(|step| {
                let direction = mount.rotation * geometry.step_direction(f64::from(step));
                let range = self.range_m(&mount.translation, &direction);
                if geometry.is_valid_range(range) {
                    (range * 1000.0).round() as u32
                } else {
                    // Out of range: the sensors report a small error code.
                    1
                }
            })
            .collect()
    }

    fn imu(&mut self, _: f64) -> ([f64; 3], [f64; 3]) {
        // At rest, level, the accelerometers read the reaction to gravity: up, i.e. -z in FRD.
        ([0.0, 0.0, -9.80665], [0.0; 3])
    }
}

/// A scenario's world and trajectory, measured in real time: the simulator's ray-cast scans at
/// the asked step-0 time, and its noise-free IMU kinematics.
pub struct SimulatedScene {
    simulator: ladar_sim::Simulator,
    imu_to_body: nalgebra::UnitQuaternion<f64>,
    /// Scenario time at the emulators' start, s.
    start_s: f64,
}

impl SimulatedScene {
    /// The scenario from `start_s` seconds on: a daemon connecting then starts in the middle
    /// of it.
    pub fn starting_at(
        scenario: &ladar_sim::Scenario,
        start_s: f64,
    ) -> Result<Self, ladar_sim::ScenarioError> {
        Ok(Self {
            start_s,
            ..Self::new(scenario)?
        })
    }

    pub(crate) fn new(scenario: &ladar_sim::Scenario) -> Result<Self, ladar_sim::ScenarioError> {
        let simulator = ladar_sim::Simulator::new(scenario)?;
        let imu_to_body = simulator
            .imu()
            .map_or_else(nalgebra::UnitQuaternion::identity, |imu| {
                imu.mount_rotation()
            });
        Ok(Self {
            simulator,
            imu_to_body,
            start_s: 0.0,
        })
    }
}

impl Scene for SimulatedScene {
    fn ranges_mm(&mut self, scanner: usize, geometry: &ScannerGeometry, step0_s: f64) -> Vec<u32> {
        let count = (geometry.amax - geometry.amin + 1) as usize;
        let mut ranges = vec![0; count];
        if scanner >= self.simulator.scanners().len() {
            return ranges;
        }
        let scan = self.simulator.scan(scanner, self.start_s + step0_s);
        let offset = scan.first_step.saturating_sub(geometry.amin) as usize;
        for (slot, range) in ranges.iter_mut().skip(offset).zip(&scan.ranges_m) {
            *slot = (range * 1000.0).round().clamp(0.0, f64::from(u32::MAX)) as u32;
        }
        ranges
    }

    fn imu(&mut self, t: f64) -> ([f64; 3], [f64; 3]) {
        let k = self.simulator.kinematics_at(self.start_s + t);
        let body_to_imu = self.imu_to_body.inverse();
        (
            (body_to_imu * k.specific_force_body).into(),
            (body_to_imu * k.omega_body).into(),
        )
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("{0}")]
    Scenario(#[from] ladar_sim::ScenarioError),
    #[error("{0}")]
    Simulate(#[from] super::simulate::SimulateError),
    #[error("cannot write {path}: {source}")]
    Write {
        path: std::path::PathBuf,
        source: io::Error,
    },
    #[error("{0}")]
    Config(#[from] ConfigErrors),
    #[error("cannot listen on {address} for sensor `{sensor}`: {source} (is another emulator or sensor using it?)")]
    Listen {
        sensor: String,
        address: String,
        source: io::Error,
    },
    #[error("cannot create a pty for sensor `{sensor}`: {source}")]
    Pty { sensor: String, source: io::Error },
}

/// Where one emulated sensor can be reached.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Served {
    pub sensor: String,
    /// A connection string for the configuration: `serial:/dev/pts/N` or `tcp:HOST:PORT`.
    pub connection: String,
}

/// What to emulate: the sensors of a configuration file in a still box room, or a scenario's
/// rig flying its trajectory through its scene (scanners on ptys).
pub enum Source<'a> {
    Config(&'a Path),
    /// A scenario; with `scanner_tcp = Some((host, port))` scanner `i` listens on TCP
    /// `host:port+i` (Ethernet UST/UTM style) instead of a pty.
    Scenario {
        name: &'a str,
        /// Scenario time at which the emulators begin, s.
        start_s: f64,
        scanner_tcp: Option<(&'a str, u16)>,
    },
}

/// Serves every sensor until `cancel`, printing where each is; with `write_config`, also writes
/// a configuration whose connections point at the emulators, ready for `run --config`.
pub async fn serve_until_cancelled(
    source: Source<'_>,
    write_config: Option<&Path>,
    cancel: CancellationToken,
) -> Result<(), ServeError> {
    let (models, config, text, scene): (Vec<scip::Model>, Config, String, SharedScene) =
        match source {
            Source::Config(path) => {
                let (config, text) = Config::load_with_text(path)?;
                let scene = Arc::new(Mutex::new(StillRoom::for_config(&config)));
                (default_models(&config), config, text, scene)
            }
            Source::Scenario {
                name,
                start_s,
                scanner_tcp,
            } => {
                let scenario = ladar_sim::Scenario::resolve(name)?;
                let mut text = super::simulate::rig_config(&scenario)?;
                if let Some((host, port)) = scanner_tcp {
                    for (i, scanner) in scenario.scanners.iter().enumerate() {
                        let tcp_port = u16::try_from(usize::from(port) + i).unwrap_or(u16::MAX);
                        text = text.replace(
                            &super::simulate::simulated_connection(&scanner.name),
                            &format!("tcp:{host}:{tcp_port}"),
                        );
                    }
                }
                let config = Config::parse(&text, Path::new(name))?;
                let models = super::simulate::emulated_models(&scenario);
                let scene = Arc::new(Mutex::new(SimulatedScene::starting_at(&scenario, start_s)?));
                (models, config, text, scene)
            }
        };
    let tracker = tokio_util::task::TaskTracker::new();
    let served = serve(&config, &models, scene, &tracker, cancel).await?;
    let mut runnable = text;
    for (s, original) in served.iter().zip(
        config
            .scanners
            .iter()
            .map(|s| &s.connection)
            .chain(std::iter::once(&config.imu.connection)),
    ) {
        println!("{} {}", s.sensor, s.connection);
        runnable = runnable.replace(
            &format!("connection = \"{original}\""),
            &format!("connection = \"{}\"", s.connection),
        );
    }
    if let Some(path) = write_config {
        std::fs::write(path, runnable).map_err(|source| ServeError::Write {
            path: path.to_path_buf(),
            source,
        })?;
    }
    tracker.close();
    tracker.wait().await;
    Ok(())
}

/// Starts one emulator per sensor on `tracker`: TCP sensors listen where the configuration
/// says, serial sensors get a fresh pty (its path is in the result).
pub async fn serve(
    config: &Config,
    models: &[scip::Model],
    scene: SharedScene,
    tracker: &tokio_util::task::TaskTracker,
    cancel: CancellationToken,
) -> Result<Vec<Served>, ServeError> {
    let start = Instant::now();
    let mut served = Vec::new();
    for (index, scanner) in config.scanners.iter().enumerate() {
        let model = models
            .get(index)
            .cloned()
            .unwrap_or_else(|| default_model(index));
        let emulate = ScipEmulation {
            model,
            scanner: index,
            scene: scene.clone(),
            start,
        };
        let connection = match scanner.connection() {
            SensorConnection::Tcp { host, port } => {
                let listener = listen(&scanner.name, &host, port).await?;
                let address = listener.local_addr().map_err(|source| ServeError::Listen {
                    sensor: scanner.name.clone(),
                    address: format!("{host}:{port}"),
                    source,
                })?;
                tracker.spawn(serve_tcp(listener, emulate, cancel.clone()));
                format!("tcp:{address}")
            }
            SensorConnection::Serial { .. } => {
                let (master, path) = pty(&scanner.name)?;
                tracker.spawn(serve_pty(master, emulate, cancel.clone()));
                format!("serial:{path}")
            }
        };
        served.push(Served {
            sensor: scanner.name.clone(),
            connection,
        });
    }
    let imu = XbusEmulation {
        rate_hz: f64::from(config.imu.rate_hz.max(1)),
        scene,
        start,
    };
    let (master, path) = pty(&config.imu.name)?;
    tracker.spawn(serve_pty(master, imu, cancel));
    served.push(Served {
        sensor: config.imu.name.clone(),
        connection: format!("serial:{path}"),
    });
    Ok(served)
}

/// Scanner models for a configuration that does not say: a URG-04LX first, UTM-30LX after.
pub fn default_models(config: &Config) -> Vec<scip::Model> {
    (0..config.scanners.len()).map(default_model).collect()
}

fn default_model(index: usize) -> scip::Model {
    if index == 0 {
        scip::Model::urg_04lx()
    } else {
        scip::Model::utm_30lx()
    }
}

async fn listen(sensor: &str, host: &str, port: u16) -> Result<TcpListener, ServeError> {
    TcpListener::bind((host, port))
        .await
        .map_err(|source| ServeError::Listen {
            sensor: sensor.to_string(),
            address: format!("{host}:{port}"),
            source,
        })
}

fn pty(sensor: &str) -> Result<(tokio_serial::SerialStream, String), ServeError> {
    use tokio_serial::SerialPort;
    let error = |e: tokio_serial::Error| ServeError::Pty {
        sensor: sensor.to_string(),
        source: io::Error::other(e.to_string()),
    };
    let (master, slave) = tokio_serial::SerialStream::pair().map_err(error)?;
    let path = slave.name().ok_or_else(|| ServeError::Pty {
        sensor: sensor.to_string(),
        source: io::Error::other("the pty has no name"),
    })?;
    // The daemon opens the slave by name (exclusively); this end keeps only the master.
    drop(slave);
    Ok((master, path))
}

/// One emulated device session over any byte stream.
trait Emulation: Clone + Send + 'static {
    fn session<P: AsyncRead + AsyncWrite + Unpin + Send>(
        &self,
        port: P,
        cancel: &CancellationToken,
    ) -> impl std::future::Future<Output = io::Result<()>> + Send;
}

async fn serve_tcp(listener: TcpListener, emulation: impl Emulation, cancel: CancellationToken) {
    loop {
        let stream = tokio::select! {
            () = cancel.cancelled() => return,
            accepted = listener.accept() => match accepted {
                Ok((stream, _)) => stream,
                Err(e) => {
                    tracing::warn!("emulator accept failed: {e}");
                    continue;
                }
            },
        };
        let _ = stream.set_nodelay(true);
        // One client at a time, like the real sensor.
        if let Err(e) = emulation.session(stream, &cancel).await {
            tracing::debug!("emulator session ended: {e}");
        }
    }
}

async fn serve_pty(
    mut master: tokio_serial::SerialStream,
    emulation: impl Emulation,
    cancel: CancellationToken,
) {
    while !cancel.is_cancelled() {
        // With no process on the slave side, the master reads EIO: wait for one.
        if emulation.session(&mut master, &cancel).await.is_err() {
            tokio::select! {
                () = cancel.cancelled() => return,
                () = tokio::time::sleep(Duration::from_millis(50)) => {}
            }
        }
    }
}

#[derive(Clone)]
struct ScipEmulation {
    model: scip::Model,
    scanner: usize,
    scene: SharedScene,
    start: Instant,
}

/// Device clocks start well away from the host's, as real ones do.
const DEVICE_CLOCK_OFFSET_MS: u64 = 1_234_567;

/// Emulator time of a tick: the instant it was scheduled for, not the instant this task got to
/// it. A real device samples on its own clock and only the delivery is late; stamping the
/// handling time instead made a loaded host's late and bunched-up ticks into IMU samples 0.1 ms
/// apart that each still carry a 2.5 ms increment, and scans taken at uneven intervals.
fn scheduled_since(start: Instant, tick: tokio::time::Instant) -> Duration {
    tick.into_std().saturating_duration_since(start)
}

impl Emulation for ScipEmulation {
    async fn session<P: AsyncRead + AsyncWrite + Unpin + Send>(
        &self,
        mut port: P,
        cancel: &CancellationToken,
    ) -> io::Result<()> {
        let geometry = super::readings::geometry_from(&self.model.parameters);
        let mut emulator = scip::Emulator::new(self.model.clone());
        let period = Duration::from_secs_f64(geometry.scan_period());
        let mut revolutions = tokio::time::interval(period);
        let mut buffer = vec![0u8; 4096];
        let mut output = Vec::new();
        let device_ms =
            |at: Duration| ((at.as_millis() as u64 + DEVICE_CLOCK_OFFSET_MS) & 0xFF_FFFF) as u32;
        loop {
            tokio::select! {
                () = cancel.cancelled() => return Ok(()),
                read = port.read(&mut buffer) => {
                    let n = read?;
                    if n == 0 {
                        return Ok(());
                    }
                    emulator.set_clock(device_ms(self.start.elapsed()));
                    emulator.handle_input(&buffer[..n]);
                }
                tick = revolutions.tick() => {
                    if emulator.is_streaming() {
                        let step0 = scheduled_since(self.start, tick).saturating_sub(period);
                        let ranges = self
                            .scene
                            .lock()
                            .unwrap_or_else(PoisonError::into_inner)
                            .ranges_mm(self.scanner, &geometry, step0.as_secs_f64());
                        emulator.set_clock(device_ms(self.start.elapsed()));
                        // The scene answers for every measurable step; a mismatch is a bug there.
                        if let Err(e) = emulator.push_scan(device_ms(step0), &ranges, None) {
                            return Err(io::Error::other(e.to_string()));
                        }
                    }
                }
            }
            output.clear();
            emulator.drain_output(&mut output);
            if !output.is_empty() {
                port.write_all(&output).await?;
            }
        }
    }
}

#[derive(Clone)]
struct XbusEmulation {
    rate_hz: f64,
    scene: SharedScene,
    start: Instant,
}

impl Emulation for XbusEmulation {
    async fn session<P: AsyncRead + AsyncWrite + Unpin + Send>(
        &self,
        mut port: P,
        cancel: &CancellationToken,
    ) -> io::Result<()> {
        let mut emulator =
            xbus::emulator::Emulator::new(xbus::emulator::EmulatorOptions::mti_630());
        let interval = 1.0 / self.rate_hz;
        let mut samples = tokio::time::interval(Duration::from_secs_f64(interval));
        let mut buffer = vec![0u8; 4096];
        let mut output = Vec::new();
        loop {
            tokio::select! {
                () = cancel.cancelled() => return Ok(()),
                read = port.read(&mut buffer) => {
                    let n = read?;
                    if n == 0 {
                        return Ok(());
                    }
                    emulator.handle_input(&buffer[..n]);
                }
                tick = samples.tick() => {
                    let t = scheduled_since(self.start, tick).as_secs_f64();
                    let (accel, gyro) = self.scene.lock().unwrap_or_else(PoisonError::into_inner).imu(t);
                    let ticks = ((t * 10_000.0) as u64 + 10 * DEVICE_CLOCK_OFFSET_MS) as u32;
                    emulator.push_sample(&xbus::emulator::Sample::from_rates(ticks, accel, gyro, interval));
                }
            }
            output.clear();
            emulator.drain_output(&mut output);
            if !output.is_empty() {
                port.write_all(&output).await?;
            }
        }
    }
}
