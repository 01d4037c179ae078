//! After warm-up the decoder allocates nothing per message, and the streaming device only the
//! two buffers each scan event owns (it leaves the device, so they cannot be reused).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use std::time::Duration;

use scip::{Body, Decoder, Device, DeviceConfig, Emulator, Event, Model, Reply};

struct CountingAllocator;

thread_local! {
    // Per thread, because the tests of this file run in parallel and allocate in their own
    // set-up; const-initialised and without a destructor, so the allocator may touch it at any
    // time.
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

fn allocations() -> usize {
    ALLOCATIONS.with(Cell::get)
}

unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

/// `scans` ME scans of a UTM-30LX after the stream acknowledgement, as one byte string.
fn me_stream(scans: u32) -> Vec<u8> {
    let mut sensor = Emulator::new(Model::utm_30lx());
    sensor.handle_input(b"ME0000108001000\n");
    let mut ack = Vec::new();
    sensor.drain_output(&mut ack); // the acknowledgement: the device below gets its own
    for i in 0..scans {
        let ranges: Vec<u32> = (0..1081).map(|s| 300 + (s * 13 + i) % 20000).collect();
        sensor.push_scan(i * 25, &ranges, Some(&ranges)).unwrap();
    }
    let mut bytes = Vec::new();
    sensor.drain_output(&mut bytes);
    bytes
}

// One test per binary: the counter is global, so a parallel test would disturb it.
#[test]
fn decoder_and_device_do_not_allocate_per_scan_after_warm_up() {
    let stream = me_stream(60);
    let half = stream.len() / 2;

    let mut decoder = Decoder::new();
    let mut scans = 0;
    let mut count = |reply: Result<scip::Reply<'_>, scip::DecodeError>| {
        if let Ok(Reply {
            body: Body::Scan(_),
            ..
        }) = reply
        {
            scans += 1;
        }
    };
    decoder.feed(&stream[..half], &mut count);
    let before = allocations();
    for chunk in stream[half..].chunks(100) {
        decoder.feed(chunk, &mut count);
    }
    assert_eq!(allocations() - before, 0, "decoder allocated");
    assert_eq!(scans, 60);

    // The device: its scans' ranges and intensities.
    let mut device = Device::new(
        DeviceConfig {
            data: scip::DataKind::DistanceIntensity,
            steps: Some((0, 1080)),
            clock_samples: 0,
            ..DeviceConfig::default()
        },
        Duration::ZERO,
    );
    let mut sensor = Emulator::new(Model::utm_30lx());
    let mut wire = Vec::new();
    for _ in 0..10 {
        while let Some(bytes) = device.poll_transmit(Duration::ZERO) {
            sensor.handle_input(bytes);
        }
        wire.clear();
        sensor.drain_output(&mut wire);
        device.handle_input(Duration::ZERO, &wire);
        while device.poll_event().is_some() {}
    }
    assert_eq!(device.phase(), scip::Phase::Streaming);
    let run = |device: &mut Device, bytes: &[u8]| {
        let mut scans = 0;
        for chunk in bytes.chunks(100) {
            device.handle_input(Duration::from_secs(1), chunk);
            while let Some(event) = device.poll_event() {
                scans += usize::from(matches!(event, Event::Scan(_)));
            }
        }
        scans
    };
    let warm_up = run(&mut device, &stream[..half]);
    let before = allocations();
    let measured = run(&mut device, &stream[half..]);
    assert_eq!(
        allocations() - before,
        2 * measured,
        "device allocated more than each scan's ranges and intensities"
    );
    assert_eq!(warm_up + measured, 60);
}
