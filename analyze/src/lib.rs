//! Offline analysis behind `railmon analyze <domain>`: run an estimator over a simulated
//! scenario or a recorded CSV, score it against ground truth where there is one, and write
//! CSV reports and PNG plots into an output directory.
//!
//! `report` holds what every domain shares (output directory, progress bar, plots); `many`
//! runs a domain over many inputs at once.

pub mod adhesion;
pub mod damper;
pub mod fuel;
pub mod many;
pub mod report;
