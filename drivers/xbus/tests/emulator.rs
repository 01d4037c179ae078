//! The emulator honours the configured outputs, rates, precisions and frames.

use xbus::emulator::{Emulator, EmulatorOptions, Sample};
use xbus::{
    mid, CoordinateSystem, DataType, Framer, Measurement, OutputConfiguration, OutputEntry,
    Precision, EVERY_PACKET,
};

fn frames(emulator: &mut Emulator) -> Vec<(u8, Vec<u8>)> {
    let mut bytes = Vec::new();
    emulator.drain_output(&mut bytes);
    let mut framer = Framer::new(xbus::DEFAULT_MAX_PAYLOAD);
    let mut rest = &bytes[..];
    let mut out = Vec::new();
    while let Some(r) = framer.decode(&mut rest) {
        let f = r.unwrap();
        out.push((f.mid, f.payload.to_vec()));
    }
    out
}

#[test]
fn slower_outputs_appear_on_every_kth_packet() {
    let entry = |t: DataType, p, c, frequency| OutputEntry {
        id: t.id(p, c),
        frequency,
    };
    let output = OutputConfiguration::new(&[
        entry(
            DataType::PacketCounter,
            Precision::Float32,
            CoordinateSystem::Enu,
            EVERY_PACKET,
        ),
        entry(
            DataType::Acceleration,
            Precision::Fp1632,
            CoordinateSystem::Nwu,
            100,
        ),
        entry(
            DataType::Temperature,
            Precision::Float64,
            CoordinateSystem::Enu,
            10,
        ),
    ])
    .unwrap();
    let options = EmulatorOptions {
        start_in_measurement: true,
        initial_output: output,
        ..EmulatorOptions::mti_630()
    };
    let mut emulator = Emulator::new(options);
    let mut sample = Sample::from_rates(0, [1.5, -2.25, 9.0], [0.0; 3], 0.01);
    sample.temperature = 31.5;
    for _ in 0..20 {
        assert!(emulator.push_sample(&sample));
    }
    let got = frames(&mut emulator);
    assert_eq!(got.len(), 20);
    for (i, (m, payload)) in got.iter().enumerate() {
        assert_eq!(*m, mid::MT_DATA2);
        let data = Measurement::from_payload(payload).unwrap();
        assert_eq!(data.packet_counter, Some(i as u16));
        let acc = data.acceleration.unwrap();
        assert_eq!(
            (acc.values, acc.frame, acc.precision),
            ([1.5, -2.25, 9.0], CoordinateSystem::Nwu, Precision::Fp1632)
        );
        assert_eq!(data.temperature, (i % 10 == 0).then_some(31.5));
        assert!(data.sample_time_fine.is_none(), "not configured");
    }
}

#[test]
fn identification_replies_carry_the_configured_identity() {
    let mut emulator = Emulator::new(EmulatorOptions {
        send_wake_up: true,
        ..EmulatorOptions::mti_g_710()
    });
    for m in [mid::REQ_DID, mid::REQ_PRODUCT_CODE, mid::REQ_FW_REV, 0x77] {
        let mut request = Vec::new();
        xbus::encode_frame(m, &[], &mut request).unwrap();
        emulator.handle_input(&request);
    }
    let got = frames(&mut emulator);
    assert_eq!(got[0], (mid::WAKE_UP, vec![]));
    assert_eq!(
        got[1],
        (mid::DEVICE_ID, 0x0370_0C6Eu32.to_be_bytes().to_vec())
    );
    assert_eq!(got[2], (mid::PRODUCT_CODE, b"MTi-G-710-2A5G4".to_vec()));
    assert_eq!(got[3], (mid::FIRMWARE_REV, vec![1, 8, 2]));
    // An unknown message is answered with Error 4 (invalid message).
    assert_eq!(got[4], (mid::ERROR, vec![4]));
}

#[test]
fn no_samples_stream_outside_measurement() {
    let mut emulator = Emulator::new(EmulatorOptions::mti_630());
    assert!(!emulator.push_sample(&Sample::from_rates(0, [0.0; 3], [0.0; 3], 0.01)));
    assert!(frames(&mut emulator).is_empty());
}

#[test]
fn increments_follow_the_rates() {
    let s = Sample::from_rates(0, [0.0, 0.0, -10.0], [0.0, 0.0, 2.0], 0.5);
    assert_eq!(s.delta_v, [0.0, 0.0, -5.0]);
    // 1 rad about z over the interval: half-angle 0.5 rad.
    let want = [0.5f64.cos(), 0.0, 0.0, 0.5f64.sin()];
    for (g, w) in s.delta_q.iter().zip(want) {
        assert!((g - w).abs() < 1e-15);
    }
}

#[test]
fn increments_and_rates_are_consistent_both_ways() {
    let forward = Sample::from_rates(7, [0.2, -0.4, -9.8], [0.3, -0.1, 1.2], 0.01);
    let back = Sample::from_increments(7, forward.delta_v, forward.delta_q, 0.01);
    assert_eq!(
        (back.delta_v, back.delta_q),
        (forward.delta_v, forward.delta_q)
    );
    for (g, w) in back
        .acceleration
        .iter()
        .zip(forward.acceleration)
        .chain(back.rate_of_turn.iter().zip(forward.rate_of_turn))
    {
        assert!((g - w).abs() < 1e-12, "{g} vs {w}");
    }
}
