//! Helpers for system tests that run the real `railmon serve` and `sensors-replay` binaries.
//!
//! Binaries: a test of this package cannot name another package's binary with
//! `env!("CARGO_BIN_EXE_...")`, and a dependency on a binary-only package is not possible on
//! stable Cargo. So the first test that needs them runs `$CARGO build --workspace --bin railmon
//! --bin sensors-replay --examples` into the same target directory and profile as the test
//! executable (derived from its path); Cargo holds no lock while tests run, and the build is a
//! no-op when they are up to date.
//!
//! Why `--workspace` and `--examples`: Cargo unifies a dependency's features over the packages
//! a command selects, and includes their dev-dependencies only when it builds a target that
//! needs them (tests, examples, benches). `cargo test --workspace` (CI, the README) does both:
//! criterion, a dev-dependency of the estimator crates, brings `half` (`zerocopy/derive`) and
//! `regex` (more `regex-automata` features), and `rand` and `tracing-subscriber` use those two,
//! so with `cargo build --bins -p railmon-service -p sensors-replay` every workspace library got
//! other features and was compiled a second time (17 crates, 176 s on the shared 2 cores, after a
//! warm `cargo test --workspace --no-run`). This command resolves features as `cargo test
//! --workspace` does: there only `sensors-replay`'s binary is new (19 s; the examples are built
//! by `cargo test` anyway). Run alone (`cargo test -p railmon-system-tests`, `cargo bench
//! --bench e2e`), the first run also builds the examples and criterion in that profile.
//!
//! Isolation: every [`PrivateBus`] has its own iceoryx2 prefix, and every service listens on
//! port 0 and reports its bound address through `--addr-file`, so tests run in parallel.
//! Child processes are killed when their handle is dropped (a failing test leaves none behind).

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use railmon_bus::BusConfig;

pub mod monitoring;
pub mod nats;
pub mod nats_cluster;

pub struct Binaries {
    pub railmon: PathBuf,
    pub replay: PathBuf,
}

/// Builds (if needed) and locates both binaries.
pub fn binaries() -> &'static Binaries {
    static BINARIES: OnceLock<Binaries> = OnceLock::new();
    BINARIES.get_or_init(|| {
        let exe = std::env::current_exe().expect("test executable path");
        // <target>/<profile dir>/deps/<test>
        let profile_dir = exe
            .parent()
            .and_then(Path::parent)
            .expect("target/<profile>/deps");
        let target_dir = profile_dir.parent().expect("target dir");
        let profile = match profile_dir.file_name().and_then(|n| n.to_str()) {
            Some("debug") => "dev",
            Some(other) => other,
            None => "dev",
        };
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let status = Command::new(cargo)
            .args([
                "build",
                "--workspace",
                "--bin",
                "railmon",
                "--bin",
                "sensors-replay",
                "--examples",
            ])
            .args(["--profile", profile])
            .arg("--target-dir")
            .arg(target_dir)
            .status()
            .expect("running cargo build for the system-test binaries");
        assert!(
            status.success(),
            "cargo build of railmon and sensors-replay failed"
        );
        Binaries {
            railmon: profile_dir.join("railmon"),
            replay: profile_dir.join("sensors-replay"),
        }
    })
}

/// The workspace root (for `config/...`).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A bus nobody else uses: its own iceoryx2 prefix and root path. Dropping it (after the
/// processes, which are declared later) removes what iceoryx2 leaves behind: the per-prefix
/// management segment in /dev/shm and the sockets of SIGKILLed processes.
#[derive(Debug)]
pub struct PrivateBus {
    pub prefix: String,
    pub root_path: String,
}

impl PrivateBus {
    pub fn new() -> Self {
        static N: AtomicUsize = AtomicUsize::new(0);
        let n = N.fetch_add(1, Ordering::Relaxed);
        let prefix = format!("rmst{}_{n}_", std::process::id());
        Self {
            root_path: format!("/tmp/railmon-test/{prefix}/"),
            prefix,
        }
    }

    /// Environment for both processes.
    pub fn env(&self) -> Vec<(String, String)> {
        vec![
            ("RAILMON_BUS__PREFIX".into(), self.prefix.clone()),
            ("RAILMON_BUS__ROOT_PATH".into(), self.root_path.clone()),
        ]
    }

    /// The same bus for an in-test publisher.
    pub fn config(&self) -> BusConfig {
        BusConfig {
            prefix: self.prefix.clone(),
            root_path: self.root_path.clone(),
            ..BusConfig::default()
        }
    }
}

impl Drop for PrivateBus {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.root_path);
        if let Ok(entries) = std::fs::read_dir("/dev/shm") {
            for entry in entries.flatten() {
                if entry
                    .file_name()
                    .to_string_lossy()
                    .starts_with(&self.prefix)
                {
                    let _ = std::fs::remove_file(entry.path());
                }
            }
        }
    }
}

impl Default for PrivateBus {
    fn default() -> Self {
        Self::new()
    }
}

/// A child process, killed on drop unless it already exited.
pub struct Process {
    pub child: Child,
    pub name: String,
}

impl Process {
    fn signal(&self, signal: libc::c_int) {
        // SAFETY: kill(2) on our own child's pid; no memory is involved.
        unsafe { libc::kill(self.child.id() as libc::pid_t, signal) };
    }

    /// SIGTERM, then waits up to `timeout` for the exit.
    pub fn terminate(&mut self, timeout: Duration) -> ExitStatus {
        self.signal(libc::SIGTERM);
        self.wait(timeout)
    }

    pub fn kill_hard(&mut self) {
        self.signal(libc::SIGKILL);
        let _ = self.child.wait();
    }

    /// Waits for the exit; panics after `timeout`.
    pub fn wait(&mut self, timeout: Duration) -> ExitStatus {
        let start = Instant::now();
        loop {
            if let Some(status) = self.child.try_wait().expect("try_wait") {
                return status;
            }
            assert!(
                start.elapsed() < timeout,
                "{} did not exit within {timeout:?}",
                self.name
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.kill_hard();
        }
    }
}

/// A running `railmon serve` and its HTTP address.
pub struct Service {
    pub process: Process,
    pub addr: String,
    /// The event database's directory when the test did not give one (removed on drop).
    own_data_dir: Option<PathBuf>,
}

impl Drop for Service {
    fn drop(&mut self) {
        if let Some(dir) = &self.own_data_dir {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

impl Service {
    /// Starts `railmon serve` on `bus` with a free port and extra `RAILMON_...` settings.
    pub fn start(bus: &PrivateBus, settings: &[(&str, &str)]) -> Service {
        Self::start_with_stderr(bus, settings, Stdio::inherit())
    }

    /// [`Service::start`] with its stderr sent to `stderr` (`Stdio::piped()` to read its log).
    pub fn start_with_stderr(
        bus: &PrivateBus,
        settings: &[(&str, &str)],
        stderr: Stdio,
    ) -> Service {
        static N: AtomicUsize = AtomicUsize::new(0);
        let addr_file = std::env::temp_dir().join(format!(
            "railmon-test-addr-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_file(&addr_file);
        // Every service its own event database, unless the test gives one (to restart on it).
        let own_data_dir = match settings
            .iter()
            .any(|(k, _)| *k == "RAILMON_STORAGE__DATA_DIR")
        {
            true => None,
            false => Some(std::env::temp_dir().join(format!(
                "railmon-test-data-{}-{}",
                std::process::id(),
                N.fetch_add(1, Ordering::Relaxed)
            ))),
        };
        let mut command = Command::new(&binaries().railmon);
        if let Some(dir) = &own_data_dir {
            command.env("RAILMON_STORAGE__DATA_DIR", dir);
        }
        command
            .args(["serve", "--addr-file"])
            .arg(&addr_file)
            .env("RAILMON_HTTP__LISTEN", "127.0.0.1:0")
            .env("RAILMON_LOG", "warn")
            .envs(bus.env())
            .envs(settings.iter().map(|(k, v)| (k.to_string(), v.to_string())))
            .stdin(Stdio::null())
            .stderr(stderr);
        let child = command.spawn().expect("starting railmon serve");
        let mut process = Process {
            child,
            name: "railmon serve".into(),
        };
        let start = Instant::now();
        let addr = loop {
            if let Ok(addr) = std::fs::read_to_string(&addr_file) {
                if !addr.is_empty() {
                    break addr;
                }
            }
            if let Some(status) = process.child.try_wait().unwrap() {
                panic!("railmon serve exited early: {status}");
            }
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "railmon serve did not start"
            );
            std::thread::sleep(Duration::from_millis(10));
        };
        let _ = std::fs::remove_file(&addr_file);
        Service {
            process,
            addr,
            own_data_dir,
        }
    }

    /// GET `path`: status code and body.
    pub fn get(&self, path: &str) -> (u16, String) {
        http_get(&self.addr, path)
    }

    pub fn get_json(&self, path: &str) -> serde_json::Value {
        let (status, body) = self.get(path);
        assert_eq!(status, 200, "GET {path}: {body}");
        serde_json::from_str(&body).unwrap_or_else(|e| panic!("GET {path}: {e}: {body}"))
    }

    /// The entry of `stream` (`drive`, `vehicle`) in `/api/v1/status`.
    pub fn status(&self, stream: &str) -> serde_json::Value {
        let status = self.get_json("/api/v1/status");
        status["streams"]
            .as_array()
            .and_then(|s| s.iter().find(|s| s["stream"] == stream))
            .unwrap_or_else(|| panic!("no stream {stream} in {status}"))
            .clone()
    }

    /// Polls until `done(status of stream)` or panics after `timeout`.
    pub fn wait_for_status(
        &self,
        stream: &str,
        timeout: Duration,
        what: &str,
        done: impl Fn(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        let start = Instant::now();
        loop {
            let status = self.status(stream);
            if done(&status) {
                return status;
            }
            assert!(
                start.elapsed() < timeout,
                "timed out waiting for {what}: {status}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// After `good` accepted frames, one rejected frame per entry of `reasons` (in order) was
    /// sent on `stream`: waits for them and checks that each was counted under its reason, in
    /// the status and in the metrics, and that none reached the estimator.
    pub fn assert_rejections(&self, stream: &str, good: u64, reasons: &[&str]) {
        let n = reasons.len() as u64;
        let status = self.wait_for_status(stream, Duration::from_secs(5), "rejections", |s| {
            s["samples_rejected"].as_u64() == Some(n)
        });
        assert_eq!(
            status["samples_received"].as_u64(),
            Some(good + n),
            "{status}"
        );
        assert_eq!(status["estimator_steps"].as_u64(), Some(good), "{status}");
        let last = reasons.last().copied().unwrap_or_default();
        assert_eq!(status["last_rejection"]["reason"], last, "{status}");
        for reason in reasons {
            let series = format!(
                "railmon_stream_samples_rejected_total{{reason=\"{reason}\",stream=\"{stream}\"}}"
            );
            assert_eq!(self.metric(&series), Some(1.0), "{series}");
        }
    }

    /// Polls `/readyz` until it answers `code`; returns how long that took.
    pub fn wait_for_readyz(&self, code: u16, timeout: Duration) -> Duration {
        let start = Instant::now();
        loop {
            if self.get("/readyz").0 == code {
                return start.elapsed();
            }
            assert!(
                start.elapsed() < timeout,
                "/readyz did not answer {code} within {timeout:?}"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// The value of a metric line (`name{labels}`) in `/metrics`.
    /// The value of `series` (name and its own labels; the identity labels are ignored).
    pub fn metric(&self, series: &str) -> Option<f64> {
        let (_, text) = self.get("/metrics");
        text.lines().find_map(|l| {
            without_identity_labels(l)
                .strip_prefix(series)?
                .strip_prefix(' ')?
                .parse()
                .ok()
        })
    }
}

/// A metrics text line without the identity labels every series carries (`vehicle_id`,
/// `fleet`), so that tests name series by their own labels.
pub fn without_identity_labels(line: &str) -> String {
    let (Some(open), Some(close)) = (line.find('{'), line.find('}')) else {
        return line.to_string();
    };
    let kept: Vec<&str> = line[open + 1..close]
        .split(',')
        .filter(|l| !l.starts_with("vehicle_id=") && !l.starts_with("fleet="))
        .collect();
    match kept.is_empty() {
        true => format!("{}{}", &line[..open], &line[close + 1..]),
        false => format!(
            "{}{{{}}}{}",
            &line[..open],
            kept.join(","),
            &line[close + 1..]
        ),
    }
}

/// Starts `sensors-replay <stream>` on `bus` with `args` (its stderr goes to the test's).
pub fn start_replay(bus: &PrivateBus, stream: &str, args: &[&str]) -> Process {
    start_replay_with_stderr(bus, stream, args, Stdio::inherit())
}

/// [`start_replay`] with its stderr sent to `stderr` (`Stdio::piped()` to read its summary).
pub fn start_replay_with_stderr(
    bus: &PrivateBus,
    stream: &str,
    args: &[&str],
    stderr: Stdio,
) -> Process {
    let child = Command::new(&binaries().replay)
        .arg(stream)
        .args(args)
        .current_dir(workspace_root())
        .envs(bus.env())
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(stderr)
        .spawn()
        .expect("starting sensors-replay");
    Process {
        child,
        name: "sensors-replay".into(),
    }
}

/// A minimal HTTP/1.1 GET (the tests need no HTTP client crate).
pub fn http_get(addr: &str, path: &str) -> (u16, String) {
    let mut stream = TcpStream::connect(addr).unwrap_or_else(|e| panic!("connect {addr}: {e}"));
    stream
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut raw = Vec::new();
    stream.read_to_end(&mut raw).unwrap();
    let text = String::from_utf8_lossy(&raw);
    let (head, body) = text.split_once("\r\n\r\n").expect("HTTP response head");
    let status = head
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .expect("HTTP status code");
    let chunked = head
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked");
    let body = if chunked {
        dechunk(body)
    } else {
        body.to_string()
    };
    (status, body)
}

fn dechunk(mut body: &str) -> String {
    let mut out = String::new();
    while let Some((size, rest)) = body.split_once("\r\n") {
        let size = usize::from_str_radix(size.trim(), 16).unwrap_or(0);
        if size == 0 {
            break;
        }
        out.push_str(&rest[..size]);
        body = &rest[size + 2..];
    }
    out
}
