//! Library side of the `phasekit` command: reading demonstrations, building
//! features, the paper-compatible evaluation protocol, model files, and the
//! commands themselves (`fit`, `segment`, `predict`, `stream`, `evaluate`,
//! `plot`, `demo`).

#![warn(missing_docs)]

pub mod cli;
pub mod commands;
pub mod data;
pub mod error;
pub mod experiment;
pub mod library_file;
pub mod model_file;
pub mod npy;
pub mod output;
pub mod pipeline;
pub mod plot;
pub mod recognition_plot;
pub mod recognition_report;

pub use error::{CliError, Result};

/// Runs a parsed command line.
pub fn run(cli: cli::Cli) -> Result<()> {
    use cli::Command;
    match &cli.command {
        Command::Fit(a) => commands::fit::run(a),
        Command::Segment(a) => commands::segment::run(a),
        Command::Predict(a) => commands::predict::run(a),
        Command::Stream(a) => commands::stream::run(a),
        Command::Evaluate(a) => commands::evaluate::run(a),
        Command::Plot(a) => commands::plot::run(a),
        Command::Demo(a) => commands::demo::run(a),
        Command::Recognise(a) => commands::recognise::run(a),
    }
}
