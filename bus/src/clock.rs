/// CLOCK_MONOTONIC in nanoseconds: the same clock in every process of the host, so a
/// publisher's stamp and the subscriber's reading give the publish-to-estimate latency.
/// (`std::time::Instant` uses this clock too but hides the raw value.)
pub fn monotonic_ns() -> u64 {
    let mut now = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `now` is a valid, writable timespec; CLOCK_MONOTONIC is always available on Linux,
    // so the call cannot fail (its return value carries no information here).
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut now) };
    (now.tv_sec as u64) * 1_000_000_000 + now.tv_nsec as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_clock_never_goes_back_and_follows_std_sleep() {
        let start = monotonic_ns();
        std::thread::sleep(std::time::Duration::from_millis(5));
        let end = monotonic_ns();
        assert!(end >= start + 5_000_000, "start {start} end {end}");
    }
}
