//! Wheel slip (adhesion loss) of traction drives: PMSM model and simulator, per-drive EKF, VB / VMP / k-means / median adhesion estimators. No I/O.
