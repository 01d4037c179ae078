//! The replay pipeline per chunk: the bundled recording (data/hallway-hover.mcap, 76 s, two
//! scanners at 4 Hz, IMU at 200 Hz) decoded and fused from memory, without file reading or
//! output writing. divan reports the time per whole recording and per chunk (throughput), and
//! the allocations. `cargo bench --bench replay`

use divan::counter::ItemsCount;
use divan::{black_box, AllocProfiler, Bencher};
use ladar_odometer::daemon::config::Config;
use ladar_odometer::daemon::fusion_estimator::FusionEstimator;
use ladar_odometer::daemon::pipeline::{sensor_specs, Chunk, Pipeline};
use ladar_odometer::daemon::readings::Receivers;
use ladar_odometer::daemon::recording::{ReadMode, Recording};
use ladar_odometer::daemon::replay::BUNDLED_RECORDING;
use std::path::Path;

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

fn main() {
    divan::main();
}

fn bundled() -> (Config, Vec<Chunk>) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(BUNDLED_RECORDING);
    let recording = Recording::open(&path, ReadMode::Strict).unwrap();
    let config = Config::parse(recording.config_toml.as_deref().unwrap(), &path).unwrap();
    let specs = sensor_specs(&config);
    let chunks = recording
        .messages
        .into_iter()
        .map(|m| Chunk {
            sensor: specs.iter().position(|s| s.name() == m.sensor).unwrap(),
            direction: m.direction,
            log_time_ns: m.log_time_ns,
            data: m.data,
            readings: Vec::new(),
        })
        .collect();
    (config, chunks)
}

#[divan::bench(sample_count = 10, sample_size = 1)]
fn bundled_recording(bencher: Bencher) {
    let (config, chunks) = bundled();
    bencher
        .counter(ItemsCount::new(chunks.len()))
        .with_inputs(|| {
            let specs = sensor_specs(&config);
            let receivers = Receivers::new(specs.iter().map(|s| s.encoding()));
            let pipeline = Pipeline::new(specs, FusionEstimator::new(Some(&config)));
            (receivers, pipeline, chunks.clone())
        })
        .bench_local_values(|(mut receivers, mut pipeline, chunks)| {
            let mut outputs = 0u64;
            let mut spare_readings = Vec::new();
            for mut chunk in chunks {
                chunk.readings = std::mem::take(&mut spare_readings);
                receivers.decode(&mut chunk);
                pipeline.push(&chunk, |output| {
                    black_box(output);
                    outputs += 1;
                });
                spare_readings = chunk.readings;
                spare_readings.clear();
            }
            outputs
        });
}
