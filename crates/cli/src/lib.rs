//! Library side of the `phasekit` command: reading demonstrations, building
//! features, the paper-compatible evaluation protocol, model files, and the
//! commands themselves (`fit`, `segment`, `predict`, `stream`, `evaluate`,
//! `plot`, `demo`).
//!
//! Every reader checks what it reads and says where it is wrong (file, row,
//! column); an empty cell, `NaN` or `NA` is a value not observed.
//!
//! # Example
//!
//! Read a demonstration from any reader, then parse a command line as the
//! `phasekit` binary does (a program can build the same [`cli::Cli`] and hand
//! it to [`run`]):
//!
//! ```
//! use clap::Parser;
//! use phasekit_cli::cli::{Cli, Command};
//! use phasekit_cli::data::read_csv_from;
//! use std::path::Path;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let csv = "p1_wrist_x,p1_wrist_y\n0.10,0.20\n0.30,\n";
//! let table = read_csv_from(csv.as_bytes(), Path::new("train_01.csv"))?;
//! assert_eq!(table.columns, ["p1_wrist_x", "p1_wrist_y"]);
//! assert_eq!(table.n_rows(), 2);
//! assert!(table.data[3].is_nan()); // the empty cell: not observed
//!
//! // A cell that is not a number is an error naming the file, the row and the column.
//! let bad = read_csv_from("x,y\n0.1,oops\n".as_bytes(), Path::new("bad.csv")).unwrap_err();
//! let message = bad.to_string();
//! assert!(message.contains("bad.csv") && message.contains("oops"), "{message}");
//!
//! let cli = Cli::try_parse_from(["phasekit", "demo"])?;
//! assert!(matches!(cli.command, Command::Demo(_)));
//! # Ok(())
//! # }
//! ```

#![warn(missing_docs)]

pub mod cli;
pub mod commands;
pub mod data;
pub mod error;
pub mod experiment;
pub mod file_header;
pub mod inputs;
pub mod interrupt;
pub mod library_file;
pub mod model_file;
pub mod npy;
pub mod output;
pub mod pipeline;
pub mod plot;
pub mod recognition_plot;
pub mod recognition_report;
pub mod units;

pub use error::{CliError, Result};

/// Runs a parsed command line.
pub fn run(cli: cli::Cli) -> Result<()> {
    use cli::Command;
    check_outputs(&cli.command)?;
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

/// Before any work: an output whose extension does not fit what the command
/// writes, or that is one of the command's inputs, is refused (`predict` and
/// `segment` check theirs themselves, with the names they derive).
fn check_outputs(command: &cli::Command) -> Result<()> {
    use cli::{Command, PlotKind};
    use std::path::Path;
    match command {
        Command::Fit(a) if a.library => commands::recognise::check_fit_output(a)?,
        Command::Fit(a) => {
            if let Some(o) = &a.output {
                output::check_extension(o, &["json"], true, "a model file is JSON")?;
                let files = inputs::fit_files(&a.data, a.action.as_deref())?;
                let ins: Vec<&Path> = files.iter().map(|p| p.as_path()).collect();
                output::refuse_inputs(&[o], &ins)?;
            }
        }
        Command::Plot(p) => {
            let (o, model, files) = match &p.kind {
                PlotKind::Segmentation(c) | PlotKind::Prediction(c) => {
                    (&c.output, &c.model, vec![c.data.clone()])
                }
                PlotKind::States(s) => (&s.output, &s.model, inputs::data_files(&s.data)?),
                PlotKind::Recognition(r) => return commands::recognise::check_plot_output(r),
            };
            output::check_extension(o, &["svg"], false, "plot writes SVG")?;
            let ins: Vec<&Path> = std::iter::once(model.as_path())
                .chain(files.iter().map(|p| p.as_path()))
                .collect();
            output::refuse_inputs(&[o], &ins)?;
        }
        _ => {}
    }
    Ok(())
}
