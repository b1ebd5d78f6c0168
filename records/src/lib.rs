//! CSV formats of recorded sensor data.
