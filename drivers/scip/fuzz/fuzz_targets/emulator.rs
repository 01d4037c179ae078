#![no_main]
//! The emulator fed arbitrary host bytes must never panic, and what it sends must decode.

use libfuzzer_sys::fuzz_target;
use scip::{Decoder, Emulator, Model};

fuzz_target!(|data: &[u8]| {
    let mut sensor = Emulator::new(Model::urg_04lx());
    let steps = sensor.model().step_count();
    let ranges: Vec<u32> = (0..steps as u32).map(|i| i * 7).collect();
    let mut out = Vec::new();
    let mut decoder = Decoder::new();
    for (i, piece) in data.split(|&b| b == 0xFF).enumerate() {
        sensor.handle_input(piece);
        sensor.set_clock(i as u32 * 100);
        sensor.push_scan(i as u32 * 100, &ranges, None).unwrap();
        out.clear();
        sensor.drain_output(&mut out);
        decoder.feed(&out, |reply| {
            reply.expect("emulator output always decodes");
        });
    }
});
