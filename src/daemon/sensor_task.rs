//! One task per sensor: owns the port (exclusive serial, or TCP), runs the driver's sans-IO
//! device for the handshake and the stream, and stamps every chunk read or written with host
//! monotonic time into the chunk queue, each received chunk with the readings the device
//! decoded from it (the only decoding the daemon does). A port that disappears (USB unplugged, TCP reset) is
//! reopened with backoff and the device re-initialised; each change of link state is logged
//! once, not each retry, and an empty rx chunk tells the fusion (and the recording) the link
//! was lost.

use super::chunk_queue::ChunkQueue;
use super::config::SensorConnection;
use super::pipeline::Chunk;
use super::readings::Reading;
use super::recording::Direction;
use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio_util::sync::CancellationToken;

const BACKOFF_MIN: Duration = Duration::from_millis(250);
const BACKOFF_MAX: Duration = Duration::from_secs(4);
const WRITE_TIMEOUT: Duration = Duration::from_secs(1);
const READ_BUFFER: usize = 16 * 1024;
/// How long a stopping scanner gets to acknowledge QT (laser off) at shutdown.
const STOP_GRACE: Duration = Duration::from_millis(300);

/// Which driver a sensor speaks.
#[derive(Debug, Clone)]
pub(crate) enum Driver {
    Scip(scip::DeviceConfig),
    Xbus(xbus::DeviceConfig),
}

/// Everything a sensor task needs.
#[derive(Debug, Clone)]
pub(crate) struct SensorLink {
    /// The [`Chunk::sensor`] number.
    pub index: usize,
    pub name: String,
    pub connection: SensorConnection,
    pub driver: Driver,
}

/// Host monotonic clock shared by every task: ns since the daemon started, never 0 (0 marks an
/// untimed raw dump).
#[derive(Debug, Clone, Copy)]
pub(crate) struct HostClock(Instant);

impl HostClock {
    pub(crate) fn start() -> Self {
        Self(Instant::now())
    }
    pub(crate) fn now_ns(&self) -> u64 {
        (self.0.elapsed().as_nanos() as u64).max(1)
    }
    pub(crate) fn now(&self) -> Duration {
        Duration::from_nanos(self.now_ns())
    }
}

trait Port: AsyncRead + AsyncWrite + Send + Unpin {}
impl<T: AsyncRead + AsyncWrite + Send + Unpin> Port for T {}

/// How long `run` waits at start for serial devices that do not exist yet: on a Pi the USB
/// devices may enumerate after the service starts. Within the unit's TimeoutStartSec (30 s),
/// and long enough that a slow enumeration does not use up StartLimitBurst with quick failures.
pub(crate) const DEVICE_WAIT: Duration = Duration::from_secs(20);
const DEVICE_POLL: Duration = Duration::from_millis(250);

/// Why a port cannot be used.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct PortProblem {
    /// The device does not exist (yet): worth waiting for at start.
    pub missing: bool,
    pub message: String,
}

/// Checks every sensor's port at start, waiting up to `patience` for devices that do not exist
/// yet (each is logged once, and named in the systemd status); any other problem, or a device
/// still missing then, is the error. A typo in the configuration thus still stops the start,
/// while a port that comes and goes later is retried by its task. Returns early on `cancel`.
pub(crate) async fn wait_for_ports(
    links: &[SensorLink],
    patience: Duration,
    cancel: &CancellationToken,
) -> Result<(), String> {
    // Tokio's clock, so that a test can run the wait in paused time.
    let deadline = tokio::time::Instant::now() + patience;
    let mut announced = vec![false; links.len()];
    loop {
        let mut missing = false;
        for (link, announced) in links.iter().zip(&mut announced) {
            match check_port(&link.name, &link.connection) {
                Ok(()) => {}
                Err(problem) if problem.missing && tokio::time::Instant::now() < deadline => {
                    missing = true;
                    if !*announced {
                        *announced = true;
                        tracing::warn!(
                            sensor = %link.name,
                            "{}; waiting up to {} s for it to appear",
                            problem.message,
                            patience.as_secs()
                        );
                        super::watchdog::status(&format!("waiting for sensor `{}`", link.name));
                    }
                }
                Err(problem) => return Err(problem.message),
            }
        }
        if !missing {
            return Ok(());
        }
        tokio::select! {
            () = cancel.cancelled() => return Ok(()),
            () = tokio::time::sleep(DEVICE_POLL) => {}
        }
    }
}

/// Why a port cannot be used at all, right now.
pub(crate) fn check_port(name: &str, connection: &SensorConnection) -> Result<(), PortProblem> {
    let SensorConnection::Serial { path, .. } = connection else {
        return Ok(());
    };
    let unusable = |message: String| PortProblem {
        missing: false,
        message,
    };
    use std::os::unix::fs::OpenOptionsExt;
    // Linux O_NONBLOCK | O_NOCTTY: a UART waiting for carrier must not hang the start-up check,
    // and a sensor port must never become our controlling terminal.
    const NONBLOCKING_NO_CTTY: i32 = 0o4000 | 0o400;
    match std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(NONBLOCKING_NO_CTTY)
        .open(path)
    {
        Ok(_) => Ok(()),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Err(PortProblem {
            missing: true,
            message: format!(
                "sensor `{name}`: serial port {} does not exist: plug the sensor in, check the udev rule, or fix its `connection`",
                path.display()
            ),
        }),
        Err(e) if e.kind() == io::ErrorKind::PermissionDenied => Err(unusable(format!(
            "sensor `{name}`: no permission to open {}: add the daemon's user to the `dialout` group (or install the udev rule)",
            path.display()
        ))),
        Err(e) if e.raw_os_error() == Some(16) => Err(unusable(format!(
            "sensor `{name}`: {} is busy: another program (or another ladar-odometer) holds it; stop that one first",
            path.display()
        ))),
        Err(e) => Err(unusable(format!(
            "sensor `{name}`: cannot open {}: {e}",
            path.display()
        ))),
    }
}

async fn open(connection: &SensorConnection) -> io::Result<Pin<Box<dyn Port>>> {
    match connection {
        SensorConnection::Tcp { host, port } => {
            let stream = tokio::net::TcpStream::connect((host.as_str(), *port)).await?;
            stream.set_nodelay(true)?;
            Ok(Box::pin(stream))
        }
        SensorConnection::Serial { path, baud } => {
            let path = path.to_string_lossy().into_owned();
            // USB CDC ignores the rate; a UART needs it.
            let builder = tokio_serial::new(path, baud.unwrap_or(115_200));
            let mut stream = tokio_serial::SerialStream::open(&builder)?;
            stream
                .set_exclusive(true)
                .map_err(|e| io::Error::other(e.to_string()))?;
            Ok(Box::pin(stream))
        }
    }
}

/// Link states, logged once per change.
#[derive(Debug, Clone, PartialEq, Eq)]
enum LinkState {
    Starting,
    Streaming,
    Down(String),
}

/// Runs until `cancel`. `streaming` is set while the device streams, for readiness.
pub(crate) async fn run(
    link: SensorLink,
    queue: Arc<ChunkQueue>,
    clock: HostClock,
    streaming: Arc<AtomicBool>,
    cancel: CancellationToken,
) {
    let mut state = LinkState::Starting;
    let mut backoff = BACKOFF_MIN;
    while !cancel.is_cancelled() {
        let outcome = match open(&link.connection).await {
            Ok(port) => {
                let mut session = Session {
                    link: &link,
                    queue: &queue,
                    clock,
                    streaming: &streaming,
                    state: &mut state,
                    garbage: 0,
                };
                let outcome = session.run(port, &cancel).await;
                streaming.store(false, Ordering::Relaxed);
                // Recorded, so that replay sees the loss exactly where the live fusion did.
                queue.push(Chunk {
                    sensor: link.index,
                    direction: Direction::Rx,
                    log_time_ns: clock.now_ns(),
                    data: Vec::new(),
                    readings: Vec::new(),
                });
                backoff = BACKOFF_MIN;
                outcome
            }
            Err(e) => Err(format!("cannot open {}: {e}", link.connection)),
        };
        if let Err(reason) = outcome {
            let down = LinkState::Down(reason_kind(&reason));
            if state != down {
                tracing::warn!(sensor = %link.name, "{reason}; retrying until it comes back");
                state = down;
            }
        }
        tokio::select! {
            () = cancel.cancelled() => break,
            () = tokio::time::sleep(backoff) => {}
        }
        backoff = (backoff * 2).min(BACKOFF_MAX);
    }
}

/// The part of a failure that identifies it, without the changing details (so that the same
/// failure repeating is not logged again).
fn reason_kind(reason: &str) -> String {
    reason.split(':').take(2).collect::<Vec<_>>().join(":")
}

struct Session<'a> {
    link: &'a SensorLink,
    queue: &'a ChunkQueue,
    clock: HostClock,
    streaming: &'a AtomicBool,
    state: &'a mut LinkState,
    garbage: u64,
}

/// The two drivers behind their one sans-IO contract. One per session, never moved in bulk.
#[allow(clippy::large_enum_variant)]
enum Device {
    Scip(scip::Device),
    Xbus(xbus::Device),
}

/// What a device said that the task acts on.
enum Notice {
    Streaming,
    /// A corrupt reply or frame was dropped.
    Garbage,
    Failed(String),
    Warning(String),
}

impl Device {
    fn new(driver: &Driver, now: Duration) -> Self {
        match driver {
            Driver::Scip(config) => Self::Scip(scip::Device::new(config.clone(), now)),
            Driver::Xbus(config) => Self::Xbus(xbus::Device::new(*config, now)),
        }
    }

    fn poll_transmit(&mut self, now: Duration) -> Option<Vec<u8>> {
        match self {
            Self::Scip(d) => d.poll_transmit(now).map(<[u8]>::to_vec),
            Self::Xbus(d) => d.poll_transmit(now).map(<[u8]>::to_vec),
        }
    }

    fn handle_input(&mut self, now: Duration, bytes: &[u8]) {
        match self {
            Self::Scip(d) => d.handle_input(now, bytes),
            Self::Xbus(d) => d.handle_input(now, bytes),
        }
    }

    fn poll_timeout(&self) -> Option<Duration> {
        match self {
            Self::Scip(d) => d.poll_timeout(),
            Self::Xbus(d) => d.poll_timeout(),
        }
    }

    fn handle_timeout(&mut self, now: Duration) {
        match self {
            Self::Scip(d) => d.handle_timeout(now),
            Self::Xbus(d) => d.handle_timeout(now),
        }
    }

    fn stop(&mut self, now: Duration) {
        if let Self::Scip(d) = self {
            d.stop(now);
        }
    }

    /// Drains the device's events: the data for the fusion, and the few the task acts on.
    fn drain(&mut self, readings: &mut Vec<Reading>, notices: &mut Vec<Notice>) {
        match self {
            Self::Scip(d) => {
                while let Some(event) = d.poll_event() {
                    if let Some(notice) = scanner_notice(&event) {
                        notices.push(notice);
                    }
                    readings.extend(Reading::from_scanner(event));
                }
            }
            Self::Xbus(d) => {
                while let Some(event) = d.poll_event() {
                    if let Some(notice) = imu_notice(&event) {
                        notices.push(notice);
                    }
                    readings.extend(Reading::from_imu(event));
                }
            }
        }
    }
}

fn scanner_notice(event: &scip::Event) -> Option<Notice> {
    use scip::{DeviceError, Event};
    Some(match event {
        Event::StreamStarted { .. } => Notice::Streaming,
        Event::DecodeError(_) => Notice::Garbage,
        Event::Error(e @ (DeviceError::StreamStalled | DeviceError::Status { .. })) => {
            Notice::Warning(e.to_string())
        }
        Event::Error(e) => Notice::Failed(e.to_string()),
        _ => return None,
    })
}

fn imu_notice(event: &xbus::Event) -> Option<Notice> {
    use xbus::Event;
    Some(match event {
        Event::Measuring => Notice::Streaming,
        Event::FrameDropped(_) | Event::BadMeasurement(_) => Notice::Garbage,
        Event::Failed(e) => Notice::Failed(e.to_string()),
        Event::DataTimeout { silent_for } => {
            Notice::Warning(format!("IMU silent for {:.1} s", silent_for.as_secs_f64()))
        }
        Event::DeviceError(code) => Notice::Warning(format!("IMU reported error {code}")),
        _ => return None,
    })
}

impl Session<'_> {
    fn chunk(&self, direction: Direction, log_time_ns: u64, data: &[u8], readings: Vec<Reading>) {
        self.queue.push(Chunk {
            sensor: self.link.index,
            direction,
            log_time_ns,
            data: data.to_vec(),
            readings,
        });
    }

    async fn flush(
        &self,
        device: &mut Device,
        port: &mut Pin<Box<dyn Port>>,
    ) -> Result<(), String> {
        loop {
            let now_ns = self.clock.now_ns();
            let Some(bytes) = device.poll_transmit(Duration::from_nanos(now_ns)) else {
                return Ok(());
            };
            match tokio::time::timeout(WRITE_TIMEOUT, port.write_all(&bytes)).await {
                Ok(Ok(())) => self.chunk(Direction::Tx, now_ns, &bytes, Vec::new()),
                Ok(Err(e)) => return Err(format!("write to {} failed: {e}", self.link.connection)),
                Err(_) => return Err(format!("write to {} timed out", self.link.connection)),
            }
        }
    }

    /// Decodes bytes read at `now_ns` and queues them with what they held, for the recording
    /// and the fusion; the notices are left for [`Session::act`].
    fn received(&self, device: &mut Device, now_ns: u64, bytes: &[u8], notices: &mut Vec<Notice>) {
        device.handle_input(Duration::from_nanos(now_ns), bytes);
        let mut readings = Vec::new();
        device.drain(&mut readings, notices);
        self.chunk(Direction::Rx, now_ns, bytes, readings);
    }

    fn act(&mut self, notices: &mut Vec<Notice>) -> Result<(), String> {
        for notice in notices.drain(..) {
            match notice {
                Notice::Streaming => {
                    self.streaming.store(true, Ordering::Relaxed);
                    if *self.state != LinkState::Streaming {
                        tracing::info!(sensor = %self.link.name, connection = %self.link.connection, "streaming");
                        *self.state = LinkState::Streaming;
                    }
                }
                Notice::Warning(text) => tracing::warn!(sensor = %self.link.name, "{text}"),
                Notice::Garbage => {
                    self.garbage += 1;
                    if super::chunk_queue::is_power_of_ten(self.garbage) {
                        tracing::warn!(
                            sensor = %self.link.name,
                            dropped = self.garbage,
                            "corrupt bytes from the sensor dropped: check the cable, baud rate and that {} is this sensor",
                            self.link.connection
                        );
                    }
                }
                Notice::Failed(text) => return Err(text),
            }
        }
        Ok(())
    }

    async fn run(
        &mut self,
        mut port: Pin<Box<dyn Port>>,
        cancel: &CancellationToken,
    ) -> Result<(), String> {
        let mut device = Device::new(&self.link.driver, self.clock.now());
        let mut buffer = vec![0u8; READ_BUFFER];
        let mut notices = Vec::new();
        loop {
            self.flush(&mut device, &mut port).await?;
            device.drain(&mut Vec::new(), &mut notices);
            self.act(&mut notices)?;
            let deadline = device.poll_timeout().map(|t| {
                let wait = t.saturating_sub(self.clock.now());
                tokio::time::Instant::now() + wait.min(Duration::from_secs(3600))
            });
            tokio::select! {
                () = cancel.cancelled() => {
                    self.stop(&mut device, &mut port, &mut buffer).await;
                    return Ok(());
                }
                read = port.read(&mut buffer) => {
                    let now_ns = self.clock.now_ns();
                    match read {
                        Ok(0) => return Err(format!("{} closed", self.link.connection)),
                        Ok(n) => self.received(&mut device, now_ns, &buffer[..n], &mut notices),
                        Err(e) => return Err(format!("read from {} failed: {e}", self.link.connection)),
                    }
                }
                () = sleep_until(deadline) => device.handle_timeout(self.clock.now()),
            }
        }
    }

    /// Switches a scanner's laser off on the way out, recording the exchange like any other.
    async fn stop(&self, device: &mut Device, port: &mut Pin<Box<dyn Port>>, buffer: &mut [u8]) {
        device.stop(self.clock.now());
        if self.flush(device, port).await.is_err() {
            return;
        }
        let until = tokio::time::Instant::now() + STOP_GRACE;
        let mut notices = Vec::new();
        while let Ok(Ok(n)) = tokio::time::timeout_at(until, port.read(buffer)).await {
            if n == 0 {
                break;
            }
            self.received(device, self.clock.now_ns(), &buffer[..n], &mut notices);
        }
    }
}

async fn sleep_until(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(deadline) => tokio::time::sleep_until(deadline).await,
        None => std::future::pending().await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn link(path: &std::path::Path) -> SensorLink {
        SensorLink {
            index: 0,
            name: "front".into(),
            connection: SensorConnection::Serial {
                path: path.to_path_buf(),
                baud: None,
            },
            driver: Driver::Scip(scip::DeviceConfig::default()),
        }
    }

    fn scratch(name: &str) -> std::path::PathBuf {
        let path = std::env::temp_dir().join(format!("ladar-port-{name}-{}", std::process::id()));
        let _ = std::fs::remove_file(&path);
        path
    }

    #[tokio::test]
    async fn a_device_that_enumerates_late_is_waited_for() {
        let device = scratch("late");
        let appear = {
            let device = device.clone();
            tokio::spawn(async move {
                tokio::time::sleep(Duration::from_millis(400)).await;
                std::os::unix::fs::symlink("/dev/null", &device).unwrap();
            })
        };
        let started = Instant::now();
        let cancel = CancellationToken::new();
        wait_for_ports(&[link(&device)], Duration::from_secs(5), &cancel)
            .await
            .unwrap();
        assert!(started.elapsed() >= Duration::from_millis(400));
        appear.await.unwrap();
        std::fs::remove_file(&device).unwrap();
    }

    #[tokio::test]
    async fn a_device_still_missing_after_the_wait_is_one_line_naming_it() {
        let device = scratch("never");
        let cancel = CancellationToken::new();
        let error = wait_for_ports(&[link(&device)], Duration::from_millis(300), &cancel)
            .await
            .unwrap_err();
        assert!(
            error.contains("does not exist") && error.contains(&device.display().to_string()),
            "{error}"
        );
        assert!(!error.contains('\n'), "{error}");
    }

    #[tokio::test]
    async fn a_device_that_cannot_be_opened_is_not_waited_for() {
        // A directory exists but is no port: a configuration error, reported at once.
        let started = Instant::now();
        let cancel = CancellationToken::new();
        let error = wait_for_ports(
            &[link(&std::env::temp_dir())],
            Duration::from_secs(30),
            &cancel,
        )
        .await
        .unwrap_err();
        assert!(error.contains("cannot open"), "{error}");
        assert!(started.elapsed() < Duration::from_secs(5));
    }
}
