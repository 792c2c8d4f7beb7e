//! `Regularisation` read from JSON runs the same checks as its constructors:
//! good settings round-trip exactly, bad ones are refused with the name of the
//! offending setting.

use phasekit_emission::{CovarianceRegularisation, Regularisation};
use serde_json::{json, Value};

fn parse(v: Value) -> Result<Regularisation, String> {
    serde_json::from_value(v).map_err(|e| e.to_string())
}

#[test]
fn good_regularisation_round_trips() {
    for reg in [
        Regularisation::none(),
        Regularisation::add_diagonal(0.0).unwrap(),
        Regularisation::add_diagonal(1e-2).unwrap(),
        Regularisation::inverse_wishart(0.3, 0.0).unwrap(),
        Regularisation::inverse_wishart(2.0, 5.5)
            .unwrap()
            .with_max_jitter(1e-4)
            .unwrap()
            .with_min_weight(0.0)
            .unwrap()
            .with_pseudo_count(0.7)
            .unwrap(),
    ] {
        let json = serde_json::to_string(&reg).unwrap();
        let back: Regularisation = serde_json::from_str(&json).unwrap();
        assert_eq!(back, reg, "{json}");
    }
}

#[test]
fn bad_regularisation_is_refused_with_the_setting_named() {
    let base = serde_json::to_value(Regularisation::none()).unwrap();
    let with = |field: &str, v: Value| {
        let mut b = base.clone();
        b[field] = v;
        b
    };
    for (value, needles) in [
        (
            with("covariance", json!({ "AddDiagonal": -1e-3 })),
            &["`covariance regularisation`", "non-negative", "-0.001"][..],
        ),
        (
            with(
                "covariance",
                json!({ "InverseWishart": { "scale": 0.0, "dof": 1.0 } }),
            ),
            &["`inverse-Wishart scale`", "positive"][..],
        ),
        (
            with(
                "covariance",
                json!({ "InverseWishart": { "scale": -2.0, "dof": 1.0 } }),
            ),
            &["`inverse-Wishart scale`", "-2"][..],
        ),
        (
            with(
                "covariance",
                json!({ "InverseWishart": { "scale": 1.0, "dof": -1.0 } }),
            ),
            &["`inverse-Wishart degrees of freedom`", "-1"][..],
        ),
        (with("max_jitter", json!(-1.0)), &["`max_jitter`"][..]),
        (with("min_weight", json!(-1e-9)), &["`min_weight`"][..]),
        (with("pseudo_count", json!(-0.5)), &["`pseudo_count`"][..]),
        // JSON has no NaN (serde_json writes it as null): a type error.
        (with("max_jitter", Value::Null), &["expected f64"][..]),
    ] {
        let err = parse(value.clone()).expect_err(&value.to_string());
        for needle in needles {
            assert!(err.contains(needle), "{value}: {err}");
        }
    }
    // The accepted values are exactly those of the constructors.
    let ok = parse(with("covariance", json!({ "AddDiagonal": 0.5 }))).unwrap();
    assert_eq!(ok.covariance(), CovarianceRegularisation::AddDiagonal(0.5));
}
