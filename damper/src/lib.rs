//! Damper health of a bogie: 17-state lateral vehicle model and simulator, Rao-Blackwellised particle filter, augmented-state EKF. No I/O.
