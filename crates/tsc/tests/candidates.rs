//! Shared by the tests of cross-validated choices: candidates from their
//! specifications.

use phasekit_tsc::auto::method_of_spec;
use phasekit_tsc::{Method, PresetOptions};

/// Each specification with its method on the default options, labelled by it.
pub fn candidates(specs: &[&str]) -> Vec<(String, Method)> {
    specs
        .iter()
        .map(|s| {
            (
                s.to_string(),
                method_of_spec(s, &PresetOptions::default()).unwrap(),
            )
        })
        .collect()
}
