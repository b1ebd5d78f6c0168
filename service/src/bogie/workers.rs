//! The bogies' filters in parallel (issue 9 item 4): a small pool of worker threads that step
//! the monitors of one sample time side by side, while the ingest thread steps its share.
//!
//! Each bogie's monitor steps its own frames in order, on whichever thread, so its estimates
//! are bit for bit those of a serial run (and of `railmon analyze damper --bogie`). A monitor
//! travels to a worker boxed and comes back before the ingest thread looks at it again: alarms,
//! events, views and snapshots stay single-threaded and unchanged.

use std::sync::mpsc::{channel, Receiver, Sender};
use std::thread::JoinHandle;

use railmon_damper::{BogieSample, DamperError, DamperMonitor};

/// One monitor's step: slot, the monitor, its sample; back with the outcome.
pub(super) struct Job {
    pub(super) slot: usize,
    pub(super) monitor: Box<DamperMonitor>,
    pub(super) sample: BogieSample,
}

pub(super) struct Done {
    pub(super) slot: usize,
    pub(super) monitor: Box<DamperMonitor>,
    pub(super) outcome: StepOutcome,
}

/// How one bogie's step went: its result, its time alone, and when it was done (monotonic).
pub(super) struct StepOutcome {
    pub(super) result: Result<(), DamperError>,
    pub(super) step_ns: u64,
    pub(super) done_at_ns: u64,
}

fn run(mut job: Job) -> Done {
    let start = std::time::Instant::now();
    // `step` validates first: on error the monitor is unchanged.
    let result = job.monitor.step(&job.sample).map(|_| ());
    Done {
        slot: job.slot,
        monitor: job.monitor,
        outcome: StepOutcome {
            result,
            step_ns: start.elapsed().as_nanos() as u64,
            done_at_ns: railmon_bus::monotonic_ns(),
        },
    }
}

/// `threads` workers besides the ingest thread (0: the ingest thread steps every bogie). Job
/// `j` of a batch goes to thread `j mod (threads + 1)`, the last share staying on the ingest
/// thread: bogies cost the same, so a fixed split balances, and no queue is shared.
pub(super) struct BogieWorkers {
    jobs: Vec<Sender<Job>>,
    done: Receiver<Done>,
    threads: Vec<JoinHandle<()>>,
}

impl BogieWorkers {
    pub(super) fn new(threads: usize) -> Self {
        let (done_tx, done) = channel();
        let (jobs, threads) = (0..threads)
            .map(|i| {
                let (tx, rx) = channel::<Job>();
                let done_tx: Sender<Done> = done_tx.clone();
                let handle = std::thread::Builder::new()
                    .name(format!("bogie-worker-{i}"))
                    .spawn(move || {
                        // Ends when the pipeline drops its sender (or stops listening).
                        while let Ok(job) = rx.recv() {
                            if done_tx.send(run(job)).is_err() {
                                return;
                            }
                        }
                    })
                    .expect("spawn a bogie worker thread");
                (tx, handle)
            })
            .unzip();
        Self {
            jobs,
            done,
            threads,
        }
    }

    /// Steps every job; returns them all in `out`, in no particular order.
    pub(super) fn step_all(&self, jobs: Vec<Job>, out: &mut Vec<Done>) {
        let share = self.jobs.len() + 1;
        let mut sent = 0;
        let mut own = Vec::new();
        for (j, job) in jobs.into_iter().enumerate() {
            match self.jobs.get(j % share) {
                // A worker that died (it cannot: `run` does not panic on bad data) would
                // return the job here, to be stepped on this thread.
                Some(tx) => match tx.send(job) {
                    Ok(()) => sent += 1,
                    Err(returned) => own.push(returned.0),
                },
                None => own.push(job),
            }
        }
        out.extend(own.into_iter().map(run));
        for _ in 0..sent {
            match self.done.recv() {
                Ok(done) => out.push(done),
                Err(_) => break,
            }
        }
    }
}

impl Drop for BogieWorkers {
    fn drop(&mut self) {
        // Closing the job channels ends every worker's loop.
        self.jobs.clear();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}
