//! The event store's figures (issue 12): sustained event writes per second (one event per
//! transaction, as when events are rare, and in batches, as after a burst), database size per
//! event, and the latency of `GET`-ing a page from a 100,000-event history (p50 / p99 over
//! pages across the whole history, with and without a kind filter).
//!
//! `cargo bench -p railmon-service --bench store` (prints a table; the machine is shared, so
//! read the numbers as orders of magnitude).

use std::time::{Duration, Instant};

use railmon_bus::StreamKind;
use railmon_service::config::Identity;
use railmon_service::config::StorageConfig;
use railmon_service::store::{EventQuery, EventStore, NewEvent};

fn event(k: u64) -> NewEvent {
    let mut detail = serde_json::Map::new();
    detail.insert("drive".into(), (k % 8 + 1).into());
    detail.insert("slip_probability".into(), 0.8134.into());
    NewEvent {
        stream: StreamKind::Drive,
        kind: if k.is_multiple_of(2) {
            "slip_started"
        } else {
            "slip_ended"
        }
        .into(),
        subject: (k % 8 + 1).to_string(),
        time_utc_ns: 1_795_000_000_000_000_000 + k as i64 * 1_000_000,
        time_s: k as f64 * 1e-3,
        run: 0,
        run_time_s: k as f64 * 1e-3,
        detail,
        alarm: Some(("slipping".into(), k.is_multiple_of(2))),
    }
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn main() {
    let dir = std::env::temp_dir().join(format!("railmon-store-bench-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let config = StorageConfig {
        data_dir: dir.display().to_string(),
        ..StorageConfig::default()
    };
    let identity = Identity {
        vehicle_id: "bench-unit".into(),
        fleet: "bench".into(),
    };
    let (store, _writer) = EventStore::open(&config, &identity).unwrap();

    // One event per commit (each waited for): the rate a burst of separate events sustains.
    let n_single = 500u64;
    let start = Instant::now();
    for k in 0..n_single {
        store.append(vec![event(k)]);
        store.flush();
    }
    let single = n_single as f64 / start.elapsed().as_secs_f64();

    // Batches of 100 (what the writer thread commits when events queue up).
    let total = 100_000u64;
    let start = Instant::now();
    let mut k = n_single;
    while k < total {
        store.append((k..(k + 100).min(total)).map(event).collect());
        k += 100;
    }
    store.flush();
    let batched = (total - n_single) as f64 / start.elapsed().as_secs_f64();
    let size: u64 = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.metadata().map_or(0, |m| m.len()))
        .sum();

    let pages = |kind: Option<&str>| {
        let mut times = Vec::new();
        for p in 0..400u64 {
            let after_id = p * (total / 400);
            let query = EventQuery {
                after_id,
                kind: kind.map(str::to_string),
                limit: 100,
                ..EventQuery::default()
            };
            let start = Instant::now();
            let page = store.page(&query).unwrap();
            times.push(start.elapsed());
            assert!(!page.is_empty());
        }
        times.sort();
        (percentile(&times, 0.5), percentile(&times, 0.99))
    };
    let (p50, p99) = pages(None);
    let (kp50, kp99) = pages(Some("slip_ended"));
    println!("event store ({}):", dir.display());
    println!("  writes, one event per commit (synchronous = FULL): {single:>10.0} events/s");
    println!("  writes, batches of 100:                            {batched:>10.0} events/s");
    println!(
        "  database after {total} events: {:.1} MB ({:.0} bytes/event)",
        size as f64 / 1e6,
        size as f64 / total as f64
    );
    println!("  GET page of 100 by after_id:        p50 {p50:>10.2?}  p99 {p99:>10.2?}");
    println!("  GET page of 100 by after_id + kind: p50 {kp50:>10.2?}  p99 {kp99:>10.2?}");
    store.close();
    let _ = std::fs::remove_dir_all(&dir);
}
