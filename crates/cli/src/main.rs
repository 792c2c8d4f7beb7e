//! The `phasekit` command.

use clap::Parser;

fn main() {
    let cli = phasekit_cli::cli::Cli::parse();
    if let Err(e) = phasekit_cli::run(cli) {
        eprintln!("phasekit: error: {e}");
        std::process::exit(1);
    }
}
