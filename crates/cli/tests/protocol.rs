//! The `hmm` preset reproduces the reference numbers of `shared/PROTOCOL.md`
//! (deterministic case: all training demonstrations, one run) to 3 significant digits.
//!
//! Needs the NuiSI demonstrations: `$PHASEKIT_NUISI`, or `shared/data/nuisi`
//! beside the repository. Without them the test says so and passes; CI has them.

use crate::common::wrist_spec;
use phasekit_cli::data::load_action;
use phasekit_cli::experiment::{
    constant_mean_mse, evaluate_action, parse_method, prepare, Protocol,
};
use phasekit_tsc::PresetOptions;
use std::path::PathBuf;

fn nuisi() -> Option<PathBuf> {
    let dir = std::env::var_os("PHASEKIT_NUISI")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../../shared/data/nuisi"
            ))
        });
    dir.is_dir().then_some(dir)
}

/// Relative agreement to 3 significant digits (half a unit of the third digit).
fn same_3_digits(a: f64, b: f64) -> bool {
    let scale = 10f64.powi(b.abs().log10().floor() as i32 - 2);
    (a - b).abs() <= 0.5 * scale
}

#[test]
fn hmm_preset_reproduces_protocol_reference_numbers() {
    let Some(dir) = nuisi() else {
        eprintln!("NuiSI data not found (set PHASEKIT_NUISI); reference check skipped");
        return;
    };
    // action, constant mean pose, HMM 4 states, HMM 7 states (PROTOCOL.md, MSE in cm²).
    let reference = [
        ("handshake", 633.744, 52.881, 47.724),
        ("rocket", 1082.670, 257.046, 236.937),
        ("parachute", 664.394, 159.649, 146.148),
        ("waving", 614.355, 107.790, 101.527),
    ];
    let methods = vec![
        parse_method("hmm", &PresetOptions::default()).unwrap(),
        parse_method("hmm:states=7", &PresetOptions::default()).unwrap(),
    ];
    let protocol = Protocol {
        seeds: 1,
        train_size: Some(usize::MAX),
        ..Protocol::default()
    };
    for (name, constant, hmm4, hmm7) in reference {
        let action = load_action(&dir.join(name)).unwrap();
        let prep = prepare(&action, &wrist_spec()).unwrap();
        let c = constant_mean_mse(&prep, 100.0);
        assert!(
            same_3_digits(c, constant),
            "{name}: constant baseline {c} vs {constant}"
        );
        let rows = evaluate_action(&action, &wrist_spec(), &methods, &protocol, &|| {}).unwrap();
        assert_eq!(rows[0].seeds, 1);
        assert!(
            same_3_digits(rows[0].mse_mean, hmm4),
            "{name}: HMM-4 {} vs {hmm4}",
            rows[0].mse_mean
        );
        assert!(
            same_3_digits(rows[1].mse_mean, hmm7),
            "{name}: HMM-7 {} vs {hmm7}",
            rows[1].mse_mean
        );
    }
}
