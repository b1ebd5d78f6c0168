//! The bad-input corpus (issue 11): every case of `tests/data/bad/cases.csv` (a file, the
//! command run on it, the exit code and a substring of the message it must print) run against
//! the real binaries. Each must end within its time limit (no hang), with the documented exit
//! code, no panic, a message naming what is wrong, and no output file left half-written.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use railmon_system_tests::{binaries, workspace_root, PrivateBus};

/// Longest a case may take (the slowest, `railmon serve` refusing its config, takes < 1 s).
const CASE_TIMEOUT: Duration = Duration::from_secs(60);

struct Case {
    category: String,
    file: String,
    command: String,
    exit: i32,
    expected: String,
}

fn cases(dir: &Path) -> Vec<Case> {
    let mut reader = csv::Reader::from_path(dir.join("cases.csv")).unwrap();
    reader
        .records()
        .map(|r| {
            let r = r.unwrap();
            Case {
                category: r[0].to_string(),
                file: r[1].to_string(),
                command: r[2].to_string(),
                exit: r[3].parse().unwrap(),
                expected: r[4].to_string(),
            }
        })
        .collect()
}

/// Files under `dir`, recursively (the output directory of a failed run).
fn files_under(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    entries
        .flatten()
        .flat_map(|e| match e.path().is_dir() {
            true => files_under(&e.path()),
            false => vec![e.path()],
        })
        .collect()
}

#[test]
fn every_bad_input_gets_its_documented_exit_code_and_a_message_naming_it() {
    let dir = workspace_root().join("tests/data/bad");
    let bus = PrivateBus::new();
    let scratch = std::env::temp_dir().join(format!("railmon-bad-input-{}", std::process::id()));
    let mut failures = Vec::new();
    let mut per_category: Vec<(String, usize, usize)> = Vec::new();
    let cases = cases(&dir);
    assert!(cases.len() >= 50, "{} cases", cases.len());
    for (k, case) in cases.iter().enumerate() {
        let out = scratch.join(format!("out-{k}"));
        let file = dir.join(&case.file);
        let command = case
            .command
            .replace("{file}", file.to_str().unwrap())
            .replace("{out}", out.to_str().unwrap())
            .replace("{root}", workspace_root().to_str().unwrap());
        let mut words = command.split_whitespace();
        let program = match words.next() {
            Some("railmon") => &binaries().railmon,
            Some("sensors-replay") => &binaries().replay,
            other => panic!("case {k}: unknown program {other:?}"),
        };
        let mut child = Command::new(program)
            .args(words)
            .current_dir(workspace_root())
            .envs(bus.env())
            .env("RAILMON_HTTP__LISTEN", "127.0.0.1:0")
            .env(
                "RAILMON_STORAGE__DATA_DIR",
                scratch.join(format!("data-{k}")),
            )
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let start = Instant::now();
        let status = loop {
            if let Some(status) = child.try_wait().unwrap() {
                break Some(status);
            }
            if start.elapsed() > CASE_TIMEOUT {
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
            std::thread::sleep(Duration::from_millis(10));
        };
        let mut stderr = String::new();
        std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
        let leftovers: Vec<PathBuf> = files_under(&out)
            .into_iter()
            .filter(|p| {
                let name = p.file_name().unwrap_or_default().to_string_lossy();
                name.starts_with(".tmp-") || name.ends_with(".csv") || name.ends_with(".png")
            })
            .collect();
        let verdict = match status {
            None => Some(format!("no exit within {CASE_TIMEOUT:?}")),
            Some(s) if s.code() != Some(case.exit) => {
                Some(format!("exit {:?}, expected {}", s.code(), case.exit))
            }
            Some(_) if stderr.contains("panicked") => Some("panicked".into()),
            Some(_) if !stderr.contains(&case.expected) => {
                Some(format!("message lacks `{}`", case.expected))
            }
            Some(_) if !leftovers.is_empty() => Some(format!("left files {leftovers:?}")),
            Some(_) => None,
        };
        let entry = match per_category
            .iter_mut()
            .find(|(c, _, _)| *c == case.category)
        {
            Some(entry) => entry,
            None => {
                per_category.push((case.category.clone(), 0, 0));
                per_category.last_mut().unwrap()
            }
        };
        entry.1 += 1;
        match verdict {
            None => entry.2 += 1,
            Some(why) => failures.push(format!(
                "{} ({}): {why}\n  stderr: {stderr}",
                case.command, case.file
            )),
        }
    }
    for (category, tried, passed) in &per_category {
        eprintln!("bad input, {category}: {passed} of {tried} passed");
    }
    let _ = std::fs::remove_dir_all(&scratch);
    assert!(
        failures.is_empty(),
        "{} failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
