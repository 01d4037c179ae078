//! Real captures (../shared/vectors) and the generated examples of docs/protocols.md, 1.10 "Worked
//! examples".

use std::path::PathBuf;

use scip::{Body, Command, DataKind, Decoder, Reply, Status, StepRange, TimeMode};

fn vectors_dir() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/vectors");
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "../shared/vectors not found (required under CI)"
    );
    println!("skipped: ../shared/vectors not found");
    None
}

/// Decodes `bytes` one byte at a time and returns (timestamp, ranges) of the single scan.
fn decode_single_scan(bytes: &[u8]) -> (u32, Vec<u32>) {
    let mut decoder = Decoder::new();
    let mut scans = Vec::new();
    for byte in bytes.chunks(1) {
        decoder.feed(byte, |reply| match reply.expect("capture decodes").body {
            Body::Scan(scan) => scans.push((scan.timestamp, scan.ranges.to_vec())),
            other => panic!("expected a scan, got {other:?}"),
        });
    }
    assert_eq!(scans.len(), 1);
    scans.pop().unwrap()
}

#[test]
fn capture_a_decodes_to_the_documented_values() {
    let Some(dir) = vectors_dir() else { return };
    let bytes = std::fs::read(dir.join("scip_urg04lx-ug01_GD0044072501_capture_A.txt")).unwrap();
    let (timestamp, ranges) = decode_single_scan(&bytes);
    assert_eq!(timestamp, 11_149_560);
    assert_eq!(ranges.len(), 682);
    assert_eq!(&ranges[..6], &[6, 6, 6, 4190, 6, 7]);
}

#[test]
fn capture_b_decodes_to_the_documented_values() {
    let Some(dir) = vectors_dir() else { return };
    let bytes = std::fs::read(dir.join("scip_urg04lx_GD0044072501_capture_B.txt")).unwrap();
    let (timestamp, ranges) = decode_single_scan(&bytes);
    assert_eq!(timestamp, 513);
    assert_eq!(ranges.len(), 682);
}

fn decode_all(bytes: &[u8], mut check: impl FnMut(Reply<'_>)) -> usize {
    let mut decoder = Decoder::new();
    let mut count = 0;
    decoder.feed(bytes, |reply| {
        count += 1;
        check(reply.expect("example decodes"));
    });
    count
}

#[test]
fn generated_gd_example_is_byte_exact() {
    let bytes = b"GD0384038601\n00P\nm2@0?\n0CB1Dh00Df\n\n";
    let n = decode_all(bytes, |reply| {
        assert_eq!(reply.status, Status::OK);
        let Body::Scan(scan) = reply.body else {
            panic!("scan expected")
        };
        assert_eq!(scan.timestamp, 16_000_000);
        assert_eq!(scan.ranges, &[1234, 5432, 20]);
        assert_eq!(
            scan.range,
            StepRange {
                start: 384,
                end: 386,
                cluster: 1
            }
        );
        assert!(scan.stream.is_none());
    });
    assert_eq!(n, 1);
    let mut out = Vec::new();
    Command::Get {
        data: DataKind::Distance,
        range: StepRange {
            start: 384,
            end: 386,
            cluster: 1,
        },
    }
    .encode(&mut out)
    .unwrap();
    assert_eq!(out, &bytes[..13]);
}

#[test]
fn generated_md_examples_are_byte_exact() {
    let mut out = Vec::new();
    let range = StepRange {
        start: 384,
        end: 386,
        cluster: 1,
    };
    Command::Stream {
        data: DataKind::Distance,
        range,
        interval: 0,
        count: 2,
    }
    .encode(&mut out)
    .unwrap();
    assert_eq!(out, b"MD0384038601002\n");
    let ack = decode_all(b"MD0384038601002\n00P\n\n", |reply| {
        assert_eq!(reply.status, Status::OK);
        assert_eq!(reply.body, Body::Empty);
    });
    assert_eq!(ack, 1);
    let scans = decode_all(b"MD0384038601001\n99b\nm2@0?\n0CB1Dh00Df\n\n", |reply| {
        let Body::Scan(scan) = reply.body else {
            panic!("scan expected")
        };
        assert_eq!(scan.stream.unwrap().remaining, 1);
        assert_eq!(scan.ranges, &[1234, 5432, 20]);
    });
    assert_eq!(scans, 1);
}

#[test]
fn generated_me_example_is_byte_exact() {
    let n = decode_all(b"ME0384038501001\n99b\nm2@0?\n0CB0^h1Dh01Tm\n\n", |reply| {
        let Body::Scan(scan) = reply.body else {
            panic!("scan expected")
        };
        assert_eq!(scan.data, DataKind::DistanceIntensity);
        assert_eq!(scan.ranges, &[1234, 5432]);
        assert_eq!(scan.intensities, &[3000, 100]);
    });
    assert_eq!(n, 1);
}

#[test]
fn generated_tm1_example_is_byte_exact() {
    let mut out = Vec::new();
    Command::Time(TimeMode::Request).encode(&mut out).unwrap();
    assert_eq!(out, b"TM1\n");
    let n = decode_all(b"TM1\n00P\nm2@0?\n\n", |reply| {
        assert_eq!(reply.body, Body::Time(16_000_000))
    });
    assert_eq!(n, 1);
}

#[test]
fn value_straddling_two_lines_decodes() {
    let line1 = b"0?X0?Y0?Z0?[0?\\0?]0?^0?_0?`0?a0?b0?c0?d0?e0?f0?g0?h0?i0?j0?k0?l0E\n";
    let line2 = b"?m\\\n";
    let mut bytes = b"GD0000002101\n00P\nm2@0?\n".to_vec();
    bytes.extend_from_slice(line1);
    bytes.extend_from_slice(line2);
    bytes.push(b'\n');
    let expected: Vec<u32> = (1000..1022).collect();
    let n = decode_all(&bytes, |reply| {
        let Body::Scan(scan) = reply.body else {
            panic!("scan expected")
        };
        assert_eq!(scan.ranges, expected.as_slice());
    });
    assert_eq!(n, 1);
}

#[test]
fn info_lines_accept_both_sum_variants_and_the_comment_quirk() {
    // Spec PP (sum without ';'), then the same line summed with ';', then an II comment line
    // summed only up to "<-".
    let with_semicolon = {
        let content = b"DMIN:20;";
        let mut line = content.to_vec();
        line.push(scip::encoding::checksum(content));
        String::from_utf8(line).unwrap()
    };
    let comment = {
        let mut line = b"SCSP:Initial(600[rpm])<-Default setting by user;".to_vec();
        line.push(scip::encoding::checksum(b"SCSP:Initial(600[rpm])"));
        String::from_utf8(line).unwrap()
    };
    let modl = "MODL:URG-04LX(Hokuyo Automatic Co.,Ltd.)";
    let modl = format!(
        "{modl};{}",
        scip::encoding::checksum(modl.as_bytes()) as char
    );
    let text = format!("PP\n00P\n{modl}\n{with_semicolon}\nARES:1024;\\\n{comment}\n\n");
    let n = decode_all(text.as_bytes(), |reply| {
        let Body::Info(info) = reply.body else {
            panic!("info expected")
        };
        assert_eq!(
            info.get("MODL"),
            Some("URG-04LX(Hokuyo Automatic Co.,Ltd.)")
        );
        assert_eq!(info.get("DMIN"), Some("20"));
        assert_eq!(info.get("ARES"), Some("1024"));
        assert_eq!(
            info.get("SCSP"),
            Some("Initial(600[rpm])<-Default setting by user")
        );
    });
    assert_eq!(n, 1);
}

#[test]
fn real_vv_lines_verify() {
    let text = b"VV\n00P\nVEND:Hokuyo Automatic Co.,Ltd.;[\nPROD:SOKUIKI Sensor URG-04LX;[\nFIRM:3.2.00(28/Aug./2007);f\nPROT:SCIP 2.0;N\nSERI:H0508486;T\n\n";
    let n = decode_all(text, |reply| {
        let Body::Info(info) = reply.body else {
            panic!("info expected")
        };
        assert_eq!(info.iter().count(), 5);
        assert_eq!(info.get("SERI"), Some("H0508486"));
    });
    assert_eq!(n, 1);
}
