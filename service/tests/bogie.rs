//! The bogie pipeline without the bus: a restart resumes its RBPFs from the saved state.

mod common;

use std::path::Path;
use std::sync::Arc;

use railmon_bus::BogieFrame;
use railmon_damper::{BogieSimulator, DamperScenario};
use railmon_service::bogie::{BogiePipeline, BogieShared, BogiesView};
use railmon_service::ingest::Pipeline;
use railmon_service::metrics::Metrics;

use common::{header, memory_store, test_config};

const BOGIE: u32 = 1;
/// Few particles keep the test quick; what is tested is the state's round trip.
const PARTICLES: usize = 100;

fn pipeline() -> (BogiePipeline, Arc<BogieShared>) {
    let mut config = test_config().bogie;
    config.enabled = true;
    config.bogies = vec![BOGIE];
    config.estimator.rbpf.particles = PARTICLES;
    let shared = Arc::new(config.outbox(memory_store()));
    let metrics = Arc::new(Metrics::new().unwrap());
    (
        BogiePipeline::new(config, shared.clone(), metrics, &[]),
        shared,
    )
}

fn feed(pipeline: &mut BogiePipeline, frame: &BogieFrame, step: u64, dt_ns: u64) {
    let header = header(step, dt_ns);
    let input = pipeline.check(&header, frame).unwrap();
    pipeline.step(&header, input).unwrap();
}

fn view((pipeline, shared): &mut (BogiePipeline, Arc<BogieShared>)) -> BogiesView {
    pipeline.publish();
    BogiesView::clone(&shared.snapshot.load())
}

/// After a restart from the saved state, the same frames give exactly the estimates of the
/// pipeline that never stopped; a pipeline started from its prior is elsewhere (issue 12: the
/// damper used to need ~30 s of data again).
#[test]
fn a_saved_state_resumes_the_bogie_filters_exactly() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenarios/damper-seed.toml");
    let scenario = DamperScenario::from_toml_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let mut simulator = BogieSimulator::new(&scenario).unwrap();
    let dt_ns = (scenario.dt_s * 1e9).round() as u64;
    let frames: Vec<BogieFrame> = (0..6_000)
        .map(|_| BogieFrame::from_sample(BOGIE, simulator.step().unwrap().0))
        .collect();

    let mut running = pipeline();
    for (step, frame) in frames[..5_000].iter().enumerate() {
        feed(&mut running.0, frame, step as u64, dt_ns);
    }
    let state = running.0.save_state().expect("a monitor to save");
    let mut resumed = pipeline();
    resumed.0.resume_state(&state).unwrap();
    let mut fresh = pipeline();
    for (step, frame) in frames.iter().enumerate().skip(5_000) {
        for p in [&mut running, &mut resumed, &mut fresh] {
            feed(&mut p.0, frame, step as u64, dt_ns);
        }
    }
    let (a, b, c) = (view(&mut running), view(&mut resumed), view(&mut fresh));
    assert_eq!(a.bogies, b.bogies);
    assert_eq!(a.time_s, b.time_s, "stream time goes on");
    assert_ne!(
        a.bogies[0].csay, c.bogies[0].csay,
        "a prior is not a resumed filter"
    );
    assert!(resumed.0.resume_state(b"not a state").is_err());
}
