//! More EM behaviour: restarts keep the run with the best final objective, the
//! convergence test under a prior is on the penalised objective, the settings
//! survive serde and bad ones are refused, the generic EM fits a mixture
//! of non-Gaussian (Poisson) components, and the default settings fit data
//! with a constant column (their `1e-6` on the covariance diagonals).
//!
//! Every random draw comes from a seeded `ChaCha8Rng`.

use phasekit_emission::{
    CovarianceType, Emission, Frames, Gaussian, Poisson, Regularisation, Shape,
};
use phasekit_gmm::{default_regularisation, Em, Gmm, GmmFit, GmmInit, DEFAULT_ADDED_DIAGONAL};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// `n` 2-D frames from three unit-variance blobs at (0, 0), (4, 0), (0, 4).
fn blobs(n: usize, seed: u64) -> Vec<f64> {
    let mut r = rng(seed);
    let centres = [[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]];
    (0..n)
        .flat_map(|t| {
            let c = centres[t % 3];
            let x: f64 = StandardNormal.sample(&mut r);
            let y: f64 = StandardNormal.sample(&mut r);
            [c[0] + x, c[1] + y]
        })
        .collect()
}

fn final_objective<E: Emission>(f: &GmmFit<E>) -> f64 {
    *f.report.objective.last().unwrap()
}

#[test]
fn restarts_return_the_run_with_the_best_final_objective() {
    let data = blobs(150, 1);
    let frames = Frames::new(&data, 2).unwrap();
    let template = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 3,
            dim: 2,
        },
    )
    .unwrap();
    // A prior on the covariances and the weights, so that the objective
    // differs from log p(X); few iterations, so that the runs end apart.
    let reg = Regularisation::inverse_wishart(0.5, 3.0)
        .unwrap()
        .with_pseudo_count(1.0)
        .unwrap();
    let settings = |seed: u64, restarts: usize| {
        Em::builder()
            .init(GmmInit::Random)
            .regularisation(reg)
            .max_iter(3)
            .tol(f64::NEG_INFINITY)
            .restarts(restarts)
            .seed(seed)
            .build()
            .unwrap()
    };
    let n = 6;
    let fitted = settings(40, n).fit(&template, frames).unwrap();
    let finals: Vec<f64> = fitted
        .report
        .restarts
        .iter()
        .map(|o| o.expect("every run succeeds"))
        .collect();
    assert_eq!(finals.len(), n);
    let argmax = (0..n).fold(0, |b, r| if finals[r] > finals[b] { r } else { b });
    assert_eq!(fitted.report.best_restart, argmax, "{finals:?}");
    assert_eq!(final_objective(&fitted), finals[argmax]);
    assert!(
        finals.iter().any(|v| (v - finals[argmax]).abs() > 1e-6),
        "the runs should differ: {finals:?}"
    );
    // Each entry is what that run alone gives (run r uses seed + r).
    for (r, want) in finals.iter().enumerate() {
        let alone = settings(40 + r as u64, 1).fit(&template, frames).unwrap();
        assert_eq!(final_objective(&alone).to_bits(), want.to_bits(), "run {r}");
    }
    // The returned model's objective, recomputed from its parameters.
    let m = &fitted.model;
    let log_prior = reg.pseudo_count() * m.weights().iter().map(|w| w.ln()).sum::<f64>()
        + m.components().log_prior(&reg);
    let obj = m.log_likelihood(frames).unwrap() + log_prior;
    assert!(
        (obj - finals[argmax]).abs() <= 1e-9 * obj.abs(),
        "{obj} vs {}",
        finals[argmax]
    );
    assert!(log_prior.abs() > 1e-3);
}

/// M-steps after which a run stops: the first `k ≥ 1` with a gain per frame below `tol`.
fn stop_at(series: &[f64], n: f64, tol: f64, max_iter: usize) -> usize {
    (1..series.len())
        .find(|&k| (series[k] - series[k - 1]) / n < tol)
        .unwrap_or(max_iter)
        .min(max_iter)
}

#[test]
fn convergence_is_tested_on_the_penalised_objective_under_a_prior() {
    let data = blobs(90, 2);
    let frames = Frames::new(&data, 2).unwrap();
    let template = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 3,
            dim: 2,
        },
    )
    .unwrap();
    let initial: Gmm<Gaussian> = Em::default()
        .initialise(&template, frames, GmmInit::Random, &mut rng(3))
        .unwrap();
    let max_iter = 60;
    let run = |reg: Regularisation, tol: f64| {
        Em::builder()
            .regularisation(reg)
            .max_iter(max_iter)
            .tol(tol)
            .build()
            .unwrap()
            .fit_from(initial.clone(), frames)
            .unwrap()
    };
    let prior = Regularisation::inverse_wishart(4.0, 4.0)
        .unwrap()
        .with_pseudo_count(2.0)
        .unwrap();
    let n = frames.len() as f64;
    for (reg, has_prior) in [
        (prior, true),
        (Regularisation::add_diagonal(1e-2).unwrap(), false),
        (Regularisation::none(), false),
    ] {
        let full = run(reg, f64::NEG_INFINITY);
        let (obj, ll) = (&full.report.objective, &full.report.log_likelihood);
        assert_eq!(obj == ll, !has_prior);
        let mut discriminating = 0;
        for tol in [1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 1e-5, 1e-6] {
            let want = stop_at(obj, n, tol, max_iter);
            if want != stop_at(ll, n, tol, max_iter) {
                discriminating += 1;
            }
            let f = run(reg, tol);
            assert_eq!(f.report.iterations, want, "tol {tol}, prior {has_prior}");
            assert_eq!(
                f.report
                    .objective
                    .iter()
                    .map(|v| v.to_bits())
                    .collect::<Vec<_>>(),
                obj[..=want].iter().map(|v| v.to_bits()).collect::<Vec<_>>()
            );
        }
        if has_prior {
            assert!(discriminating > 0, "obj {obj:?}\nll {ll:?}");
        }
    }
}

#[test]
fn em_settings_round_trip_and_bad_ones_are_refused() {
    let good = Em::builder()
        .max_iter(7)
        .tol(1e-5)
        .regularisation(Regularisation::add_diagonal(1e-3).unwrap())
        .init(GmmInit::Random)
        .restarts(4)
        .seed(3)
        .threads(2)
        .build()
        .unwrap();
    let json = serde_json::to_string(&good).unwrap();
    assert_eq!(serde_json::from_str::<Em>(&json).unwrap(), good);
    let default: Em =
        serde_json::from_str(&serde_json::to_string(&Em::default()).unwrap()).unwrap();
    assert_eq!(default, Em::default());

    let value: serde_json::Value = serde_json::from_str(&json).unwrap();
    for (edit, needles) in [
        (
            ("restarts", serde_json::json!(0)),
            &["`restarts`", "at least one run"][..],
        ),
        (
            ("threads", serde_json::json!(0)),
            &["`threads`", "at least one thread"][..],
        ),
        (
            (
                "regularisation",
                serde_json::json!({ "covariance": { "AddDiagonal": -0.1 }, "max_jitter": 0.0, "min_weight": 1e-10, "pseudo_count": 0.0 }),
            ),
            &["covariance regularisation", "-0.1"][..],
        ),
        (
            (
                "regularisation",
                serde_json::json!({ "covariance": "None", "max_jitter": 0.0, "min_weight": 1e-10, "pseudo_count": -2.0 }),
            ),
            &["`pseudo_count`", "-2"][..],
        ),
    ] {
        let mut v = value.clone();
        v[edit.0] = edit.1;
        let err = serde_json::from_value::<Em>(v).unwrap_err().to_string();
        for needle in needles {
            assert!(err.contains(needle), "{needles:?}: {err}");
        }
    }
}

#[test]
fn generic_em_fits_a_poisson_mixture() {
    // Three components of 2-D independent counts with well-separated rates.
    let weights = [0.5, 0.3, 0.2];
    let rates = [1.0, 8.0, 6.0, 2.0, 15.0, 15.0];
    let truth = Gmm::new(weights.to_vec(), Poisson::new(2, rates.to_vec()).unwrap()).unwrap();
    let n = 6000;
    let (data, labels) = truth.sample(n, &mut rng(7)).unwrap();
    assert!(data.iter().all(|x| x.fract() == 0.0 && *x >= 0.0));
    let frames = Frames::new(&data, 2).unwrap();
    let fitted = Em::builder()
        .restarts(3)
        .seed(8)
        .build()
        .unwrap()
        .fit(&Poisson::unit(3, 2).unwrap(), frames)
        .unwrap();
    let ll = &fitted.report.log_likelihood;
    assert!(ll.windows(2).all(|w| w[1] >= w[0] - 1e-9 * w[0].abs()));
    let m = &fitted.model;
    // Match fitted components to true ones by their first rate (all distinct).
    for k in 0..3 {
        let j = (0..3)
            .min_by(|&a, &b| {
                let da = (m.components().rates()[2 * a] - rates[2 * k]).abs();
                let db = (m.components().rates()[2 * b] - rates[2 * k]).abs();
                da.total_cmp(&db)
            })
            .unwrap();
        // Five standard errors: a rate λ estimated from ~n w_k counts has
        // variance λ / (n w_k); a weight, w (1 − w) / n.
        let nk = n as f64 * weights[k];
        for dim in 0..2 {
            let (got, want) = (m.components().rates()[2 * j + dim], rates[2 * k + dim]);
            assert!(
                (got - want).abs() <= 5.0 * (want / nk).sqrt() + 0.05,
                "component {k}, dim {dim}: rate {got} vs {want}"
            );
        }
        let w = m.weights()[j];
        assert!(
            (w - weights[k]).abs()
                <= 5.0 * (weights[k] * (1.0 - weights[k]) / n as f64).sqrt() + 0.01,
            "component {k}: weight {w} vs {}",
            weights[k]
        );
    }
    // Hard labels agree with the generating components for most frames.
    let pred = m.predict(frames).unwrap();
    let map: Vec<usize> = (0..3)
        .map(|k| {
            let mut c = [0usize; 3];
            for (p, l) in pred.iter().zip(&labels) {
                if *l == k {
                    c[*p] += 1;
                }
            }
            (0..3).max_by_key(|&j| c[j]).unwrap()
        })
        .collect();
    let agree = pred
        .iter()
        .zip(&labels)
        .filter(|(p, l)| **p == map[**l])
        .count();
    assert!(agree as f64 > 0.9 * n as f64, "{agree} of {n}");
}

#[test]
fn the_default_regularisation_fits_a_constant_column() {
    // Three blobs in x, y; z never moves (a marker that is constant).
    let frames: Vec<f64> = blobs(300, 7)
        .chunks_exact(2)
        .flat_map(|f| [f[0], f[1], 2.5])
        .collect();
    let frames = Frames::new(&frames, 3).unwrap();
    let template = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 3,
            dim: 3,
        },
    )
    .unwrap();
    assert_eq!(Em::default().regularisation(), &default_regularisation());
    assert_eq!(
        default_regularisation(),
        Regularisation::add_diagonal(DEFAULT_ADDED_DIAGONAL).unwrap()
    );
    let fitted = Em::default().fit(&template, frames).unwrap();
    for k in 0..3 {
        // The constant column's variance is exactly the added diagonal.
        let v = fitted.model.components().covariance(k)[(2, 2)];
        assert!(
            (v - DEFAULT_ADDED_DIAGONAL).abs() < 1e-12,
            "component {k}: {v}"
        );
    }
    // Plain maximum likelihood refuses the singular covariance, in words.
    let err = Em::builder()
        .regularisation(Regularisation::none())
        .build()
        .unwrap()
        .fit(&template, frames)
        .unwrap_err();
    assert!(err.to_string().contains("not positive definite"), "{err}");
}
