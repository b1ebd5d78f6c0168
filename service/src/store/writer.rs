//! The writer thread's loop, apart from SQLite ([`Sink`]): events wait in a bounded backlog
//! until a commit takes them; a failed commit (disk full, file system gone read-only) is
//! retried with backoff, so events wait out a full disk rather than being lost. Events are
//! dropped only when the backlog is full (`buffer_full`) or when the service stops before they
//! could be written (`shutdown`); both are counted ([`StoreCounters`]) and logged.

use std::collections::BTreeMap;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender};
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::{NewEvent, StoreCounters, StoreError};

/// Events waiting to be written at most (a full disk for hours at the demo's ~7,700 events an
/// hour); beyond it new events are dropped and counted.
pub const MAX_BACKLOG: usize = 50_000;
/// The first retry after a failed commit; doubled up to [`MAX_RETRY_DELAY`].
pub const FIRST_RETRY_DELAY: Duration = Duration::from_millis(100);
pub const MAX_RETRY_DELAY: Duration = Duration::from_secs(5);
/// At shutdown, how long the writer keeps trying to write what is queued.
pub const CLOSE_DEADLINE: Duration = Duration::from_secs(2);

/// Where committed events go.
pub trait Sink {
    /// Commits `events` in one transaction, or none of them: the id of the last.
    fn write(&mut self, events: &[NewEvent]) -> Result<Written, StoreError>;
}

/// What a commit did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Written {
    pub last_id: u64,
    pub pruned: u64,
}

pub enum Command {
    Append(Vec<NewEvent>),
    /// Answer once everything sent before is committed, or a commit of it failed.
    Flush(Sender<()>),
    /// Write what is queued (within [`Close::deadline`]), count the rest as dropped, answer
    /// with that count, and end.
    Close(Close),
}

pub struct Close {
    pub deadline: Duration,
    pub done: Sender<u64>,
}

/// The writer thread's state.
pub struct Writer<S> {
    pub sink: S,
    pub counters: Arc<StoreCounters>,
    pub capacity: usize,
    backlog: Vec<NewEvent>,
    retry_delay: Duration,
    next_attempt: Option<Instant>,
    /// Dropped since the backlog last had room (one log line per episode).
    overflowing: u64,
}

impl<S: Sink> Writer<S> {
    pub fn new(sink: S, counters: Arc<StoreCounters>, capacity: usize) -> Self {
        Self {
            sink,
            counters,
            capacity,
            backlog: Vec::new(),
            retry_delay: FIRST_RETRY_DELAY,
            next_attempt: None,
            overflowing: 0,
        }
    }

    /// Runs until a [`Command::Close`] or until every sender is gone (then what is queued is
    /// counted as dropped at shutdown, as with a close).
    pub fn run(mut self, commands: Receiver<Command>) {
        loop {
            let received = match self.next_attempt {
                None => commands.recv().map_err(|_| RecvTimeoutError::Disconnected),
                Some(at) => commands.recv_timeout(at.saturating_duration_since(Instant::now())),
            };
            let mut flushes = Vec::new();
            let mut close = None;
            match received {
                Ok(first) => {
                    for command in std::iter::once(first).chain(commands.try_iter()) {
                        match command {
                            Command::Append(events) => self.accept(events),
                            Command::Flush(done) => flushes.push(done),
                            Command::Close(c) => close = Some(c),
                        }
                    }
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => {
                    self.close(Duration::ZERO);
                    return;
                }
            }
            if self.next_attempt.is_none_or(|at| Instant::now() >= at) {
                self.attempt();
            }
            for done in flushes {
                let _ = done.send(());
            }
            if let Some(close) = close {
                let dropped = self.close(close.deadline);
                let _ = close.done.send(dropped);
                return;
            }
        }
    }

    /// Takes `events` into the backlog as far as it has room; the rest are dropped.
    fn accept(&mut self, mut events: Vec<NewEvent>) {
        let room = self.capacity.saturating_sub(self.backlog.len());
        if events.len() > room {
            let dropped = (events.len() - room) as u64;
            if self.overflowing == 0 {
                tracing::error!(
                    capacity = self.capacity,
                    "event backlog full (the database does not take writes): dropping new events"
                );
            }
            self.overflowing += dropped;
            self.counters
                .dropped_buffer_full
                .fetch_add(dropped, Ordering::Relaxed);
            self.counters.pending.fetch_sub(dropped, Ordering::Relaxed);
            events.truncate(room);
        }
        self.backlog.extend(events);
    }

    /// One commit of the whole backlog; on failure the next is scheduled with backoff.
    fn attempt(&mut self) -> bool {
        if self.backlog.is_empty() {
            self.next_attempt = None;
            return true;
        }
        match self.sink.write(&self.backlog) {
            Ok(written) => {
                let n = self.backlog.len() as u64;
                let c = &self.counters;
                c.stored.fetch_add(n, Ordering::Relaxed);
                c.pending.fetch_sub(n, Ordering::Relaxed);
                c.last_id.store(written.last_id, Ordering::Relaxed);
                c.pruned.fetch_add(written.pruned, Ordering::Relaxed);
                if self.next_attempt.is_some() {
                    tracing::info!(events = n, "event database takes writes again");
                }
                if self.overflowing > 0 {
                    tracing::error!(
                        dropped = self.overflowing,
                        "event backlog has room again after dropping events"
                    );
                    self.overflowing = 0;
                }
                self.backlog.clear();
                self.retry_delay = FIRST_RETRY_DELAY;
                self.next_attempt = None;
                true
            }
            Err(e) => {
                self.counters.write_errors.fetch_add(1, Ordering::Relaxed);
                let message = e.to_string();
                let mut last = self
                    .counters
                    .last_write_error
                    .lock()
                    .unwrap_or_else(|p| p.into_inner());
                if last.as_deref() != Some(message.as_str()) || self.next_attempt.is_none() {
                    tracing::error!(
                        waiting = self.backlog.len(),
                        retry_in_ms = self.retry_delay.as_millis() as u64,
                        "writing events failed, keeping them and retrying: {message}"
                    );
                }
                *last = Some(message);
                self.next_attempt = Some(Instant::now() + self.retry_delay);
                self.retry_delay = (self.retry_delay * 2).min(MAX_RETRY_DELAY);
                false
            }
        }
    }

    /// Tries to write the backlog until `deadline` has passed; counts and logs what is left.
    fn close(&mut self, deadline: Duration) -> u64 {
        let end = Instant::now() + deadline;
        loop {
            if self.attempt() {
                return 0;
            }
            let now = Instant::now();
            if now >= end {
                break;
            }
            let wait = self.retry_delay.min(Duration::from_millis(250));
            std::thread::sleep(wait.min(end - now));
        }
        let dropped = self.backlog.len() as u64;
        let c = &self.counters;
        c.dropped_shutdown.fetch_add(dropped, Ordering::Relaxed);
        c.pending.fetch_sub(dropped, Ordering::Relaxed);
        let mut kinds: BTreeMap<String, u64> = BTreeMap::new();
        for e in &self.backlog {
            *kinds.entry(format!("{}/{}", e.stream, e.kind)).or_default() += 1;
        }
        let first = self
            .backlog
            .iter()
            .map(|e| e.time_utc_ns)
            .min()
            .unwrap_or(0);
        let last = self
            .backlog
            .iter()
            .map(|e| e.time_utc_ns)
            .max()
            .unwrap_or(0);
        tracing::error!(
            dropped,
            kinds = ?kinds,
            from = %railmon_bus::utc::format_rfc3339(first),
            to = %railmon_bus::utc::format_rfc3339(last),
            "stopping with {dropped} events not stored (the database did not take writes): {}",
            c.last_write_error
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .as_deref()
                .unwrap_or("no error recorded")
        );
        self.backlog.clear();
        dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use railmon_bus::StreamKind;
    use std::sync::atomic::AtomicBool;
    use std::sync::mpsc::channel;

    /// A sink that fails while `broken` is set (an injected I/O error) and otherwise numbers
    /// the events it takes.
    struct FakeSink {
        broken: Arc<AtomicBool>,
        written: Arc<std::sync::Mutex<Vec<String>>>,
        attempts: Arc<std::sync::atomic::AtomicU64>,
    }

    impl Sink for FakeSink {
        fn write(&mut self, events: &[NewEvent]) -> Result<Written, StoreError> {
            self.attempts.fetch_add(1, Ordering::Relaxed);
            if self.broken.load(Ordering::Relaxed) {
                return Err(StoreError::Open {
                    path: "fake".into(),
                    reason: "No space left on device (os error 28)".into(),
                });
            }
            let mut written = self.written.lock().unwrap();
            written.extend(events.iter().map(|e| e.subject.clone()));
            Ok(Written {
                last_id: written.len() as u64,
                pruned: 0,
            })
        }
    }

    fn event(n: usize) -> NewEvent {
        NewEvent {
            stream: StreamKind::Drive,
            kind: "slip_started".into(),
            subject: n.to_string(),
            time_utc_ns: n as i64,
            time_s: 0.0,
            run: 0,
            run_time_s: 0.0,
            detail: serde_json::Map::new(),
            alarm: None,
        }
    }

    struct Harness {
        tx: Sender<Command>,
        counters: Arc<StoreCounters>,
        broken: Arc<AtomicBool>,
        written: Arc<std::sync::Mutex<Vec<String>>>,
        attempts: Arc<std::sync::atomic::AtomicU64>,
        thread: std::thread::JoinHandle<()>,
    }

    fn start(capacity: usize, broken: bool) -> Harness {
        let counters = Arc::new(StoreCounters::default());
        let broken = Arc::new(AtomicBool::new(broken));
        let written = Arc::default();
        let attempts = Arc::default();
        let sink = FakeSink {
            broken: broken.clone(),
            written: Arc::clone(&written),
            attempts: Arc::clone(&attempts),
        };
        let (tx, rx) = channel();
        let writer = Writer::new(sink, counters.clone(), capacity);
        let thread = std::thread::spawn(move || writer.run(rx));
        Harness {
            tx,
            counters,
            broken,
            written,
            attempts,
            thread,
        }
    }

    impl Harness {
        fn append(&self, range: std::ops::Range<usize>) {
            self.counters
                .pending
                .fetch_add(range.len() as u64, Ordering::Relaxed);
            self.tx
                .send(Command::Append(range.map(event).collect()))
                .unwrap();
        }
        fn flush(&self) {
            let (done, wait) = channel();
            self.tx.send(Command::Flush(done)).unwrap();
            wait.recv().unwrap();
        }
        fn close(self, deadline: Duration) -> u64 {
            let (done, wait) = channel();
            self.tx
                .send(Command::Close(Close { deadline, done }))
                .unwrap();
            let dropped = wait.recv().unwrap();
            self.thread.join().unwrap();
            dropped
        }
        fn get(&self, c: impl Fn(&StoreCounters) -> &std::sync::atomic::AtomicU64) -> u64 {
            c(&self.counters).load(Ordering::Relaxed)
        }
    }

    #[test]
    fn events_wait_out_a_failing_disk_and_are_written_by_a_retry_without_new_events() {
        let h = start(100, true);
        h.append(0..10);
        h.flush();
        assert_eq!(h.get(|c| &c.pending), 10);
        assert_eq!(h.get(|c| &c.write_errors), 1);
        assert!(h.counters.last_write_error.lock().unwrap().is_some());
        // Retries come on their own (no new event needed), with backoff: 100, 200, 400 ms...
        std::thread::sleep(Duration::from_millis(450));
        let attempts = h.attempts.load(Ordering::Relaxed);
        assert!((2..=4).contains(&attempts), "{attempts} attempts in 450 ms");
        h.broken.store(false, Ordering::Relaxed);
        let start = Instant::now();
        while h.get(|c| &c.pending) > 0 {
            assert!(start.elapsed() < Duration::from_secs(3), "not retried");
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(h.written.lock().unwrap().len(), 10);
        assert_eq!(h.get(|c| &c.stored), 10);
        assert_eq!(h.get(|c| &c.last_id), 10);
        assert_eq!(h.close(Duration::from_secs(1)), 0);
    }

    #[test]
    fn a_full_backlog_drops_new_events_and_counts_them() {
        let h = start(25, true);
        h.append(0..20);
        h.append(20..30);
        h.append(30..40);
        h.flush();
        assert_eq!(h.get(|c| &c.dropped_buffer_full), 15);
        assert_eq!(h.get(|c| &c.pending), 25);
        h.broken.store(false, Ordering::Relaxed);
        let written = h.written.clone();
        assert_eq!(h.close(Duration::from_secs(1)), 0);
        let written = written.lock().unwrap().clone();
        // The oldest 25 kept, in order.
        assert_eq!(written, (0..25).map(|n| n.to_string()).collect::<Vec<_>>());
    }

    #[test]
    fn what_cannot_be_written_by_the_close_deadline_is_counted_as_dropped_at_shutdown() {
        let h = start(100, true);
        h.append(0..38);
        let counters = h.counters.clone();
        let written = h.written.clone();
        let start = Instant::now();
        assert_eq!(h.close(Duration::from_millis(300)), 38);
        assert!(start.elapsed() < Duration::from_secs(2));
        assert_eq!(counters.dropped_shutdown.load(Ordering::Relaxed), 38);
        assert_eq!(counters.pending.load(Ordering::Relaxed), 0);
        assert_eq!(counters.stored.load(Ordering::Relaxed), 0);
        assert!(written.lock().unwrap().is_empty());
    }

    #[test]
    fn a_disk_that_recovers_before_the_close_deadline_loses_nothing() {
        let h = start(100, true);
        h.append(0..5);
        h.flush();
        let broken = h.broken.clone();
        let healer = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(200));
            broken.store(false, Ordering::Relaxed);
        });
        let written = h.written.clone();
        assert_eq!(h.close(Duration::from_secs(2)), 0);
        healer.join().unwrap();
        assert_eq!(written.lock().unwrap().len(), 5);
    }
}
