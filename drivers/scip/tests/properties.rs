//! Property tests: encoder-to-decoder round trips, arbitrary bytes never panic, a corrupted
//! stream loses only the replies its flipped bytes touch, and a device and a bare receiver fed
//! the same bytes report the same data.

use std::time::Duration;

use proptest::prelude::*;
use scip::encoding::{encode_value, push_data_blocks, push_summed_line};
use scip::{
    Body, Command, DataKind, Decoder, Device, DeviceConfig, Emulator, Event, Model, Receiver,
    StepRange,
};

/// Replies a UTM-30LX sends in a session, each complete, for mixing with garbage.
fn session_replies() -> Vec<Vec<u8>> {
    let mut sensor = Emulator::new(Model::utm_30lx());
    let mut replies = Vec::new();
    let take = |sensor: &mut Emulator| {
        let mut out = Vec::new();
        sensor.drain_output(&mut out);
        out
    };
    for command in [
        &b"QT\n"[..],
        b"VV\n",
        b"PP\n",
        b"TM0\n",
        b"TM1\n",
        b"TM2\n",
        b"BM\n",
    ] {
        sensor.handle_input(command);
        replies.push(take(&mut sensor));
    }
    sensor.handle_input(b"MD0000108001000\n");
    replies.push(take(&mut sensor));
    for i in 0..3u32 {
        sensor
            .push_scan(16_777_000 + 300 * i, &[1000 + i; 1081], None)
            .unwrap();
        replies.push(take(&mut sensor));
    }
    replies
}

fn data_kind() -> impl Strategy<Value = DataKind> {
    prop_oneof![
        Just(DataKind::Distance),
        Just(DataKind::ShortDistance),
        Just(DataKind::DistanceIntensity)
    ]
}

/// Sensor side of a scan reply, built from the encoding primitives.
fn scan_reply(
    echo: &[u8],
    streamed: bool,
    kind: DataKind,
    timestamp: u32,
    values: &[(u32, u32)],
) -> Vec<u8> {
    let mut out = echo.to_vec();
    out.push(b'\n');
    push_summed_line(if streamed { b"99" } else { b"00" }, &mut out);
    let mut ts = Vec::new();
    encode_value(timestamp, 4, &mut ts);
    push_summed_line(&ts, &mut out);
    let mut data = Vec::new();
    for &(range, intensity) in values {
        encode_value(range, kind.value_width(), &mut data);
        if kind == DataKind::DistanceIntensity {
            encode_value(intensity, kind.value_width(), &mut data);
        }
    }
    push_data_blocks(&data, &mut out);
    out.push(b'\n');
    out
}

fn chunked_feed(
    decoder: &mut Decoder,
    bytes: &[u8],
    cuts: &[usize],
    mut on: impl FnMut(Result<scip::Reply<'_>, scip::DecodeError>),
) {
    let mut start = 0;
    for &cut in cuts.iter().chain(std::iter::once(&bytes.len())) {
        let end = cut.clamp(start, bytes.len());
        decoder.feed(&bytes[start..end], &mut on);
        start = end;
    }
}

proptest! {
    #[test]
    fn scans_round_trip_through_encoder_and_decoder(
        kind in data_kind(),
        streamed in any::<bool>(),
        start in 0u16..2000,
        len in 1u16..400,
        cluster in 0u8..4,
        interval in 0u8..10,
        count in 0u8..100,
        timestamp in 0u32..(1 << 24),
        seed in any::<u64>(),
        cuts in proptest::collection::vec(0usize..8000, 0..20),
    ) {
        let range = StepRange { start, end: start + len - 1, cluster };
        let command = if streamed {
            Command::Stream { data: kind, range, interval, count }
        } else {
            Command::Get { data: kind, range }
        };
        let mut echo = Vec::new();
        command.encode(&mut echo).unwrap();
        echo.pop();
        let max = (1u32 << (6 * kind.value_width())) - 1;
        let mut state = seed | 1;
        let values: Vec<(u32, u32)> = (0..range.value_count())
            .map(|_| {
                state ^= state << 13; state ^= state >> 7; state ^= state << 17;
                ((state as u32) % (max + 1), ((state >> 32) as u32) % (max + 1))
            })
            .collect();
        let bytes = scan_reply(&echo, streamed, kind, timestamp, &values);
        let mut cuts = cuts;
        cuts.sort_unstable();
        let mut decoder = Decoder::new();
        let mut seen = 0;
        chunked_feed(&mut decoder, &bytes, &cuts, |reply| {
            let reply = reply.expect("well-formed reply decodes");
            let Body::Scan(scan) = reply.body else { panic!("scan expected") };
            assert_eq!(scan.data, kind);
            assert_eq!(scan.range, range);
            assert_eq!(scan.timestamp, timestamp);
            assert_eq!(scan.stream.map(|s| (s.interval, s.remaining)), streamed.then_some((interval, count)));
            let ranges: Vec<u32> = values.iter().map(|v| v.0).collect();
            assert_eq!(scan.ranges, ranges.as_slice());
            if kind == DataKind::DistanceIntensity {
                let intensities: Vec<u32> = values.iter().map(|v| v.1).collect();
                assert_eq!(scan.intensities, intensities.as_slice());
            } else {
                assert!(scan.intensities.is_empty());
            }
            seen += 1;
        });
        prop_assert_eq!(seen, 1);
    }

    #[test]
    fn decoder_never_panics_on_arbitrary_bytes(
        bytes in proptest::collection::vec(any::<u8>(), 0..4000),
        cuts in proptest::collection::vec(0usize..4000, 0..20),
    ) {
        let mut cuts = cuts;
        cuts.sort_unstable();
        let mut decoder = Decoder::with_max_frame(512);
        chunked_feed(&mut decoder, &bytes, &cuts, |reply| {
            if let Err(e) = reply {
                assert!(!e.to_string().contains('\n'));
            }
        });
        // After garbage, a clean reply behind an empty line still decodes.
        let mut ok = 0;
        decoder.feed(b"\n\nQT\n00P\n\n", |reply| ok += usize::from(reply.is_ok()));
        prop_assert!(ok >= 1);
    }

    #[test]
    fn corrupted_stream_loses_only_replies_its_flips_touch(seed in any::<u64>()) {
        const SCANS: usize = 200;
        let mut sensor = Emulator::new(Model::utm_30lx());
        sensor.handle_input(b"MD0000002001000\n");
        let mut bytes = Vec::new();
        sensor.drain_output(&mut bytes);
        let mut bounds = vec![0usize];
        bounds.push(bytes.len());
        for i in 0..SCANS {
            let ranges: Vec<u32> = (0..1081).map(|s| 1000 + i as u32 + s).collect();
            sensor.push_scan(1000 + 25 * i as u32, &ranges, None).unwrap();
            sensor.drain_output(&mut bytes);
            bounds.push(bytes.len());
        }
        // Flip one bit in 1% of the bytes.
        let mut state = seed | 1;
        let mut next = || { state ^= state << 13; state ^= state >> 7; state ^= state << 17; state };
        let flips = bytes.len() / 100;
        let mut hit = vec![false; bytes.len()];
        for _ in 0..flips {
            let at = (next() as usize) % bytes.len();
            bytes[at] ^= 1 << (next() % 8);
            hit[at] = true;
        }
        // Reply r spans bounds[r]..bounds[r+1]; reply 0 is the MD acknowledgement.
        let replies = bounds.len() - 1;
        let corrupted: Vec<bool> = (0..replies).map(|r| hit[bounds[r]..bounds[r + 1]].iter().any(|&h| h)).collect();
        // A flip in a reply's two closing line feeds merges it with the next reply.
        let merged: Vec<bool> = (0..replies).map(|r| r > 0 && hit[bounds[r] - 2..bounds[r]].iter().any(|&h| h)).collect();

        let mut cuts: Vec<usize> = (0..50).map(|_| (next() as usize) % bytes.len()).collect();
        cuts.sort_unstable();
        let mut decoder = Decoder::new();
        let mut decoded = vec![false; replies];
        let mut errors = 0usize;
        let mut undetected = 0usize;
        let mut offset = 0;
        let mut chunk_start = 0;
        for &cut in cuts.iter().chain(std::iter::once(&bytes.len())) {
            let mut chunk = &bytes[chunk_start..cut.max(chunk_start)];
            chunk_start = cut.max(chunk_start);
            while !chunk.is_empty() {
                let used = decoder.push(chunk);
                chunk = &chunk[used..];
                offset += used;
                match decoder.reply() {
                    None => {}
                    Some(Err(_)) => errors += 1,
                    Some(Ok(reply)) => {
                        // The reply whose bytes end where this frame ended.
                        let r = bounds.partition_point(|&b| b < offset) - 1;
                        let Body::Scan(scan) = reply.body else { continue };
                        let i = (r - 1) as u32;
                        let expected: Vec<u32> = (0..21).map(|s| 1000 + i + s).collect();
                        let exact = scan.ranges == expected.as_slice() && scan.timestamp == 1000 + 25 * i;
                        prop_assert!(exact || corrupted[r], "clean reply {} decoded wrongly", r);
                        // Two flips can cancel in a 6-bit sum; those are counted, not hidden.
                        undetected += usize::from(!exact);
                        decoded[r] = exact;
                    }
                }
            }
        }
        let mut lost = 0;
        for r in 1..replies {
            if !corrupted[r] && !merged[r] {
                prop_assert!(decoded[r], "clean reply {} was lost", r);
            }
            lost += usize::from(!decoded[r]);
        }
        let damaged = (1..replies).filter(|&r| corrupted[r] || merged[r]).count();
        prop_assert!(lost <= damaged);
        prop_assert!(lost == 0 || errors > 0, "losses must be reported as errors");
        prop_assert!(undetected * 20 <= damaged.max(20), "{} undetected of {} damaged", undetected, damaged);
    }

    /// Whatever the bytes, their chunking, the handshake's phase and its timeouts, the device
    /// reports exactly the data a bare receiver does, and neither panics.
    #[test]
    fn device_and_receiver_report_the_same_data_from_any_bytes(
        pieces in proptest::collection::vec(
            prop_oneof![
                (0usize..11).prop_map(Err),
                proptest::collection::vec(any::<u8>(), 0..40).prop_map(Ok),
            ],
            0..40,
        ),
        cuts in proptest::collection::vec(0usize..60_000, 0..30),
        steps_ms in proptest::collection::vec(0u64..1500, 30),
    ) {
        let replies = session_replies();
        let bytes: Vec<u8> = pieces
            .iter()
            .flat_map(|p| match p {
                Err(i) => replies[*i].clone(),
                Ok(garbage) => garbage.clone(),
            })
            .collect();
        let mut cuts: Vec<usize> = cuts.into_iter().map(|c| c % (bytes.len() + 1)).collect();
        cuts.sort_unstable();
        cuts.push(bytes.len());
        let mut now = Duration::from_secs(1);
        let mut device = Device::new(DeviceConfig::default(), now);
        let mut receiver = Receiver::new();
        let (mut live, mut replayed) = (Vec::new(), Vec::new());
        let mut start = 0;
        for (cut, step) in cuts.into_iter().zip(steps_ms.into_iter().cycle()) {
            let chunk = &bytes[start..cut];
            start = cut;
            while device.poll_transmit(now).is_some() {}
            device.handle_input(now, chunk);
            receiver.handle_input(now, chunk);
            now += Duration::from_millis(step);
            if device.poll_timeout().is_some_and(|t| t <= now) {
                device.handle_timeout(now);
            }
            live.extend(std::iter::from_fn(|| device.poll_event()).filter(Event::is_data));
            replayed.extend(std::iter::from_fn(|| receiver.poll_event()));
        }
        prop_assert_eq!(live, replayed);
    }
}
