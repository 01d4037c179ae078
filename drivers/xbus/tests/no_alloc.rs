//! After warm-up, receiving and decoding messages allocates nothing.

mod support;

#[path = "support/alloc.rs"]
mod alloc;

use std::time::Duration;

use support::measuring_link;
use xbus::emulator::{EmulatorOptions, Sample};
use xbus::{DeviceConfig, Event, Framer, ImuOutput, Measurement, Precision};

#[global_allocator]
static COUNTING: alloc::Counting = alloc::Counting;

#[test]
fn steady_state_decoding_does_not_allocate() {
    let config = DeviceConfig {
        imu_output: ImuOutput::Rates,
        precision: Precision::Fp1632,
        ..DeviceConfig::default()
    };
    let mut link = measuring_link(config, EmulatorOptions::mti_g_710());
    let mut stream = Vec::new();
    for i in 0..2000u32 {
        link.emulator.push_sample(&Sample::from_rates(
            i * 100,
            [0.0, 0.1, -9.8],
            [0.01, 0.0, 0.0],
            0.01,
        ));
    }
    link.emulator.drain_output(&mut stream);
    let (warm_up, measured) = stream.split_at(stream.len() / 4);
    let mut framer = Framer::new(xbus::DEFAULT_MAX_PAYLOAD);

    let mut now = Duration::from_secs(20);
    let mut drive = |bytes: &[u8], count: &mut u64| {
        for chunk in bytes.chunks(37) {
            now += Duration::from_millis(1);
            link.device.handle_input(now, chunk);
            while let Some(event) = link.device.poll_event() {
                *count += u64::from(matches!(event, Event::Measurement(_)));
            }
            let mut rest = chunk;
            while let Some(Ok(frame)) = framer.decode(&mut rest) {
                *count += u64::from(Measurement::from_payload(frame.payload).is_ok());
            }
        }
    };
    let mut count = 0;
    drive(warm_up, &mut count);
    let before = alloc::allocations();
    drive(measured, &mut count);
    let allocated = alloc::allocations() - before;
    assert_eq!(
        count,
        2 * 2000,
        "every message decoded twice (device and bare framer)"
    );
    assert_eq!(
        allocated, 0,
        "{allocated} allocations while decoding 1500 messages"
    );
}
