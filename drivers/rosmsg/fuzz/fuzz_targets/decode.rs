//! Arbitrary bytes as every message type in both encodings: decoding never panics, and an
//! error is one line.
#![no_main]

use libfuzzer_sys::fuzz_target;
use rosmsg::{decode, Encoding, Kind};

fuzz_target!(|data: &[u8]| {
    for encoding in [Encoding::Ros1, Encoding::Cdr] {
        for kind in Kind::ALL {
            if let Err(e) = decode(kind, encoding, data) {
                assert!(!e.to_string().contains('\n'));
            }
        }
    }
});
