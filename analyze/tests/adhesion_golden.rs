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

fn same(golden: &str, now: &str) -> bool {
    match (golden.parse::<f64>(), now.parse::<f64>()) {
        (Ok(g), Ok(n)) => (g - n).abs() <= RELATIVE_TOLERANCE * g.abs().max(1e-9),
        _ => golden == now,
    }
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
        },
        table1_skip_steps: 0,
    })
    .unwrap();
    let _ = std::fs::remove_dir_all(&out);
    let now = rows(&report);
    let path = root().join("tests/data/golden/adhesion-seed.csv");
    if std::env::var_os("RAILMON_UPDATE_GOLDEN").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        let mut text = String::from("table,method,drive,field,value\n");
        for r in &now {
            text.push_str(&r.join(","));
            text.push('\n');
        }
        std::fs::write(&path, text).unwrap();
        return;
    }
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (generate it with RAILMON_UPDATE_GOLDEN=1)",
            path.display()
        )
    });
    let golden: Vec<Vec<&str>> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(golden.len(), now.len(), "row count of {}", path.display());
    for (g, n) in golden.iter().zip(&now) {
        assert_eq!(&g[..4], &n[..4], "row keys");
        assert!(
            same(g[4], &n[4]),
            "{} {} drive {} {}: golden {}, now {}",
            n[0],
            n[1],
            n[2],
            n[3],
            g[4],
            n[4]
        );
    }
}
