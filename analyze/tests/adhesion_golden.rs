//! Golden file of the seed scenario's headline numbers (issue 8): Table 1 and the detection
//! scores (both rules) of the seeded paper experiment, pinned in
//! `tests/data/golden/adhesion-seed.csv` and compared at a tight relative tolerance. After an
//! intended change of the numbers, regenerate (and explain the change in the commit):
//!
//! `RAILMON_UPDATE_GOLDEN=1 cargo test -p railmon-analyze --test adhesion_golden`

use std::path::{Path, PathBuf};

use railmon_analyze::adhesion::{run, AdhesionReport, Args};
use railmon_analyze::report::RunArgs;

const RELATIVE_TOLERANCE: f64 = 1e-6;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// `table,method,drive,field,value` rows of the report (undefined values empty).
fn rows(report: &AdhesionReport) -> Vec<[String; 5]> {
    let mut rows = Vec::new();
    let mut push = |table: &str, method: String, drive: usize, field: &str, value: String| {
        rows.push([table.into(), method, drive.to_string(), field.into(), value]);
    };
    let opt = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x:e}"));
    for r in &report.table1 {
        let s = r.summary;
        for (field, v) in [
            ("min", s.min),
            ("q1", s.q1),
            ("median", s.median),
            ("q3", s.q3),
            ("max", s.max),
            ("mean", s.mean),
            ("std", s.std),
            ("iqr", s.iqr),
        ] {
            push(
                "table1",
                r.method.to_string(),
                r.drive,
                field,
                format!("{v:e}"),
            );
        }
    }
    for r in &report.detection {
        for (rule, s) in [("p>0.5", &r.score), ("alarm", &r.alarm)] {
            let m = r.method.to_string();
            let table = format!("detection[{rule}]");
            push(&table, m.clone(), r.drive, "precision", opt(s.precision));
            push(&table, m.clone(), r.drive, "recall", opt(s.recall));
            push(&table, m.clone(), r.drive, "f1", opt(s.f1));
            push(
                &table,
                m.clone(),
                r.drive,
                "median_delay_steps",
                opt(s.median_delay_steps),
            );
            push(
                &table,
                m.clone(),
                r.drive,
                "false_pos",
                s.false_pos.to_string(),
            );
            push(
                &table,
                m,
                r.drive,
                "missed_events",
                s.missed_events.to_string(),
            );
        }
    }
    rows
}

#[test]
fn seed_scenario_headline_numbers_match_the_golden_file() {
    let out = std::env::temp_dir().join(format!("railmon-adhesion-golden-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let report = run(&Args {
        run: RunArgs {
            input: None,
            scenario: Some(root().join("config/scenarios/adhesion-seed.toml")),
            config: None,
            out: out.clone(),
            no_plots: true,
            strict: false,
        },
        table1_skip_steps: 0,
    })
    .unwrap();
    let _ = std::fs::remove_dir_all(&out);
    let now: Vec<Vec<String>> = rows(&report).into_iter().map(Vec::from).collect();
    railmon_golden::check(
        "adhesion-seed.csv",
        &["table", "method", "drive", "field", "value"],
        &now,
        RELATIVE_TOLERANCE,
    );
}
