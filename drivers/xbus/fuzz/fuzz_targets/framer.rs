//! Arbitrary bytes in arbitrary chunks: the framer never panics, and every frame it returns is
//! within the size guard and made of input bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use xbus::Framer;

fuzz_target!(|data: &[u8]| {
    let Some((&max, data)) = data.split_first() else {
        return;
    };
    let max_payload = usize::from(max) * 8;
    let mut framer = Framer::new(max_payload);
    let mut rest = data;
    let mut chunk_len = 1;
    while !rest.is_empty() {
        let (mut chunk, tail) = rest.split_at(chunk_len.min(rest.len()));
        rest = tail;
        chunk_len = chunk_len % 97 + 13;
        while let Some(result) = framer.decode(&mut chunk) {
            if let Ok(frame) = result {
                assert!(frame.payload.len() <= max_payload);
                assert!(
                    frame.payload.is_empty()
                        || data
                            .windows(frame.payload.len())
                            .any(|w| w == frame.payload)
                );
            }
        }
    }
});
