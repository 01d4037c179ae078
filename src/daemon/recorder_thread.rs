//! The recorder runs on its own thread: the fusion thread hands it each chunk after consuming it,
//! so that the recording's order is the order replay must follow, without waiting (a full queue
//! drops the chunk and counts it, it never stalls the fusion), and file writes and flushes never
//! run on the tokio workers.

use super::recording::{Direction, Encoding, Recorder, RecordingError};
use std::io::{Seek, Write};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Chunks that can wait for the disk: at 1 kHz of IMU frames plus 40 Hz scans, seconds' worth.
pub(crate) const QUEUE_CHUNKS: usize = 8192;

/// One chunk of device bytes on its way to the recording.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Tap {
    pub sensor: Arc<str>,
    pub encoding: Encoding,
    pub direction: Direction,
    pub log_time_ns: u64,
    pub data: Vec<u8>,
}

/// Cloneable handle the fusion thread records through.
#[derive(Debug, Clone)]
pub(crate) struct RecorderHandle {
    queue: SyncSender<Tap>,
    dropped: Arc<AtomicU64>,
}

impl RecorderHandle {
    /// Queues a chunk; never blocks. Returns false when it had to be dropped.
    pub(crate) fn record(&self, tap: Tap) -> bool {
        match self.queue.try_send(tap) {
            Ok(()) => true,
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }

    /// Chunks dropped so far because the disk could not keep up (or the recorder had stopped).
    pub(crate) fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// What the recorder thread did, when it ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RecorderSummary {
    pub chunks: u64,
    pub bytes: u64,
}

/// Starts the thread. It ends, finishing the file, when every handle has been dropped; join it
/// for the summary or the first write error.
pub(crate) fn spawn<W: Write + Seek + Send + 'static>(
    mut recorder: Recorder<W>,
    flush_interval: Duration,
) -> (
    RecorderHandle,
    JoinHandle<Result<RecorderSummary, RecordingError>>,
) {
    let (queue, taps) = mpsc::sync_channel::<Tap>(QUEUE_CHUNKS);
    let handle = RecorderHandle {
        queue,
        dropped: Arc::new(AtomicU64::new(0)),
    };
    let thread = std::thread::Builder::new()
        .name("recorder".into())
        .spawn(move || {
            let mut summary = RecorderSummary {
                chunks: 0,
                bytes: 0,
            };
            let mut last_flush = Instant::now();
            loop {
                match taps.recv_timeout(flush_interval) {
                    Ok(tap) => {
                        recorder.bytes(
                            &tap.sensor,
                            tap.encoding,
                            tap.direction,
                            tap.log_time_ns,
                            &tap.data,
                        )?;
                        summary.chunks += 1;
                        summary.bytes += tap.data.len() as u64;
                    }
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => break,
                }
                if last_flush.elapsed() >= flush_interval {
                    recorder.flush()?;
                    last_flush = Instant::now();
                }
            }
            recorder.finish()?;
            Ok(summary)
        })
        .expect("the OS refused to start the recorder thread");
    (handle, thread)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::recording::{ReadMode, Recording};

    #[test]
    fn every_chunk_from_many_senders_reaches_the_file() {
        let file = std::env::temp_dir().join(format!("ladar-recorder-{}.mcap", std::process::id()));
        let recorder = Recorder::create(&file, "").unwrap();
        let (handle, thread) = spawn(recorder, Duration::from_millis(5));
        let senders: Vec<_> = ["front", "pitched", "imu"]
            .into_iter()
            .map(|name| {
                let handle = handle.clone();
                std::thread::spawn(move || {
                    let sensor: Arc<str> = name.into();
                    for i in 0..500u64 {
                        let tap = Tap {
                            sensor: sensor.clone(),
                            encoding: Encoding::Scip2,
                            direction: Direction::Rx,
                            log_time_ns: i,
                            data: i.to_le_bytes().to_vec(),
                        };
                        while !handle.record(tap.clone()) {
                            std::thread::yield_now();
                        }
                    }
                })
            })
            .collect();
        senders.into_iter().for_each(|s| s.join().unwrap());
        drop(handle);
        let summary = thread.join().unwrap().unwrap();
        assert_eq!(
            summary,
            RecorderSummary {
                chunks: 1500,
                bytes: 12_000
            }
        );

        let recording = Recording::open(&file, ReadMode::Strict).unwrap();
        std::fs::remove_file(&file).unwrap();
        for name in ["front", "pitched", "imu"] {
            let values: Vec<u64> = recording
                .messages
                .iter()
                .filter(|m| m.sensor == name)
                .map(|m| u64::from_le_bytes(m.data.clone().try_into().unwrap()))
                .collect();
            assert_eq!(values, (0..500).collect::<Vec<_>>(), "{name}");
        }
    }

    #[test]
    fn a_full_queue_drops_and_counts_instead_of_blocking() {
        let (queue, _taps) = mpsc::sync_channel(1);
        let handle = RecorderHandle {
            queue,
            dropped: Arc::new(AtomicU64::new(0)),
        };
        let tap = Tap {
            sensor: "front".into(),
            encoding: Encoding::Scip2,
            direction: Direction::Rx,
            log_time_ns: 0,
            data: vec![1],
        };
        assert!(handle.record(tap.clone()));
        assert!(!handle.record(tap.clone()));
        assert!(!handle.record(tap));
        assert_eq!(handle.dropped(), 2);
    }
}
