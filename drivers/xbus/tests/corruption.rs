//! A stream with 1% of its bytes flipped, cut at random places: only corrupted frames are lost,
//! the losses are counted, nothing panics.

mod support;

use std::collections::HashSet;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use support::measuring_link;
use xbus::emulator::{EmulatorOptions, Sample};
use xbus::{DeviceConfig, Event, Framer, ImuOutput, Precision};

const FRAMES: usize = 3000;

#[test]
fn one_percent_flipped_bytes_lose_only_corrupted_frames() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x0D0C);
    // Float64 rates: payloads are long and full of arbitrary bytes, 0xFA included.
    let config = DeviceConfig {
        imu_output: ImuOutput::Rates,
        precision: Precision::Float64,
        ..DeviceConfig::default()
    };
    let mut link = measuring_link(config, EmulatorOptions::mti_630());

    let mut stream = Vec::new();
    let mut frame_ends = Vec::new();
    let mut samples = Vec::new();
    for i in 0..FRAMES {
        let acc = [
            rng.gen_range(-20.0..20.0),
            rng.gen_range(-20.0..20.0),
            rng.gen_range(-20.0..20.0),
        ];
        let gyro = [
            rng.gen_range(-5.0..5.0),
            rng.gen_range(-5.0..5.0),
            rng.gen_range(-5.0..5.0),
        ];
        let sample = Sample::from_rates(100 * i as u32, acc, gyro, 0.01);
        assert!(link.emulator.push_sample(&sample));
        link.emulator.drain_output(&mut stream);
        frame_ends.push(stream.len());
        samples.push(sample);
    }

    let mut corrupted = HashSet::new();
    for _ in 0..stream.len() / 100 {
        let at = rng.gen_range(0..stream.len());
        stream[at] ^= 1 << rng.gen_range(0..8);
        corrupted.insert(frame_ends.partition_point(|&end| end <= at));
    }

    let mut now = link.now;
    let mut rest = &stream[..];
    while !rest.is_empty() {
        let (chunk, tail) = rest.split_at(rng.gen_range(1..=200).min(rest.len()));
        rest = tail;
        now += std::time::Duration::from_millis(1);
        link.device.handle_input(now, chunk);
    }

    // A measurement is genuine when it is exactly the frame the emulator sent with its counter.
    let genuine = |m: &xbus::ImuMeasurement| -> Option<usize> {
        let i = usize::from(m.data.packet_counter?);
        let s = samples.get(i)?;
        let exact = m.data.sample_time_fine == Some(s.sample_time_fine)
            && m.data.acceleration.map(|a| a.values) == Some(s.acceleration)
            && m.data.rate_of_turn.map(|g| g.values) == Some(s.rate_of_turn);
        exact.then_some(i)
    };
    let mut delivered = HashSet::new();
    let mut impostors = 0;
    let mut previous_genuine = None;
    while let Some(event) = link.device.poll_event() {
        let Event::Measurement(m) = event else {
            continue;
        };
        match genuine(&m) {
            Some(i) => {
                if let Some(p) = previous_genuine {
                    // Between two genuine frames the reported gap is exactly what went missing.
                    assert_eq!(
                        usize::from(m.lost_packets),
                        i - p - 1,
                        "gap before frame {i}"
                    );
                }
                previous_genuine = Some(i);
                delivered.insert(i);
            }
            None => {
                impostors += 1;
                previous_genuine = None;
            }
        }
    }

    let intact: Vec<usize> = (0..FRAMES).filter(|i| !corrupted.contains(i)).collect();
    assert!(
        corrupted.len() > FRAMES / 2,
        "the test must corrupt many frames"
    );
    for i in &intact {
        assert!(delivered.contains(i), "intact frame {i} was lost");
    }
    // An 8-bit additive checksum passes two flips that cancel, so a few corrupted frames get
    // through; they must stay rare.
    assert!(
        impostors * 20 < corrupted.len(),
        "{impostors} corrupted frames passed"
    );
    let stats = link.device.stats();
    assert!(stats.framer.bad_checksums > 0 && stats.framer.skipped_bytes > 0);
    assert!(stats.lost_packets >= (FRAMES - delivered.len()) as u64 - 1);
}

#[test]
fn framer_alone_recovers_every_intact_frame_fed_byte_by_byte() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut stream = Vec::new();
    let mut payloads = Vec::new();
    for i in 0..500u32 {
        let len = rng.gen_range(0..300);
        let payload: Vec<u8> = (0..len)
            .map(|_| if rng.gen_bool(0.2) { 0xFA } else { rng.gen() })
            .collect();
        xbus::encode_frame((i % 200) as u8, &payload, &mut stream).unwrap();
        payloads.push((stream.len(), payload));
    }
    let mut hit = HashSet::new();
    for _ in 0..stream.len() / 100 {
        let at = rng.gen_range(0..stream.len());
        stream[at] = rng.gen();
        hit.insert(payloads.partition_point(|(end, _)| *end <= at));
    }
    let mut framer = Framer::new(xbus::DEFAULT_MAX_PAYLOAD);
    let mut got = Vec::new();
    for b in &stream {
        let mut one = std::slice::from_ref(b);
        while let Some(r) = framer.decode(&mut one) {
            if let Ok(f) = r {
                got.push(f.payload.to_vec());
            }
        }
    }
    let got: HashSet<Vec<u8>> = got.into_iter().collect();
    for (i, (_, p)) in payloads.iter().enumerate() {
        if !hit.contains(&i) {
            assert!(got.contains(p), "intact frame {i} lost");
        }
    }
}
