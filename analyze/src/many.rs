//! Many recordings in one `railmon analyze <domain>` run (issue 28 item 2): `--input` takes
//! several files or a directory of them, and `--jobs N` threads analyse them at once, each
//! into its own folder `OUT/<file stem>/`.
//!
//! Every input is one run of the domain's `run` with its own arguments (the same settings,
//! its file, its folder): nothing is shared between runs, each seeds its own generators as a
//! run of that file alone does, so an input's outputs are the same whatever the number of
//! threads and whichever input finished first.

use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use crate::report::{bar_of, hide_step_bars, ReportError, RunArgs};

/// A domain's arguments, run once per input by [`run_all`].
pub trait Analysis: Clone + Send + Sync {
    /// What a run returns.
    type Report: Send;
    /// Why a run failed (naming the file).
    type Error: std::error::Error + Send + Sync + 'static;
    /// The input, output directory and options every domain shares.
    fn run_args(&self) -> &RunArgs;
    fn run_args_mut(&mut self) -> &mut RunArgs;
    /// Runs the analysis and writes every report file into `run_args().out`.
    fn analyse(&self) -> Result<Self::Report, Self::Error>;
    /// The parts of `input` to analyse each on its own, when the arguments ask for that (a
    /// damper recording's bogies with `--every-bogie`); `None`: the input is one run.
    fn parts(&self, _input: &Path) -> Result<Option<Vec<Part>>, Self::Error> {
        Ok(None)
    }
    /// Makes the arguments analyse part `id` of their input (one of [`Self::parts`]).
    fn select_part(&mut self, _id: u32) {}
}

/// A part of an input analysed on its own (a bogie of a recording), into its own folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Part {
    pub id: u32,
    /// The folder under the input's, e.g. `bogie-2`.
    pub folder: String,
}

/// [`Analysis`] for the domain module's `Args` (its `RunArgs` in the field `run`) and its
/// `run`: `analysis!(Report, Error);` in each domain, followed by any other method of the
/// trait the domain defines (`analysis!(Report, Error; fn parts(..) {..})`).
macro_rules! analysis {
    ($report:ty, $error:ty $(; $($extra:tt)*)?) => {
        impl $crate::many::Analysis for Args {
            type Report = $report;
            type Error = $error;
            fn run_args(&self) -> &RunArgs {
                &self.run
            }
            fn run_args_mut(&mut self) -> &mut RunArgs {
                &mut self.run
            }
            fn analyse(&self) -> Result<$report, $error> {
                run(self)
            }
            $($($extra)*)?
        }
    };
}
pub(crate) use analysis;

/// What `--input` and `--jobs` of every `railmon analyze <domain>` read.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct Inputs {
    /// Recorded CSVs (layouts: docs/adhesion.md, docs/damper.md, docs/fuel.md; for fuel also an
    /// ANL Camry dynamometer file as shipped): one file, writing into `--out` itself, or
    /// several files and directories (their `*.csv` files), each writing into
    /// `--out/<file stem>/`.
    #[arg(
        long,
        value_name = "FILE|DIR",
        num_args = 1..,
        required_unless_present = "scenario",
        conflicts_with = "scenario"
    )]
    pub input: Vec<PathBuf>,
    /// How many inputs are analysed at once. Default: the available cores; 1: one after
    /// another.
    #[arg(long, value_name = "N")]
    pub jobs: Option<NonZeroUsize>,
}

/// A domain's arguments with [`Inputs`]: what `railmon analyze <domain>` parses.
#[derive(clap::Args, Debug, Clone)]
pub struct Many<A: clap::Args> {
    #[command(flatten)]
    pub inputs: Inputs,
    #[command(flatten)]
    pub args: A,
}

/// One input of a many-input run (or one part of it) and the folder its outputs go to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Job {
    pub input: PathBuf,
    pub out: PathBuf,
    /// The part of the input ([`Analysis::parts`]); `None`: all of it.
    pub part: Option<u32>,
}

impl Job {
    /// The input as the lines of a run name it: its path, and its part's folder.
    pub fn name(&self) -> String {
        match self.part {
            Some(_) => format!(
                "{} ({})",
                self.input.display(),
                self.out.file_name().unwrap_or_default().to_string_lossy()
            ),
            None => self.input.display().to_string(),
        }
    }
}

/// `jobs` with each input that [`Analysis::parts`] splits replaced by a job per part, in the
/// input's folder's subfolder; an input whose parts cannot be read is returned with its error
/// and left out (the other inputs still run).
pub fn split_into_parts<A: Analysis>(args: &A, jobs: Vec<Job>) -> (Vec<Job>, Vec<(Job, A::Error)>) {
    let (mut split, mut failed) = (Vec::new(), Vec::new());
    for job in jobs {
        match args.parts(&job.input) {
            Ok(None) => split.push(job),
            Ok(Some(parts)) => split.extend(parts.into_iter().map(|p| Job {
                input: job.input.clone(),
                out: job.out.join(&p.folder),
                part: Some(p.id),
            })),
            Err(e) => failed.push((job, e)),
        }
    }
    (split, failed)
}

/// What a command line asks for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Plan {
    /// One run into `--out`, as before many inputs: a scenario, or one file.
    One,
    /// Every input into its own folder.
    Many(Vec<Job>),
}

impl Inputs {
    /// The runs these inputs make with outputs under `out`: one file is one run into `out`;
    /// several, or a directory (its `*.csv` files by name), one run each into
    /// `out/<file stem>`. Two inputs that would share a folder are an error naming both.
    pub fn plan(&self, out: &Path) -> Result<Plan, ReportError> {
        match self.input.as_slice() {
            [] => return Ok(Plan::One),
            [one] if !one.is_dir() => return Ok(Plan::One),
            _ => {}
        }
        let mut jobs: Vec<Job> = Vec::new();
        for path in &self.input {
            let files = match path.is_dir() {
                true => csv_files_in(path)?,
                false => vec![path.clone()],
            };
            for input in files {
                let stem = input
                    .file_stem()
                    .ok_or_else(|| ReportError::new(&input, "not a file name"))?;
                let folder = out.join(stem);
                if let Some(other) = jobs.iter().find(|j| j.out == folder) {
                    return Err(ReportError::new(
                        &input,
                        format!(
                            "would write into {} as {} does: give inputs of different file \
                             names, or analyse them in separate runs",
                            folder.display(),
                            other.input.display()
                        ),
                    ));
                }
                jobs.push(Job {
                    input,
                    out: folder,
                    part: None,
                });
            }
        }
        Ok(Plan::Many(jobs))
    }

    /// Threads for `n` inputs: `--jobs`, or the available cores, at most one per input.
    pub fn threads(&self, n: usize) -> usize {
        let cores = || std::thread::available_parallelism().map_or(1, NonZeroUsize::get);
        self.jobs
            .map_or_else(cores, NonZeroUsize::get)
            .min(n)
            .max(1)
    }
}

/// The `*.csv` files of `dir` (not its subdirectories), sorted by name.
fn csv_files_in(dir: &Path) -> Result<Vec<PathBuf>, ReportError> {
    let entries = std::fs::read_dir(dir)
        .map_err(|e| ReportError::new(dir, format!("cannot list the directory: {e}")))?;
    let mut files = Vec::new();
    for entry in entries {
        let path = entry
            .map_err(|e| ReportError::new(dir, format!("cannot list the directory: {e}")))?
            .path();
        let csv = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("csv"));
        if csv && path.is_file() {
            files.push(path);
        }
    }
    if files.is_empty() {
        return Err(ReportError::new(dir, "no *.csv file in the directory"));
    }
    files.sort();
    Ok(files)
}

/// Why one input of a many-input run gave no report.
#[derive(Debug, thiserror::Error)]
pub enum Failed<E: std::error::Error + 'static> {
    #[error(transparent)]
    Error(#[from] E),
    /// A bug in the analysis: the other inputs still run.
    #[error("the analysis panicked: {0}")]
    Panic(String),
}

/// One input done.
pub struct Finished<'a, A: Analysis> {
    pub job: &'a Job,
    pub result: Result<A::Report, Failed<A::Error>>,
    /// Wall time of its run.
    pub elapsed: Duration,
}

/// Runs `args` once per job (its input and folder set) on `threads` threads taking the jobs
/// in turn from one queue, and hands each result to `done` on the calling thread as it
/// finishes. A failed input does not stop the others. A bar counting the inputs is drawn on a
/// terminal (`done` writes with it out of the way); the runs' own step bars are not.
pub fn run_all<A: Analysis>(
    args: &A,
    jobs: &[Job],
    threads: usize,
    mut done: impl FnMut(Finished<'_, A>),
) {
    let next = AtomicUsize::new(0);
    let bar = bar_of(jobs.len() as u64, "inputs", "inputs");
    let (sender, finished) = mpsc::channel();
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            let sender = sender.clone();
            let next = &next;
            scope.spawn(move || {
                hide_step_bars();
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(job) = jobs.get(i) else { break };
                    let started = Instant::now();
                    let result = run_one(args, job);
                    if sender.send((i, result, started.elapsed())).is_err() {
                        break;
                    }
                }
            });
        }
        // The workers hold the only senders left: the loop ends when they are all done.
        drop(sender);
        for (i, result, elapsed) in finished {
            let job = &jobs[i];
            bar.suspend(|| {
                done(Finished {
                    job,
                    result,
                    elapsed,
                })
            });
            bar.inc(1);
        }
    });
    bar.finish_and_clear();
}

/// `args` run on `job`'s input into its folder; a panic is this input's failure.
fn run_one<A: Analysis>(args: &A, job: &Job) -> Result<A::Report, Failed<A::Error>> {
    let mut args = args.clone();
    let run = args.run_args_mut();
    run.input = Some(job.input.clone());
    run.scenario = None;
    run.out = job.out.clone();
    if let Some(id) = job.part {
        args.select_part(id);
    }
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| args.analyse()))
        .map_err(|panic| {
            let text = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned());
            Failed::Panic(text.unwrap_or_else(|| "(no message)".into()))
        })?
        .map_err(Failed::Error)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("railmon-many-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn inputs(paths: &[&Path]) -> Inputs {
        Inputs {
            input: paths.iter().map(|p| p.to_path_buf()).collect(),
            jobs: None,
        }
    }

    #[test]
    fn one_file_writes_into_out_and_a_directory_into_a_folder_per_file() {
        let dir = scratch("plan");
        for name in ["b.csv", "a.CSV", "notes.txt"] {
            std::fs::write(dir.join(name), "").unwrap();
        }
        std::fs::create_dir(dir.join("sub.csv")).unwrap();
        let out = Path::new("out");
        assert_eq!(inputs(&[&dir.join("b.csv")]).plan(out).unwrap(), Plan::One);
        assert_eq!(inputs(&[]).plan(out).unwrap(), Plan::One);
        let job = |name: &str, stem: &str| Job {
            input: dir.join(name),
            out: out.join(stem),
            part: None,
        };
        assert_eq!(
            inputs(&[&dir]).plan(out).unwrap(),
            Plan::Many(vec![job("a.CSV", "a"), job("b.csv", "b")])
        );
        let e = inputs(&[&dir, &dir.join("b.csv")])
            .plan(out)
            .unwrap_err()
            .to_string();
        assert!(e.contains("b.csv") && e.contains("out/b"), "{e}");
        let e = inputs(&[&dir.join("sub.csv")])
            .plan(out)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no *.csv file"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn threads_are_at_most_one_per_input() {
        let mut i = inputs(&[]);
        i.jobs = NonZeroUsize::new(4);
        assert_eq!(i.threads(3), 3);
        assert_eq!(i.threads(8), 4);
        assert_eq!(i.threads(0), 1);
        i.jobs = None;
        assert!(i.threads(64) >= 1);
    }
}
