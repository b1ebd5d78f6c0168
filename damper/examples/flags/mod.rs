//! The flag values the damper's examples and benches share (`mod flags;`; the benches by
//! `#[path]`): a value that must parse, and `on|off`. Each user takes what it needs.
#![allow(dead_code)]

use std::fmt::Display;
use std::str::FromStr;

/// `value` of `flag` parsed, or an error naming both.
pub fn parsed<T: FromStr>(flag: &str, value: &str) -> Result<T, String>
where
    T::Err: Display,
{
    value.parse().map_err(|e| format!("{flag} {value}: {e}"))
}

/// `on` or `off` of `flag`.
pub fn on_off(flag: &str, value: &str) -> Result<bool, String> {
    match value {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("{flag} {value}: on or off")),
    }
}
