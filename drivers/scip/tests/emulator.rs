//! The emulator answers like a real sensor: byte-exact against the worked examples of
//! docs/protocols.md (1.10), and the statuses of its 1.6 "Commands and statuses".

use scip::{Body, Decoder, Emulator, Model, Status};

fn urg_with_scan() -> Emulator {
    let mut sensor = Emulator::new(Model::urg_04lx());
    let mut ranges = vec![0u32; sensor.model().step_count()];
    // Steps 384..=386 (indices from AMIN = 44).
    ranges[340..343].copy_from_slice(&[1234, 5432, 20]);
    let mut intensities = vec![0u32; ranges.len()];
    intensities[340..342].copy_from_slice(&[3000, 100]);
    sensor
        .push_scan(16_000_000, &ranges, Some(&intensities))
        .unwrap();
    sensor
}

fn exchange(sensor: &mut Emulator, command: &[u8]) -> Vec<u8> {
    sensor.handle_input(command);
    let mut out = Vec::new();
    sensor.drain_output(&mut out);
    out
}

fn statuses(bytes: &[u8]) -> Vec<Status> {
    let mut decoder = Decoder::new();
    let mut out = Vec::new();
    decoder.feed(bytes, |reply| {
        out.push(reply.expect("emulator output decodes").status)
    });
    out
}

#[test]
fn gd_md_me_and_tm1_replies_are_byte_exact() {
    let mut sensor = urg_with_scan();
    assert_eq!(
        exchange(&mut sensor, b"GD0384038601\n"),
        b"GD0384038601\n10Q\n\n",
        "laser off"
    );
    exchange(&mut sensor, b"BM\n");
    assert_eq!(
        exchange(&mut sensor, b"GD0384038601\n"),
        b"GD0384038601\n00P\nm2@0?\n0CB1Dh00Df\n\n"
    );
    assert_eq!(
        exchange(&mut sensor, b"MD0384038601002\n"),
        b"MD0384038601002\n00P\n\n"
    );
    let mut sensor2 = urg_with_scan();
    sensor2.handle_input(b"MD0384038601002\n");
    let mut ack = Vec::new();
    sensor2.drain_output(&mut ack);
    let ranges = {
        let mut r = vec![0u32; sensor2.model().step_count()];
        r[340..343].copy_from_slice(&[1234, 5432, 20]);
        r
    };
    sensor2.push_scan(16_000_000, &ranges, None).unwrap();
    let mut scan = Vec::new();
    sensor2.drain_output(&mut scan);
    assert_eq!(scan, b"MD0384038601001\n99b\nm2@0?\n0CB1Dh00Df\n\n");

    let mut sensor3 = urg_with_scan();
    sensor3.handle_input(b"ME0384038501001\n");
    let mut ignore = Vec::new();
    sensor3.drain_output(&mut ignore);
    let mut intensities = vec![0u32; ranges.len()];
    intensities[340..342].copy_from_slice(&[3000, 100]);
    sensor3
        .push_scan(16_000_000, &ranges, Some(&intensities))
        .unwrap();
    let mut me = Vec::new();
    sensor3.drain_output(&mut me);
    assert_eq!(me, b"ME0384038501000\n99b\nm2@0?\n0CB0^h1Dh01Tm\n\n");

    let mut sensor4 = Emulator::new(Model::utm_30lx());
    sensor4.set_clock(16_000_000);
    exchange(&mut sensor4, b"TM0\n");
    assert_eq!(exchange(&mut sensor4, b"TM1\n"), b"TM1\n00P\nm2@0?\n\n");
}

#[test]
fn stream_counts_down_skips_interval_scans_and_stops() {
    let mut sensor = Emulator::new(Model::utm_30lx());
    exchange(&mut sensor, b"MD0000000101103;tag\n");
    let ranges = vec![777u32; sensor.model().step_count()];
    let mut out = Vec::new();
    // Interval 1: every other pushed revolution is sent, three in all.
    for i in 0..8 {
        sensor.push_scan(i * 25, &ranges, None).unwrap();
    }
    sensor.drain_output(&mut out);
    let mut echoes = Vec::new();
    let mut decoder = Decoder::new();
    decoder.feed(&out, |reply| {
        let reply = reply.unwrap();
        echoes.push(String::from_utf8(reply.echo.to_vec()).unwrap());
        let Body::Scan(scan) = reply.body else {
            panic!("scan expected")
        };
        assert_eq!(scan.ranges, &[777, 777]);
    });
    assert_eq!(
        echoes,
        vec![
            "MD0000000101102;tag",
            "MD0000000101101;tag",
            "MD0000000101100;tag"
        ]
    );
    assert!(!sensor.is_streaming());
}

#[test]
fn error_statuses_match_the_protocol() {
    let mut sensor = Emulator::new(Model::urg_04lx());
    let cases: [(&[u8], &[u8; 2]); 12] = [
        (b"XX\n", b"0E"),
        (b"SCIP2.0\n", b"0E"),
        (b"GD0044999901\n", b"04"),
        (b"GD0500044001\n", b"05"),
        (b"GD004x072501\n", b"01"),
        (b"MD00440725010x0\n", b"07"),
        (b"BM\n", b"00"),
        (b"BM\n", b"02"),
        (b"TM1\n", b"04"),
        (b"TM2\n", b"03"),
        (b"TM0\n", b"00"),
        (b"QT\n", b"0E"),
    ];
    for (command, status) in cases {
        let reply = exchange(&mut sensor, command);
        assert_eq!(
            statuses(&reply),
            vec![Status::Code(*status)],
            "{}",
            command.escape_ascii()
        );
    }
    assert_eq!(statuses(&exchange(&mut sensor, b"TM2\n")), vec![Status::OK]);
    assert_eq!(
        statuses(&exchange(&mut sensor, b"QT;0123456789abcdefg\n")),
        vec![Status::Code(*b"0G")]
    );
}

#[test]
fn info_replies_decode_with_sums_excluding_the_semicolon() {
    let mut sensor = Emulator::new(Model::ust_20lx());
    for command in [&b"VV\n"[..], b"PP\n", b"II\n"] {
        let reply = exchange(&mut sensor, command);
        // Every info line's sum covers KEY:VALUE only.
        for line in reply
            .split(|&b| b == b'\n')
            .filter(|l| l.len() > 4 && l.contains(&b':'))
        {
            let (content, sum) = line.split_at(line.len() - 2);
            assert_eq!(scip::encoding::checksum(content), sum[1]);
        }
        let mut decoder = Decoder::new();
        decoder.feed(&reply, |r| {
            assert!(matches!(r.unwrap().body, Body::Info(_)))
        });
    }
    let pp = exchange(&mut sensor, b"PP\n");
    let mut decoder = Decoder::new();
    decoder.feed(&pp, |r| {
        let Body::Info(info) = r.unwrap().body else {
            panic!()
        };
        let params = scip::Parameters::from_info(&info).unwrap();
        assert_eq!(params, Model::ust_20lx().parameters);
    });
}

#[test]
fn scip11_sensor_answers_e_until_switched() {
    let mut sensor = Emulator::new(Model::urg_04lx());
    sensor.boot_in_scip11();
    assert_eq!(exchange(&mut sensor, b"QT\n"), b"QT\nE\n\n");
    exchange(&mut sensor, b"SCIP2.0\n");
    assert_eq!(exchange(&mut sensor, b"QT\n"), b"QT\n00P\n\n");
}

#[test]
fn pushed_scans_of_the_wrong_length_are_refused() {
    let mut sensor = Emulator::new(Model::urg_04lx());
    let error = sensor.push_scan(0, &[1, 2, 3], None).unwrap_err();
    assert_eq!((error.expected, error.got), (682, 3));
}
