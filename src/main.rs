//! The `pipeline` binary: parse the command line, run, map errors to exit codes
//! (0 ok, 1 the work failed, 2 usage or configuration error, 130 interrupted).

use clap::Parser;
use std::io::Write;

fn main() {
    let cli = pipeline::cli::Cli::parse();
    if let Err(e) = pipeline::cli::run(cli) {
        let code = match e.downcast_ref::<pipeline::Error>() {
            Some(pipeline::Error::Config(_) | pipeline::Error::Toml { .. } | pipeline::Error::Set(_) | pipeline::Error::Usage(_)) => 2,
            Some(pipeline::Error::Interrupted(_)) => 130,
            _ => 1,
        };
        // A closed stderr loses the message, never the exit code.
        let _ = writeln!(std::io::stderr(), "error: {e:#}");
        std::process::exit(code);
    }
}
