//! The MAVLink link to the autopilot: connection strings as users know them from MAVProxy and
//! QGroundControl, MAVLink 2 signing, and an async connection shared (`Arc<Link>`) between the
//! sender and a receive loop that answers TIMESYNC.
//!
//! Outgoing frames are serialised (and signed) here rather than inside the mavlink crate so that
//! the exact bytes put on the wire can also go to `mavlink.tlog`.

use super::mavlink_out::{timesync_reply, Identity};
use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::{
    AsyncConnection, AsyncMavConnection, MAVLinkMessageRaw, MAVLinkV2MessageRaw, MavHeader,
    SigningConfig, SigningData,
};
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use tokio::sync::Mutex;
use tokio_util::sync::CancellationToken;

const ADDRESS_FORMS: &str = "use serial:/dev/ttyAMA0:921600, udpout:HOST:PORT, udpin:ADDR:PORT, tcpout:HOST:PORT or tcpin:ADDR:PORT";

#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("MAVLink connection `{address}` is not valid: {reason}; {ADDRESS_FORMS}")]
    BadAddress { address: String, reason: String },
    #[error("cannot open MAVLink connection `{address}`: {source}")]
    Connect {
        address: String,
        source: std::io::Error,
    },
    #[error(
        "MAVLink signing key {0}: give 64 hex digits (32 bytes), e.g. from `openssl rand -hex 32`"
    )]
    BadKey(String),
    #[error("cannot read MAVLink signing key file {path}: {source}")]
    KeyFile {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("sending to the autopilot failed: {0}")]
    Send(String),
    #[error("receiving from the autopilot failed: {0}")]
    Receive(String),
}

/// A validated MAVLink connection string.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum LinkAddress {
    Serial { port: String, baud: u32 },
    UdpOut { host: String, port: u16 },
    UdpIn { host: String, port: u16 },
    TcpOut { host: String, port: u16 },
    TcpIn { host: String, port: u16 },
}

impl FromStr for LinkAddress {
    type Err = LinkError;

    fn from_str(address: &str) -> Result<Self, LinkError> {
        let bad = |reason: &str| LinkError::BadAddress {
            address: address.to_string(),
            reason: reason.to_string(),
        };
        let (scheme, rest) = address
            .split_once(':')
            .ok_or_else(|| bad("no scheme before the first `:`"))?;
        let (left, right) = rest
            .rsplit_once(':')
            .ok_or_else(|| bad("expected two `:`-separated parts after the scheme"))?;
        if left.is_empty() {
            return Err(bad("the device or host is empty"));
        }
        let host = left.to_string();
        let port = || match right.parse::<u16>() {
            Ok(port) if port > 0 => Ok(port),
            _ => Err(bad(&format!("`{right}` is not a port number (1-65535)"))),
        };
        match scheme {
            "serial" => match right.parse::<u32>() {
                Ok(baud) if baud > 0 => Ok(Self::Serial { port: host, baud }),
                _ => Err(bad(&format!("`{right}` is not a baud rate"))),
            },
            "udpout" => Ok(Self::UdpOut {
                host,
                port: port()?,
            }),
            "udpin" => Ok(Self::UdpIn {
                host,
                port: port()?,
            }),
            "tcpout" => Ok(Self::TcpOut {
                host,
                port: port()?,
            }),
            "tcpin" => Ok(Self::TcpIn {
                host,
                port: port()?,
            }),
            other => Err(bad(&format!("unknown scheme `{other}`"))),
        }
    }
}

impl fmt::Display for LinkAddress {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Serial { port, baud } => write!(f, "serial:{port}:{baud}"),
            Self::UdpOut { host, port } => write!(f, "udpout:{host}:{port}"),
            Self::UdpIn { host, port } => write!(f, "udpin:{host}:{port}"),
            Self::TcpOut { host, port } => write!(f, "tcpout:{host}:{port}"),
            Self::TcpIn { host, port } => write!(f, "tcpin:{host}:{port}"),
        }
    }
}

/// MAVLink 2 message signing: every frame we send is signed; frames from the autopilot must be
/// signed with the same key unless `allow_unsigned`.
#[derive(Clone, PartialEq, Eq)]
pub(crate) struct Signing {
    pub key: [u8; 32],
    pub link_id: u8,
    pub allow_unsigned: bool,
}

impl fmt::Debug for Signing {
    // The key is a secret: keep it out of logs.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Signing")
            .field("link_id", &self.link_id)
            .field("allow_unsigned", &self.allow_unsigned)
            .finish_non_exhaustive()
    }
}

impl Signing {
    fn config(&self) -> SigningConfig {
        SigningConfig::new(self.key, self.link_id, true, self.allow_unsigned)
    }
}

/// A 32-byte key from 64 hex digits (surrounding whitespace ignored).
pub(crate) fn parse_key_hex(text: &str) -> Result<[u8; 32], LinkError> {
    decode_hex_key(text).map_err(LinkError::BadKey)
}

fn decode_hex_key(text: &str) -> Result<[u8; 32], String> {
    let hex = text.trim();
    if hex.len() != 64 {
        return Err(format!("has {} characters", hex.len()));
    }
    let mut key = [0u8; 32];
    for (i, byte) in key.iter_mut().enumerate() {
        *byte = hex
            .get(2 * i..2 * i + 2)
            .and_then(|pair| u8::from_str_radix(pair, 16).ok())
            .ok_or_else(|| format!("has a non-hex digit near position {}", 2 * i))?;
    }
    Ok(key)
}

/// A key file holds either the 64 hex digits or the 32 raw bytes.
pub(crate) fn read_key_file(path: &Path) -> Result<[u8; 32], LinkError> {
    let bytes = std::fs::read(path).map_err(|source| LinkError::KeyFile {
        path: path.to_path_buf(),
        source,
    })?;
    let as_hex = decode_hex_key(&String::from_utf8_lossy(&bytes));
    match (as_hex, <[u8; 32]>::try_from(bytes.as_slice())) {
        (Ok(key), _) | (Err(_), Ok(key)) => Ok(key),
        (Err(problem), Err(_)) => Err(LinkError::BadKey(format!(
            "in {} {problem} and is not 32 raw bytes",
            path.display()
        ))),
    }
}

/// An open MAVLink link. Share it as `Arc<Link>` between the sender and [`Link::receive_loop`].
pub(crate) struct Link {
    connection: AsyncConnection<MavMessage>,
    identity: Identity,
    signing: Option<SigningData>,
    /// Sequence numbers must follow send order, so serialisation and write happen under it.
    sequence: Mutex<u8>,
}

impl Link {
    pub(crate) async fn connect(
        address: &LinkAddress,
        identity: Identity,
        signing: Option<Signing>,
    ) -> Result<Self, LinkError> {
        let text = address.to_string();
        let mut connection =
            mavlink::connect_async::<MavMessage>(&text)
                .await
                .map_err(|source| LinkError::Connect {
                    address: text,
                    source,
                })?;
        // Verification of incoming frames is the connection's; outgoing signing is ours.
        connection.setup_signing(signing.as_ref().map(Signing::config));
        Ok(Self {
            connection,
            identity,
            signing: signing.map(|s| SigningData::from_config(s.config())),
            sequence: Mutex::new(0),
        })
    }

    /// Sends one message and returns the frame exactly as written (for `mavlink.tlog`), or
    /// `None` when there is nobody to send to yet (`udpin` before the autopilot has spoken).
    pub(crate) async fn send(&self, message: &MavMessage) -> Result<Option<Vec<u8>>, LinkError> {
        let mut sequence = self.sequence.lock().await;
        let header = MavHeader {
            sequence: *sequence,
            ..self.identity.header()
        };
        let mut raw = MAVLinkV2MessageRaw::new();
        match &self.signing {
            Some(signing) => {
                raw.serialize_message_for_signing(header, message);
                signing.sign_message(&mut raw);
            }
            None => raw.serialize_message(header, message),
        }
        let frame = raw.raw_bytes().to_vec();
        let written = self
            .connection
            .send_raw(&MAVLinkMessageRaw::V2(raw))
            .await
            .map_err(|e| LinkError::Send(e.to_string()))?;
        if written == 0 {
            return Ok(None);
        }
        *sequence = sequence.wrapping_add(1);
        Ok(Some(frame))
    }

    pub(crate) async fn recv(&self) -> Result<(MavHeader, MavMessage), LinkError> {
        self.connection
            .recv()
            .await
            .map_err(|e| LinkError::Receive(e.to_string()))
    }

    /// Reads the autopilot until `cancel`: answers TIMESYNC requests stamped with `now_ns` (the
    /// clock of the estimates' `time_usec`) and hands every frame sent to `on_sent`.
    pub(crate) async fn receive_loop(
        &self,
        now_ns: impl Fn() -> i64,
        mut on_sent: impl FnMut(&[u8]),
        cancel: CancellationToken,
    ) -> Result<(), LinkError> {
        loop {
            let (header, message) = tokio::select! {
                () = cancel.cancelled() => return Ok(()),
                received = self.recv() => received?,
            };
            if let MavMessage::TIMESYNC(request) = &message {
                let reply = timesync_reply(request, &header, now_ns());
                if let Some(frame) = match reply {
                    Some(reply) => self.send(&reply).await?,
                    None => None,
                } {
                    on_sent(&frame);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::mavlink_out::{heartbeat, DEFAULT_COMPONENT_ID};
    use mavlink::dialects::ardupilotmega::MavState;
    use mavlink::dialects::ardupilotmega::TIMESYNC_DATA;
    use mavlink::{MavlinkReader, MavlinkVersion};
    use std::sync::Arc;
    use std::time::Duration;
    use tokio::net::UdpSocket;
    use tokio::time::timeout;

    const IDENTITY: Identity = Identity {
        system_id: 1,
        component_id: DEFAULT_COMPONENT_ID,
    };
    const KEY: [u8; 32] = [7; 32];

    #[test]
    fn connection_strings_parse_and_print_back() {
        for text in [
            "serial:/dev/ttyAMA0:921600",
            "udpout:127.0.0.1:14550",
            "udpin:0.0.0.0:14550",
            "tcpout:fc.local:5760",
            "tcpin:0.0.0.0:5760",
        ] {
            assert_eq!(text.parse::<LinkAddress>().unwrap().to_string(), text);
        }
        assert_eq!(
            "serial:/dev/ttyAMA0:921600".parse::<LinkAddress>().unwrap(),
            LinkAddress::Serial {
                port: "/dev/ttyAMA0".into(),
                baud: 921_600
            }
        );
    }

    #[test]
    fn bad_connection_strings_are_one_line_naming_the_problem() {
        for (text, needle) in [
            ("/dev/ttyAMA0", "no scheme"),
            ("udp:127.0.0.1:14550", "unknown scheme `udp`"),
            ("udpout:127.0.0.1", "two"),
            ("udpout:127.0.0.1:0", "port"),
            ("udpout:127.0.0.1:70000", "port"),
            ("serial:/dev/ttyAMA0:fast", "baud"),
            ("tcpout::5760", "empty"),
        ] {
            let err = text.parse::<LinkAddress>().unwrap_err().to_string();
            assert!(err.contains(needle), "{text}: {err}");
            assert!(err.contains(text) && !err.contains('\n'), "{err}");
        }
    }

    #[test]
    fn keys_from_hex_and_files() {
        let hex = "00112233445566778899aabbccddeeff00112233445566778899AABBCCDDEEFF";
        let key = parse_key_hex(&format!("{hex}\n")).unwrap();
        assert_eq!(key[1], 0x11);
        assert_eq!(key[31], 0xff);
        assert!(parse_key_hex("abcd")
            .unwrap_err()
            .to_string()
            .contains("64 hex digits"));
        assert!(parse_key_hex(&hex.replace('a', "g")).is_err());

        let dir = std::env::temp_dir();
        let hex_file = dir.join(format!("ladar-key-hex-{}", std::process::id()));
        std::fs::write(&hex_file, format!("{hex}\n")).unwrap();
        assert_eq!(read_key_file(&hex_file).unwrap(), key);
        let raw_file = dir.join(format!("ladar-key-raw-{}", std::process::id()));
        let raw = *b"0123456789abcdef0123456789abcdef"; // 32 raw bytes that happen to be text
        std::fs::write(&raw_file, raw).unwrap();
        assert_eq!(read_key_file(&raw_file).unwrap(), raw);
        std::fs::write(&hex_file, "abcd").unwrap();
        let err = read_key_file(&hex_file).unwrap_err().to_string();
        assert_eq!(err.matches("MAVLink signing key").count(), 1, "{err}");
        assert!(
            err.contains("has 4 characters") && err.contains("64 hex digits"),
            "{err}"
        );
        std::fs::remove_file(hex_file).unwrap();
        std::fs::remove_file(raw_file).unwrap();
        let missing = read_key_file(Path::new("/nonexistent/key"))
            .unwrap_err()
            .to_string();
        assert!(missing.contains("/nonexistent/key"));
        assert!(!format!(
            "{:?}",
            Signing {
                key: KEY,
                link_id: 1,
                allow_unsigned: false
            }
        )
        .contains('7'));
    }

    fn decode(bytes: &[u8]) -> (MavHeader, MavMessage) {
        MavlinkReader::new(bytes)
            .read_message::<MavMessage>(MavlinkVersion::V2)
            .unwrap()
    }

    #[tokio::test]
    async fn sends_over_udp_and_answers_timesync() {
        let autopilot = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let address = LinkAddress::UdpOut {
            host: "127.0.0.1".into(),
            port: autopilot.local_addr().unwrap().port(),
        };
        let link = Arc::new(Link::connect(&address, IDENTITY, None).await.unwrap());

        let mut buffer = [0u8; 300];
        for expected_sequence in 0..3u8 {
            let frame = link
                .send(&heartbeat(MavState::MAV_STATE_ACTIVE))
                .await
                .unwrap()
                .unwrap();
            let (n, _) = timeout(Duration::from_secs(5), autopilot.recv_from(&mut buffer))
                .await
                .unwrap()
                .unwrap();
            assert_eq!(
                &buffer[..n],
                &frame[..],
                "the frame returned is the frame sent"
            );
            let (header, message) = decode(&buffer[..n]);
            assert_eq!(header.sequence, expected_sequence);
            assert_eq!(
                (header.system_id, header.component_id),
                (1, DEFAULT_COMPONENT_ID)
            );
            assert!(matches!(message, MavMessage::HEARTBEAT(_)));
        }
        let (_, daemon) = {
            link.send(&heartbeat(MavState::MAV_STATE_ACTIVE))
                .await
                .unwrap();
            autopilot.recv_from(&mut buffer).await.unwrap()
        };

        let cancel = CancellationToken::new();
        let sent = Arc::new(std::sync::Mutex::new(Vec::<Vec<u8>>::new()));
        let receiver = {
            let (link, cancel, sent) = (link.clone(), cancel.clone(), sent.clone());
            tokio::spawn(async move {
                link.receive_loop(|| 42_000, |f| sent.lock().unwrap().push(f.to_vec()), cancel)
                    .await
            })
        };
        let request = MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 0,
            ts1: 777,
            ..Default::default()
        });
        let autopilot_header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        };
        let mut frame = Vec::new();
        mavlink::write_v2_msg(&mut frame, autopilot_header, &request).unwrap();
        autopilot.send_to(&frame, daemon).await.unwrap();
        let (n, _) = timeout(Duration::from_secs(5), autopilot.recv_from(&mut buffer))
            .await
            .unwrap()
            .unwrap();
        let (_, reply) = decode(&buffer[..n]);
        let MavMessage::TIMESYNC(reply) = reply else {
            panic!("expected TIMESYNC, got {reply:?}");
        };
        assert_eq!((reply.tc1, reply.ts1), (42_000, 777));
        assert_eq!((reply.target_system, reply.target_component), (1, 1));
        cancel.cancel();
        timeout(Duration::from_secs(5), receiver)
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        assert_eq!(sent.lock().unwrap().as_slice(), &[buffer[..n].to_vec()]);
    }

    #[tokio::test]
    async fn udpin_sends_nothing_until_the_autopilot_speaks() {
        let port = std::net::UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let address = LinkAddress::UdpIn {
            host: "127.0.0.1".into(),
            port,
        };
        let link = Link::connect(&address, IDENTITY, None).await.unwrap();
        assert_eq!(
            link.send(&heartbeat(MavState::MAV_STATE_ACTIVE))
                .await
                .unwrap(),
            None
        );

        let autopilot = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let mut hello = Vec::new();
        let autopilot_header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        };
        mavlink::write_v2_msg(
            &mut hello,
            autopilot_header,
            &heartbeat(MavState::MAV_STATE_ACTIVE),
        )
        .unwrap();
        autopilot
            .send_to(&hello, ("127.0.0.1", port))
            .await
            .unwrap();
        let (header, _) = timeout(Duration::from_secs(5), link.recv())
            .await
            .unwrap()
            .unwrap();
        assert_eq!(header.component_id, 1);
        let frame = link
            .send(&heartbeat(MavState::MAV_STATE_ACTIVE))
            .await
            .unwrap()
            .expect("a peer is known now");
        let mut buffer = [0u8; 64];
        let (n, _) = timeout(Duration::from_secs(5), autopilot.recv_from(&mut buffer))
            .await
            .unwrap()
            .unwrap();
        assert_eq!(&buffer[..n], &frame[..]);
        assert_eq!(
            decode(&buffer[..n]).0.sequence,
            0,
            "the unsent frame used no sequence number"
        );
    }

    async fn signed_heartbeat_accepted_by(receiver_key: [u8; 32]) -> bool {
        let port = std::net::UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let mut autopilot =
            mavlink::connect_async::<MavMessage>(&format!("udpin:127.0.0.1:{port}"))
                .await
                .unwrap();
        autopilot.setup_signing(Some(SigningConfig::new(receiver_key, 0, false, false)));
        let signing = Signing {
            key: KEY,
            link_id: 3,
            allow_unsigned: false,
        };
        let address = LinkAddress::UdpOut {
            host: "127.0.0.1".into(),
            port,
        };
        let link = Link::connect(&address, IDENTITY, Some(signing))
            .await
            .unwrap();
        let frame = link
            .send(&heartbeat(MavState::MAV_STATE_ACTIVE))
            .await
            .unwrap()
            .unwrap();
        assert_eq!(frame[2] & 0x01, 0x01, "the signed flag is set");
        assert_eq!(
            frame.len(),
            21 + 13,
            "a heartbeat plus the 13-byte signature"
        );
        let received = timeout(Duration::from_millis(500), autopilot.recv()).await;
        matches!(received, Ok(Ok((_, MavMessage::HEARTBEAT(_)))))
    }

    #[tokio::test]
    async fn signed_frames_pass_only_with_the_right_key() {
        assert!(signed_heartbeat_accepted_by(KEY).await);
        assert!(!signed_heartbeat_accepted_by([8; 32]).await);
    }

    #[tokio::test]
    async fn an_unreachable_serial_port_is_one_line() {
        let address: LinkAddress = "serial:/dev/nonexistent-autopilot:921600".parse().unwrap();
        let err = Link::connect(&address, IDENTITY, None)
            .await
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("/dev/nonexistent-autopilot") && !err.contains('\n'),
            "{err}"
        );
    }
}
