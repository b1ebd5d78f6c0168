//! `railmon analyze damper` end to end: a short scenario run writes every report, and its
//! recorded `bogie.csv` replayed through `--input` gives the same estimates.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use railmon_analyze::damper::{run, Args, DamperAnalysisError};
use railmon_analyze::report::RunArgs;
use railmon_records::bogie::{BogieCsvReader, BogieCsvWriter};

fn scenario(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../config/scenarios/{name}.toml"))
}

fn out_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("railmon-damper-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// The gain cache (`--gain-cache`) of every run here but those of the cache's own test: the
/// runs reach the same gain-table nodes again and again (every replay those of the run it
/// replays; the recordings without a mass column the 11 mass nodes of the unmeasured mass's
/// prior at the same speed; damper-load's its two measured masses through a stop), and each
/// solved them afresh (0.3-0.5 s a node) in most of this binary's time. A node taken from the
/// cache gives the estimates of one solved in the run, to the bit (checked on the way in, and
/// by `a_run_with_the_gain_cache_cold_or_warm_estimates_as_one_without`, which runs without
/// it and with a cache of its own). Emptied at the binary's first run, so that each test run
/// solves what it needs afresh; in the target directory, so at most one copy stays on disk.
fn shared_gain_cache() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("railmon-analyze-damper-gain-cache");
        let _ = std::fs::remove_dir_all(&dir);
        dir
    })
    .clone()
}

fn args(out: &Path) -> Args {
    Args {
        run: RunArgs {
            input: None,
            scenario: None,
            config: None,
            out: out.to_owned(),
            no_plots: false,
            strict: false,
        },
        particles: Some(100),
        propagation: None,
        duration_s: Some(3.0),
        bogie: 1,
        every_bogie: false,
        csv_every: 10,
        gain_cache: Some(shared_gain_cache()),
    }
}

/// With `--gain-cache` a first run stores the nodes it solved and a second loads them: both
/// write exactly the estimates of a run without the cache.
#[test]
fn a_run_with_the_gain_cache_cold_or_warm_estimates_as_one_without() {
    let cache = out_dir("gain-cache");
    let estimates = |tag: &str, gain_cache: Option<PathBuf>| {
        let out = out_dir(tag);
        let mut a = args(&out);
        a.run.scenario = Some(scenario("damper-seed"));
        a.run.no_plots = true;
        a.gain_cache = gain_cache;
        let report = run(&a).unwrap();
        // The EKF baseline is off by default: the summary holds the RBPF's rows only.
        assert!(report.summary.iter().all(|r| r.method == "rbpf"));
        assert_eq!(report.summary.len(), 2);
        let text = std::fs::read_to_string(out.join("estimates.csv")).unwrap();
        std::fs::remove_dir_all(&out).unwrap();
        text
    };
    let without = estimates("no-cache", None);
    let cold = estimates("cold", Some(cache.clone()));
    let stored = std::fs::read_dir(&cache).unwrap().count();
    assert!(stored >= 1, "{stored} nodes stored");
    let warm = estimates("warm", Some(cache.clone()));
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), stored);
    assert!(cold == without && warm == without);
    std::fs::remove_dir_all(&cache).unwrap();
}

/// A measured body mass travels with the samples (issue 24 item 1): the scenario run of
/// damper-load (0.85 x the design mass, 1.3 x after a stop at 2-3 s) and its recording, read
/// back, give the same estimates; its `half_body_mass_kg` column holds the plant's mass. The
/// same recording with the column's cells empty (not measured) gives other estimates: the
/// column is read, not ignored.
#[test]
fn a_measured_mass_gives_the_same_estimates_from_the_scenario_and_its_recording() {
    let out = out_dir("load");
    let mut a = args(&out);
    a.run.scenario = Some(scenario("damper-load"));
    a.run.no_plots = true;
    a.duration_s = Some(4.5);
    run(&a).unwrap();
    let estimates = std::fs::read_to_string(out.join("estimates.csv")).unwrap();
    let mut reader = BogieCsvReader::open(&out.join("bogie.csv")).unwrap();
    let mut masses = vec![];
    let mut records = vec![];
    while let Some(r) = reader.next_record().unwrap() {
        if masses.last() != Some(&r.half_body_mass_kg) {
            masses.push(r.half_body_mass_kg);
        }
        records.push(r);
    }
    assert_eq!(masses, [Some(11050.0), Some(16900.0)]);

    let replay = out_dir("load-replay");
    std::fs::create_dir_all(&replay).unwrap();
    let config = replay.join("monitor.toml");
    std::fs::write(&config, "track_velocity_std_m_s = 0.1\n[rbpf]\nseed = 13\n").unwrap();
    let mut b = args(&replay);
    b.run.input = Some(out.join("bogie.csv"));
    b.run.config = Some(config);
    b.run.no_plots = true;
    b.duration_s = None;
    let report = run(&b).unwrap();
    assert_eq!(report.refused.total(), 0);
    let replayed = std::fs::read_to_string(replay.join("estimates.csv")).unwrap();
    assert_eq!(replayed, estimates);

    let unmeasured = replay.join("unmeasured.csv");
    let mut writer = BogieCsvWriter::create(&unmeasured, true).unwrap();
    for r in &records {
        let r = railmon_records::bogie::BogieRecord {
            half_body_mass_kg: None,
            ..*r
        };
        writer.write(&r).unwrap();
    }
    writer.finish().unwrap();
    b.run.input = Some(unmeasured);
    run(&b).unwrap();
    let design = std::fs::read_to_string(replay.join("estimates.csv")).unwrap();
    assert_ne!(design, estimates);
    std::fs::remove_dir_all(&out).unwrap();
    std::fs::remove_dir_all(&replay).unwrap();
}

#[test]
fn scenario_run_writes_reports_and_its_recording_replays_identically() {
    let out = out_dir("scenario");
    // With the EKF baseline (off by default), for the paper's figures 2-5.
    let with_ekf = out_dir("scenario-ekf").with_extension("toml");
    let text = std::fs::read_to_string(scenario("damper-seed")).unwrap();
    std::fs::write(
        &with_ekf,
        format!("{text}\n[monitor.ekf]\nenabled = true\n"),
    )
    .unwrap();
    let mut a = args(&out);
    a.run.scenario = Some(with_ekf.clone());
    let report = run(&a).unwrap();
    std::fs::remove_file(&with_ekf).unwrap();
    assert_eq!(report.steps, 3000);
    assert_eq!(report.summary.len(), 4);
    let summary = std::fs::read_to_string(out.join("summary.csv")).unwrap();
    let mut lines = summary.lines();
    assert_eq!(
        lines.next(),
        Some("method,damper,truth,error_10s,error_30s,error_end,settle_s,covered_end")
    );
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), 4);
    assert!(rows[0].starts_with("rbpf,csy,16000.0,,,"), "{}", rows[0]);
    assert!(rows[3].starts_with("ekf,csay,160000.0,,,"), "{}", rows[3]);
    let timing = std::fs::read_to_string(out.join("timing.csv")).unwrap();
    assert!(timing.starts_with("steps,particles,propagation,mean_step_us,real_time_factor"));
    assert!(timing
        .lines()
        .nth(1)
        .unwrap()
        .starts_with("3000,100,steady_state,"));
    for png in ["rbpf_csy", "rbpf_csay", "ekf_csy", "ekf_csay", "ess"] {
        let bytes = std::fs::read(out.join(format!("{png}.png"))).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
    }
    let estimates = std::fs::read_to_string(out.join("estimates.csv")).unwrap();
    assert_eq!(estimates.lines().count(), 301);

    // Replay: the scenario's monitor settings as a config file, the recording as input.
    let replay = out_dir("replay");
    std::fs::create_dir_all(&replay).unwrap();
    let config = replay.join("monitor.toml");
    std::fs::write(
        &config,
        "track_velocity_std_m_s = 0.1\n[rbpf]\ndelta = 0.99\nseed = 11\n[ekf]\nenabled = true\n",
    )
    .unwrap();
    let mut b = args(&replay);
    b.run.input = Some(out.join("bogie.csv"));
    b.run.config = Some(config);
    run(&b).unwrap();
    let replayed = std::fs::read_to_string(replay.join("estimates.csv")).unwrap();
    assert_eq!(replayed, estimates);

    // The same rows as bogie 2 of a two-bogie recording (bogie 1: other, halved, signals),
    // analysed with `--bogie 2`, give the same estimates again: bogie 2's RBPF runs on
    // `rbpf.seed + 1` (as the service seeds it), so the configured seed is one less.
    let two = replay.join("two-bogies.csv");
    let mut reader = BogieCsvReader::open(&out.join("bogie.csv")).unwrap();
    let mut writer = BogieCsvWriter::create_with_bogie_ids(&two, reader.has_truth()).unwrap();
    while let Some(record) = reader.next_record().unwrap() {
        let mut other = record;
        other.sensors = other.sensors.map(|x| 0.5 * x);
        writer.write_bogie(1, &other).unwrap();
        writer.write_bogie(2, &record).unwrap();
    }
    writer.finish().unwrap();
    let config_2 = replay.join("monitor-2.toml");
    std::fs::write(
        &config_2,
        "track_velocity_std_m_s = 0.1\n[rbpf]\ndelta = 0.99\nseed = 10\n[ekf]\nenabled = true\n",
    )
    .unwrap();
    b.run.input = Some(two);
    b.run.config = Some(config_2);
    b.bogie = 2;
    run(&b).unwrap();
    let bogie_2 = std::fs::read_to_string(replay.join("estimates.csv")).unwrap();
    assert_eq!(bogie_2, estimates);
    std::fs::remove_dir_all(&out).unwrap();
    std::fs::remove_dir_all(&replay).unwrap();
}

#[test]
fn a_bad_recording_is_an_error_naming_file_line_and_field() {
    let out = out_dir("bad");
    std::fs::create_dir_all(&out).unwrap();
    let input = out.join("bad.csv");
    std::fs::write(
        &input,
        "time_s,wheelset1_accel_m_s2,wheelset2_accel_m_s2,bogie_accel_m_s2,bogie_yaw_rate_rad_s,body_accel_m_s2\n\
         0.001,0.1,0.1,0.1,0.01,0.01\n0.002,0.1,nan,0.1,0.01,0.01\n",
    )
    .unwrap();
    let mut a = args(&out);
    a.run.input = Some(input);
    a.duration_s = None;
    // The service drops the NaN sample (`not_finite`) and goes on: so does analyze.
    let report = run(&a).unwrap();
    assert_eq!(report.refused.count("not_finite"), 1);
    assert_eq!(report.steps, 1);
    let refused = std::fs::read_to_string(out.join("refused.csv")).unwrap();
    assert!(refused.contains("not_finite,1\n"), "{refused}");
    // `--strict`: the error names file, line, field and value.
    a.run.strict = true;
    let err = run(&a).unwrap_err();
    assert!(matches!(err, DamperAnalysisError::Record(_)));
    let msg = err.to_string();
    assert!(
        msg.contains("bad.csv:3:") && msg.contains("wheelset2_accel_m_s2") && msg.contains("NaN"),
        "{msg}"
    );
    std::fs::remove_dir_all(&out).unwrap();
}

/// A bogie recording of bogie 1 at the given times (s), every sample the same plausible one.
fn recording_at(out: &Path, name: &str, times_s: impl IntoIterator<Item = f64>) -> PathBuf {
    std::fs::create_dir_all(out).unwrap();
    let mut text = String::from(
        "time_s,wheelset1_accel_m_s2,wheelset2_accel_m_s2,bogie_accel_m_s2,bogie_yaw_rate_rad_s,body_accel_m_s2\n",
    );
    for t in times_s {
        text.push_str(&format!("{t},0.1,-0.1,0.05,0.01,0.01\n"));
    }
    let path = out.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn input_args(out: &Path, input: PathBuf) -> Args {
    let mut a = args(out);
    a.run.input = Some(input);
    a.run.no_plots = true;
    a.duration_s = None;
    a
}

#[test]
fn samples_at_another_rate_are_refused_as_the_service_refuses_them() {
    let out = out_dir("rate");
    // 1 s at 1 kHz, then 0.2 s of 100 Hz stamps: the third 100 Hz sample in a row and every
    // one after it is refused (`rate_mismatch`), counted, the run goes on.
    let times = (1..=1000)
        .map(|k| k as f64 * 1e-3)
        .chain((1..=20).map(|k| 1.0 + k as f64 * 1e-2));
    let input = recording_at(&out, "mixed.csv", times);
    let report = run(&input_args(&out.join("a"), input)).unwrap();
    assert_eq!(
        report.refused.count("rate_mismatch"),
        18,
        "{:?}",
        report.refused
    );
    assert_eq!(report.refused.total(), 18);
    assert_eq!(report.steps, 1002);
    // The two 100 Hz samples used each skipped 9 periods.
    assert_eq!(report.timeline.skipped_periods, 18);
    let refused = std::fs::read_to_string(out.join("a/refused.csv")).unwrap();
    assert!(refused.contains("rate_mismatch,18\n"), "{refused}");
    // A file all at 100 Hz is mostly refused: an error naming the first refused sample.
    let input = recording_at(&out, "100hz.csv", (1..=50).map(|k| k as f64 * 1e-2));
    let msg = run(&input_args(&out.join("b"), input.clone()))
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("47 of 50 samples refused")
            && msg.contains("100hz.csv:5: field \"time_s\" = \"0.04\"")
            && msg.contains("rate_mismatch"),
        "{msg}"
    );
    // `--strict`: the first refused sample is the error.
    let mut a = input_args(&out.join("c"), input);
    a.run.strict = true;
    let msg = run(&a).unwrap_err().to_string();
    assert!(
        msg.starts_with("100hz.csv:5: field \"time_s\" = \"0.04\"")
            || msg.contains("100hz.csv:5: field \"time_s\" = \"0.04\""),
        "{msg}"
    );
    // Time in ms read as s: every sample after the first jumps a second ahead.
    let input = recording_at(&out, "ms.csv", (1..=20).map(f64::from));
    let msg = run(&input_args(&out.join("d"), input))
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("19 of 20 samples refused") && msg.contains("time_jump"),
        "{msg}"
    );
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn a_jump_of_an_hour_starts_a_new_timeline_and_restarts_the_estimator() {
    let out = out_dir("jump");
    let before = (1..=1000).map(|k| k as f64 * 1e-3);
    let after = (1..=1000).map(|k| 3600.0 + k as f64 * 1e-3);
    let input = recording_at(&out, "jump.csv", before.chain(after));
    let report = run(&input_args(&out.join("a"), input)).unwrap();
    // The first sample after the jump is refused (an outlier, until the next confirms it),
    // the next starts the new timeline: the estimator restarts there.
    assert_eq!(report.refused.count("time_jump"), 1, "{:?}", report.refused);
    assert_eq!(report.refused.total(), 1);
    assert_eq!(report.timeline.new_timelines_s, [3600.002]);
    assert_eq!(report.steps, 1999);
    // The restarted filter's last estimate is that of a fresh run over the same 999 samples.
    let fresh = recording_at(
        &out,
        "fresh.csv",
        (2..=1000).map(|k| 3600.0 + k as f64 * 1e-3),
    );
    run(&input_args(&out.join("b"), fresh)).unwrap();
    let last = |dir: &str| {
        let text = std::fs::read_to_string(out.join(dir).join("estimates.csv")).unwrap();
        let line = text.lines().last().unwrap().to_owned();
        // Everything but the time column (the monitor counts its own steps).
        line.split_once(',').unwrap().1.to_owned()
    };
    assert_eq!(last("a"), last("b"));
    std::fs::remove_dir_all(&out).unwrap();
}
