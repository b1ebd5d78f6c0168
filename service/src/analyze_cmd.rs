//! `railmon analyze <domain>`: one input into `--out` as before (its tables and summary), or
//! many at once (`railmon_analyze::many`): a line per input as it finishes, each failure
//! named with its file on stderr, then the total; the exit status fails if any input did.

use std::time::{Duration, Instant, SystemTime};

use anyhow::anyhow;
use railmon_analyze::many::{run_all, split_into_parts, Analysis, Job, Many, Plan};

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
        // One file whose parts are analysed each on its own (a recording's bogies): a run
        // per part, in `--out/<part>/`.
        Plan::One if inputs.input.len() == 1 && args.parts(&inputs.input[0])?.is_some() => {
            vec![Job {
                input: inputs.input[0].clone(),
                out: out.clone(),
                part: None,
            }]
        }
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
    let (jobs, unreadable) = split_into_parts(&args, jobs);
    let total = jobs.len() + unreadable.len();
    // A recording split into its bogies makes several runs of one input: count runs then.
    let what = match jobs.iter().any(|j| j.part.is_some()) {
        true => "runs",
        false => "inputs",
    };
    let mut failed = Vec::new();
    for (job, e) in unreadable {
        report_failure(&job, e.into(), &mut failed);
    }
    let threads = inputs.threads(jobs.len());
    let clock = Instant::now();
    let mut printed = Ok(());
    run_all(&args, &jobs, threads, |done| {
        let input = done.job.name();
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
            Err(e) => report_failure(done.job, e.into(), &mut failed),
        }
    });
    printed?;
    crate::print_out(&format!(
        "analysed {total} {what} in {:.1} s on {threads} threads: {} done, {} failed\n",
        clock.elapsed().as_secs_f64(),
        total - failed.len(),
        failed.len()
    ))?;
    match failed.is_empty() {
        true => Ok(()),
        false => Err(anyhow!(
            "{} of {total} {what} failed: {}",
            failed.len(),
            failed.join(", ")
        )),
    }
}

/// Prints a failed input's error (naming its file once) and notes it.
fn report_failure(job: &Job, e: anyhow::Error, failed: &mut Vec<String>) {
    let input = job.name();
    let error = crate::one_line(&e);
    match job.part.is_none() && error.starts_with(&input) {
        true => eprintln!("railmon: {error}"),
        false => eprintln!("railmon: {input}: {error}"),
    }
    failed.push(input);
}
