//! The MAVLink task: sends the messages the fusion thread decided on (a [`MavlinkStream`] there
//! picks them on estimate time, so a replay sends the same ones) and the heartbeat on the host
//! clock. The fusion hands messages over a bounded channel without ever waiting: a link that
//! cannot keep up loses messages, never holds up the fusion.
//!
//! It also measures the scan-to-MAVLink latency: a message carrying an odometry epoch comes
//! with the host time its closing scan chunk was read, compared with the time the link's write
//! returned.
//!
//! [`MavlinkStream`]: super::mavlink_out::MavlinkStream

use super::latency::LatencyLog;
use super::link::{Link, LinkError};
use super::mavlink_out::{heartbeat, MavlinkStream, RateLimiter, HEARTBEAT_RATE_HZ};
use super::outputs::{OutputError, Outputs};
use super::sink::Autopilot;
use crate::estimate::Estimate;
use mavlink::dialects::ardupilotmega::{MavMessage, MavState};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// How often the heartbeat schedule is checked; the heartbeat itself goes out at 1 Hz.
const HEARTBEAT_POLL: Duration = Duration::from_millis(100);

/// One message for the autopilot.
#[derive(Debug, Clone)]
pub(crate) struct Outgoing {
    pub message: MavMessage,
    /// Host ns at which the scan chunk that closed the epoch this message is the first to
    /// carry was read; `None` for a message carrying no new epoch.
    pub epoch_read_ns: Option<u64>,
}

/// After this long with no message from the fusion, the estimates have stopped (the IMU is away,
/// or every sensor): the HEARTBEAT then says CRITICAL, as it does for quality -1.
const SILENT_AFTER_S: f64 = 1.0;

/// Messages waiting for the link: a second of ODOMETRY at 50 Hz.
pub(crate) const QUEUE_MESSAGES: usize = 64;

/// The HEARTBEAT state the fusion thread decides and the MAVLink task sends at 1 Hz.
pub(crate) type SharedState = Arc<Mutex<MavState>>;

/// The fusion thread's end: decides with the profile's stream and hands over without waiting.
pub(crate) struct Feed {
    stream: MavlinkStream,
    messages: mpsc::Sender<Outgoing>,
    state: SharedState,
    /// Read time of the chunk that closed the newest epoch no message has carried yet.
    epoch_read_ns: Option<u64>,
    dropped: u64,
    falling_behind: bool,
}

impl Feed {
    pub(crate) fn new(
        stream: MavlinkStream,
        messages: mpsc::Sender<Outgoing>,
        state: SharedState,
    ) -> Self {
        Self {
            stream,
            messages,
            state,
            epoch_read_ns: None,
            dropped: 0,
            falling_behind: false,
        }
    }

    /// Hands over the STATUSTEXT an estimate called for and publishes the HEARTBEAT state.
    fn after_estimate(&mut self) {
        let text = self.stream.take_statustext();
        self.hand_over(text);
        *self.state.lock().unwrap_or_else(PoisonError::into_inner) = self.stream.system_state();
    }

    /// Messages lost because the link did not keep up.
    pub(crate) fn dropped(&self) -> u64 {
        self.dropped
    }

    fn hand_over(&mut self, message: Option<MavMessage>) {
        let Some(message) = message else {
            return;
        };
        let outgoing = Outgoing {
            message,
            epoch_read_ns: self.epoch_read_ns.take(),
        };
        match self.messages.try_send(outgoing) {
            Ok(()) if self.falling_behind => {
                self.falling_behind = false;
                tracing::info!(dropped = self.dropped, "the MAVLink link keeps up again");
            }
            Ok(()) => {}
            Err(mpsc::error::TrySendError::Full(_)) => {
                self.dropped += 1;
                if !self.falling_behind {
                    self.falling_behind = true;
                    tracing::warn!(
                        "the MAVLink link does not keep up: messages are dropped until it does \
                         (check the baud rate and the profile's rate_hz)"
                    );
                }
            }
            // The task has stopped and logged why.
            Err(mpsc::error::TrySendError::Closed(_)) => {}
        }
    }
}

/// The link task writes `mavlink.tlog` as it sends, stamped with wall-clock time, so the files
/// are not touched here.
impl Autopilot for Feed {
    type Error = OutputError;

    /// An IMU-rate estimate: sent at the steady rate.
    fn estimate(
        &mut self,
        estimate: &Estimate,
        _: Option<&mut Outputs>,
    ) -> Result<(), OutputError> {
        let message = self.stream.on_estimate(estimate.t, estimate);
        self.hand_over(message);
        self.after_estimate();
        Ok(())
    }

    /// The estimate of an epoch closed by the chunk read at `read_ns`: sent at once where the
    /// profile allows, else carried by the next message.
    fn epoch_estimate(
        &mut self,
        estimate: &Estimate,
        read_ns: u64,
        _: Option<&mut Outputs>,
    ) -> Result<(), OutputError> {
        self.epoch_read_ns = Some(read_ns);
        let message = self.stream.on_epoch_estimate(estimate);
        self.hand_over(message);
        self.after_estimate();
        Ok(())
    }
}

/// Runs until `cancel` or until the fusion drops its sender. `now_ns` is the host clock of the
/// chunks' read times, which also paces the heartbeat; `on_sent(frame)` sees every frame sent,
/// for `mavlink.tlog` (stamped by the caller with wall-clock time); `latency` gets one entry
/// per epoch-carrying message written. A send error ends the task: the caller decides whether
/// to reconnect.
pub(crate) async fn run(
    link: &Link,
    mut messages: mpsc::Receiver<Outgoing>,
    now_ns: impl Fn() -> u64,
    mut on_sent: impl FnMut(&[u8]),
    latency: &Mutex<LatencyLog>,
    state: &Mutex<MavState>,
    cancel: CancellationToken,
) -> Result<(), LinkError> {
    let mut heartbeat_poll = tokio::time::interval(HEARTBEAT_POLL);
    heartbeat_poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut heartbeats = RateLimiter::new(HEARTBEAT_RATE_HZ);
    let mut last_message_s: Option<f64> = None;
    loop {
        let outgoing = tokio::select! {
            () = cancel.cancelled() => return Ok(()),
            received = messages.recv() => match received {
                Some(outgoing) => {
                    last_message_s = Some(now_ns() as f64 * 1e-9);
                    outgoing
                }
                None => return Ok(()),
            },
            _ = heartbeat_poll.tick() => {
                let now_s = now_ns() as f64 * 1e-9;
                let silent = last_message_s.is_some_and(|t| now_s - t > SILENT_AFTER_S);
                let system_state = match silent {
                    true => MavState::MAV_STATE_CRITICAL,
                    false => *state.lock().unwrap_or_else(PoisonError::into_inner),
                };
                match heartbeats.ready(now_s) {
                    true => Outgoing {
                        message: heartbeat(system_state),
                        epoch_read_ns: None,
                    },
                    false => continue,
                }
            }
        };
        if let Some(frame) = link.send(&outgoing.message).await? {
            if let Some(read_ns) = outgoing.epoch_read_ns {
                let written_ns = now_ns();
                latency
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .add(read_ns, written_ns);
            }
            on_sent(&frame);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::link::LinkAddress;
    use crate::daemon::mavlink_out::{odometry, Identity, QualityPolicy, DEFAULT_COMPONENT_ID};
    use crate::estimate::IntegrityStatus;
    use mavlink::{MavlinkReader, MavlinkVersion};
    use nalgebra::{Matrix3, UnitQuaternion, Vector3};
    use tokio::net::UdpSocket;
    use tokio::time::timeout;

    fn estimate(t: f64) -> Estimate {
        Estimate {
            t,
            position: Vector3::new(t, 0.0, -1.0),
            velocity: Vector3::new(1.0, 0.0, 0.0),
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

    async fn link_to(autopilot: &UdpSocket) -> Link {
        let address = LinkAddress::UdpOut {
            host: "127.0.0.1".into(),
            port: autopilot.local_addr().unwrap().port(),
        };
        let identity = Identity {
            system_id: 1,
            component_id: DEFAULT_COMPONENT_ID,
        };
        Link::connect(&address, identity, None).await.unwrap()
    }

    #[tokio::test]
    async fn sends_what_the_fusion_decided_and_heartbeats_and_times_epoch_messages() {
        let autopilot = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let link = link_to(&autopilot).await;
        let (messages_tx, messages_rx) = mpsc::channel(8);
        let sent = Arc::new(Mutex::new(Vec::new()));
        let latency = Arc::new(Mutex::new(LatencyLog::new("scan-to-MAVLink")));
        let cancel = CancellationToken::new();
        let task = {
            let (sent, latency, cancel) = (sent.clone(), latency.clone(), cancel.clone());
            tokio::spawn(async move {
                let on_sent = |f: &[u8]| sent.lock().unwrap().push(f.to_vec());
                // The clock stands at 3 ms: one heartbeat, and 2 ms from a read at 1 ms.
                let now_ns = || 3_000_000;
                let state = Mutex::new(MavState::MAV_STATE_ACTIVE);
                run(
                    &link,
                    messages_rx,
                    now_ns,
                    on_sent,
                    &latency,
                    &state,
                    cancel,
                )
                .await
            })
        };
        let policy = QualityPolicy::default();
        for i in 0..3 {
            let e = estimate(f64::from(i));
            let message = odometry(&e, policy.quality(&e));
            let epoch_read_ns = (i == 1).then_some(1_000_000);
            messages_tx
                .send(Outgoing {
                    message,
                    epoch_read_ns,
                })
                .await
                .unwrap();
        }
        let mut buffer = [0u8; 300];
        let mut received = Vec::new();
        while received.len() < 4 {
            let (n, _) = timeout(Duration::from_secs(5), autopilot.recv_from(&mut buffer))
                .await
                .unwrap()
                .unwrap();
            received.push(buffer[..n].to_vec());
        }
        cancel.cancel();
        timeout(Duration::from_secs(5), task)
            .await
            .unwrap()
            .unwrap()
            .unwrap();

        let messages: Vec<MavMessage> = received
            .iter()
            .map(|f| {
                MavlinkReader::new(&f[..])
                    .read_message::<MavMessage>(MavlinkVersion::V2)
                    .unwrap()
                    .1
            })
            .collect();
        let heartbeats = messages
            .iter()
            .filter(|m| matches!(m, MavMessage::HEARTBEAT(_)))
            .count();
        let xs: Vec<f32> = messages
            .iter()
            .filter_map(|m| match m {
                MavMessage::ODOMETRY(o) => Some(o.x),
                _ => None,
            })
            .collect();
        assert_eq!(heartbeats, 1, "the clock stood still: one heartbeat only");
        assert_eq!(xs, [0.0, 1.0, 2.0], "in the order decided");
        assert_eq!(
            *sent.lock().unwrap(),
            received,
            "on_sent saw every frame on the wire"
        );
        let summary = latency.lock().unwrap().summary().unwrap();
        assert_eq!((summary.count, summary.median_us), (1, 2_000));
    }

    /// No estimate while the IMU is away, so no ODOMETRY: the HEARTBEAT must not go on saying
    /// ACTIVE from the last estimate.
    #[tokio::test]
    async fn the_heartbeat_says_critical_once_the_estimates_stop() {
        use std::sync::atomic::{AtomicU64, Ordering};
        let autopilot = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let link = link_to(&autopilot).await;
        let (messages_tx, messages_rx) = mpsc::channel(8);
        let clock = Arc::new(AtomicU64::new(1_000_000_000));
        let cancel = CancellationToken::new();
        let task = {
            let (clock, cancel) = (clock.clone(), cancel.clone());
            tokio::spawn(async move {
                let latency = Mutex::new(LatencyLog::new("scan-to-MAVLink"));
                let state = Mutex::new(MavState::MAV_STATE_ACTIVE);
                let now_ns = move || clock.load(Ordering::Relaxed);
                run(&link, messages_rx, now_ns, |_| {}, &latency, &state, cancel).await
            })
        };
        let e = estimate(1.0);
        let message = odometry(&e, QualityPolicy::default().quality(&e));
        messages_tx
            .send(Outgoing {
                message,
                epoch_read_ns: None,
            })
            .await
            .unwrap();
        let mut buffer = [0u8; 300];
        let mut states = Vec::new();
        let mut odometry_seen = false;
        while states.len() < 2 {
            let (n, _) = timeout(Duration::from_secs(5), autopilot.recv_from(&mut buffer))
                .await
                .unwrap()
                .unwrap();
            let (_, message) = MavlinkReader::new(&buffer[..n])
                .read_message::<MavMessage>(MavlinkVersion::V2)
                .unwrap();
            match message {
                MavMessage::HEARTBEAT(h) => states.push(h.system_status),
                MavMessage::ODOMETRY(_) => odometry_seen = true,
                _ => {}
            }
            if odometry_seen && !states.is_empty() {
                // 2 s without another estimate.
                clock.store(3_000_000_000, Ordering::Relaxed);
            }
        }
        cancel.cancel();
        timeout(Duration::from_secs(5), task)
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        assert_eq!(
            states,
            [MavState::MAV_STATE_ACTIVE, MavState::MAV_STATE_CRITICAL]
        );
    }

    #[tokio::test]
    async fn ends_when_the_fusion_drops_its_sender() {
        let autopilot = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let link = link_to(&autopilot).await;
        let (messages_tx, messages_rx) = mpsc::channel(1);
        drop(messages_tx);
        let latency = Mutex::new(LatencyLog::new("scan-to-MAVLink"));
        let result = timeout(
            Duration::from_secs(5),
            run(
                &link,
                messages_rx,
                || 0,
                |_| {},
                &latency,
                &Mutex::new(MavState::MAV_STATE_ACTIVE),
                CancellationToken::new(),
            ),
        )
        .await
        .unwrap();
        assert!(result.is_ok());
    }
}
