//! Arbitrary MTData2 payloads: decoding never panics and never reads past the payload.
#![no_main]

use libfuzzer_sys::fuzz_target;
use xbus::{items, Measurement};

fuzz_target!(|payload: &[u8]| {
    let mut consumed = 0;
    for item in items(payload) {
        match item {
            Ok(_) => consumed += 1,
            Err(e) => assert!(!e.to_string().contains('\n')),
        }
    }
    assert!(consumed <= payload.len() / 3);
    let _ = Measurement::from_payload(payload);
});
