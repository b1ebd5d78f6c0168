//! The drive pipeline without the bus: the service's numbers are the library's numbers, bad
//! frames change nothing, hysteresis events follow the seed scenario's slips.

mod common;

use common::{frame_of, header, seed, Harness};
use railmon_service::ingest::Pipeline;
use railmon_service::ServiceConfig;
use railmon_slip::SlipMonitor;

#[test]
fn service_estimator_defaults_are_the_seed_scenarios_monitor() {
    assert_eq!(
        ServiceConfig::default().drive.estimator,
        seed().monitor_config()
    );
}

#[test]
fn pipeline_reproduces_the_library_and_flags_drive_1_slips() {
    let scenario = seed();
    let mut reference = SlipMonitor::new(&scenario.monitor_config(), scenario.n_drives()).unwrap();
    let mut harness = Harness::new();
    while let Some(samples) = harness.advance() {
        reference.step(&samples).unwrap();
        if harness.step.is_multiple_of(250) {
            let view = harness.view();
            for (got, want) in view.drives.iter().zip(&reference.last().drives) {
                assert_eq!(got.slip_probability, want.slip_probability);
                assert_eq!(got.load_torque_nm, want.torque_nm);
                assert_eq!(got.electrical_speed_rad_s, want.speed_rad_s);
            }
        }
    }
    harness.view();
    let events = common::stored_events(&harness.shared.store);
    assert!(
        events
            .iter()
            .all(|e| e.detail["drive"] == 1 && e.subject == "1"),
        "{events:?}"
    );
    // Drive 1 slips on steps [500, 1500] (62.5-187.5 ms), edges smoothed by a normal CDF of
    // scale 30 steps (so the load starts falling ~3 scales early): one start, its end after.
    let dt_s = scenario.dt_s();
    let first_start = events.iter().find(|e| e.kind == "slip_started").unwrap();
    assert!(
        (410.0 * dt_s..1500.0 * dt_s).contains(&first_start.run_time_s),
        "{first_start:?}"
    );
    let first_end = events.iter().find(|e| e.kind == "slip_ended").unwrap();
    assert!(first_end.run_time_s > 1500.0 * dt_s, "{first_end:?}");
}

#[test]
fn bad_frames_are_rejected_and_change_nothing() {
    let mut harness = Harness::new();
    for _ in 0..600 {
        harness.advance();
    }
    let before = harness.view();
    let (samples, _) = harness.simulator.step().unwrap();
    let good = frame_of(samples, harness.dt_ns);
    let next = header(harness.step, harness.dt_ns);

    let mut nan = good;
    nan.drives[1].i_alpha_a = f64::NAN;
    let rejection = harness.pipeline.check(&next, &nan).unwrap_err();
    assert_eq!(rejection.reason, "not_finite");
    assert!(
        rejection.message.contains("drive 2"),
        "{}",
        rejection.message
    );

    let mut too_many = good;
    too_many.n_drives = 40;
    assert_eq!(
        harness.pipeline.check(&next, &too_many).unwrap_err().reason,
        "too_many_drives"
    );

    let mut other_dt = good;
    other_dt.dt_ns = 100_000;
    assert_eq!(
        harness.pipeline.check(&next, &other_dt).unwrap_err().reason,
        "dt_mismatch"
    );

    // Currents in mA instead of A: refused, naming the drive, the channel and the limit.
    let mut milliamps = good;
    for d in &mut milliamps.drives[..3] {
        d.i_alpha_a *= 1000.0;
        d.i_beta_a *= 1000.0;
    }
    let rejection = harness.pipeline.check(&next, &milliamps).unwrap_err();
    assert_eq!(rejection.reason, "out_of_range");
    assert!(
        rejection.message.contains("drive 1") && rejection.message.contains("max_abs_current_a"),
        "{}",
        rejection.message
    );

    // An implausible train speed is a sensor fault: refused under its own reason.
    for (speed, reason) in [
        (f64::NAN, "not_finite"),
        (-1.0, "train_speed_out_of_range"),
        (360.0 / 3.6 + 1.0, "train_speed_out_of_range"),
    ] {
        let bad = good.with_train_speed(Some(speed));
        let rejection = harness.pipeline.check(&next, &bad).unwrap_err();
        assert_eq!(rejection.reason, reason, "{speed}");
        assert!(
            rejection.message.contains("train_speed_m_s"),
            "{}",
            rejection.message
        );
    }
    let mut unknown = good;
    unknown.present = 1 << 7;
    assert_eq!(
        harness.pipeline.check(&next, &unknown).unwrap_err().reason,
        "unknown_channels"
    );

    let mut fewer = good;
    fewer.n_drives = 2;
    assert_eq!(
        harness.pipeline.check(&next, &fewer).unwrap_err().reason,
        "drive_count_changed"
    );
    assert_eq!(harness.view(), before);
}

/// A restart resumes the saved estimator: the same frames then give exactly the estimates the
/// pipeline that never stopped gives (no second lock-on of the EKFs).
#[test]
fn a_saved_state_resumes_the_estimator_exactly() {
    let mut running = Harness::new();
    for _ in 0..800 {
        running.advance();
    }
    running.view();
    let state = running.pipeline.save_state().expect("a monitor to save");
    let mut resumed = Harness::new();
    resumed.pipeline.resume_state(&state).unwrap();
    // The resumed pipeline gets the frames that follow.
    for _ in 0..400 {
        let step = running.step;
        let samples = running.advance().unwrap();
        let (frame, header) = (
            frame_of(&samples, running.dt_ns),
            header(step, running.dt_ns),
        );
        let input = resumed.pipeline.check(&header, &frame).unwrap();
        resumed.pipeline.step(&header, input).unwrap();
    }
    let (a, b) = (running.view(), resumed.view());
    assert_eq!(a.drives, b.drives);
    assert_eq!(a.time_s, b.time_s, "stream time goes on");
    // Settings of another estimator refuse the state's shape only if it cannot be read: the
    // snapshot file's settings fingerprint is what guards that (tested in snapshot.rs).
    assert!(resumed.pipeline.resume_state(b"not a state").is_err());
}

/// Frames carrying the train speed reach the monitor's train-speed test: the service's
/// estimates are the library's `step_with_train_speed`, and the drives view says which
/// reference judged them (`group` while the test warms up, then `train_speed`).
#[test]
fn the_train_speed_of_the_frames_is_the_reference_once_calibrated() {
    let scenario = seed();
    let config = ServiceConfig::default().drive;
    let mut reference = SlipMonitor::new(&config.estimator, scenario.n_drives()).unwrap();
    reference
        .set_speed_reference(config.speed_reference)
        .unwrap();
    let mut harness = Harness::new();
    assert_eq!(harness.view().reference, None);
    let mut seen = Vec::new();
    // Frames until the step 1,999 is published (the train speed calibrated by then).
    let last = 2_000 + railmon_slip::fixed_lag::FIXED_LAG_STEPS as u64 - 1;
    for _ in 0..=last {
        let step = harness.step;
        let (samples, _) = harness.simulator.step().unwrap();
        let samples = samples.to_vec();
        harness.step += 1;
        // The seed plant's rotors at 200 rad/s electrical: 5.75 m/s with the default geometry.
        let frame = frame_of(&samples, harness.dt_ns).with_train_speed(Some(5.75));
        let header = header(step, harness.dt_ns);
        let input = harness.pipeline.check(&header, &frame).unwrap();
        harness.pipeline.step(&header, input).unwrap();
        // Both publish the step FIXED_LAG_STEPS back, from frame FIXED_LAG_STEPS on.
        let want = reference
            .step_with_train_speed(&samples, Some(5.75))
            .unwrap()
            .cloned();
        if let Some(want) = want.filter(|_| step.is_multiple_of(250) || step == last) {
            let view = harness.view();
            for (got, want) in view.drives.iter().zip(&want.drives) {
                assert_eq!(got.slip_probability, want.slip_probability);
            }
            let got = view.reference.clone().unwrap();
            assert_eq!(got, want.reference.name());
            if !seen.contains(&got) {
                seen.push(got);
            }
        }
    }
    assert_eq!(seen, ["group", "train_speed"]);
}

/// The estimate trails the frames by the fixed lag: no view before the first estimate, and
/// when the stream falls silent the held steps are published from the frames there are (the
/// library's `drain`), the last one dated at the last frame; after a restart of the service
/// its snapshot dates them the same way.
#[test]
fn the_steps_behind_the_fixed_lag_are_published_when_the_stream_falls_silent() {
    let scenario = seed();
    let lag = railmon_slip::fixed_lag::FIXED_LAG_STEPS as u64;
    let mut reference = SlipMonitor::new(&scenario.monitor_config(), scenario.n_drives()).unwrap();
    let mut harness = Harness::new();
    for _ in 0..lag {
        reference.step(&harness.advance().unwrap()).unwrap();
    }
    assert!(
        harness.view().drives.is_empty(),
        "no estimate before the lag is full"
    );
    for _ in lag..700 {
        reference.step(&harness.advance().unwrap()).unwrap();
    }
    let dt_s = scenario.dt_s();
    let view = harness.view();
    assert!((view.run_time_s.unwrap() - (699 - lag) as f64 * dt_s).abs() < 1e-9);
    let state = harness.pipeline.save_state().unwrap();

    harness.pipeline.end_of_data();
    let mut last = None;
    while let Some(e) = reference.drain().unwrap() {
        last = Some(e.clone());
    }
    let last = last.unwrap();
    assert_eq!(last.step, 699);
    let view = harness.view();
    assert!(
        (view.run_time_s.unwrap() - 699.0 * dt_s).abs() < 1e-9,
        "{view:?}"
    );
    for (got, want) in view.drives.iter().zip(&last.drives) {
        assert_eq!(got.slip_probability, want.slip_probability);
        assert_eq!(got.load_torque_nm, want.torque_nm);
    }

    // The service restarts from the snapshot taken before the silence.
    let mut resumed = Harness::new();
    resumed.pipeline.resume_state(&state).unwrap();
    resumed.pipeline.end_of_data();
    let view = resumed.view();
    assert!(
        (view.run_time_s.unwrap() - 699.0 * dt_s).abs() < 1e-9,
        "{view:?}"
    );
    assert_eq!(view.drives.len(), last.drives.len());
    for (got, want) in view.drives.iter().zip(&last.drives) {
        assert_eq!(got.slip_probability, want.slip_probability);
    }
}
