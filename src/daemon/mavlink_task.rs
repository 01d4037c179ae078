//! The MAVLink task: takes the latest [`Estimate`] from a watch channel (so a slow autopilot link
//! never holds up the fusion: it only ever sees the newest estimate), sends what the profile's
//! [`MavlinkStream`] decides, and the heartbeat on the host clock.
//!
//! Estimate messages are rate-limited on the estimate's own time, so replay at any speed sends
//! the same messages as the flight did.

use super::link::{Link, LinkError};
use super::mavlink_out::MavlinkStream;
use crate::estimate::Estimate;
use std::time::Duration;
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

/// How often the heartbeat schedule is checked; the heartbeat itself goes out at 1 Hz.
const HEARTBEAT_POLL: Duration = Duration::from_millis(100);

/// Runs until `cancel` or until the estimate sender is dropped. `now` is the host time in
/// seconds, which paces the heartbeat; `on_sent(frame)` sees every frame sent, for
/// `mavlink.tlog` (stamped by the caller with wall-clock time). A send error ends the task: the
/// caller decides whether to reconnect.
pub async fn run(
    link: &Link,
    mut stream: MavlinkStream,
    mut estimates: watch::Receiver<Option<Estimate>>,
    now: impl Fn() -> f64,
    mut on_sent: impl FnMut(&[u8]),
    cancel: CancellationToken,
) -> Result<(), LinkError> {
    let mut heartbeat_poll = tokio::time::interval(HEARTBEAT_POLL);
    heartbeat_poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        let message = tokio::select! {
            () = cancel.cancelled() => return Ok(()),
            changed = estimates.changed() => {
                if changed.is_err() {
                    return Ok(());
                }
                let latest = estimates.borrow_and_update().clone();
                latest.and_then(|estimate| stream.on_estimate(estimate.t, &estimate))
            }
            _ = heartbeat_poll.tick() => stream.heartbeat_due(now()),
        };
        if let Some(message) = message {
            if let Some(frame) = link.send(&message).await? {
                on_sent(&frame);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::link::LinkAddress;
    use crate::daemon::mavlink_out::{Identity, Profile, QualityPolicy, DEFAULT_COMPONENT_ID};
    use crate::estimate::IntegrityStatus;
    use mavlink::dialects::ardupilotmega::MavMessage;
    use mavlink::{MavlinkReader, MavlinkVersion};
    use nalgebra::{Matrix3, UnitQuaternion, Vector3};
    use std::sync::{Arc, Mutex};
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
            attitude_covariance: Matrix3::identity() * 1e-4,
            gyro_bias: Vector3::zeros(),
            accel_bias: Vector3::zeros(),
            reset_counter: 0,
            integrity: Some(IntegrityStatus::Ok),
            since_last_fused: 0.0,
            degraded: false,
        }
    }

    #[tokio::test]
    async fn sends_odometry_and_heartbeats_to_the_autopilot() {
        let autopilot = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let address = LinkAddress::UdpOut {
            host: "127.0.0.1".into(),
            port: autopilot.local_addr().unwrap().port(),
        };
        let identity = Identity {
            system_id: 1,
            component_id: DEFAULT_COMPONENT_ID,
        };
        let link = Link::connect(&address, identity, None).await.unwrap();
        let stream = MavlinkStream::new(Profile::Px4, 30.0, QualityPolicy::default());
        let (estimates_tx, estimates_rx) = watch::channel(None);
        let sent = Arc::new(Mutex::new(Vec::new()));
        let cancel = CancellationToken::new();
        let task = {
            let (sent, cancel) = (sent.clone(), cancel.clone());
            tokio::spawn(async move {
                let on_sent = |f: &[u8]| sent.lock().unwrap().push(f.to_vec());
                run(&link, stream, estimates_rx, || 0.0, on_sent, cancel).await
            })
        };

        let mut buffer = [0u8; 300];
        let mut received = Vec::new();
        for i in 0..3 {
            estimates_tx.send(Some(estimate(f64::from(i)))).unwrap();
            // One heartbeat (the clock stands still at 0) plus one ODOMETRY per estimate; waiting
            // for each keeps the watch channel from merging estimates.
            while received.len() < i as usize + 2 {
                let (n, _) = timeout(Duration::from_secs(5), autopilot.recv_from(&mut buffer))
                    .await
                    .unwrap()
                    .unwrap();
                received.push(buffer[..n].to_vec());
            }
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
        assert_eq!(xs, [0.0, 1.0, 2.0]);
        assert_eq!(
            *sent.lock().unwrap(),
            received,
            "on_sent saw every frame on the wire"
        );
    }

    #[tokio::test]
    async fn ends_when_the_fusion_drops_its_sender() {
        let autopilot = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let address = LinkAddress::UdpOut {
            host: "127.0.0.1".into(),
            port: autopilot.local_addr().unwrap().port(),
        };
        let identity = Identity {
            system_id: 1,
            component_id: DEFAULT_COMPONENT_ID,
        };
        let link = Link::connect(&address, identity, None).await.unwrap();
        let stream = MavlinkStream::new(Profile::Ardupilot, 10.0, QualityPolicy::default());
        let (estimates_tx, estimates_rx) = watch::channel(None);
        drop(estimates_tx);
        let result = timeout(
            Duration::from_secs(5),
            run(
                &link,
                stream,
                estimates_rx,
                || 0.0,
                |_| {},
                CancellationToken::new(),
            ),
        )
        .await
        .unwrap();
        assert!(result.is_ok());
    }
}
