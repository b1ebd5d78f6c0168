//! The event store and its disk (issue 26, item 2), with the real binaries:
//!
//! - the database stops taking writes while the service runs (every write of the process fails
//!   with EFBIG: `RLIMIT_FSIZE` lowered to 1 byte on the running service, which works as root
//!   too, where permission bits do not stop writes): the service keeps running and answering,
//!   the events wait and are counted as pending, and are written once writes work again;
//! - SIGTERM while events wait: each one not stored is counted in the log, and the events
//!   stored plus those counted are exactly the events raised;
//! - a data directory that does not take writes is refused at start (exit 1, naming it).

use std::io::Read;
use std::process::Stdio;
use std::time::{Duration, Instant};

use railmon_system_tests::{start_replay, PrivateBus, Service};
use serde_json::Value;

const SEED: &str = "config/scenarios/adhesion-seed.toml";

/// Sets the file size limit of process `pid` (`None`: unlimited).
fn limit_file_size(pid: u32, bytes: Option<u64>) {
    let value = bytes.unwrap_or(libc::RLIM_INFINITY);
    let limit = libc::rlimit {
        rlim_cur: value,
        rlim_max: libc::RLIM_INFINITY,
    };
    // SAFETY: prlimit(2) on our own child with a valid rlimit; the old value is not read.
    let rc = unsafe {
        libc::prlimit(
            pid as libc::pid_t,
            libc::RLIMIT_FSIZE,
            &limit,
            std::ptr::null_mut(),
        )
    };
    assert_eq!(rc, 0, "prlimit: {}", std::io::Error::last_os_error());
}

fn store_status(service: &Service) -> Value {
    service.get_json("/api/v1/status")["events"].clone()
}

fn wait_for_store(service: &Service, what: &str, done: impl Fn(&Value) -> bool) -> Value {
    let start = Instant::now();
    loop {
        let status = store_status(service);
        if done(&status) {
            return status;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "timed out waiting for {what}: {status}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The sum of every `railmon_drive_slip_events_total` series: the slip events raised.
fn slip_events_raised(service: &Service) -> u64 {
    let (_, text) = service.get("/metrics");
    text.lines()
        .filter(|l| l.starts_with("railmon_drive_slip_events_total{"))
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum::<f64>() as u64
}

/// Every event, page by page.
fn all_events(service: &Service) -> Vec<Value> {
    let mut after_id = 0;
    let mut all = Vec::new();
    loop {
        let page = service.get_json(&format!("/api/v1/events?after_id={after_id}&limit=1000"));
        let events = page["events"].as_array().unwrap().clone();
        if events.is_empty() {
            return all;
        }
        after_id = page["next_after_id"].as_u64().unwrap();
        all.extend(events);
    }
}

#[test]
fn a_database_that_stops_taking_writes_gives_errors_not_a_crash_and_shutdown_counts_the_loss() {
    let bus = PrivateBus::new();
    let data_dir = std::env::temp_dir().join(format!("railmon-store-disk-{}", bus.prefix));
    let _ = std::fs::remove_dir_all(&data_dir);
    let data = data_dir.to_str().unwrap().to_string();
    let settings = [("RAILMON_STORAGE__DATA_DIR", data.as_str())];
    let mut service = Service::start_with_stderr(&bus, &settings, Stdio::piped());
    let mut stderr = service.process.child.stderr.take().unwrap();
    let log = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = stderr.read_to_string(&mut text);
        text
    });
    let pid = service.process.child.id();
    let mut replay = start_replay(
        &bus,
        "drive",
        &[
            "--scenario",
            SEED,
            "--speed",
            "max",
            "--loop",
            "--wait-subscriber-s",
            "0",
        ],
    );
    wait_for_store(&service, "events stored", |s| {
        s["events_stored"].as_u64() >= Some(5)
    });

    // Every write fails (EFBIG) from now on.
    limit_file_size(pid, Some(1));
    let failing = wait_for_store(&service, "write errors and events waiting", |s| {
        s["write_errors"].as_u64() >= Some(1) && s["events_pending"].as_u64() >= Some(3)
    });
    std::thread::sleep(Duration::from_millis(1500));
    assert!(
        service.process.child.try_wait().unwrap().is_none(),
        "the service died while its disk refused writes"
    );
    assert_eq!(service.get("/healthz").0, 200);
    assert_eq!(service.get("/api/v1/events?limit=5").0, 200);
    let status = store_status(&service);
    assert!(status["last_write_error"].is_string(), "{status}");
    assert!(
        status["events_pending"].as_u64() >= failing["events_pending"].as_u64(),
        "{status}"
    );
    let series = |name: &str| service.metric(name).unwrap_or(-1.0);
    assert!(series("railmon_event_store_write_errors_total") >= 1.0);
    assert!(series("railmon_events_pending") >= 3.0);
    eprintln!("while failing: {status}");

    // Writes work again: what waited is written, by the retry alone.
    limit_file_size(pid, None);
    let recovered = wait_for_store(&service, "the backlog written", |s| {
        s["events_pending"].as_u64() == Some(0)
            && s["events_stored"].as_u64() > status["events_stored"].as_u64()
    });
    assert_eq!(recovered["events_dropped_buffer_full"], 0, "{recovered}");

    // Failing again, the replay stopped: the events waiting at SIGTERM are counted.
    limit_file_size(pid, Some(1));
    wait_for_store(&service, "events waiting again", |s| {
        s["events_pending"].as_u64() >= Some(3)
    });
    replay.terminate(Duration::from_secs(10));
    // Settled: the service has taken every frame it will get.
    let mut raised = slip_events_raised(&service);
    let mut settled_at = Instant::now();
    while settled_at.elapsed() < Duration::from_millis(800) {
        std::thread::sleep(Duration::from_millis(100));
        let now = slip_events_raised(&service);
        if now != raised {
            raised = now;
            settled_at = Instant::now();
        }
    }
    let before = store_status(&service);
    let pending = before["events_pending"].as_u64().unwrap();
    assert!(pending >= 3, "{before}");
    let exit = service.process.terminate(Duration::from_secs(20));
    let log = log.join().unwrap();
    assert_eq!(exit.code(), Some(1), "events lost: exit 1\n{log}");
    let dropped: u64 = log
        .lines()
        .find_map(|l| {
            let rest = l.split("stopping with ").nth(1)?;
            rest.split(' ').next()?.parse().ok()
        })
        .unwrap_or_else(|| panic!("no count of the events not stored in the log:\n{log}"));
    assert_eq!(dropped, pending, "{log}");
    assert!(
        log.contains(&format!(
            "railmon: stopped with {dropped} events not stored"
        )),
        "{log}"
    );
    drop(service);

    // Restarted on a disk that works: stored + dropped = raised, ids increasing.
    let service = Service::start(&bus, &settings);
    let events = all_events(&service);
    let slips: Vec<&Value> = events
        .iter()
        .filter(|e| e["kind"].as_str().is_some_and(|k| k.starts_with("slip_")))
        .collect();
    let ids: Vec<u64> = events.iter().map(|e| e["id"].as_u64().unwrap()).collect();
    assert!(ids.windows(2).all(|w| w[0] < w[1]), "ids not increasing");
    eprintln!(
        "raised {raised}, stored {}, dropped at SIGTERM {dropped} (pending {pending})",
        slips.len()
    );
    assert_eq!(slips.len() as u64 + dropped, raised);
    drop(service);
    let _ = std::fs::remove_dir_all(&data_dir);
}

#[test]
fn a_data_directory_that_takes_no_writes_is_refused_at_start() {
    use std::os::unix::fs::PermissionsExt;
    let bus = PrivateBus::new();
    let data_dir = std::env::temp_dir().join(format!("railmon-store-ro-{}", bus.prefix));
    let _ = std::fs::remove_dir_all(&data_dir);
    std::fs::create_dir_all(&data_dir).unwrap();
    std::fs::set_permissions(&data_dir, std::fs::Permissions::from_mode(0o500)).unwrap();
    // SAFETY: geteuid has no preconditions.
    let root = unsafe { libc::geteuid() } == 0;
    if root {
        // Permission bits do not stop root: the immutable flag does.
        let status = std::process::Command::new("chattr")
            .arg("+i")
            .arg(&data_dir)
            .status()
            .expect("chattr");
        assert!(status.success(), "chattr +i {}", data_dir.display());
    }
    let output = std::process::Command::new(&railmon_system_tests::binaries().railmon)
        .arg("serve")
        .env("RAILMON_STORAGE__DATA_DIR", &data_dir)
        .env("RAILMON_HTTP__LISTEN", "127.0.0.1:0")
        .envs(bus.env())
        .stdin(Stdio::null())
        .output()
        .unwrap();
    if root {
        let _ = std::process::Command::new("chattr")
            .arg("-i")
            .arg(&data_dir)
            .status();
    }
    let _ = std::fs::remove_dir_all(&data_dir);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "data directory {} does not take writes",
            data_dir.display()
        )),
        "{stderr}"
    );
}
