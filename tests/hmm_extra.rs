//! More HMM behaviour: sampling against the model, random initialisation,
//! restarts, (de)serialisation of the Baum-Welch settings, shape checks of the
//! E-/M-step statistics, the parameter count of models with structural zeros,
//! and the convergence test under a prior. Every random draw is a
//! `ChaCha8Rng` with a fixed seed.

use phasekit::emission::{
    CovarianceType, Emission, Gaussian, Poisson, Regularisation, SequenceSet, Shape,
    SufficientStatistics,
};
use phasekit::hmm::{
    initialise, BaumWelch, Convergence, ExpectedStatistics, Hmm, HmmError, HmmFit, HmmInit, Update,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// A dense 3-state, 2-D diagonal-Gaussian HMM with well-separated means.
fn three_state() -> Hmm<Gaussian> {
    Hmm::new(
        vec![0.5, 0.3, 0.2],
        vec![0.8, 0.15, 0.05, 0.1, 0.7, 0.2, 0.25, 0.05, 0.7],
        Gaussian::diagonal(
            2,
            vec![0.0, 0.0, 6.0, 0.0, 0.0, 6.0],
            vec![1.0, 0.5, 0.3, 2.0, 1.5, 1.0],
        )
        .unwrap(),
    )
    .unwrap()
}

fn sample_set<E: Emission>(hmm: &Hmm<E>, n_seq: usize, len: usize, seed: u64) -> SequenceSet {
    let mut r = rng(seed);
    let seqs: Vec<Vec<f64>> = (0..n_seq)
        .map(|_| hmm.sample(len, &mut r).unwrap().0)
        .collect();
    SequenceSet::new(&seqs, hmm.dim()).unwrap()
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn gaussian_bits(h: &Hmm<Gaussian>) -> Vec<u64> {
    let mut b = bits(h.start());
    b.extend(bits(h.transition()));
    b.extend(bits(h.emission().means()));
    b.extend(bits(h.emission().covariances_raw()));
    b
}

// ---------------------------------------------------------------------------
// Hmm::sample
// ---------------------------------------------------------------------------

/// `|got − want| ≤ 5 σ`, with `σ` the standard error of the estimate.
fn within_5_se(what: &str, got: f64, want: f64, se: f64) {
    assert!(
        (got - want).abs() <= 5.0 * se,
        "{what}: sampled {got}, model {want} (tolerance 5 × {se:.2e})"
    );
}

#[test]
fn long_sample_matches_the_model() {
    // Tolerances are five standard errors of each estimate, so a correct
    // sampler fails with probability < 1e-5 per check, and the seed is fixed.
    let hmm = three_state();
    let (s, d, len) = (3, 2, 200_000);
    let (frames, states) = hmm.sample(len, &mut rng(1)).unwrap();
    assert_eq!(frames.len(), len * d);
    assert_eq!(states.len(), len);
    assert!(states.iter().all(|z| *z < s));

    // Transition frequencies n_ij / n_i against a_ij (binomial standard error).
    let mut counts = vec![0usize; s * s];
    for w in states.windows(2) {
        counts[w[0] * s + w[1]] += 1;
    }
    for i in 0..s {
        let n_i: usize = counts[i * s..(i + 1) * s].iter().sum();
        assert!(n_i > 10_000, "state {i} visited {n_i} times");
        for j in 0..s {
            let a = hmm.transition()[i * s + j];
            let se = (a * (1.0 - a) / n_i as f64).sqrt();
            within_5_se(
                &format!("a[{i}][{j}]"),
                counts[i * s + j] as f64 / n_i as f64,
                a,
                se,
            );
        }
    }

    // State-conditional means and variances of the frames.
    let em = hmm.emission();
    for i in 0..s {
        let xs: Vec<&[f64]> = frames
            .chunks_exact(d)
            .zip(&states)
            .filter(|(_, z)| **z == i)
            .map(|(x, _)| x)
            .collect();
        let n = xs.len() as f64;
        for k in 0..d {
            let (mu, var) = (em.mean(i)[k], em.covariance(i)[(k, k)]);
            let mean = xs.iter().map(|x| x[k]).sum::<f64>() / n;
            let v = xs.iter().map(|x| (x[k] - mean).powi(2)).sum::<f64>() / (n - 1.0);
            within_5_se(
                &format!("mean of state {i}, dim {k}"),
                mean,
                mu,
                (var / n).sqrt(),
            );
            within_5_se(
                &format!("variance of state {i}, dim {k}"),
                v,
                var,
                (2.0 * var * var / (n - 1.0)).sqrt(),
            );
        }
        // Diagonal model: the two dimensions are uncorrelated given the state.
        let m: Vec<f64> = (0..d)
            .map(|k| xs.iter().map(|x| x[k]).sum::<f64>() / n)
            .collect();
        let cov01 = xs
            .iter()
            .map(|x| (x[0] - m[0]) * (x[1] - m[1]))
            .sum::<f64>()
            / n;
        let sd = (em.covariance(i)[(0, 0)] * em.covariance(i)[(1, 1)]).sqrt();
        within_5_se(
            &format!("covariance of state {i}"),
            cov01,
            0.0,
            sd / n.sqrt(),
        );
    }

    // The first state of many sequences follows π.
    let mut r = rng(2);
    let n_seq = 20_000;
    let mut first = vec![0usize; s];
    for _ in 0..n_seq {
        first[hmm.sample(1, &mut r).unwrap().1[0]] += 1;
    }
    for (i, (&p, &count)) in hmm.start().iter().zip(&first).enumerate() {
        within_5_se(
            &format!("π[{i}]"),
            count as f64 / n_seq as f64,
            p,
            (p * (1.0 - p) / n_seq as f64).sqrt(),
        );
    }

    // Structural zeros are never taken, and a seed reproduces the sample.
    let lr = left_right(4);
    let (_, z) = lr.sample(5_000, &mut rng(3)).unwrap();
    assert_eq!(z[0], 0);
    assert!(z.windows(2).all(|w| w[1] == w[0] || w[1] == w[0] + 1));
    let again = lr.sample(5_000, &mut rng(3)).unwrap();
    assert_eq!(again.1, z);
    assert_eq!(hmm.sample(0, &mut rng(4)).unwrap(), (vec![], vec![]));
}

// ---------------------------------------------------------------------------
// HmmInit::Random
// ---------------------------------------------------------------------------

fn random_init(seed: u64) -> BaumWelch {
    BaumWelch::builder()
        .init(HmmInit::Random)
        .seed(seed)
        .max_iter(200)
        .build()
        .unwrap()
}

#[test]
fn random_initialisation_fits_reproducibly_and_depends_on_the_seed() {
    let truth = three_state();
    let data = sample_set(&truth, 8, 150, 10);
    let template = Gaussian::standard(
        CovarianceType::Diagonal,
        Shape {
            n_states: 3,
            dim: 2,
        },
    )
    .unwrap();

    let a = random_init(5).fit(&template, &data).unwrap();
    let b = random_init(5).fit(&template, &data).unwrap();
    assert_eq!(gaussian_bits(&a.model), gaussian_bits(&b.model));
    assert_eq!(
        bits(&a.report.log_likelihood),
        bits(&b.report.log_likelihood)
    );

    // The fit works: EM increases log p(X) and recovers the three means
    // (after matching labels) to within 0.3 on 1200 frames.
    let ll = &a.report.log_likelihood;
    assert!(a.report.converged, "{:?}", a.report);
    assert!(ll.windows(2).all(|w| w[1] >= w[0] - 1e-9 * w[0].abs()));
    assert!(ll.last().unwrap() > &(ll[0] + 1.0));
    for i in 0..3 {
        let want = truth.emission().mean(i);
        let best = (0..3)
            .map(|j| {
                let m = a.model.emission().mean(j);
                ((m[0] - want[0]).powi(2) + (m[1] - want[1]).powi(2)).sqrt()
            })
            .fold(f64::INFINITY, f64::min);
        assert!(
            best < 0.3,
            "true state {i}: nearest fitted mean {best} away"
        );
    }

    // Another seed gives another initial model, hence another trajectory.
    let c = random_init(6).fit(&template, &data).unwrap();
    assert_ne!(
        a.report.log_likelihood[0].to_bits(),
        c.report.log_likelihood[0].to_bits()
    );
    let reg = Regularisation::none();
    let i5 = initialise(&template, &data, HmmInit::Random, &reg, &mut rng(5)).unwrap();
    let i5b = initialise(&template, &data, HmmInit::Random, &reg, &mut rng(5)).unwrap();
    let i6 = initialise(&template, &data, HmmInit::Random, &reg, &mut rng(6)).unwrap();
    assert_eq!(gaussian_bits(&i5), gaussian_bits(&i5b));
    assert_ne!(gaussian_bits(&i5), gaussian_bits(&i6));
    // Random rows are proper distributions with no structural zero.
    assert!(i6.start().iter().all(|p| *p > 0.0));
    assert!(i6.transition().iter().all(|p| *p > 0.0));
}

// ---------------------------------------------------------------------------
// Restarts
// ---------------------------------------------------------------------------

fn final_objective<E: Emission>(f: &HmmFit<E>) -> f64 {
    *f.report.objective.last().unwrap()
}

#[test]
fn restarts_return_the_run_with_the_best_final_objective() {
    let truth = three_state();
    let data = sample_set(&truth, 4, 60, 20);
    let template = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 3,
            dim: 2,
        },
    )
    .unwrap();
    // A proper prior, so that the objective differs from log p(X) and the
    // test sees which of the two is compared; few iterations, so that runs
    // from different random starts end at different objectives.
    let reg = Regularisation::inverse_wishart(0.5, 3.0).unwrap();
    let settings = |seed: u64, restarts: usize| {
        BaumWelch::builder()
            .init(HmmInit::Random)
            .regularisation(reg)
            .max_iter(4)
            .tol(f64::NEG_INFINITY)
            .restarts(restarts)
            .seed(seed)
            .build()
            .unwrap()
    };
    let n = 6;
    let fitted = settings(100, n).fit(&template, &data).unwrap();
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
    // The runs really differ, so the choice matters.
    assert!(
        finals.iter().any(|v| (v - finals[argmax]).abs() > 1e-6),
        "{finals:?}"
    );

    // Every entry is what that run alone gives (run r uses seed + r) ...
    for (r, want) in finals.iter().enumerate() {
        let alone = settings(100 + r as u64, 1).fit(&template, &data).unwrap();
        assert_eq!(final_objective(&alone).to_bits(), want.to_bits(), "run {r}");
    }
    // ... and the returned model's objective, recomputed, is that maximum.
    let m = &fitted.model;
    let obj = m.log_likelihood_all(&data).unwrap() + m.emission().log_prior(&reg);
    assert!(
        (obj - finals[argmax]).abs() <= 1e-9 * obj.abs(),
        "{obj} vs {}",
        finals[argmax]
    );
    // The objective, not log p(X), decides: the prior term is not negligible here.
    assert!(m.emission().log_prior(&reg).abs() > 1e-3);
}

// ---------------------------------------------------------------------------
// Serde of the settings
// ---------------------------------------------------------------------------

#[test]
fn baum_welch_settings_round_trip_and_bad_ones_are_refused() {
    let good = BaumWelch::builder()
        .max_iter(17)
        .tol(1e-6)
        .convergence(Convergence::MeanPerFrame)
        .regularisation(
            Regularisation::inverse_wishart(0.1, 2.0)
                .unwrap()
                .with_max_jitter(1e-6)
                .unwrap()
                .with_pseudo_count(0.5)
                .unwrap(),
        )
        .update(Update {
            start: false,
            transition: true,
            emission: true,
        })
        .init(HmmInit::KBins { smoothing: 0.2 })
        .restarts(3)
        .seed(9)
        .threads(2)
        .build()
        .unwrap();
    let json = serde_json::to_string(&good).unwrap();
    let back: BaumWelch = serde_json::from_str(&json).unwrap();
    assert_eq!(back, good);
    let default: BaumWelch =
        serde_json::from_str(&serde_json::to_string(&BaumWelch::default()).unwrap()).unwrap();
    assert_eq!(default, BaumWelch::default());

    let value: serde_json::Value = serde_json::from_str(&json).unwrap();
    let refuse = |edit: &dyn Fn(&mut serde_json::Value), needles: &[&str]| {
        let mut v = value.clone();
        edit(&mut v);
        let err = serde_json::from_value::<BaumWelch>(v)
            .expect_err("invalid settings must be refused")
            .to_string();
        for needle in needles {
            assert!(err.contains(needle), "{needles:?}: {err}");
        }
    };
    refuse(
        &|v| v["restarts"] = 0.into(),
        &["`restarts`", "at least one run"],
    );
    refuse(
        &|v| v["threads"] = 0.into(),
        &["`threads`", "at least one thread"],
    );
    refuse(
        &|v| v["init"] = serde_json::json!({ "KBins": { "smoothing": 1.5 } }),
        &["`smoothing`", "[0, 1]", "1.5"],
    );
    refuse(
        &|v| v["init"] = serde_json::json!({ "KBins": { "smoothing": -0.1 } }),
        &["`smoothing`"],
    );
    // Nested regularisation is validated too.
    refuse(
        &|v| v["regularisation"]["covariance"] = serde_json::json!({ "AddDiagonal": -1.0 }),
        &["covariance regularisation", "non-negative", "-1"],
    );
    refuse(
        &|v| {
            v["regularisation"]["covariance"] =
                serde_json::json!({ "InverseWishart": { "scale": 0.0, "dof": 1.0 } })
        },
        &["inverse-Wishart scale", "positive"],
    );
    refuse(
        &|v| v["regularisation"]["min_weight"] = (-1.0).into(),
        &["`min_weight`"],
    );
    // JSON cannot spell NaN (serde_json writes it as null): refused as a type
    // error before validation; other formats reach `build`, which refuses NaN.
    refuse(&|v| v["tol"] = serde_json::Value::Null, &["expected f64"]);
}

// ---------------------------------------------------------------------------
// Shapes of the statistics
// ---------------------------------------------------------------------------

fn statistics() -> (
    Hmm<Gaussian>,
    ExpectedStatistics<<Gaussian as Emission>::Stats>,
) {
    let hmm = three_state();
    let data = sample_set(&hmm, 3, 40, 30);
    let stats = hmm.expected_statistics(&data).unwrap();
    (hmm, stats)
}

fn snapshot<S: SufficientStatistics>(s: &ExpectedStatistics<S>) -> (Vec<u64>, u64, usize) {
    let mut v = bits(&s.start);
    v.extend(bits(&s.transitions));
    v.push(s.emission.total_weight().to_bits());
    (
        v,
        s.log_likelihood.to_bits(),
        s.n_frames + 1000 * s.n_sequences,
    )
}

fn invalid(err: HmmError, name: &str, needles: &[&str]) {
    match &err {
        HmmError::InvalidParameter { name: n, .. } => assert_eq!(*n, name, "{err}"),
        _ => panic!("expected InvalidParameter `{name}`, got {err:?}"),
    }
    let msg = err.to_string();
    for needle in needles {
        assert!(msg.contains(needle), "{msg}");
    }
}

#[test]
fn merging_statistics_of_another_shape_is_an_error_not_a_truncation() {
    let (_, stats) = statistics();
    let before = snapshot(&stats);

    // Matching shapes: plain addition.
    let mut twice = stats.clone();
    twice.merge(&stats).unwrap();
    assert_eq!(twice.n_frames, 2 * stats.n_frames);
    for (a, b) in twice.transitions.iter().zip(&stats.transitions) {
        assert_eq!(*a, 2.0 * b);
    }

    let mut short_start = stats.clone();
    short_start.start.pop();
    let mut long_trans = stats.clone();
    long_trans.transitions.push(1.0);
    let other_emission = ExpectedStatistics {
        emission: Gaussian::standard(
            CovarianceType::Diagonal,
            Shape {
                n_states: 3,
                dim: 1,
            },
        )
        .unwrap()
        .new_stats(),
        ..stats.clone()
    };
    let mut acc = stats.clone();
    invalid(
        acc.merge(&short_start).unwrap_err(),
        "start statistics",
        &["2 entries, expected 3", "another model"],
    );
    assert_eq!(snapshot(&acc), before);
    invalid(
        acc.merge(&long_trans).unwrap_err(),
        "transition statistics",
        &["10 entries, expected 9"],
    );
    assert_eq!(snapshot(&acc), before);
    let err = acc.merge(&other_emission).unwrap_err();
    assert!(matches!(err, HmmError::Emission { .. }), "{err:?}");
    assert_eq!(
        snapshot(&acc),
        before,
        "a failed merge leaves the statistics unchanged"
    );
    // Merging into malformed statistics is refused as well.
    let mut bad = long_trans.clone();
    invalid(
        bad.merge(&stats).unwrap_err(),
        "transition statistics",
        &["10 entries, expected 9"],
    );
}

#[test]
fn maximise_refuses_misshapen_or_invalid_statistics() {
    let (hmm, stats) = statistics();
    let reg = Regularisation::none();
    let up = Update::default();
    // The good case works and gives proper distributions.
    let (next, _) = hmm.maximise(&stats, up, &reg).unwrap();
    assert!((next.start().iter().sum::<f64>() - 1.0).abs() < 1e-12);

    let mut s = stats.clone();
    s.transitions.truncate(4);
    invalid(
        hmm.maximise(&s, up, &reg).unwrap_err(),
        "transition statistics",
        &["4 entries, expected 9", "3 states"],
    );
    let mut s = stats.clone();
    s.start = vec![1.0; 5];
    invalid(
        hmm.maximise(&s, up, &reg).unwrap_err(),
        "start statistics",
        &["5 entries, expected 3"],
    );
    // Frozen parts are checked too: the statistics are wrong whatever is updated.
    let frozen = Update {
        start: false,
        transition: false,
        emission: true,
    };
    let mut s = stats.clone();
    s.transitions.clear();
    assert!(hmm.maximise(&s, frozen, &reg).is_err());
    for (v, name) in [
        (f64::NAN, "transition statistics"),
        (-0.5, "transition statistics"),
    ] {
        let mut s = stats.clone();
        s.transitions[7] = v;
        invalid(hmm.maximise(&s, up, &reg).unwrap_err(), name, &["entry 7"]);
    }
    let mut s = stats.clone();
    s.start[1] = f64::INFINITY;
    invalid(
        hmm.maximise(&s, up, &reg).unwrap_err(),
        "start statistics",
        &["entry 1", "inf"],
    );
    // Emission statistics of another model: the emission's own error.
    let s = ExpectedStatistics {
        emission: Gaussian::standard(
            CovarianceType::Full,
            Shape {
                n_states: 3,
                dim: 2,
            },
        )
        .unwrap()
        .new_stats(),
        ..stats
    };
    assert!(matches!(
        hmm.maximise(&s, up, &reg),
        Err(HmmError::Emission { .. })
    ));
}

// ---------------------------------------------------------------------------
// Free parameters
// ---------------------------------------------------------------------------

/// Strict left-right chain of `s` 2-D diagonal Gaussians: `π = e_0`,
/// `a_ii = 0.9`, `a_{i,i+1} = 0.1`, last state absorbing.
fn left_right(s: usize) -> Hmm<Gaussian> {
    let mut start = vec![0.0; s];
    start[0] = 1.0;
    let mut trans = vec![0.0; s * s];
    for i in 0..s {
        if i + 1 < s {
            trans[i * s + i] = 0.9;
            trans[i * s + i + 1] = 0.1;
        } else {
            trans[i * s + i] = 1.0;
        }
    }
    let means = (0..s)
        .flat_map(|i| [4.0 * i as f64, -2.0 * i as f64])
        .collect();
    Hmm::new(
        start,
        trans,
        Gaussian::diagonal(2, means, vec![1.0; 2 * s]).unwrap(),
    )
    .unwrap()
}

/// The obvious count: for `π` and every row of `A`, non-zeros minus one.
fn reference_free_parameters<E: Emission>(h: &Hmm<E>) -> usize {
    let s = h.n_states();
    let mut p = h.start().iter().filter(|v| **v > 0.0).count() - 1;
    for i in 0..s {
        p += (0..s).filter(|&j| h.transition()[i * s + j] > 0.0).count() - 1;
    }
    p + h.emission().n_parameters()
}

#[test]
fn left_right_models_count_only_free_parameters() {
    let (s, d) = (4, 2);
    let lr = left_right(s);
    // π: 1 non-zero → 0; rows 0..2: 2 non-zeros → 1 each; last row: 0;
    // emissions: S·D means + S·D variances.
    let p = 3 + 2 * s * d;
    assert_eq!(lr.n_parameters(), p);
    assert_eq!(p, 19);
    assert_eq!(lr.n_parameters(), reference_free_parameters(&lr));
    // hmmlearn's dense count stays available.
    assert_eq!(lr.n_parameters_dense(), (s - 1) + s * (s - 1) + 2 * s * d);

    let data = sample_set(&lr, 5, 80, 40);
    let ll = lr.log_likelihood_all(&data).unwrap();
    let n = data.total_frames() as f64;
    let aic = lr.aic(&data).unwrap();
    let bic = lr.bic(&data).unwrap();
    assert!((aic - (-2.0 * ll + 2.0 * p as f64)).abs() <= 1e-12 * aic.abs());
    assert!((bic - (-2.0 * ll + p as f64 * n.ln())).abs() <= 1e-12 * bic.abs());

    // Baum-Welch keeps the structural zeros, so the count does not change.
    let fitted = BaumWelch::builder()
        .max_iter(10)
        .build()
        .unwrap()
        .fit_from(lr.clone(), &data)
        .unwrap();
    assert_eq!(fitted.model.n_parameters(), p);

    // Without zeros the two counts agree; partial zeros count row by row.
    let dense = three_state();
    assert_eq!(dense.n_parameters(), dense.n_parameters_dense());
    assert_eq!(dense.n_parameters(), 2 + 3 * 2 + 12);
    let partial = Hmm::new(
        vec![0.5, 0.5, 0.0],
        vec![0.5, 0.5, 0.0, 0.0, 1.0, 0.0, 0.2, 0.3, 0.5],
        Poisson::unit(3, 2).unwrap(),
    )
    .unwrap();
    // π: 1; rows: 1, 0, 2; six Poisson rates.
    assert_eq!(partial.n_parameters(), 1 + 3 + 6);
    assert_eq!(partial.n_parameters(), reference_free_parameters(&partial));
}

// ---------------------------------------------------------------------------
// The convergence test under a prior
// ---------------------------------------------------------------------------

/// Number of M-steps after which a run stops: the first `k ≥ 1` with
/// `series[k] − series[k − 1] < tol`, else `max_iter`.
fn stop_at(series: &[f64], tol: f64, max_iter: usize) -> usize {
    (1..series.len())
        .find(|&k| series[k] - series[k - 1] < tol)
        .unwrap_or(max_iter)
        .min(max_iter)
}

#[test]
fn convergence_is_tested_on_the_penalised_objective_under_a_prior() {
    let truth = three_state();
    let data = sample_set(&truth, 4, 50, 50);
    let template = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 3,
            dim: 2,
        },
    )
    .unwrap();
    let initial = initialise(
        &template,
        &data,
        HmmInit::Random,
        &Regularisation::none(),
        &mut rng(51),
    )
    .unwrap();
    let max_iter = 60;
    let run = |reg: Regularisation, tol: f64| {
        BaumWelch::builder()
            .regularisation(reg)
            .max_iter(max_iter)
            .tol(tol)
            .build()
            .unwrap()
            .fit_from(initial.clone(), &data)
            .unwrap()
    };
    // A strong proper prior (ν = 4 > D − 1), so that log p(X) and the
    // objective have visibly different gains.
    let prior = Regularisation::inverse_wishart(4.0, 4.0).unwrap();
    for (reg, has_prior) in [
        (prior, true),
        (Regularisation::add_diagonal(1e-2).unwrap(), false),
        (Regularisation::none(), false),
    ] {
        let full = run(reg, f64::NEG_INFINITY);
        let (obj, ll) = (&full.report.objective, &full.report.log_likelihood);
        assert_eq!(obj == ll, !has_prior);
        // The objective EM increases is monotone (a proper prior, or none).
        if !matches!(
            reg.covariance(),
            phasekit::emission::CovarianceRegularisation::AddDiagonal(_)
        ) {
            assert!(obj.windows(2).all(|w| w[1] >= w[0] - 1e-9 * w[0].abs()));
        }
        let mut discriminating = 0;
        for tol in [1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 1e-5, 1e-6] {
            let want = stop_at(obj, tol, max_iter);
            if want != stop_at(ll, tol, max_iter) {
                discriminating += 1;
            }
            let f = run(reg, tol);
            assert_eq!(f.report.iterations, want, "tol {tol}, prior {has_prior}");
            assert_eq!(f.report.converged, obj[want] - obj[want - 1] < tol);
            // Same trajectory as the untruncated run, bit for bit.
            assert_eq!(bits(&f.report.objective), bits(&obj[..=want]));
        }
        // Under the prior some tolerances stop at another iteration than a
        // log-likelihood test would, so the test above can tell the two apart.
        if has_prior {
            assert!(discriminating > 0, "obj {obj:?}\nll {ll:?}");
        }
    }
}
