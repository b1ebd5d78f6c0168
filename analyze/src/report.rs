//! What every offline report shares: the output directory, a progress bar, and PNG plots.

use std::path::{Path, PathBuf};
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

/// An error writing a report: which file, and why.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {reason}")]
pub struct ReportError {
    pub path: PathBuf,
    pub reason: String,
}

impl ReportError {
    pub fn new(path: &Path, reason: impl ToString) -> Self {
        ReportError {
            path: path.to_owned(),
            reason: reason.to_string(),
        }
    }
}

/// Why an analysis failed: a bad input file, a report that could not be written, or the
/// estimator (of type `E`) refusing a sample, each naming the file.
#[derive(Debug, thiserror::Error)]
pub enum AnalysisError<E: std::error::Error + 'static> {
    #[error(transparent)]
    Record(#[from] railmon_records::RecordError),
    #[error(transparent)]
    Report(#[from] ReportError),
    #[error("{file}: {reason}")]
    Input { file: String, reason: String },
    #[error("{file}: {source}")]
    Estimator {
        file: String,
        #[source]
        source: E,
    },
}

/// What every `railmon analyze <domain>` command reads and where it writes. Each domain's
/// `Args` flattens this and adds its own options.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct RunArgs {
    /// The recorded CSV analysed. The command line's `--input` (one file, several, or a
    /// directory) is `crate::many::Inputs`, which sets this field for each file it runs.
    #[arg(skip)]
    pub input: Option<PathBuf>,
    /// A simulator scenario (`config/scenarios/<domain>-*.toml`).
    #[arg(long)]
    pub scenario: Option<PathBuf>,
    /// Estimator settings (TOML, the fields of the domain's monitor configuration). Default:
    /// the scenario's `[monitor]` table, or the built-in settings for recordings.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output directory (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// Skip the PNG plots (CSV reports only).
    #[arg(long)]
    pub no_plots: bool,
    /// Stop at the first sample the service would refuse (an error naming file, line, field
    /// and value) instead of counting and skipping it (`refused.csv`).
    #[arg(long)]
    pub strict: bool,
}

/// The samples an analysis refused, by reason: the reasons (and labels) the service counts
/// the same drops under in `railmon_stream_samples_rejected_total{reason}`. Every reason of
/// the domain is listed, refused or not, so a clean run shows its zeros.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refusals {
    counts: Vec<(&'static str, u64)>,
}

impl Refusals {
    /// No refusals yet, of the domain's `reasons`.
    pub fn new(reasons: &[&'static str]) -> Self {
        Refusals {
            counts: reasons.iter().map(|&r| (r, 0)).collect(),
        }
    }

    /// Counts one refused sample (a reason the domain does not list is added).
    pub fn add(&mut self, reason: &'static str) {
        match self.counts.iter_mut().find(|(r, _)| *r == reason) {
            Some((_, n)) => *n += 1,
            None => self.counts.push((reason, 1)),
        }
    }

    /// The samples refused for `reason`.
    pub fn count(&self, reason: &str) -> u64 {
        self.counts
            .iter()
            .find(|(r, _)| *r == reason)
            .map_or(0, |(_, n)| *n)
    }

    /// Every refused sample.
    pub fn total(&self) -> u64 {
        self.counts.iter().map(|(_, n)| n).sum()
    }

    /// `(reason, count)`, every reason of the domain.
    pub fn counts(&self) -> &[(&'static str, u64)] {
        &self.counts
    }

    /// One line for the terminal: `refused samples: 3 (out_of_range 2, not_finite 1)`.
    pub fn line(&self) -> String {
        let some: Vec<String> = self
            .counts
            .iter()
            .filter(|(_, n)| *n > 0)
            .map(|(r, n)| format!("{r} {n}"))
            .collect();
        match some.is_empty() {
            true => "refused samples: 0".to_owned(),
            false => format!("refused samples: {} ({})", self.total(), some.join(", ")),
        }
    }

    /// `refused.csv`: `reason,count`, one row per reason, then `total`.
    pub fn write_csv(&self, path: &Path) -> Result<(), railmon_records::RecordError> {
        let rows = self
            .counts
            .iter()
            .map(|(r, n)| vec![(*r).to_owned(), n.to_string()])
            .chain([vec!["total".to_owned(), self.total().to_string()]]);
        railmon_records::write_csv_table(path, &["reason", "count"], rows)
    }
}

/// What the samples' own clock did in a run (judged as the service's ingest judges it,
/// `railmon_records::sample_clock::TimeJudge`): the sample periods no sample covered, which
/// the estimator bridged (the service's `railmon_stream_skipped_periods_total`), and the
/// sample times at which a confirmed jump of the source's clock restarted the estimator (the
/// service counts them as new sources).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Timeline {
    pub skipped_periods: u64,
    /// Sample time (s) of the first sample of each new timeline.
    pub new_timelines_s: Vec<f64>,
}

impl Timeline {
    /// One line for the terminal: `skipped periods: 2; new timelines: 1 (at 3600.001 s)`.
    pub fn line(&self) -> String {
        let at: Vec<String> = self
            .new_timelines_s
            .iter()
            .take(5)
            .map(|t| format!("{t:.6} s"))
            .collect();
        let more = match self.new_timelines_s.len() > at.len() {
            true => ", ...",
            false => "",
        };
        match at.is_empty() {
            true => format!(
                "skipped periods (bridged): {}; new timelines: 0",
                self.skipped_periods
            ),
            false => format!(
                "skipped periods (bridged): {}; new timelines (estimator restarted): {} (at {}{more})",
                self.skipped_periods,
                self.new_timelines_s.len(),
                at.join(", ")
            ),
        }
    }
}

/// What a run needs, estimated from its size before any work starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunSize {
    /// Held in memory until the end (traces for the tables and plots).
    pub memory_bytes: u64,
    /// Written into `--out`.
    pub disk_bytes: u64,
}

impl RunSize {
    /// `units` (drive-steps, bogie-steps) at the measured bytes per unit.
    pub fn of(units: u64, memory_bytes_per_unit: u64, disk_bytes_per_unit: u64) -> Self {
        RunSize {
            memory_bytes: units.saturating_mul(memory_bytes_per_unit),
            disk_bytes: units.saturating_mul(disk_bytes_per_unit),
        }
    }

    /// Refuses a run that cannot finish on this machine: more memory than is available now
    /// (`MemAvailable`), or more output than the file system of `out` has free (an allowed
    /// `n_steps` once needed ~24 GB of RAM and 77 GB of disk, found hours into the run). A
    /// figure the system does not give is not checked.
    pub fn check_fits(&self, out: &Path, what: &str) -> Result<(), ReportError> {
        let gb = |b: u64| b as f64 / 1e9;
        if let Some(available) = memory_available_bytes() {
            if self.memory_bytes > available {
                return Err(ReportError::new(
                    out,
                    format!(
                        "{what} would hold ~{:.1} GB in memory; {:.1} GB are available: \
                         shorten the run",
                        gb(self.memory_bytes),
                        gb(available)
                    ),
                ));
            }
        }
        if let Some(free) = disk_free_bytes(out) {
            if self.disk_bytes > free {
                return Err(ReportError::new(
                    out,
                    format!(
                        "{what} would write ~{:.1} GB; its file system has {:.1} GB free: \
                         shorten the run or choose another --out",
                        gb(self.disk_bytes),
                        gb(free)
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// `MemAvailable` of /proc/meminfo, in bytes.
fn memory_available_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Bytes an unprivileged process may still write on the file system of `dir`.
fn disk_free_bytes(dir: &Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let path = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    let mut stat = std::mem::MaybeUninit::<libc::statvfs>::uninit();
    // SAFETY: `path` is a valid C string and `stat` a buffer of the right type; statvfs writes
    // it in full when it returns 0.
    let stat = unsafe {
        if libc::statvfs(path.as_ptr(), stat.as_mut_ptr()) != 0 {
            return None;
        }
        stat.assume_init()
    };
    Some((stat.f_bavail as u64).saturating_mul(stat.f_frsize as u64))
}

/// Creates `dir` (and parents) if needed.
pub fn create_out_dir(dir: &Path) -> Result<(), ReportError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| ReportError::new(dir, format!("cannot create directory: {e}")))
}

std::thread_local! {
    /// Whether this thread's runs draw their step bars: not on the workers of a many-input run
    /// (`crate::many`), whose one bar counts the inputs.
    static STEP_BARS_SHOWN: std::cell::Cell<bool> = const { std::cell::Cell::new(true) };
}

/// No step bars from the runs of this thread (a worker of a many-input run).
pub(crate) fn hide_step_bars() {
    STEP_BARS_SHOWN.with(|shown| shown.set(false));
}

/// A progress bar over `len` steps, labelled `what`. It draws to stderr only when stderr is a
/// terminal, and only after the first second, so short runs and logs stay clean.
pub fn progress_bar(len: u64, what: &str) -> ProgressBar {
    match STEP_BARS_SHOWN.with(|shown| shown.get()) {
        true => bar_of(len, what, "steps"),
        false => ProgressBar::hidden(),
    }
}

/// A progress bar over `len` `unit`s, as [`progress_bar`] draws it.
pub(crate) fn bar_of(len: u64, what: &str, unit: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::hidden());
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{{msg}} [{{bar:40}}] {{pos}}/{{len}} {unit}, {{per_sec}}, eta {{eta}}"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_message(what.to_owned());
    if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        let shown = bar.clone();
        // Show the bar only for runs longer than a second.
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_secs(1));
            if !shown.is_finished() {
                shown.set_draw_target(ProgressDrawTarget::stderr());
            }
        });
    }
    bar
}

/// One line of a [`line_plot`]: `(x, y)` points and a legend label.
pub struct Series<'a> {
    pub label: &'a str,
    pub points: Vec<(f64, f64)>,
}

/// Axis labels and title of a plot.
pub struct Axes<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
}

const PLOT_SIZE: (u32, u32) = (1200, 500);

fn palette(i: usize) -> RGBColor {
    const COLORS: [RGBColor; 8] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
    ];
    COLORS[i % COLORS.len()]
}

/// Range of finite values with a 5% margin (a flat series still gets a visible band).
fn padded_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return 0.0..1.0;
    }
    let pad = ((hi - lo) * 0.05).max(1e-9 * lo.abs().max(1.0));
    (lo - pad)..(hi + pad)
}

/// DejaVu Sans 2.37 (Debian's fonts-dejavu-core; licence in `fonts/DejaVuSans-LICENSE`), the
/// font of every plot's text: plotters' `ab_glyph` text needs its fonts registered, and an
/// embedded one makes plots the same on every machine with no system font library.
const EMBEDDED_FONT: &[u8] = include_bytes!("../fonts/DejaVuSans.ttf");

/// Registers [`EMBEDDED_FONT`] as `sans-serif` (the family plotters' labels default to), once.
fn register_embedded_font() -> Result<(), String> {
    static REGISTERED: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            plotters::style::register_font("sans-serif", FontStyle::Normal, EMBEDDED_FONT)
                .map_err(|_| "the embedded font DejaVuSans.ttf is not a valid font".to_string())
        })
        .clone()
}

type Chart<'a> = ChartContext<'a, BitMapBackend<'a>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Draws the white background, caption and labelled mesh every plot shares, then hands the
/// chart to `draw`, and writes the file.
fn draw_chart(
    path: &Path,
    size: (u32, u32),
    axes: &Axes,
    x_range: std::ops::Range<f64>,
    y_range: std::ops::Range<f64>,
    draw: impl FnOnce(&mut Chart) -> Result<(), String>,
) -> Result<(), ReportError> {
    // Drawn under a temporary name and renamed when complete: no half-written PNG.
    let file =
        railmon_records::AtomicFile::create(path).map_err(|e| ReportError::new(path, e.reason))?;
    let err = |e: &dyn std::fmt::Display| ReportError::new(path, e);
    register_embedded_font().map_err(|e| err(&e))?;
    let root = BitMapBackend::new(file.temporary_path(), size).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(axes.title, ("sans-serif", 22))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x_range, y_range)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .x_desc(axes.x_label)
        .y_desc(axes.y_label)
        .draw()
        .map_err(|e| err(&e))?;
    draw(&mut chart).map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    drop(chart);
    drop(root);
    file.commit().map_err(|e| ReportError::new(path, e.reason))
}

fn draw_legend(chart: &mut Chart) -> Result<(), String> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| e.to_string())
}

fn x_and_y_ranges(series: &[Series]) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    (
        padded_range(series.iter().flat_map(|s| s.points.iter().map(|p| p.0))),
        padded_range(series.iter().flat_map(|s| s.points.iter().map(|p| p.1))),
    )
}

/// Writes a PNG with one line per series.
pub fn line_plot(path: &Path, axes: &Axes, series: &[Series]) -> Result<(), ReportError> {
    let (x_range, y_range) = x_and_y_ranges(series);
    draw_chart(path, PLOT_SIZE, axes, x_range, y_range, |chart| {
        for (i, s) in series.iter().enumerate() {
            let color = palette(i);
            chart
                .draw_series(LineSeries::new(
                    s.points.iter().copied(),
                    color.stroke_width(1),
                ))
                .map_err(|e| e.to_string())?
                .label(s.label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
        }
        if series.len() > 1 {
            draw_legend(chart)?;
        }
        Ok(())
    })
}

/// Writes a PNG scatter plot, one colour per series (e.g. per mixture component).
pub fn scatter_plot(path: &Path, axes: &Axes, series: &[Series]) -> Result<(), ReportError> {
    let (x_range, y_range) = x_and_y_ranges(series);
    draw_chart(path, (900, 700), axes, x_range, y_range, |chart| {
        for (i, s) in series.iter().enumerate() {
            let color = palette(i);
            chart
                .draw_series(s.points.iter().map(|&p| Circle::new(p, 2, color.filled())))
                .map_err(|e| e.to_string())?
                .label(s.label)
                .legend(move |(x, y)| Circle::new((x + 10, y), 4, color.filled()));
        }
        draw_legend(chart)
    })
}

/// Writes a PNG histogram of `values` with `bins` equal-width bins.
pub fn histogram(path: &Path, axes: &Axes, values: &[f64], bins: usize) -> Result<(), ReportError> {
    let bins = bins.max(1);
    let range = padded_range(values.iter().copied());
    let width = (range.end - range.start) / bins as f64;
    let mut counts = vec![0u64; bins];
    for v in values.iter().filter(|v| v.is_finite()) {
        let k = (((v - range.start) / width) as usize).min(bins - 1);
        counts[k] += 1;
    }
    let max_count = counts.iter().copied().max().unwrap_or(0).max(1) as f64;
    draw_chart(
        path,
        PLOT_SIZE,
        axes,
        range.clone(),
        0.0..max_count * 1.05,
        |chart| {
            chart
                .draw_series(counts.iter().enumerate().map(|(k, &c)| {
                    let x0 = range.start + k as f64 * width;
                    Rectangle::new([(x0, 0.0), (x0 + width, c as f64)], palette(0).filled())
                }))
                .map(|_| ())
                .map_err(|e| e.to_string())
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_that_cannot_fit_is_refused_by_what_it_lacks() {
        let out = std::env::temp_dir();
        RunSize::of(1000, 100, 270)
            .check_fits(&out, "a run")
            .unwrap();
        let e = RunSize::of(u64::MAX / 1000, 1000, 0)
            .check_fits(&out, "a run")
            .unwrap_err()
            .to_string();
        assert!(e.contains("in memory"), "{e}");
        let e = RunSize::of(u64::MAX, 0, 1)
            .check_fits(&out, "a run")
            .unwrap_err()
            .to_string();
        assert!(e.contains("GB free"), "{e}");
        assert!(memory_available_bytes().is_some_and(|b| b > 0));
        assert!(disk_free_bytes(&out).is_some_and(|b| b > 0));
    }

    #[test]
    fn plots_are_written_as_png() {
        let dir = std::env::temp_dir().join(format!("railmon-report-test-{}", std::process::id()));
        create_out_dir(&dir).unwrap();
        let axes = Axes {
            title: "t",
            x_label: "x",
            y_label: "y",
        };
        let line = dir.join("line.png");
        let series = [
            Series {
                label: "a",
                points: (0..100)
                    .map(|i| (i as f64, (i as f64 * 0.1).sin()))
                    .collect(),
            },
            Series {
                label: "b",
                points: vec![(0.0, 1.0), (99.0, 1.0)],
            },
        ];
        line_plot(&line, &axes, &series).unwrap();
        let hist = dir.join("hist.png");
        histogram(&hist, &axes, &[1.0, 2.0, 2.5, f64::NAN, 3.0], 10).unwrap();
        let scatter = dir.join("scatter.png");
        scatter_plot(&scatter, &axes, &series).unwrap();
        for p in [line, hist, scatter] {
            let bytes = std::fs::read(&p).unwrap();
            assert_eq!(&bytes[1..4], b"PNG", "{}", p.display());
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn padded_range_ignores_non_finite_and_widens_flat_series() {
        let r = padded_range([1.0, f64::NAN, 1.0].into_iter());
        assert!(r.start < 1.0 && r.end > 1.0);
        assert_eq!(padded_range(std::iter::empty()), 0.0..1.0);
    }
}
