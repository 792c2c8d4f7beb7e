//! Every integration test of this package, compiled as one binary: one link
//! instead of one per file keeps the test command inside its time budget.
//! Each file stays a module of its own; add a `mod` line for a new one.

mod auto_cli;
mod by_test_demonstration;
mod calibration;
mod cli;
mod common;
mod emission;
mod error_by_time;
mod files;
mod hostile_input;
mod hsmm_cli;
mod json_flag;
mod missing;
mod novelty;
mod outputs;
mod protocol;
mod recognition_cli;
mod reg_positions_cli;
mod reg_units_cli;
mod reports;
mod robustness;
mod stream;
