//! Every integration test of this package, compiled as one binary: one link
//! instead of one per file keeps the test command inside its time budget.
//! Each file stays a module of its own; add a `mod` line for a new one.

mod capabilities;
mod checked_api;
mod common;
mod discrete;
mod properties;
mod regularisation_serde;
mod sampling_io;
mod scale_features;
mod student_t;
