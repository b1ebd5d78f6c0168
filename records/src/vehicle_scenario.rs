//! A fuel scenario run through the vehicle simulator, with the drive cycles it names read from
//! their CSV files. The fuel crate does no I/O, so reading the scenario and its cycles lives
//! here, beside the vehicle format the run is written in; `sensors-replay vehicle --scenario`
//! and `railmon analyze fuel --scenario` both call it, so both see the same samples.

use std::collections::BTreeMap;
use std::path::Path;

use railmon_fuel::{
    DriveCycle, FuelMonitorConfig, RailcarScenario, RailcarSimulator, VehicleSample,
    VehicleScenario, VehicleSimulator,
};

use crate::vehicle::{read_drive_cycle, VehicleRow};
use crate::RecordError;

/// What a scenario run produced: the estimator settings of the scenario (`[monitor]`), the
/// regime names, every simulated row (with its regime's name) and each row's regime as an
/// index into `regime_names`.
#[derive(Clone, Debug)]
pub struct SimulatedVehicle {
    pub monitor: FuelMonitorConfig,
    pub regime_names: Vec<String>,
    pub rows: Vec<VehicleRow>,
    pub regimes: Vec<usize>,
}

impl SimulatedVehicle {
    fn new(monitor: FuelMonitorConfig, regime_names: Vec<String>) -> Self {
        SimulatedVehicle {
            monitor,
            regime_names,
            rows: Vec::new(),
            regimes: Vec::new(),
        }
    }

    fn push(&mut self, sample: VehicleSample, regime: usize) {
        self.rows.push(VehicleRow {
            sample,
            regime: Some(self.regime_names[regime].clone()),
            // As `simulated.csv` has it: after the header.
            line: self.rows.len() as u64 + 2,
        });
        self.regimes.push(regime);
    }
}

/// Reads the scenario file at `path` and runs its simulator to the end: a railcar on a route
/// (`fuel-railcar.toml`: `[[section]]` tables) or a car on drive cycles (`fuel-cycles.toml`,
/// the cycles read from `drive_cycle_dir`, relative to the scenario file). Errors name the
/// file at fault.
pub fn simulate_vehicle_scenario(path: &Path) -> Result<SimulatedVehicle, RecordError> {
    let label = path.display().to_string();
    let text = crate::read_text_file(path, crate::MAX_SETTINGS_FILE_BYTES)
        .map_err(|e| RecordError::file(&label, format!("cannot read: {e}")))?;
    if RailcarScenario::is_one(&text) {
        let scenario = RailcarScenario::from_toml_str(&text)
            .map_err(|e| RecordError::file(&label, e.to_string()))?;
        let mut simulator = RailcarSimulator::new(&scenario)
            .map_err(|e| RecordError::file(&label, e.to_string()))?;
        let mut run = SimulatedVehicle::new(scenario.monitor.clone(), scenario.regimes());
        while let Some((sample, truth)) = simulator.step() {
            run.push(sample, truth.regime);
        }
        return Ok(run);
    }
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
    let mut run = SimulatedVehicle::new(scenario.monitor.clone(), scenario.regimes());
    while let Some((sample, truth)) = simulator.step() {
        run.push(sample, truth.regime);
    }
    Ok(run)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCENARIO: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../config/scenarios/fuel-cycles.toml"
    );

    #[test]
    fn the_railcar_route_runs_to_the_terminus_through_every_regime() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../config/scenarios/fuel-railcar.toml"
        );
        let run = simulate_vehicle_scenario(Path::new(path)).unwrap();
        let n = run.rows.len();
        assert!(n > 1000 && n < 20_000, "{n} s");
        let mut counts = vec![0usize; run.regime_names.len()];
        for r in &run.regimes {
            counts[*r] += 1;
        }
        assert!(counts.iter().all(|&c| c > 50), "{counts:?}");
        // It ends standing at the terminus (the brake brought it to rest on the last sample),
        // and the fuel spans idle to full power.
        let last = run.rows.last().unwrap();
        assert_eq!(last.sample.speed_m_s, Some(0.0));
        let fuel = run.rows.iter().map(|r| r.sample.fuel_cm3_s.unwrap());
        let max = fuel.fold(0.0f64, f64::max);
        assert!(max > 100.0, "{max}");
    }

    #[test]
    fn a_scenario_runs_with_its_cycles_and_labels_every_row() {
        let run = simulate_vehicle_scenario(Path::new(SCENARIO)).unwrap();
        assert!(!run.rows.is_empty());
        assert_eq!(run.rows.len(), run.regimes.len());
        let names = &run.regime_names;
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
