//! Encoder-to-decoder round trips, "never panics on arbitrary bytes", and a device and a bare
//! receiver fed the same bytes report the same data.

mod support;

use std::time::Duration;

use proptest::prelude::*;
use xbus::mtdata2::encode_floats;
use xbus::{
    encode_frame, items, Command, CoordinateSystem, DataId, DataItem, DataType, Device,
    DeviceConfig, Event, Framer, OutputConfiguration, OutputEntry, Precision, Receiver,
    SampleTimeWrap, DEFAULT_MAX_PAYLOAD, MAX_OUTPUTS,
};

/// Feeds `wire` cut at `cuts` and returns the frames.
fn decode_in_chunks(wire: &[u8], cuts: &[usize]) -> Vec<(u8, Vec<u8>)> {
    let mut framer = Framer::new(xbus::DEFAULT_MAX_PAYLOAD);
    let mut bounds: Vec<usize> = cuts.iter().map(|c| c % (wire.len() + 1)).collect();
    bounds.push(0);
    bounds.push(wire.len());
    bounds.sort_unstable();
    let mut frames = Vec::new();
    for w in bounds.windows(2) {
        let mut chunk = &wire[w[0]..w[1]];
        while let Some(r) = framer.decode(&mut chunk) {
            let f = r.expect("clean stream");
            frames.push((f.mid, f.payload.to_vec()));
        }
    }
    frames
}

fn float_types() -> impl Strategy<Value = (DataType, usize)> {
    prop::sample::select(vec![
        (DataType::Temperature, 1),
        (DataType::LatLon, 2),
        (DataType::Acceleration, 3),
        (DataType::RateOfTurn, 3),
        (DataType::DeltaV, 3),
        (DataType::EulerAngles, 3),
        (DataType::MagneticField, 3),
        (DataType::FreeAcceleration, 3),
        (DataType::Quaternion, 4),
        (DataType::DeltaQ, 4),
        (DataType::RotationMatrix, 9),
    ])
}

fn values_of(item: DataItem<'_>) -> (Vec<f64>, CoordinateSystem, Precision) {
    macro_rules! v {
        ($x:expr) => {
            ($x.values.to_vec(), $x.frame, $x.precision)
        };
    }
    match item {
        DataItem::Temperature(x) => v!(x),
        DataItem::LatLon(x) => v!(x),
        DataItem::Acceleration(x) | DataItem::RateOfTurn(x) | DataItem::DeltaV(x) => v!(x),
        DataItem::EulerAngles(x) | DataItem::MagneticField(x) | DataItem::FreeAcceleration(x) => {
            v!(x)
        }
        DataItem::Quaternion(x) | DataItem::DeltaQ(x) => v!(x),
        DataItem::RotationMatrix(x) => v!(x),
        other => panic!("unexpected {other:?}"),
    }
}

proptest! {
    #[test]
    fn frames_round_trip_in_any_chunking(
        messages in prop::collection::vec((any::<u8>(), prop::collection::vec(any::<u8>(), 0..700)), 1..6),
        cuts in prop::collection::vec(any::<usize>(), 0..20),
    ) {
        let mut wire = Vec::new();
        for (m, payload) in &messages {
            encode_frame(*m, payload, &mut wire).unwrap();
        }
        prop_assert_eq!(decode_in_chunks(&wire, &cuts), messages);
    }

    #[test]
    fn output_configuration_round_trips(
        entries in prop::collection::vec((any::<u16>(), any::<u16>()), 0..=MAX_OUTPUTS),
    ) {
        let entries: Vec<OutputEntry> = entries.iter().map(|&(id, frequency)| OutputEntry { id: DataId(id), frequency }).collect();
        let config = OutputConfiguration::new(&entries).unwrap();
        let mut wire = Vec::new();
        Command::SetOutputConfiguration(config).encode(&mut wire);
        let frames = decode_in_chunks(&wire, &[]);
        prop_assert_eq!(frames.len(), 1);
        prop_assert_eq!(frames[0].0, 0xC0);
        let back = OutputConfiguration::from_payload(&frames[0].1).unwrap();
        prop_assert_eq!(back.entries(), &entries[..]);
    }

    #[test]
    fn float_items_round_trip_in_every_precision_and_frame(
        packets in prop::collection::vec(
            (float_types(), prop::sample::select(Precision::ALL.to_vec()), prop::sample::select(CoordinateSystem::ALL.to_vec()),
             prop::collection::vec(-2047.0f64..2047.0, 9)),
            1..8),
    ) {
        let mut payload = Vec::new();
        for ((t, n), precision, frame, values) in &packets {
            prop_assert!(encode_floats(t.id(*precision, *frame), &values[..*n], &mut payload));
        }
        let decoded: Vec<_> = items(&payload).collect::<Result<_, _>>().unwrap();
        prop_assert_eq!(decoded.len(), packets.len());
        for (item, ((_, n), precision, frame, values)) in decoded.into_iter().zip(&packets) {
            let (got, got_frame, got_precision) = values_of(item);
            prop_assert_eq!((got_frame, got_precision), (*frame, *precision));
            for (g, w) in got.iter().zip(&values[..*n]) {
                let tolerance = match precision {
                    Precision::Float32 => w.abs() * 1e-7,
                    Precision::Fp1220 => 0.5 / f64::from(1u32 << 20),
                    Precision::Fp1632 => 0.5 / 4_294_967_296.0,
                    Precision::Float64 => 0.0,
                };
                prop_assert!((g - w).abs() <= tolerance, "{:?}: {} vs {}", precision, g, w);
            }
        }
    }

    #[test]
    fn arbitrary_bytes_never_panic(
        bytes in prop::collection::vec(any::<u8>(), 0..2000),
        cuts in prop::collection::vec(any::<usize>(), 0..10),
    ) {
        for item in items(&bytes) {
            let _ = item;
        }
        let _ = xbus::Measurement::from_payload(&bytes);
        let _ = OutputConfiguration::from_payload(&bytes);
        let mut device = Device::new(DeviceConfig::default(), Duration::ZERO);
        let mut receiver = Receiver::new(SampleTimeWrap::FromProductCode, DEFAULT_MAX_PAYLOAD);
        let mut framer = Framer::new(64);
        let mut at = 0;
        for cut in cuts.iter().map(|c| c % (bytes.len() + 1)) {
            let (from, to) = (at.min(cut), at.max(cut));
            device.handle_input(Duration::from_millis(to as u64), &bytes[from..to]);
            receiver.handle_input(Duration::from_millis(to as u64), &bytes[from..to]);
            let mut chunk = &bytes[from..to];
            while framer.decode(&mut chunk).is_some() {}
            at = cut;
        }
        device.handle_timeout(Duration::from_secs(100));
        let live: Vec<Event> = std::iter::from_fn(|| device.poll_event()).filter(Event::is_data).collect();
        let replayed: Vec<Event> = std::iter::from_fn(|| receiver.poll_event()).collect();
        prop_assert_eq!(live, replayed);
        while device.poll_transmit(Duration::from_secs(100)).is_some() {}
    }

    #[test]
    /// Whatever the replies, their order, the handshake's phase and its timeouts, the device
    /// reports exactly the data a bare receiver does, and neither panics.
    fn device_and_receiver_report_the_same_data_from_any_frames(
        payloads in prop::collection::vec((prop::sample::select(vec![0x01u8, 0x13, 0x1D, 0x31, 0x11, 0x36, 0x3E, 0x42, 0xC1]),
                                           prop::collection::vec(any::<u8>(), 0..300),
                                           0u64..800), 0..30),
    ) {
        let config = DeviceConfig::default();
        let mut now = Duration::from_secs(1);
        let mut device = Device::new(config, now);
        let mut receiver = Receiver::new(config.sample_time_wrap, config.max_payload);
        let (mut live, mut replayed) = (Vec::new(), Vec::new());
        for (m, p, step_ms) in &payloads {
            let mut wire = Vec::new();
            encode_frame(*m, p, &mut wire).unwrap();
            while device.poll_transmit(now).is_some() {}
            device.handle_input(now, &wire);
            receiver.handle_input(now, &wire);
            now += Duration::from_millis(*step_ms);
            if device.poll_timeout().is_some_and(|t| t <= now) {
                device.handle_timeout(now);
            }
            live.extend(std::iter::from_fn(|| device.poll_event()).filter(Event::is_data));
            replayed.extend(std::iter::from_fn(|| receiver.poll_event()));
        }
        prop_assert_eq!(live, replayed);
    }
}
