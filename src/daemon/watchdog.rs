//! systemd's watchdog, fed by the fusion loop's progress rather than by a timer: a task that
//! pings on a timer would keep a daemon whose pipeline is stuck "healthy" forever.
//!
//! The fusion loop calls [`Progress::advance`] once per iteration; [`run`] pings systemd at half
//! the watchdog interval only if the loop advanced since the last ping. `sd_notify` is a
//! blocking datagram send, so it runs on the blocking pool, never on a worker thread.

use sd_notify::NotifyState;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

/// Cloneable counter the fusion loop advances.
#[derive(Debug, Clone, Default)]
pub(crate) struct Progress(Arc<AtomicU64>);

impl Progress {
    pub(crate) fn advance(&self) {
        self.0.fetch_add(1, Ordering::Relaxed);
    }

    fn count(&self) -> u64 {
        self.0.load(Ordering::Relaxed)
    }
}

/// Decides, tick by tick, whether the loop has moved since the previous tick.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct ProgressGate {
    last: Option<u64>,
}

impl ProgressGate {
    pub(crate) fn new() -> Self {
        Self { last: None }
    }

    /// True when `count` differs from the count at the previous call (the first call only
    /// records it: starting up is not progress).
    pub(crate) fn moved(&mut self, count: u64) -> bool {
        let moved = self.last.is_some_and(|last| last != count);
        self.last = Some(count);
        moved
    }
}

impl Default for ProgressGate {
    fn default() -> Self {
        Self::new()
    }
}

async fn notify(state: NotifyState<'static>) {
    // Losing a notification is harmless (systemd restarts us if it matters); blocking is not.
    let _ = tokio::task::spawn_blocking(move || sd_notify::notify(&[state])).await;
}

/// Replaces the status line of `systemctl status` (from the fusion thread: a datagram, no
/// waiting; outside systemd it does nothing).
pub(crate) fn status(line: &str) {
    let _ = sd_notify::notify(&[NotifyState::Status(line)]);
}

/// Tells systemd the daemon is up (`Type=notify`), with a status line for `systemctl status`.
pub(crate) async fn ready(status: &str) {
    let status = status.to_string();
    let _ = tokio::task::spawn_blocking(move || {
        sd_notify::notify(&[NotifyState::Ready, NotifyState::Status(&status)])
    })
    .await;
}

pub(crate) async fn stopping() {
    notify(NotifyState::Stopping).await;
}

/// Feeds the watchdog until `cancel`; returns at once when systemd set none (`WatchdogSec`
/// unset, or not running under systemd).
pub(crate) async fn run(progress: Progress, cancel: CancellationToken) {
    let Some(interval) = sd_notify::watchdog_enabled() else {
        return;
    };
    run_every(interval / 2, progress, cancel, || {
        notify(NotifyState::Watchdog)
    })
    .await;
}

async fn run_every<F, Fut>(period: Duration, progress: Progress, cancel: CancellationToken, ping: F)
where
    F: Fn() -> Fut,
    Fut: std::future::Future<Output = ()>,
{
    let mut ticks = tokio::time::interval(period);
    let mut gate = ProgressGate::new();
    loop {
        tokio::select! {
            () = cancel.cancelled() => return,
            _ = ticks.tick() => {
                if gate.moved(progress.count()) {
                    ping().await;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;

    #[test]
    fn the_gate_opens_only_on_progress() {
        let mut gate = ProgressGate::new();
        assert!(!gate.moved(0), "start-up is not progress");
        assert!(!gate.moved(0));
        assert!(gate.moved(3));
        assert!(!gate.moved(3), "a stuck loop stops the pings");
        assert!(gate.moved(4));
    }

    #[tokio::test]
    async fn pings_while_the_loop_advances_and_stops_when_it_sticks() {
        let progress = Progress::default();
        let pings = Arc::new(AtomicUsize::new(0));
        let cancel = CancellationToken::new();
        let task = {
            let (progress, pings, cancel) = (progress.clone(), pings.clone(), cancel.clone());
            tokio::spawn(async move {
                let ping = move || {
                    pings.fetch_add(1, Ordering::Relaxed);
                    std::future::ready(())
                };
                run_every(Duration::from_millis(20), progress, cancel, ping).await;
            })
        };
        for _ in 0..20 {
            progress.advance();
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        // Real time on a loaded machine: ticks may be late, so only a loose lower bound.
        let while_running = pings.load(Ordering::Relaxed);
        assert!((3..=20).contains(&while_running), "{while_running}");
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(
            pings.load(Ordering::Relaxed) <= while_running + 1,
            "no pings once the loop is stuck"
        );
        cancel.cancel();
        task.await.unwrap();
    }
}
