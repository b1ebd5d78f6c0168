//! The filter given what the plant drew (`--oracle-conicity` of `condition_matrix` and
//! `dip_trace`): an upper bound on what estimating a parameter the vehicle does not measure
//! could bring, not a configuration a vehicle can run.

use railmon_damper::sampler::Draw;
use railmon_damper::{slowest_time_constant_s, DamperMonitorConfig};

/// `config` with the vehicle's conicity the plant's own. At a high conicity the design
/// dampers' model hunts below the default top of the speed range, which the jump search
/// refuses: the range then ends where the draw's speeds do (its top speed, kept below the
/// plant's critical speed), lower only while the model is unstable there.
pub fn with_plant_conicity(config: &DamperMonitorConfig, draw: &Draw) -> DamperMonitorConfig {
    let mut config = *config;
    config.vehicle.conicity = draw.scenario.vehicle.conicity;
    config.speed.max_m_s = config.speed.max_m_s.min(draw.top_speed_m_s + 1.0);
    while slowest_time_constant_s(&config.filter_model(), &config.speed).is_err()
        && config.speed.max_m_s > draw.top_speed_m_s
    {
        config.speed.max_m_s -= 0.5;
    }
    config
}
