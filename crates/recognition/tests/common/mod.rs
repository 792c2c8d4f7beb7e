//! Generated interactions of the four kinds and a library fitted to them,
//! shared by the tests (fitted once per test binary).

#![allow(dead_code)]

use phasekit_emission::SequenceSet;
use phasekit_recognition::{Library, LibrarySettings};
use phasekit_tsc::synthetic::{generate_kind, with_velocities, Kind};
use phasekit_tsc::{Method, Preset, PresetOptions, Roles};
use std::sync::OnceLock;

/// Human: hand position and velocity (0..6); robot: the same (6..12).
pub fn roles() -> Roles {
    Roles::new((0..6).collect(), (6..12).collect()).unwrap()
}

/// `n` demonstrations of `kind` as joint features (`T × 12`).
pub fn demos(kind: Kind, n: usize, seed: u64) -> Vec<Vec<f64>> {
    generate_kind(kind, n, seed)
        .iter()
        .map(with_velocities)
        .collect()
}

/// The human's features of a joint demonstration.
pub fn human(joint: &[f64]) -> Vec<f64> {
    joint
        .chunks_exact(12)
        .flat_map(|x| x[..6].iter().copied())
        .collect()
}

/// The paper's HMM (4 states, reg 1e-2) as a method.
pub fn hmm() -> Method {
    Method::preset(Preset::Hmm, &PresetOptions::default()).unwrap()
}

/// Training sets of the given kinds: 10 demonstrations each (seed 1).
pub fn training(kinds: &[Kind]) -> Vec<(String, SequenceSet)> {
    kinds
        .iter()
        .map(|&k| {
            (
                k.name().to_string(),
                SequenceSet::new(&demos(k, 10, 1), 12).unwrap(),
            )
        })
        .collect()
}

/// A library of `kinds` fitted with `method`.
pub fn fit(kinds: &[Kind], method: &Method) -> Library {
    let data = training(kinds);
    let actions: Vec<(&str, &SequenceSet, &Method)> =
        data.iter().map(|(n, d)| (n.as_str(), d, method)).collect();
    Library::fit(&actions, None, &roles(), &LibrarySettings::default())
        .unwrap()
        .0
}

/// The library of all four kinds (HMM), fitted once.
pub fn library() -> &'static Library {
    static LIB: OnceLock<Library> = OnceLock::new();
    LIB.get_or_init(|| fit(&Kind::ALL, &hmm()))
}

/// The library of handshake, fist bump and handover (no wave), fitted once.
pub fn library_without_wave() -> &'static Library {
    static LIB: OnceLock<Library> = OnceLock::new();
    LIB.get_or_init(|| fit(&[Kind::Handshake, Kind::FistBump, Kind::Handover], &hmm()))
}
