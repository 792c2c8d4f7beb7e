//! Every integration test of this package, compiled as one binary: one link
//! instead of one per file keeps the test command inside its time budget.
//! Each file stays a module of its own; add a `mod` line for a new one.

mod every_emission;
mod gmm_hmm;
mod hmm_behaviour;
mod hmm_extra;
mod hmm_formulas;
mod hmm_monotone;
mod hmm_properties;
mod missing_values;
mod parity_hmmlearn;
