//! Offline analysis behind `railmon analyze`.
