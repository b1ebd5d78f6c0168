//! A fuel scenario run through the vehicle simulator, with the drive cycles it names read from
//! their CSV files. The fuel crate does no I/O, so reading the scenario and its cycles lives
//! here, beside the vehicle format the run is written in; `sensors-replay vehicle --scenario`
//! and `railmon analyze fuel --scenario` both call it, so both see the same samples.

use std::collections::BTreeMap;
use std::path::Path;

use railmon_fuel::{DriveCycle, VehicleScenario, VehicleSimulator};

use crate::vehicle::{read_drive_cycle, VehicleRow};
use crate::RecordError;

/// What a scenario run produced: the scenario, every simulated row (with its regime's name)
/// and each row's regime as an index into `scenario.regimes()`.
#[derive(Clone, Debug)]
pub struct SimulatedVehicle {
    pub scenario: VehicleScenario,
    pub rows: Vec<VehicleRow>,
    pub regimes: Vec<usize>,
}

/// Reads the scenario file at `path`, the drive cycles from `drive_cycle_dir` (relative to the
/// scenario file), and runs the simulator to the end. Errors name the file at fault.
pub fn simulate_vehicle_scenario(path: &Path) -> Result<SimulatedVehicle, RecordError> {
    let label = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| RecordError::file(&label, format!("cannot read: {e}")))?;
    let scenario = VehicleScenario::from_toml_str(&text)
        .map_err(|e| RecordError::file(&label, e.to_string()))?;
    let dir = path
        .parent()
        .unwrap_or(Path::new("."))
        .join(&scenario.drive_cycle_dir);
    let mut cycles = BTreeMap::new();
    for name in scenario.cycle_names() {
        let trace = read_drive_cycle(&dir.join(format!("{name}.csv")))?;
        cycles.insert(
            name,
            DriveCycle {
                speed_m_s: trace.speed_m_s,
                grade_rad: trace.grade_rad,
            },
        );
    }
    let mut simulator = VehicleSimulator::new(&scenario, &cycles)
        .map_err(|e| RecordError::file(&label, e.to_string()))?;
    let names = scenario.regimes();
    let (mut rows, mut regimes) = (Vec::new(), Vec::new());
    while let Some((sample, truth)) = simulator.step() {
        rows.push(VehicleRow {
            sample,
            regime: Some(names[truth.regime].clone()),
            // As `simulated.csv` has it: after the header.
            line: rows.len() as u64 + 2,
        });
        regimes.push(truth.regime);
    }
    Ok(SimulatedVehicle {
        scenario,
        rows,
        regimes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCENARIO: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../config/scenarios/fuel-cycles.toml"
    );

    #[test]
    fn a_scenario_runs_with_its_cycles_and_labels_every_row() {
        let run = simulate_vehicle_scenario(Path::new(SCENARIO)).unwrap();
        assert!(!run.rows.is_empty());
        assert_eq!(run.rows.len(), run.regimes.len());
        let names = run.scenario.regimes();
        for (row, regime) in run.rows.iter().zip(&run.regimes) {
            assert_eq!(row.regime.as_deref(), Some(names[*regime].as_str()));
        }
    }

    #[test]
    fn a_missing_scenario_names_the_file() {
        let err = simulate_vehicle_scenario(Path::new("/nonexistent/fuel.toml")).unwrap_err();
        assert!(
            err.to_string()
                .starts_with("/nonexistent/fuel.toml: cannot read"),
            "{err}"
        );
    }
}
