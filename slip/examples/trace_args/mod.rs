//! The command line the trace examples share: `SCENARIO.toml DRIVE FROM TO`, read into the
//! scenario, the drive's 0-based index (DRIVE counts from 1, as the CSVs do) and the range of
//! steps to print.

use std::ops::RangeInclusive;

use railmon_slip::AdhesionScenario;

pub fn trace_args(example: &str) -> (AdhesionScenario, usize, RangeInclusive<usize>) {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [path, drive, from, to] = args.as_slice() else {
        eprintln!("usage: {example} SCENARIO.toml DRIVE FROM TO");
        std::process::exit(2);
    };
    let text = std::fs::read_to_string(path).expect("scenario file");
    let scenario = AdhesionScenario::from_toml_str(&text).expect("scenario");
    let k = drive.parse::<usize>().expect("DRIVE") - 1;
    let range = from.parse::<usize>().expect("FROM")..=to.parse::<usize>().expect("TO");
    (scenario, k, range)
}
