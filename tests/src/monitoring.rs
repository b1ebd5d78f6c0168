//! Real Prometheus and Alertmanager servers for the system tests (Debian packages
//! `prometheus` and `prometheus-alertmanager`; `scripts/install-test-deps` installs them, or
//! set `PROMETHEUS` / `ALERTMANAGER` / `PROMTOOL` to the binaries). Each runs in a temporary
//! directory of its own on a free port of 127.0.0.1, and is killed when dropped.

use std::net::TcpListener;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::{http_get, workspace_root, Process};

/// A free TCP port of 127.0.0.1 (as `127.0.0.1:port`).
pub fn free_addr() -> String {
    let port = TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port");
    format!("127.0.0.1:{port}")
}

/// Percent-encodes a query parameter.
pub fn encode(value: &str) -> String {
    value
        .bytes()
        .map(|b| match b {
            b'a'..=b'z' | b'A'..=b'Z' | b'0'..=b'9' | b'_' | b'-' | b'.' => (b as char).to_string(),
            _ => format!("%{b:02X}"),
        })
        .collect()
}

/// Polls `check` every 100 ms; panics naming `what` after `timeout`.
pub fn wait_for(what: &str, timeout: Duration, mut check: impl FnMut() -> bool) {
    let start = Instant::now();
    while !check() {
        assert!(start.elapsed() < timeout, "{what} within {timeout:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn temp_dir(name: &str) -> PathBuf {
    use std::sync::atomic::{AtomicUsize, Ordering};
    static N: AtomicUsize = AtomicUsize::new(0);
    let dir = std::env::temp_dir().join(format!(
        "railmon-{name}-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn spawn(env: &str, default: &str, args: Vec<String>) -> Process {
    spawn_with_env(env, default, args, &[])
}

fn spawn_with_env(
    env: &str,
    default: &str,
    args: Vec<String>,
    envs: &[(String, String)],
) -> Process {
    let binary = std::env::var(env).unwrap_or_else(|_| default.into());
    let child = Command::new(&binary)
        .args(&args)
        .envs(envs.iter().map(|(k, v)| (k, v)))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| {
            panic!("cannot start `{binary}` ({e}): run scripts/install-test-deps, or set {env}")
        });
    Process {
        child,
        name: binary,
    }
}

/// A Prometheus server.
pub struct Prometheus {
    pub process: Process,
    pub addr: String,
    dir: PathBuf,
    /// The command line and environment, to start it again on the same port and data.
    args: Vec<String>,
    envs: Vec<(String, String)>,
}

/// What a [`Prometheus`] runs as.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum PrometheusMode {
    /// A server that scrapes, stores and evaluates rules.
    Server,
    /// A server that also accepts remote writes (`--web.enable-remote-write-receiver`): the
    /// ground of dashboards/prometheus/ground.yml.
    Receiver,
    /// Agent mode (`--enable-feature=agent`): scrapes and remote-writes from its WAL, no
    /// queries; `${VAR}` in external labels from the environment (`expand-external-labels`):
    /// the onboard agent of dashboards/prometheus/agent.yml.
    Agent,
}

impl Prometheus {
    /// Starts Prometheus with `config` (prometheus.yml text; `{rules}` in it is replaced by
    /// the path of the repository's `dashboards/prometheus/alerts.yml`) and waits until it
    /// answers.
    pub fn start(config: &str) -> Prometheus {
        Self::start_as(PrometheusMode::Server, config, &[])
    }

    /// [`Prometheus::start`] in `mode`, with `envs` added to its environment.
    pub fn start_as(mode: PrometheusMode, config: &str, envs: &[(&str, &str)]) -> Prometheus {
        let dir = temp_dir("prometheus");
        let rules = workspace_root().join("dashboards/prometheus/alerts.yml");
        let config = config.replace("{rules}", &rules.display().to_string());
        std::fs::write(dir.join("prometheus.yml"), config).unwrap();
        let addr = free_addr();
        let mut args = vec![
            format!("--config.file={}", dir.join("prometheus.yml").display()),
            format!("--web.listen-address={addr}"),
        ];
        match mode {
            PrometheusMode::Server | PrometheusMode::Receiver => args.push(format!(
                "--storage.tsdb.path={}",
                dir.join("data").display()
            )),
            // 2.42 refuses the tsdb flags in agent mode; its WAL has a flag of its own.
            PrometheusMode::Agent => args.extend([
                "--enable-feature=agent,expand-external-labels".to_string(),
                format!("--storage.agent.path={}", dir.join("agent").display()),
                "--storage.agent.wal-compression".to_string(),
            ]),
        }
        if mode == PrometheusMode::Receiver {
            args.push("--web.enable-remote-write-receiver".into());
        }
        let envs: Vec<(String, String)> = envs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        let process = spawn_with_env("PROMETHEUS", "prometheus", args.clone(), &envs);
        let prometheus = Prometheus {
            process,
            addr,
            dir,
            args,
            envs,
        };
        prometheus.wait_ready();
        prometheus
    }

    fn wait_ready(&self) {
        wait_for("Prometheus answering", Duration::from_secs(30), || {
            std::net::TcpStream::connect(&self.addr).is_ok()
        });
    }

    /// Stops it (SIGTERM, a clean shutdown), keeping its data directory.
    pub fn stop(&mut self) {
        self.process.terminate(Duration::from_secs(30));
    }

    /// Starts it again after [`Prometheus::stop`]: same port, configuration and data.
    pub fn start_again(&mut self) {
        self.process = spawn_with_env("PROMETHEUS", "prometheus", self.args.clone(), &self.envs);
        self.wait_ready();
    }

    /// The total size in bytes of the files under `sub` of its directory (`agent/wal`).
    pub fn disk_bytes(&self, sub: &str) -> u64 {
        fn walk(dir: &std::path::Path) -> u64 {
            std::fs::read_dir(dir)
                .into_iter()
                .flatten()
                .flatten()
                .map(|e| match e.metadata() {
                    Ok(m) if m.is_dir() => walk(&e.path()),
                    Ok(m) => m.len(),
                    Err(_) => 0,
                })
                .sum()
        }
        walk(&self.dir.join(sub))
    }

    /// A scrape config of job `job` over `targets`, every 250 ms, rules evaluated every 250 ms.
    pub fn fast_config(job: &str, targets: &[&str]) -> String {
        let targets: Vec<String> = targets.iter().map(|t| format!("'{t}'")).collect();
        format!(
            "global:\n  scrape_interval: 250ms\n  scrape_timeout: 200ms\n  evaluation_interval: 250ms\n\
             scrape_configs:\n  - job_name: {job}\n    static_configs:\n      - targets: [{}]\n",
            targets.join(", ")
        )
    }

    /// The result vector of an instant query (`[]` on an error status).
    pub fn query(&self, query: &str) -> Vec<Value> {
        self.query_path(&format!("/api/v1/query?query={}", encode(query)))
    }

    /// [`Prometheus::query`] evaluated at `time_s` (Unix seconds); a range selector's result
    /// is the raw samples (`values`: `[time_s, "value"]`).
    pub fn query_at(&self, query: &str, time_s: f64) -> Vec<Value> {
        self.query_path(&format!(
            "/api/v1/query?query={}&time={time_s:.3}",
            encode(query)
        ))
    }

    fn query_path(&self, path: &str) -> Vec<Value> {
        let (status, body) = http_get(&self.addr, path);
        if status != 200 {
            return Vec::new();
        }
        let json: Value = serde_json::from_str(&body).unwrap_or(Value::Null);
        json["data"]["result"]
            .as_array()
            .cloned()
            .unwrap_or_default()
    }

    /// The value of the single result of `query`, if there is exactly one.
    pub fn value(&self, query: &str) -> Option<f64> {
        match self.query(query).as_slice() {
            [one] => one["value"][1].as_str()?.parse().ok(),
            _ => None,
        }
    }
}

impl Drop for Prometheus {
    fn drop(&mut self) {
        self.process.terminate(Duration::from_secs(10));
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// An Alertmanager (no clustering) whose one receiver discards notifications: the alerts it
/// holds are read back from its API.
pub struct Alertmanager {
    pub process: Process,
    pub addr: String,
    dir: PathBuf,
}

impl Alertmanager {
    pub fn start() -> Alertmanager {
        let dir = temp_dir("alertmanager");
        std::fs::write(
            dir.join("alertmanager.yml"),
            "route:\n  receiver: test\n  group_wait: 0s\nreceivers:\n  - name: test\n",
        )
        .unwrap();
        let addr = free_addr();
        let process = spawn(
            "ALERTMANAGER",
            "prometheus-alertmanager",
            vec![
                format!("--config.file={}", dir.join("alertmanager.yml").display()),
                format!("--storage.path={}", dir.join("data").display()),
                format!("--web.listen-address={addr}"),
                // No gossip port (it would collide between parallel tests).
                "--cluster.listen-address=".into(),
            ],
        );
        let alertmanager = Alertmanager { process, addr, dir };
        wait_for("Alertmanager answering", Duration::from_secs(30), || {
            std::net::TcpStream::connect(&alertmanager.addr).is_ok()
                && http_get(&alertmanager.addr, "/-/ready").0 == 200
        });
        alertmanager
    }

    /// The alerts Alertmanager holds now (its API v2).
    pub fn alerts(&self) -> Vec<Value> {
        let (status, body) = http_get(&self.addr, "/api/v2/alerts");
        assert_eq!(status, 200, "GET /api/v2/alerts: {body}");
        serde_json::from_str::<Value>(&body)
            .ok()
            .and_then(|v| v.as_array().cloned())
            .unwrap_or_default()
    }
}

impl Drop for Alertmanager {
    fn drop(&mut self) {
        self.process.terminate(Duration::from_secs(10));
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Runs `promtool args...` with `stdin`; (success, stdout + stderr).
pub fn promtool(args: &[&str], stdin: &str) -> (bool, String) {
    use std::io::Write;
    let binary = std::env::var("PROMTOOL").unwrap_or_else(|_| "promtool".into());
    let mut child = Command::new(&binary)
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| {
            panic!("cannot run `{binary}` ({e}): run scripts/install-test-deps, or set PROMTOOL")
        });
    child
        .stdin
        .take()
        .unwrap()
        .write_all(stdin.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}
