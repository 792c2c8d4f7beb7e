//! Every integration test of this package, compiled as one binary: one link
//! instead of one per file keeps the test command inside its time budget.
//! Each file stays a module of its own; add a `mod` line for a new one.

mod auto;
mod calibration;
mod candidates;
mod emissions;
mod ensemble;
mod error_units;
mod gmeans_states;
mod hsmm_preset;
mod model_files_v1;
mod reg_positions;
mod reg_units;
mod settings_and_defects;
mod tsc;
