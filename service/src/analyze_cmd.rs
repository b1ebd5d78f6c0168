//! `railmon analyze <domain>`: one input into `--out` as before (its tables and summary), or
//! many at once (`railmon_analyze::many`): a line per input as it finishes, each failure
//! named with its file on stderr, then the total; the exit status fails if any input did.

use std::time::{Duration, Instant, SystemTime};

use anyhow::anyhow;
use railmon_analyze::many::{run_all, Analysis, Many, Plan};

use crate::summary;

/// What a domain's report shows on the terminal.
pub struct Shown<R> {
    /// Tables printed before the summary of a single run (adhesion's Table 1).
    pub tables: fn(&R) -> Option<&str>,
    /// The headline numbers (`summary::<domain>`).
    pub headline: fn(&R) -> String,
}

pub fn run<A: Analysis + clap::Args>(many: Many<A>, shown: Shown<A::Report>) -> anyhow::Result<()> {
    // Whole seconds: a file system may store coarser times than the clock reads.
    let started = SystemTime::now() - Duration::from_secs(1);
    let Many { inputs, mut args } = many;
    let out = args.run_args().out.clone();
    let jobs = match inputs.plan(&out)? {
        Plan::Many(jobs) => jobs,
        Plan::One => {
            args.run_args_mut().input = inputs.input.first().cloned();
            let report = args.analyse()?;
            if let Some(tables) = (shown.tables)(&report) {
                crate::print_out(tables)?;
            }
            return crate::print_out(&format!(
                "{}\n{}\n",
                summary::written(&out, started),
                (shown.headline)(&report)
            ));
        }
    };
    let threads = inputs.threads(jobs.len());
    let clock = Instant::now();
    let mut failed = Vec::new();
    let mut printed = Ok(());
    run_all(&args, &jobs, threads, |done| {
        let input = done.job.input.display().to_string();
        match done.result {
            Ok(report) => {
                let line = format!(
                    "{input}: {:.1} s, {}; {}\n",
                    done.elapsed.as_secs_f64(),
                    summary::written_briefly(&done.job.out, started),
                    summary::as_one_line(&(shown.headline)(&report))
                );
                if printed.is_ok() {
                    printed = crate::print_out(&line);
                }
            }
            Err(e) => {
                let error = crate::one_line(&e.into());
                match error.starts_with(&input) {
                    true => eprintln!("railmon: {error}"),
                    false => eprintln!("railmon: {input}: {error}"),
                }
                failed.push(input);
            }
        }
    });
    printed?;
    crate::print_out(&format!(
        "analysed {} inputs in {:.1} s on {threads} threads: {} done, {} failed\n",
        jobs.len(),
        clock.elapsed().as_secs_f64(),
        jobs.len() - failed.len(),
        failed.len()
    ))?;
    match failed.is_empty() {
        true => Ok(()),
        false => Err(anyhow!(
            "{} of {} inputs failed: {}",
            failed.len(),
            jobs.len(),
            failed.join(", ")
        )),
    }
}
