#![no_main]
//! Arbitrary bytes, split where the first byte says, must never panic the decoder, and every
//! decoded scan must be self-consistent.

use libfuzzer_sys::fuzz_target;
use scip::{Body, DataKind, Decoder};

fuzz_target!(|data: &[u8]| {
    let Some((&split, bytes)) = data.split_first() else {
        return;
    };
    let mut decoder = Decoder::with_max_frame(4096);
    let chunk = usize::from(split).max(1);
    for piece in bytes.chunks(chunk) {
        decoder.feed(piece, |reply| {
            if let Ok(reply) = reply {
                if let Body::Scan(scan) = reply.body {
                    assert_eq!(scan.ranges.len(), scan.range.value_count());
                    let intensities = if scan.data == DataKind::DistanceIntensity {
                        scan.ranges.len()
                    } else {
                        0
                    };
                    assert_eq!(scan.intensities.len(), intensities);
                }
            } else if let Err(error) = reply {
                assert!(!error.to_string().contains('\n'));
            }
        });
    }
});
