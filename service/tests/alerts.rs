//! The alert rules (`dashboards/prometheus/alerts.yml`) are valid and pass their unit tests
//! (`alerts.test.yml`: where each alert must fire and where it must not), by Prometheus' own
//! `promtool` (Debian package `prometheus`; `scripts/install-test-deps` installs it, or set
//! `PROMTOOL`).

use std::path::PathBuf;
use std::process::Command;

fn promtool(args: &[&str]) -> (bool, String) {
    let binary = std::env::var("PROMTOOL").unwrap_or_else(|_| "promtool".into());
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../dashboards/prometheus");
    let out = Command::new(&binary)
        .args(args)
        .current_dir(&dir)
        .output()
        .unwrap_or_else(|e| {
            panic!("cannot run `{binary}` ({e}): run scripts/install-test-deps, or set PROMTOOL")
        });
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

#[test]
fn alert_rules_are_valid() {
    let (ok, out) = promtool(&["check", "rules", "alerts.yml"]);
    assert!(ok, "promtool check rules:\n{out}");
}

#[test]
fn alert_rules_pass_their_unit_tests() {
    let (ok, out) = promtool(&["test", "rules", "alerts.test.yml"]);
    assert!(ok, "promtool test rules:\n{out}");
}

/// Every `railmon_` metric the rules use is one the service exports (a renamed metric would
/// leave a rule that never fires, which `promtool` cannot see).
#[test]
fn alert_rules_use_exported_metrics() {
    let rules = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../dashboards/prometheus/alerts.yml"),
    )
    .unwrap();
    let metrics = railmon_service::metrics::Metrics::new().unwrap();
    let mut used: Vec<&str> = rules
        .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .filter(|w| w.starts_with("railmon_") && w.len() > "railmon_".len())
        .collect();
    used.sort();
    used.dedup();
    assert!(used.len() >= 6, "{used:?}");
    for name in used {
        assert!(
            metrics.exports(name),
            "alerts.yml uses {name}, which the service does not export"
        );
    }
}

/// compose.yaml's Prometheus and Alertmanager configs are valid for the packaged versions
/// (`promtool check config --syntax-only`: the rule file's path is the container's;
/// `amtool check-config`, Debian package `prometheus-alertmanager`, or set `AMTOOL`).
#[test]
fn compose_prometheus_and_alertmanager_configs_are_valid() {
    let (ok, out) = promtool(&["check", "config", "--syntax-only", "prometheus.yml"]);
    assert!(ok, "promtool check config:\n{out}");
    let binary = std::env::var("AMTOOL").unwrap_or_else(|_| "amtool".into());
    let out = Command::new(&binary)
        .args(["check-config", "alertmanager.yml"])
        .current_dir(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../dashboards/alertmanager"))
        .output()
        .unwrap_or_else(|e| {
            panic!("cannot run `{binary}` ({e}): run scripts/install-test-deps, or set AMTOOL")
        });
    assert!(
        out.status.success(),
        "amtool check-config:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
