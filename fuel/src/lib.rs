//! Fuel consumption: recursive Bayesian mixture with data-dependent switching, vehicle simulator. No I/O.
