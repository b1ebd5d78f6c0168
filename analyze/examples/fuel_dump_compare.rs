//! Compares two dumps of `fuel_bit_dump` number by number: the text between numbers must be
//! equal, and each pair of numbers within `1e-9` relative or `1e-12` absolute (near zero) of
//! each other. For a change that may move the numbers by rounding but must not change them
//! otherwise (docs/fuel.md, "Benchmark"). Prints the largest relative deviation (over pairs
//! whose larger magnitude exceeds `1e-3`), the largest absolute deviation (over the others),
//! the count of pairs outside the tolerance and the first of them; exits with 1 if any.
//!
//! `cargo run --release -p railmon-analyze --example fuel_dump_compare -- before.txt after.txt`

use std::io::BufRead;

/// Relative tolerance between a value of the reference dump and the same value of the other.
const RELATIVE_TOLERANCE: f64 = 1e-9;
/// Absolute tolerance (values near zero, where a relative one means nothing).
const ABSOLUTE_TOLERANCE: f64 = 1e-12;
/// Below this magnitude a deviation is reported as absolute, above as relative.
const RELATIVE_FROM: f64 = 1e-3;

/// The line split into its text between numbers and its numbers (`NaN` and `inf` included).
fn split(line: &str) -> (String, Vec<f64>) {
    let bytes = line.as_bytes();
    let (mut text, mut numbers) = (String::new(), Vec::new());
    let mut i = 0;
    while i < bytes.len() {
        let starts_number = bytes[i].is_ascii_digit()
            || (bytes[i] == b'-' && bytes.get(i + 1).is_some_and(|b| b.is_ascii_digit()))
            || line[i..].starts_with("NaN")
            || line[i..].starts_with("inf")
            || line[i..].starts_with("-inf");
        // A digit inside a name (`p90`, `f64`) is text.
        let in_word = i > 0 && (bytes[i - 1].is_ascii_alphabetic() || bytes[i - 1] == b'_');
        if starts_number && !in_word {
            let end = (i + 1..=bytes.len())
                .find(|&j| {
                    j == bytes.len()
                        || !(bytes[j].is_ascii_alphanumeric()
                            || matches!(bytes[j], b'.' | b'-' | b'+'))
                })
                .unwrap_or(bytes.len());
            match line[i..end].parse::<f64>() {
                Ok(v) => {
                    numbers.push(v);
                    text.push('#');
                }
                Err(_) => text.push_str(&line[i..end]),
            }
            i = end;
        } else {
            let c = line[i..].chars().next().expect("inside the line");
            text.push(c);
            i += c.len_utf8();
        }
    }
    (text, numbers)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [reference, other] = args.as_slice() else {
        return Err("usage: fuel_dump_compare REFERENCE OTHER".into());
    };
    let open = |p: &str| -> Result<_, Box<dyn std::error::Error>> {
        Ok(
            std::io::BufReader::new(std::fs::File::open(p).map_err(|e| format!("{p}: {e}"))?)
                .lines(),
        )
    };
    let (mut a_lines, mut b_lines) = (open(reference)?, open(other)?);
    let (mut max_rel, mut max_abs, mut bad, mut values) = (0.0f64, 0.0f64, 0usize, 0usize);
    let (mut first_bad, mut worst) = (None, (0, 0.0, 0.0));
    for line_no in 1.. {
        let (a, b) = match (a_lines.next(), b_lines.next()) {
            (None, None) => break,
            (Some(a), Some(b)) => (a?, b?),
            _ => return Err(format!("line {line_no}: one dump ends before the other").into()),
        };
        let ((a_text, a_num), (b_text, b_num)) = (split(&a), split(&b));
        if a_text != b_text || a_num.len() != b_num.len() {
            return Err(format!("line {line_no}: the text differs:\n{a}\n{b}").into());
        }
        for (x, y) in a_num.iter().zip(&b_num) {
            values += 1;
            if x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()) {
                continue;
            }
            let diff = (x - y).abs();
            let size = x.abs().max(y.abs());
            if size > RELATIVE_FROM {
                if diff / size > max_rel {
                    worst = (line_no, *x, *y);
                }
                max_rel = max_rel.max(diff / size);
            } else {
                max_abs = max_abs.max(diff);
            }
            let within = diff <= ABSOLUTE_TOLERANCE || diff <= RELATIVE_TOLERANCE * size;
            if !within {
                bad += 1;
                first_bad.get_or_insert((line_no, *x, *y));
            }
        }
    }
    println!(
        "{values} values, max relative deviation {max_rel:.3e} (|value| > {RELATIVE_FROM:e}), \
         max absolute deviation {max_abs:.3e} (below), {bad} outside {RELATIVE_TOLERANCE:e} \
         relative / {ABSOLUTE_TOLERANCE:e} absolute"
    );
    if max_rel > 0.0 {
        println!(
            "largest relative: line {}: {:?} against {:?}",
            worst.0, worst.1, worst.2
        );
    }
    if let Some((line, x, y)) = first_bad {
        println!("first outside: line {line}: {x:?} against {y:?}");
        std::process::exit(1);
    }
    Ok(())
}
