//! The one bounded queue from the sensor tasks to the fusion thread. Producers never wait: when
//! the fusion falls behind, the oldest chunk is dropped and counted (stale bytes are worth less
//! than fresh ones), and the drop is logged at 1, 10, 100, ... so a slow consumer cannot flood
//! the journal.

use super::pipeline::Chunk;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Condvar, Mutex, PoisonError};
use std::time::Duration;

/// At 1 kHz of IMU frames plus 4 x 40 Hz scan reads, about two seconds.
pub(crate) const QUEUE_CHUNKS: usize = 2048;

#[derive(Debug)]
pub(crate) struct ChunkQueue {
    state: Mutex<State>,
    ready: Condvar,
    capacity: usize,
    dropped: AtomicU64,
}

#[derive(Debug, Default)]
struct State {
    chunks: VecDeque<Chunk>,
    closed: bool,
}

/// What [`ChunkQueue::pop`] found.
#[derive(Debug, PartialEq)]
pub(crate) enum Popped {
    Chunk(Chunk),
    /// Nothing within the wait; the consumer may check on other things and wait again.
    Idle,
    /// Closed and drained: every producer is done.
    Closed,
}

impl ChunkQueue {
    pub(crate) fn new(capacity: usize) -> Self {
        Self {
            state: Mutex::new(State::default()),
            ready: Condvar::new(),
            capacity: capacity.max(1),
            dropped: AtomicU64::new(0),
        }
    }

    /// Appends a chunk, dropping the oldest if full. Never blocks beyond the brief lock.
    pub(crate) fn push(&self, chunk: Chunk) {
        let mut state = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        if state.closed {
            return;
        }
        if state.chunks.len() >= self.capacity {
            state.chunks.pop_front();
            let dropped = self.dropped.fetch_add(1, Ordering::Relaxed) + 1;
            if is_power_of_ten(dropped) {
                tracing::warn!(
                    dropped,
                    "fusion is behind: dropping the oldest sensor bytes (the recording misses them too)"
                );
            }
        }
        state.chunks.push_back(chunk);
        drop(state);
        self.ready.notify_one();
    }

    /// The oldest chunk, waiting up to `wait` for one.
    pub(crate) fn pop(&self, wait: Duration) -> Popped {
        let mut state = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        if state.chunks.is_empty() && !state.closed {
            state = self
                .ready
                .wait_timeout(state, wait)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
        match state.chunks.pop_front() {
            Some(chunk) => Popped::Chunk(chunk),
            None if state.closed => Popped::Closed,
            None => Popped::Idle,
        }
    }

    /// No more chunks will be accepted; the consumer drains what is queued, then sees `Closed`.
    pub(crate) fn close(&self) {
        self.state
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .closed = true;
        self.ready.notify_all();
    }

    pub(crate) fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// 1, 10, 100, ...: when a growing count is worth a log line.
pub(crate) fn is_power_of_ten(mut n: u64) -> bool {
    while n >= 10 && n.is_multiple_of(10) {
        n /= 10;
    }
    n == 1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::recording::Direction;

    fn chunk(t: u64) -> Chunk {
        Chunk {
            sensor: 0,
            direction: Direction::Rx,
            log_time_ns: t,
            data: vec![t as u8],
            readings: Vec::new(),
        }
    }

    #[test]
    fn a_full_queue_drops_the_oldest_and_counts() {
        let queue = ChunkQueue::new(3);
        for t in 1..=5 {
            queue.push(chunk(t));
        }
        assert_eq!(queue.dropped(), 2);
        queue.close();
        let mut got = Vec::new();
        while let Popped::Chunk(c) = queue.pop(Duration::ZERO) {
            got.push(c.log_time_ns);
        }
        assert_eq!(got, [3, 4, 5]);
        assert_eq!(queue.pop(Duration::ZERO), Popped::Closed);
    }

    #[test]
    fn an_empty_open_queue_is_idle_after_the_wait() {
        let queue = ChunkQueue::new(3);
        assert_eq!(queue.pop(Duration::from_millis(1)), Popped::Idle);
    }

    #[test]
    fn drops_are_logged_at_powers_of_ten() {
        let logged: Vec<u64> = (1..=1000).filter(|&n| is_power_of_ten(n)).collect();
        assert_eq!(logged, [1, 10, 100, 1000]);
    }
}
