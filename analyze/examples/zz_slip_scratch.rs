use clap::Parser;
#[derive(Parser)]
struct Cli { #[command(flatten)] args: railmon_analyze::adhesion::Args }
fn main() { let c = Cli::parse(); if let Err(e) = railmon_analyze::adhesion::run(&c.args) { eprintln!("error: {e}"); std::process::exit(1); } }
