//! Decoding one 1081-step MD scan (target < 10 µs), and the allocation count per message
//! after warm-up (must be zero).

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use scip::{Body, Decoder, Emulator, Model};

struct CountingAllocator;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

fn md_stream(scans: usize) -> Vec<u8> {
    let mut sensor = Emulator::new(Model::utm_30lx());
    sensor.handle_input(b"MD0000108001000\n");
    for i in 0..scans {
        let ranges: Vec<u32> = (0..1081)
            .map(|s| 500 + ((s * 37 + i) % 30000) as u32)
            .collect();
        sensor.push_scan(i as u32 * 25, &ranges, None).unwrap();
    }
    let mut bytes = Vec::new();
    sensor.drain_output(&mut bytes);
    let ack_end = bytes.windows(2).position(|w| w == b"\n\n").unwrap() + 2;
    bytes.drain(..ack_end);
    bytes
}

fn decode_all(decoder: &mut Decoder, bytes: &[u8]) -> usize {
    let mut total = 0;
    decoder.feed(bytes, |reply| {
        if let Ok(reply) = reply {
            if let Body::Scan(scan) = reply.body {
                total += scan.ranges.len();
            }
        }
    });
    total
}

#[divan::bench]
fn md_scan_1081_steps(bencher: divan::Bencher) {
    let scan = md_stream(1);
    let mut decoder = Decoder::new();
    decode_all(&mut decoder, &scan);
    bencher
        .counter(divan::counter::BytesCount::new(scan.len()))
        .bench_local(|| decode_all(&mut decoder, divan::black_box(&scan)));
}

fn main() {
    let stream = md_stream(100);
    let mut decoder = Decoder::new();
    decode_all(&mut decoder, &stream[..stream.len() / 100 * 2]);
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    let values = decode_all(&mut decoder, &stream);
    let allocations = ALLOCATIONS.load(Ordering::Relaxed) - before;
    println!(
        "decoded {values} values from 100 MD scans with {allocations} allocations after warm-up"
    );
    assert_eq!(
        allocations, 0,
        "the decoder must not allocate per message after warm-up"
    );
    divan::main();
}
