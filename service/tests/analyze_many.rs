//! `railmon analyze <domain>` over many recordings (issue 28 item 2): each input's outputs in
//! its own folder, the same bytes whatever `--jobs`, and a bad input among good ones named and
//! failing the run while the others complete.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("railmon-many-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A small drive recording of two drives (no `time_s`: consecutive samples), its voltages
/// and currents turning at a rate set by `k`, so that every file gives other numbers.
fn recording(path: &Path, k: usize) {
    let mut text = String::from("step,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a\n");
    for step in 0..300 {
        for drive in 1..=2 {
            let angle = (step * (k + drive)) as f64 * 1e-2;
            let (u, i) = (40.0 + 5.0 * k as f64, 7.0 + drive as f64);
            text.push_str(&format!(
                "{step},{drive},{:.6},{:.6},{:.6},{:.6}\n",
                u * angle.cos(),
                u * angle.sin(),
                i * angle.cos(),
                i * angle.sin()
            ));
        }
    }
    std::fs::write(path, text).unwrap();
}

fn analyze(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_railmon"))
        .args(["analyze", "adhesion"])
        .args(args)
        .output()
        .expect("running railmon analyze adhesion")
}

/// Every file under `dir` by its path relative to `dir`, with its bytes.
fn tree(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            match path.is_dir() {
                true => todo.push(path),
                false => {
                    let bytes = std::fs::read(&path).unwrap();
                    files.insert(path.strip_prefix(dir).unwrap().to_path_buf(), bytes);
                }
            }
        }
    }
    files
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn each_input_writes_the_same_files_whatever_the_jobs() {
    let dir = scratch("same");
    let inputs = dir.join("recordings");
    std::fs::create_dir_all(&inputs).unwrap();
    let names = ["a", "b", "c"];
    for (k, name) in names.iter().enumerate() {
        recording(&inputs.join(format!("{name}.csv")), k);
    }
    let (serial, parallel, single) = (dir.join("j1"), dir.join("j3"), dir.join("single"));
    // A directory on one thread; the same files named one by one on three.
    let out = analyze(&[
        "--input".as_ref(),
        inputs.as_os_str(),
        "--jobs".as_ref(),
        "1".as_ref(),
        "--out".as_ref(),
        serial.as_os_str(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let files: Vec<PathBuf> = names
        .iter()
        .map(|n| inputs.join(format!("{n}.csv")))
        .collect();
    let mut args: Vec<&std::ffi::OsStr> = vec!["--input".as_ref()];
    args.extend(files.iter().map(|f| f.as_os_str()));
    args.extend([
        "--jobs".as_ref(),
        "3".as_ref(),
        "--out".as_ref(),
        parallel.as_os_str(),
    ]);
    let out = analyze(&args);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    for file in &files {
        let line = format!("{}: ", file.display());
        assert!(stdout.contains(&line), "no line for {line} in:\n{stdout}");
    }
    assert!(
        stdout.contains("analysed 3 inputs") && stdout.contains("3 done, 0 failed"),
        "{stdout}"
    );

    let (serial, parallel) = (tree(&serial), tree(&parallel));
    for name in names {
        for file in ["estimates.csv", "table1.csv", "events.csv", "refused.csv"] {
            let path = Path::new(name).join(file);
            assert!(serial.contains_key(&path), "no {}", path.display());
        }
    }
    assert!(serial
        .keys()
        .any(|p| p.extension().is_some_and(|e| e == "png")));
    assert_eq!(
        serial.keys().collect::<Vec<_>>(),
        parallel.keys().collect::<Vec<_>>()
    );
    for (path, bytes) in &serial {
        assert!(parallel[path] == *bytes, "{} differs", path.display());
    }

    // One file writes into --out itself, the same bytes as its folder of a many-input run.
    let out = analyze(&[
        "--input".as_ref(),
        files[1].as_os_str(),
        "--out".as_ref(),
        single.as_os_str(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let single = tree(&single);
    let b: BTreeMap<PathBuf, Vec<u8>> = serial
        .iter()
        .filter_map(|(p, bytes)| Some((p.strip_prefix("b").ok()?.to_path_buf(), bytes.clone())))
        .collect();
    assert_eq!(single, b);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_bad_input_is_named_and_fails_the_run_while_the_others_complete() {
    let dir = scratch("bad");
    let inputs = dir.join("recordings");
    std::fs::create_dir_all(&inputs).unwrap();
    recording(&inputs.join("a.csv"), 0);
    recording(&inputs.join("c.csv"), 2);
    let bad = inputs.join("b.csv");
    std::fs::write(
        &bad,
        "step,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a\n0,1,10,-40,abc,7\n",
    )
    .unwrap();
    let out_dir = dir.join("out");
    let out = analyze(&[
        "--input".as_ref(),
        inputs.as_os_str(),
        "--jobs".as_ref(),
        "2".as_ref(),
        "--out".as_ref(),
        out_dir.as_os_str(),
        "--no-plots".as_ref(),
    ]);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(!out.status.success(), "{stdout}\n{stderr}");
    let bad_name = bad.display().to_string();
    assert!(
        stderr.contains(&format!("{bad_name}:2: field \"i_alpha_a\"")),
        "{stderr}"
    );
    assert!(
        stderr.contains(&format!("1 of 3 inputs failed: {bad_name}")),
        "{stderr}"
    );
    assert!(stdout.contains("2 done, 1 failed"), "{stdout}");
    for good in ["a", "c"] {
        assert!(
            out_dir.join(good).join("estimates.csv").is_file(),
            "{good}: {stdout}"
        );
    }

    // Two inputs of one file name would share a folder: refused before any run, both named.
    let other = dir.join("other");
    std::fs::create_dir_all(&other).unwrap();
    recording(&other.join("a.csv"), 1);
    let clash = dir.join("clash");
    let out = analyze(&[
        "--input".as_ref(),
        inputs.join("a.csv").as_os_str(),
        other.join("a.csv").as_os_str(),
        "--out".as_ref(),
        clash.as_os_str(),
    ]);
    let stderr = text(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains(&other.join("a.csv").display().to_string())
            && stderr.contains(&inputs.join("a.csv").display().to_string()),
        "{stderr}"
    );
    assert!(!clash.exists(), "nothing runs");
    std::fs::remove_dir_all(&dir).unwrap();
}

fn analyze_damper(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_railmon"))
        .args(["analyze", "damper", "--particles", "30", "--no-plots"])
        .args(args)
        .output()
        .expect("running railmon analyze damper")
}

/// `path`'s rows as two bogies: bogie 2 as recorded, bogie 1 with every sensor halved (so
/// that the two give other estimates), interleaved as a recording of several bogies is.
fn two_bogies(path: &Path, two: &Path) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let sensor: Vec<bool> = header
        .iter()
        .map(|h| h.ends_with("_m_s2") || h.ends_with("_rad_s"))
        .collect();
    let row = |bogie: u32, fields: &[&str], scale: f64| {
        let mut out = vec![fields[0].to_owned(), bogie.to_string()];
        out.extend(fields[1..].iter().zip(&sensor[1..]).map(|(f, s)| match s {
            true => (scale * f.parse::<f64>().unwrap()).to_string(),
            false => f.to_string(),
        }));
        out.join(",")
    };
    let mut out = vec![format!("{},bogie,{}", header[0], header[1..].join(","))];
    for line in lines {
        let fields: Vec<&str> = line.split(',').collect();
        out.push(row(1, &fields, 0.5));
        out.push(row(2, &fields, 1.0));
    }
    std::fs::write(two, out.join("\n") + "\n").unwrap();
}

#[test]
fn every_bogie_of_a_recording_is_analysed_as_its_own_run() {
    let dir = scratch("bogies");
    let scenario =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenarios/damper-seed.toml");
    let sim = dir.join("sim");
    let out = analyze_damper(&[
        "--scenario".as_ref(),
        scenario.as_os_str(),
        "--duration-s".as_ref(),
        "1".as_ref(),
        "--out".as_ref(),
        sim.as_os_str(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let two = dir.join("two.csv");
    two_bogies(&sim.join("bogie.csv"), &two);

    let every = dir.join("every");
    let out = analyze_damper(&[
        "--input".as_ref(),
        two.as_os_str(),
        "--every-bogie".as_ref(),
        "--jobs".as_ref(),
        "2".as_ref(),
        "--out".as_ref(),
        every.as_os_str(),
    ]);
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    for part in [
        "(bogie-1)",
        "(bogie-2)",
        "analysed 2 runs",
        "2 done, 0 failed",
    ] {
        assert!(stdout.contains(part), "no {part} in:\n{stdout}");
    }
    // Each bogie's folder holds what `--bogie N` writes (its seed, its rows), to the byte but
    // for the run's timing.
    let without_timing = |dir: &Path| {
        let mut t = tree(dir);
        t.remove(Path::new("timing.csv")).expect("a timing.csv");
        t
    };
    let mut estimates = Vec::new();
    for bogie in ["1", "2"] {
        let alone = dir.join(format!("alone-{bogie}"));
        let out = analyze_damper(&[
            "--input".as_ref(),
            two.as_os_str(),
            "--bogie".as_ref(),
            bogie.as_ref(),
            "--out".as_ref(),
            alone.as_os_str(),
        ]);
        assert!(out.status.success(), "{}", text(&out.stderr));
        let part = without_timing(&every.join(format!("bogie-{bogie}")));
        assert_eq!(part, without_timing(&alone), "bogie {bogie}");
        estimates.push(part[Path::new("estimates.csv")].clone());
    }
    assert_ne!(estimates[0], estimates[1], "the two bogies' data differ");

    // With `--bogie` or a scenario there is nothing to split: refused by the command line.
    let out = analyze_damper(&[
        "--scenario".as_ref(),
        scenario.as_os_str(),
        "--every-bogie".as_ref(),
        "--out".as_ref(),
        dir.join("no").as_os_str(),
    ]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("cannot be used with"),
        "{}",
        text(&out.stderr)
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
