//! `ScaleFeatures`: the mapped emission is the distribution of `y = diag(s) x`
//! (checked by the change of variables on densities, independently of how
//! the mapping is written), scaling by `s` then `1/s` is the identity, and
//! the emissions a scaling cannot map refuse with a reason.

use crate::common::{random_gaussian, random_pd, rng, row_major, KINDS};
use phasekit_emission::{
    Categorical, CovarianceType, Emission, EmissionError, Frames, Gaussian, MixtureEmission,
    PerState, Poisson, ScaleFeatures, StudentT, StudentTDof,
};
use proptest::prelude::*;
use rand::Rng;

/// A named check of one emission.
type Case = (String, Box<dyn Fn(&[f64]) -> Checked>);

/// Every emission the mapping supports, random, of dimension `d` (a spherical
/// Gaussian only when `equal` factors are used).
fn emissions(d: usize, seed: u64, equal: bool) -> Vec<Case> {
    let mut r = rng(seed);
    let mut out: Vec<Case> = Vec::new();
    for kind in KINDS {
        if kind == CovarianceType::Spherical && !equal {
            continue;
        }
        let g = random_gaussian(kind, 3, d, &mut r).model;
        out.push((format!("{kind:?}"), Box::new(move |s| check(&g, s))));
    }
    let t = PerState::new(
        (0..2)
            .map(|_| {
                let mean = (0..d).map(|_| r.random_range(-2.0..2.0)).collect();
                let scale = row_major(&random_pd(d, 0.2, &mut r));
                StudentT::new(
                    mean,
                    scale,
                    r.random_range(1.0..20.0),
                    StudentTDof::Estimated,
                )
                .unwrap()
            })
            .collect(),
    )
    .unwrap();
    out.push(("student-t".into(), Box::new(move |s| check(&t, s))));
    let comps: Vec<Gaussian> = (0..2)
        .map(|_| random_gaussian(CovarianceType::Full, 3, d, &mut r).model)
        .collect();
    let m = MixtureEmission::new(vec![0.2, 0.5, 0.3, 0.6, 0.1, 0.3], comps).unwrap();
    out.push(("mixture".into(), Box::new(move |s| check(&m, s))));
    out
}

/// What one emission's check found: the largest error of the change of
/// variables and of the round trip (relative to the densities' scale).
struct Checked {
    density: f64,
    round_trip: f64,
}

/// `log b'(S x) = log b(x) − Σ log s_j` for random frames, and `b` mapped by
/// `s` then `1/s` gives the same densities and the same parameters (by JSON).
fn check<E: Emission + ScaleFeatures + serde::Serialize>(e: &E, s: &[f64]) -> Checked {
    let d = e.dim();
    let mut r = rng(7);
    let x: Vec<f64> = (0..20 * d).map(|_| r.random_range(-3.0..3.0)).collect();
    let y: Vec<f64> = x.iter().enumerate().map(|(k, v)| v * s[k % d]).collect();
    let log_jac: f64 = s.iter().map(|v| v.ln()).sum();
    let mapped = e.scale_features(s).unwrap();
    let a = e.log_density(Frames::new(&x, d).unwrap()).unwrap();
    let b = mapped.log_density(Frames::new(&y, d).unwrap()).unwrap();
    let density = a
        .iter()
        .zip(&b)
        .map(|(a, b)| (a - log_jac - b).abs() / (1.0 + a.abs()))
        .fold(0.0, f64::max);
    let inv: Vec<f64> = s.iter().map(|v| 1.0 / v).collect();
    let back = mapped.scale_features(&inv).unwrap();
    let pa = serde_json::to_value(e).unwrap();
    let pb = serde_json::to_value(&back).unwrap();
    let round_trip = max_relative_difference(&pa, &pb);
    Checked {
        density,
        round_trip,
    }
}

/// The largest `|a − b| / (1 + |a|)` over the numbers of two JSON values of
/// one shape (infinite when the shapes differ).
fn max_relative_difference(a: &serde_json::Value, b: &serde_json::Value) -> f64 {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            (x - y).abs() / (1.0 + x.abs())
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .map(|(x, y)| max_relative_difference(x, y))
            .fold(0.0, f64::max),
        (Value::Object(x), Value::Object(y)) if x.len() == y.len() => x
            .iter()
            .map(|(k, v)| {
                y.get(k)
                    .map_or(f64::INFINITY, |w| max_relative_difference(v, w))
            })
            .fold(0.0, f64::max),
        _ if a == b => 0.0,
        _ => f64::INFINITY,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn scaled_emission_is_the_distribution_of_the_scaled_frames(
        d in 1usize..5,
        seed in 0u64..1000,
        log_s in proptest::collection::vec(-4.0f64..4.0, 4),
        equal in any::<bool>(),
    ) {
        let s: Vec<f64> = (0..d).map(|j| if equal { log_s[0] } else { log_s[j] }.exp()).collect();
        for (name, run) in emissions(d, seed, equal) {
            let c = run(&s);
            prop_assert!(c.density < 1e-9, "{name}: change of variables off by {}", c.density);
            prop_assert!(c.round_trip < 1e-12, "{name}: s then 1/s off by {}", c.round_trip);
        }
    }
}

#[test]
fn the_mapping_would_fail_without_the_covariance_scaling() {
    // The check above is not vacuous: a Gaussian whose means alone are scaled
    // (covariances left) fails the change of variables.
    let g = random_gaussian(CovarianceType::Full, 2, 3, &mut rng(1)).model;
    let s = [10.0, 1.0, 0.1];
    let means: Vec<f64> = g
        .means()
        .iter()
        .enumerate()
        .map(|(k, m)| m * s[k % 3])
        .collect();
    let wrong = Gaussian::full(3, means, g.covariances_raw().to_vec()).unwrap();
    let x = [0.3, -0.2, 1.0];
    let y = [3.0, -0.2, 0.1];
    let want = g.log_density_one(0, &x).unwrap() - s.iter().map(|v: &f64| v.ln()).sum::<f64>();
    assert!((wrong.log_density_one(0, &y).unwrap() - want).abs() > 1e-3);
    let right = g.scale_features(&s).unwrap();
    assert!((right.log_density_one(0, &y).unwrap() - want).abs() < 1e-10);
}

#[test]
fn emissions_a_scaling_cannot_map_refuse_with_the_reason() {
    let unsupported = |e: EmissionError, words: &[&str]| {
        let EmissionError::Unsupported(msg) = &e else {
            panic!("expected Unsupported, got {e}");
        };
        for w in words {
            assert!(msg.contains(w), "`{msg}` does not say `{w}`");
        }
    };
    let sph = random_gaussian(CovarianceType::Spherical, 2, 3, &mut rng(2)).model;
    unsupported(
        sph.scale_features(&[1.0, 2.0, 1.0]).unwrap_err(),
        &["spherical", "not spherical"],
    );
    // Equal factors keep it spherical: σ² s².
    let same = sph.scale_features(&[2.0; 3]).unwrap();
    for (a, b) in sph.covariances_raw().iter().zip(same.covariances_raw()) {
        assert!((a * 4.0 - b).abs() <= 1e-15 * b);
    }
    let cat = Categorical::new(3, vec![0.2, 0.3, 0.5]).unwrap();
    unsupported(
        cat.scale_features(&[1.0]).unwrap_err(),
        &["categorical", "symbols"],
    );
    let poi = Poisson::new(2, vec![1.0, 2.0]).unwrap();
    unsupported(
        poi.scale_features(&[1.0, 1.0]).unwrap_err(),
        &["Poisson", "counts"],
    );
    // Factors that are not one finite positive value per dimension.
    let g = random_gaussian(CovarianceType::Full, 2, 3, &mut rng(3)).model;
    for bad in [
        vec![1.0, 2.0],
        vec![1.0, 0.0, 1.0],
        vec![1.0, f64::NAN, 1.0],
        vec![-1.0, 1.0, 1.0],
    ] {
        let e = g.scale_features(&bad).unwrap_err();
        assert!(
            matches!(e, EmissionError::InvalidParameter { name: "scales", .. }),
            "{e}"
        );
    }
}
