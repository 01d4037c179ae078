//! The decoder against bytes laid out by hand, against its own encoder in both encodings, and
//! against arbitrary and cut input.

use proptest::prelude::*;
use rosmsg::encode::{encode, encode_with};
use rosmsg::{
    decode, DecodeError, Echoes, Encoding, Header, Imu, Kind, LaserScan, Message,
    MultiEchoLaserScan, Quaternion, ScanInfo, TfMessage, Time, TransformStamped, Vector3,
};

fn info() -> ScanInfo {
    ScanInfo {
        angle_min: -2.0,
        angle_max: 2.0,
        angle_increment: 0.5,
        time_increment: 1e-4,
        scan_time: 0.025,
        range_min: 0.1,
        range_max: 30.0,
    }
}

fn scan() -> LaserScan {
    LaserScan {
        header: Header {
            seq: 7,
            stamp: Time {
                sec: 10,
                nanosec: 500,
            },
            frame_id: "l".into(),
        },
        info: info(),
        ranges: vec![1.0, 2.0],
        intensities: vec![],
    }
}

fn info_bytes() -> Vec<u8> {
    [-2.0f32, 2.0, 0.5, 1e-4, 0.025, 0.1, 30.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect()
}

#[test]
fn a_ros1_laser_scan_laid_out_by_hand() {
    let mut bytes = Vec::new();
    bytes.extend(7u32.to_le_bytes()); // seq
    bytes.extend(10u32.to_le_bytes());
    bytes.extend(500u32.to_le_bytes());
    bytes.extend(1u32.to_le_bytes()); // "l", no NUL
    bytes.push(b'l');
    bytes.extend(info_bytes()); // packed: no padding after the string
    bytes.extend(2u32.to_le_bytes());
    bytes.extend(1.0f32.to_le_bytes());
    bytes.extend(2.0f32.to_le_bytes());
    bytes.extend(0u32.to_le_bytes());
    let decoded = decode(Kind::LaserScan, Encoding::Ros1, &bytes).unwrap();
    assert_eq!(decoded, Message::LaserScan(scan()));
    assert_eq!(encode(&decoded, Encoding::Ros1), bytes);
}

#[test]
fn a_cdr_laser_scan_laid_out_by_hand_aligns_after_the_encapsulation_header() {
    let mut bytes = vec![0, 1, 0, 0];
    bytes.extend(10i32.to_le_bytes());
    bytes.extend(500u32.to_le_bytes());
    bytes.extend(2u32.to_le_bytes()); // "l" and its NUL
    bytes.extend([b'l', 0]);
    bytes.extend([0, 0]); // to the next multiple of 4 counted from after the header
    bytes.extend(info_bytes());
    bytes.extend(2u32.to_le_bytes());
    bytes.extend(1.0f32.to_le_bytes());
    bytes.extend(2.0f32.to_le_bytes());
    bytes.extend(0u32.to_le_bytes());
    let decoded = decode(Kind::LaserScan, Encoding::Cdr, &bytes).unwrap();
    let ros2 = LaserScan {
        header: Header {
            seq: 0,
            ..scan().header
        },
        ..scan()
    };
    assert_eq!(decoded, Message::LaserScan(ros2));
    assert_eq!(encode(&decoded, Encoding::Cdr), bytes);
}

#[test]
fn cdr_doubles_align_to_eight_from_after_the_header() {
    // Stamp (8) and "ab\0" behind its length (7) end at 15: the quaternion starts at 16.
    let mut bytes = vec![0, 1, 0, 0];
    bytes.extend(1i32.to_le_bytes());
    bytes.extend(2u32.to_le_bytes());
    bytes.extend(3u32.to_le_bytes());
    bytes.extend([b'a', b'b', 0, 0]);
    let values: Vec<f64> = (0..4 + 9 + 3 + 9 + 3 + 9).map(f64::from).collect();
    bytes.extend(values.iter().flat_map(|v| v.to_le_bytes()));
    let Message::Imu(imu) = decode(Kind::Imu, Encoding::Cdr, &bytes).unwrap() else {
        panic!("an Imu");
    };
    assert_eq!(imu.header.frame_id, "ab");
    assert_eq!(
        imu.orientation,
        Quaternion {
            x: 0.0,
            y: 1.0,
            z: 2.0,
            w: 3.0
        }
    );
    assert_eq!(imu.angular_velocity.x, 13.0);
    assert_eq!(imu.linear_acceleration.z, 27.0);
    assert_eq!(imu.linear_acceleration_covariance[8], 36.0);
}

#[test]
fn big_endian_cdr_is_read_too() {
    let message = Message::LaserScan(LaserScan {
        header: Header {
            seq: 0,
            ..scan().header
        },
        ..scan()
    });
    let bytes = encode_with(&message, Encoding::Cdr, true);
    assert_eq!(&bytes[..2], [0, 0]);
    assert_eq!(decode(Kind::LaserScan, Encoding::Cdr, &bytes), Ok(message));
}

#[test]
fn other_cdr_representations_are_refused_in_one_line() {
    let mut bytes = encode(&Message::LaserScan(scan()), Encoding::Cdr);
    bytes[1] = 0x07; // XCDR2 little-endian
    let error = decode(Kind::LaserScan, Encoding::Cdr, &bytes).unwrap_err();
    assert_eq!(error, DecodeError::Representation([0, 7]));
    assert!(error.to_string().contains("not plain CDR"), "{error}");
}

#[test]
fn a_length_past_the_end_is_refused_before_allocating() {
    let mut bytes = encode(&Message::LaserScan(scan()), Encoding::Ros1);
    let ranges_at = 4 + 8 + 5 + 28;
    bytes[ranges_at..ranges_at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
    let error = decode(Kind::LaserScan, Encoding::Ros1, &bytes).unwrap_err();
    assert!(
        matches!(error, DecodeError::CutShort { field: "ranges", at, .. } if at == ranges_at),
        "{error:?}"
    );
}

#[test]
fn nanoseconds_of_a_second_or_more_are_refused() {
    let mut bytes = encode(&Message::LaserScan(scan()), Encoding::Ros1);
    bytes[8..12].copy_from_slice(&1_000_000_000u32.to_le_bytes());
    let error = decode(Kind::LaserScan, Encoding::Ros1, &bytes).unwrap_err();
    assert_eq!(
        error.to_string(),
        "`header.stamp` has 1000000000 nanoseconds, a second or more"
    );
}

#[test]
fn negative_ros2_seconds_stay_negative() {
    let mut message = scan();
    message.header.seq = 0;
    message.header.stamp.sec = -3;
    let bytes = encode(&Message::LaserScan(message.clone()), Encoding::Cdr);
    let decoded = decode(Kind::LaserScan, Encoding::Cdr, &bytes).unwrap();
    assert_eq!(decoded, Message::LaserScan(message));
}

#[test]
fn schema_names_of_both_ros_versions_and_the_mcap_encodings_are_recognised() {
    assert_eq!(
        Kind::from_schema_name("sensor_msgs/msg/LaserScan"),
        Some(Kind::LaserScan)
    );
    assert_eq!(
        Kind::from_schema_name("sensor_msgs/MultiEchoLaserScan"),
        Some(Kind::MultiEchoLaserScan)
    );
    assert_eq!(
        Kind::from_schema_name("tf2_msgs/TFMessage"),
        Some(Kind::TfMessage)
    );
    assert_eq!(Kind::from_schema_name("sensor_msgs/msg/PointCloud2"), None);
    assert_eq!(Kind::from_schema_name("Imu"), None);
    for kind in Kind::ALL {
        assert_eq!(Kind::from_schema_name(kind.schema_name()), Some(kind));
    }
    assert_eq!(Encoding::from_mcap("ros1", "ros1msg"), Some(Encoding::Ros1));
    assert_eq!(Encoding::from_mcap("cdr", "ros2msg"), Some(Encoding::Cdr));
    assert_eq!(Encoding::from_mcap("cdr", "ros1msg"), None);
    assert_eq!(Encoding::from_mcap("json", "jsonschema"), None);
}

#[test]
fn echoes_give_each_beam_its_own_values() {
    let echoes = Echoes::from_beams([&[1.0f32, 1.5][..], &[], &[2.0]]);
    assert_eq!(echoes.beams(), 3);
    assert_eq!(echoes.beam(0), [1.0, 1.5]);
    assert!(echoes.beam(1).is_empty());
    assert_eq!(echoes.beam(2), [2.0]);
    assert!(echoes.beam(3).is_empty());
}

fn finite() -> impl Strategy<Value = f32> {
    -1e6f32..1e6
}

fn header(ros1: bool) -> impl Strategy<Value = Header> {
    (
        any::<u32>(),
        any::<u32>(),
        0u32..1_000_000_000,
        "[a-z_/]{0,12}",
    )
        .prop_map(move |(seq, sec, nanosec, frame_id)| Header {
            seq: if ros1 { seq } else { 0 },
            stamp: Time {
                // ROS 1 seconds are unsigned, ROS 2 seconds signed: each keeps its own range.
                sec: if ros1 {
                    i64::from(sec)
                } else {
                    i64::from(sec as i32)
                },
                nanosec,
            },
            frame_id,
        })
}

fn scan_info() -> impl Strategy<Value = ScanInfo> {
    proptest::array::uniform7(finite()).prop_map(|v| ScanInfo {
        angle_min: v[0],
        angle_max: v[1],
        angle_increment: v[2],
        time_increment: v[3],
        scan_time: v[4],
        range_min: v[5],
        range_max: v[6],
    })
}

fn vector3() -> impl Strategy<Value = Vector3> {
    proptest::array::uniform3(-1e9f64..1e9).prop_map(|[x, y, z]| Vector3 { x, y, z })
}

fn quaternion() -> impl Strategy<Value = Quaternion> {
    proptest::array::uniform4(-1f64..1.0).prop_map(|[x, y, z, w]| Quaternion { x, y, z, w })
}

fn echoes() -> impl Strategy<Value = Echoes> {
    proptest::collection::vec(proptest::collection::vec(finite(), 0..3), 0..20)
        .prop_map(|beams| Echoes::from_beams(beams.iter().map(Vec::as_slice)))
}

fn message(ros1: bool) -> impl Strategy<Value = Message> {
    let floats = || proptest::collection::vec(finite(), 0..40);
    let covariance = || proptest::array::uniform9(-1f64..1.0);
    prop_oneof![
        (header(ros1), scan_info(), floats(), floats()).prop_map(
            |(header, info, ranges, intensities)| {
                Message::LaserScan(LaserScan {
                    header,
                    info,
                    ranges,
                    intensities,
                })
            }
        ),
        (header(ros1), scan_info(), echoes(), echoes()).prop_map(
            |(header, info, ranges, intensities)| {
                Message::MultiEchoLaserScan(MultiEchoLaserScan {
                    header,
                    info,
                    ranges,
                    intensities,
                })
            }
        ),
        (
            header(ros1),
            quaternion(),
            vector3(),
            vector3(),
            covariance()
        )
            .prop_map(
                |(header, orientation, angular_velocity, linear_acceleration, covariance)| {
                    Message::Imu(Imu {
                        header,
                        orientation,
                        orientation_covariance: covariance,
                        angular_velocity,
                        angular_velocity_covariance: covariance,
                        linear_acceleration,
                        linear_acceleration_covariance: covariance,
                    })
                }
            ),
        proptest::collection::vec((header(ros1), "[a-z_]{0,9}", vector3(), quaternion()), 0..4)
            .prop_map(|transforms| Message::Tf(TfMessage {
                transforms: transforms
                    .into_iter()
                    .map(
                        |(header, child_frame_id, translation, rotation)| TransformStamped {
                            header,
                            child_frame_id,
                            translation,
                            rotation,
                        }
                    )
                    .collect(),
            })),
    ]
}

fn kind_of(message: &Message) -> Kind {
    match message {
        Message::LaserScan(_) => Kind::LaserScan,
        Message::MultiEchoLaserScan(_) => Kind::MultiEchoLaserScan,
        Message::Imu(_) => Kind::Imu,
        Message::Tf(_) => Kind::TfMessage,
    }
}

proptest! {
    #[test]
    fn any_bytes_decode_or_fail_in_one_line(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        for encoding in [Encoding::Ros1, Encoding::Cdr] {
            for kind in Kind::ALL {
                if let Err(e) = decode(kind, encoding, &bytes) {
                    prop_assert!(!e.to_string().contains('\n'));
                }
            }
        }
    }

    #[test]
    fn ros1_messages_round_trip(message in message(true)) {
        let bytes = encode(&message, Encoding::Ros1);
        prop_assert_eq!(decode(kind_of(&message), Encoding::Ros1, &bytes), Ok(message));
    }

    #[test]
    fn cdr_messages_round_trip_in_both_byte_orders(message in message(false), big in any::<bool>()) {
        let bytes = encode_with(&message, Encoding::Cdr, big);
        prop_assert_eq!(decode(kind_of(&message), Encoding::Cdr, &bytes), Ok(message));
    }

    #[test]
    fn every_cut_of_a_message_is_an_error_never_a_panic(
        message in message(false),
        cdr in any::<bool>(),
        cut in any::<prop::sample::Index>(),
    ) {
        let encoding = if cdr { Encoding::Cdr } else { Encoding::Ros1 };
        let bytes = encode(&message, encoding);
        let cut = cut.index(bytes.len());
        prop_assert!(decode(kind_of(&message), encoding, &bytes[..cut]).is_err());
    }

    #[test]
    fn flipped_bytes_never_panic(message in message(true), at in any::<prop::sample::Index>(), xor in 1u8..) {
        for encoding in [Encoding::Ros1, Encoding::Cdr] {
            let mut bytes = encode(&message, encoding);
            let at = at.index(bytes.len());
            bytes[at] ^= xor;
            let _ = decode(kind_of(&message), encoding, &bytes);
        }
    }
}
