//! Timing for the bench binaries of the estimator crates (a dev-dependency only).
//!
//! Why the thread's CPU time: benches run on a 2-core machine shared with other engineers'
//! builds, where the wall clock also counts the time the thread waited for a core and so rises
//! with the other jobs' load; the time this thread spent on a core (`CLOCK_THREAD_CPUTIME_ID`)
//! much less (caches and the other hyperthread are still shared). The benches print both.

use std::time::{Duration, Instant};

/// The CPU time the calling thread has used so far.
pub fn thread_cpu_time() -> Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant Linux supports.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID)");
    Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
}

/// Thread CPU time and wall time of one measured stretch.
#[derive(Clone, Copy, Debug)]
pub struct CpuWall {
    pub cpu: Duration,
    pub wall: Duration,
}

/// Runs `f` once and returns the thread CPU time and the wall time it took.
pub fn measure(f: impl FnOnce()) -> CpuWall {
    let (cpu, wall) = (thread_cpu_time(), Instant::now());
    f();
    CpuWall {
        cpu: thread_cpu_time() - cpu,
        wall: wall.elapsed(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Work counts as CPU time, sleeping does not (the reason to use this clock).
    #[test]
    fn cpu_time_counts_work_not_sleep() {
        let busy = measure(|| {
            let mut x = 0u64;
            for i in 0..20_000_000u64 {
                x = std::hint::black_box(x ^ i);
            }
        });
        assert!(busy.cpu > Duration::ZERO, "{busy:?}");
        assert!(busy.cpu <= busy.wall + Duration::from_millis(1), "{busy:?}");
        let asleep = measure(|| std::thread::sleep(Duration::from_millis(100)));
        assert!(asleep.wall >= Duration::from_millis(100), "{asleep:?}");
        assert!(asleep.cpu < Duration::from_millis(20), "{asleep:?}");
    }
}
