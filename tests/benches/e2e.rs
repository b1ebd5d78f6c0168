//! End-to-end benchmark of the real processes (release build):
//! `cargo bench -p railmon-system-tests --bench e2e`.
//!
//! 1. Throughput: `sensors-replay --speed max` of an 8-drive, 8 kHz scenario (the seed with 8
//!    drives); sustained drive frames/s through bus + estimator, drops, publish-to-estimate
//!    latency p50/p99 (interpolated in the service's histogram buckets, like Prometheus'
//!    `histogram_quantile`).
//! 2. Real-time pace (`--speed 1`): latency p50/p99.
//! 3. HTTP under load while ingesting at real-time pace: `wrk` against `/api/v1/drives`
//!    (skipped when `wrk` is not installed: `apt-get install wrk`).

use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use railmon_system_tests::{start_replay, workspace_root, PrivateBus, Service};

const DRIVES: usize = 8;

/// The seed scenario with `DRIVES` drives and `steps` steps, written to a temporary file.
fn scenario(steps: usize) -> PathBuf {
    let seed =
        std::fs::read_to_string(workspace_root().join("config/scenarios/adhesion-seed.toml"))
            .expect("seed scenario");
    let mut table: toml::Table = seed.parse().expect("seed TOML");
    table.insert("n_drives".into(), toml::Value::Integer(DRIVES as i64));
    table.insert("n_steps".into(), toml::Value::Integer(steps as i64));
    table.insert("name".into(), toml::Value::String("bench-8-drives".into()));
    let path =
        std::env::temp_dir().join(format!("railmon-bench-{}-{steps}.toml", std::process::id()));
    std::fs::write(&path, toml::to_string(&table).unwrap()).unwrap();
    path
}

/// `q`-quantile of a Prometheus histogram in `/metrics` (linear within the bucket).
fn histogram_quantile(metrics: &str, name: &str, q: f64) -> Option<f64> {
    let prefix = format!("{name}_bucket{{");
    let mut buckets: Vec<(f64, f64)> = metrics
        .lines()
        .filter(|l| l.starts_with(&prefix))
        .filter_map(|l| {
            let le = l.split("le=\"").nth(1)?.split('"').next()?;
            let le = if le == "+Inf" {
                f64::INFINITY
            } else {
                le.parse().ok()?
            };
            let count = l.rsplit(' ').next()?.parse().ok()?;
            Some((le, count))
        })
        .collect();
    buckets.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total = buckets.last()?.1;
    if total == 0.0 {
        return None;
    }
    let rank = q * total;
    let (mut lower, mut below) = (0.0, 0.0);
    for (le, count) in buckets {
        if count >= rank {
            if le.is_infinite() {
                return Some(lower);
            }
            let fraction = if count > below {
                (rank - below) / (count - below)
            } else {
                1.0
            };
            return Some(lower + (le - lower) * fraction);
        }
        (lower, below) = (le, count);
    }
    None
}

fn latency_us(service: &Service) -> (f64, f64) {
    let (_, metrics) = service.get("/metrics");
    let name = "railmon_publish_to_estimate_latency_seconds";
    let q = |q| histogram_quantile(&metrics, name, q).unwrap_or(f64::NAN) * 1e6;
    (q(0.5), q(0.99))
}

fn throughput(steps: usize) {
    let path = scenario(steps);
    let bus = PrivateBus::new();
    let service = Service::start(&bus, &[]);
    let mut replay = start_replay(
        &bus,
        "drive",
        &["--scenario", path.to_str().unwrap(), "--speed", "max"],
    );
    let first = service.wait_for_status("drive", Duration::from_secs(30), "first frame", |s| {
        s["samples_received"].as_u64() > Some(0)
    });
    let t_first = Instant::now();
    let n = steps as u64;
    let last = service.wait_for_status("drive", Duration::from_secs(300), "all frames", |s| {
        s["estimator_steps"].as_u64().unwrap_or(0) + s["samples_rejected"].as_u64().unwrap_or(0)
            >= n - s["sequence_gaps"].as_u64().unwrap_or(0)
    });
    let elapsed = t_first.elapsed().as_secs_f64();
    assert!(replay.wait(Duration::from_secs(60)).success());
    let received =
        last["samples_received"].as_u64().unwrap() - first["samples_received"].as_u64().unwrap();
    let frames_per_s = received as f64 / elapsed;
    let drops = last["sequence_gaps"].as_u64().unwrap()
        + last["samples_rejected"].as_u64().unwrap()
        + (n - last["samples_received"].as_u64().unwrap());
    let (p50, p99) = latency_us(&service);
    println!(
        "throughput  --speed max  {DRIVES} drives x {steps} frames: {frames_per_s:>9.0} frames/s = {:.2} M drive-samples/s = {:.1}x real time (8 kHz); drops {drops}; estimator step mean {:.2} us; publish->estimate p50 {p50:.0} us, p99 {p99:.0} us",
        frames_per_s * DRIVES as f64 / 1e6,
        frames_per_s / 8000.0,
        last["estimator_step_mean_us"].as_f64().unwrap_or(f64::NAN),
    );
    let _ = std::fs::remove_file(path);
}

fn real_time_and_http(seconds: f64) {
    let steps = (seconds * 8000.0) as usize;
    let path = scenario(steps);
    let bus = PrivateBus::new();
    let service = Service::start(&bus, &[]);
    let mut replay = start_replay(
        &bus,
        "drive",
        &[
            "--scenario",
            path.to_str().unwrap(),
            "--speed",
            "1",
            "--loop",
        ],
    );
    service.wait_for_readyz(200, Duration::from_secs(30));
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let (p50, p99) = latency_us(&service);
    let status = service.status("drive");
    println!(
        "real time   --speed 1    {DRIVES} drives at 8 kHz, {seconds} s: publish->estimate p50 {p50:.0} us, p99 {p99:.0} us; gaps {}",
        status["sequence_gaps"]
    );
    match Command::new("wrk")
        .args(["-t2", "-c32", "-d5s", "--latency"])
        .arg(format!("http://{}/api/v1/drives", service.addr))
        .output()
    {
        Ok(out) if out.status.success() => {
            let text = String::from_utf8_lossy(&out.stdout);
            let pick = |key: &str| {
                text.lines()
                    .find(|l| l.trim_start().starts_with(key))
                    .map(|l| l.split_whitespace().collect::<Vec<_>>().join(" "))
                    .unwrap_or_default()
            };
            let after = service.status("drive");
            println!(
                "http        wrk -t2 -c32 -d5s /api/v1/drives while ingesting at real time: {}; latency {}; {}; ingest gaps {}",
                pick("Requests/sec"),
                pick("99%"),
                pick("50%"),
                after["sequence_gaps"]
            );
        }
        _ => println!("http        skipped: `wrk` not installed (apt-get install wrk)"),
    }
    replay.terminate(Duration::from_secs(10));
    let _ = std::fs::remove_file(path);
}

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` passes nothing special: keep it short then.
    let full = std::env::args().any(|a| a == "--bench");
    if full {
        throughput(320_000);
        real_time_and_http(5.0);
    } else {
        throughput(20_000);
    }
}
