//! Property tests of the Gaussian and mixture emissions against slow, obvious
//! reference computations (textbook densities with nalgebra's determinant and
//! inverse, two-pass weighted moments, direct log-sum-exp).

// Index loops mirror the formulas they check (several arrays indexed alike).
#![allow(clippy::needless_range_loop)]

use crate::common;

use common::*;
use nalgebra::{DMatrix, DVector};
use phasekit_emission::{
    CovarianceType, Emission, EmissionError, Frames, Gaussian, MStepEvent, Marginal,
    MixtureEmission, Regularisation, Shape, SufficientStatistics,
};
use proptest::prelude::*;
use rand::seq::SliceRandom;
use rand::Rng;

fn kind_of(i: usize) -> CovarianceType {
    KINDS[i % 4]
}

fn frame_rows(data: &[f64], d: usize) -> Vec<DVector<f64>> {
    data.chunks_exact(d)
        .map(DVector::from_column_slice)
        .collect()
}

/// Corrected two-pass weighted mean and scatter `Σ_t w_t (x_t − μ)(x_t − μ)ᵀ` of the frames.
fn weighted_moments(xs: &[DVector<f64>], w: &[f64]) -> (f64, DVector<f64>, DMatrix<f64>) {
    let d = xs[0].len();
    let n: f64 = w.iter().sum();
    let mut mu = DVector::zeros(d);
    for (x, wt) in xs.iter().zip(w) {
        mu += x * *wt;
    }
    mu /= n;
    // Second pass: correct the mean by the weighted mean deviation (exact even far
    // from the origin, where the plain weighted sum loses digits).
    let mut corr = DVector::zeros(d);
    for (x, wt) in xs.iter().zip(w) {
        corr += (x - &mu) * *wt;
    }
    mu += corr / n;
    let mut scatter = DMatrix::zeros(d, d);
    for (x, wt) in xs.iter().zip(w) {
        let e = x - &mu;
        scatter += &e * e.transpose() * *wt;
    }
    (n, mu, scatter)
}

/// Column `i` of a row-major `T × S` weight matrix.
fn column(weights: &[f64], s: usize, i: usize) -> Vec<f64> {
    weights.iter().skip(i).step_by(s).copied().collect()
}

/// Expected covariance of every state after an M-step with the given
/// regularisation, from the textbook weighted formulas.
#[derive(Clone, Copy, Debug)]
enum Reg {
    None,
    Add(f64),
    Iw(f64, f64),
}

fn expected_m_step(
    kind: CovarianceType,
    xs: &[DVector<f64>],
    weights: &[f64],
    s: usize,
    reg: Reg,
) -> (Vec<DVector<f64>>, Vec<DMatrix<f64>>) {
    let d = xs[0].len();
    let df = d as f64;
    let moments: Vec<_> = (0..s)
        .map(|i| weighted_moments(xs, &column(weights, s, i)))
        .collect();
    let means = moments.iter().map(|m| m.1.clone()).collect();
    let eye = DMatrix::<f64>::identity(d, d);
    let covs = match kind {
        CovarianceType::Tied => {
            let n_tot: f64 = moments.iter().map(|m| m.0).sum();
            let pooled: DMatrix<f64> = moments
                .iter()
                .fold(DMatrix::zeros(d, d), |acc, m| acc + &m.2);
            let c = match reg {
                Reg::None => &pooled / n_tot,
                Reg::Add(r) => &pooled / n_tot + &eye * r,
                Reg::Iw(psi, nu) => (&pooled + &eye * psi) / (n_tot + nu + df + 1.0),
            };
            vec![c; s]
        }
        _ => moments
            .iter()
            .map(|(n, _, scatter)| {
                let ml = project(kind, &(scatter / *n));
                match reg {
                    Reg::None => ml,
                    Reg::Add(r) => ml + &eye * r,
                    // Structured MAP: the inverse-Wishart prior restricted to the structure.
                    Reg::Iw(psi, nu) => (project(kind, scatter) + &eye * psi) / (n + nu + df + 1.0),
                }
            })
            .collect(),
    };
    (means, covs)
}

fn random_weights<R: Rng + ?Sized>(t: usize, s: usize, rng: &mut R) -> Vec<f64> {
    (0..t * s).map(|_| rng.random_range(0.05..1.0)).collect()
}

fn stats_for(model: &Gaussian, data: &[f64], weights: &[f64]) -> <Gaussian as Emission>::Stats {
    let frames = Frames::new(data, model.dim()).unwrap();
    let mut st = model.new_stats();
    model.accumulate(frames, weights, &mut st).unwrap();
    st
}

/// Every number in a serialised value, in order (for comparing private statistics).
fn numeric_leaves(v: &serde_json::Value, out: &mut Vec<f64>) {
    match v {
        serde_json::Value::Number(n) => out.push(n.as_f64().unwrap()),
        serde_json::Value::Array(a) => a.iter().for_each(|x| numeric_leaves(x, out)),
        serde_json::Value::Object(o) => o.values().for_each(|x| numeric_leaves(x, out)),
        _ => {}
    }
}

fn assert_stats_close<S: serde::Serialize>(a: &S, b: &S, tol: f64) {
    let (va, vb) = (
        serde_json::to_value(a).unwrap(),
        serde_json::to_value(b).unwrap(),
    );
    let (mut la, mut lb) = (Vec::new(), Vec::new());
    numeric_leaves(&va, &mut la);
    numeric_leaves(&vb, &mut lb);
    assert_eq!(la.len(), lb.len(), "statistics have different shapes");
    let scale = la
        .iter()
        .chain(&lb)
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(1e-300);
    for (k, (x, y)) in la.iter().zip(&lb).enumerate() {
        assert!(
            (x - y).abs() <= tol * x.abs().max(y.abs()).max(scale * 1e-3),
            "statistic {k}: {x} vs {y}"
        );
    }
}

fn model_snapshot<E: serde::Serialize>(e: &E) -> String {
    serde_json::to_string(e).unwrap()
}

// ---------------------------------------------------------------------------
// Log-density
// ---------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0x9a0b_e471), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(64) })]

    #[test]
    fn gaussian_log_density_matches_textbook(seed in any::<u64>(), d in 1usize..=5, s in 1usize..=3, k in 0usize..4) {
        let kind = kind_of(k);
        let mut rng = rng(seed);
        let rg = random_gaussian(kind, s, d, &mut rng);
        let t = 7;
        let data: Vec<f64> = (0..t * d).map(|_| 2.0 * normal(&mut rng)).collect();
        let frames = Frames::new(&data, d).unwrap();
        let got = rg.model.log_density(frames).unwrap();
        prop_assert_eq!(got.len(), t * s);
        for (tt, x) in data.chunks_exact(d).enumerate() {
            for i in 0..s {
                let want = textbook_log_normal(x, &rg.means[i], &rg.covs[i]);
                prop_assert!(close(got[tt * s + i], want, 1e-9), "t {} state {}: {} vs {}", tt, i, got[tt * s + i], want);
                prop_assert!(close(rg.model.log_density_one(i, x).unwrap(), want, 1e-9));
            }
        }
        for i in 0..s {
            prop_assert!(close(rg.model.log_det(i), rg.covs[i].determinant().ln(), 1e-9));
            assert_matrix_close(&rg.model.covariance(i), &rg.covs[i], 1e-12, "covariance()");
            let l = rg.model.cholesky_factor(i);
            assert_matrix_close(&(&l * l.transpose()), &rg.covs[i], 1e-12, "L Lᵀ");
            prop_assert_eq!(rg.model.mean(i), rg.means[i].as_slice());
        }
        // A wrongly sized output buffer or frame dimension is an error, not a panic.
        let mut short = vec![0.0; t * s - 1];
        prop_assert!(rg.model.log_density_into(frames, &mut short).is_err());
        let wrong = vec![0.0; d + 1];
        let wrong_dim = matches!(
            rg.model.log_density(Frames::new(&wrong, d + 1).unwrap()),
            Err(EmissionError::DimensionMismatch { .. })
        );
        prop_assert!(wrong_dim);
    }
}

#[test]
fn gaussian_log_density_is_invariant_across_blocks() {
    // The batch form must agree with frame-by-frame evaluation for any block split.
    let mut rng = rng(7);
    for kind in KINDS {
        let rg = random_gaussian(kind, 3, 4, &mut rng);
        let data = random_frames(11, 4, 2.0, &mut rng);
        let all = rg
            .model
            .log_density(Frames::new(&data, 4).unwrap())
            .unwrap();
        let frames = Frames::new(&data, 4).unwrap();
        let a = rg.model.log_density(frames.slice(0..5)).unwrap();
        let b = rg.model.log_density(frames.slice(5..11)).unwrap();
        assert_eq!([a, b].concat(), all);
    }
}

// ---------------------------------------------------------------------------
// Marginals
// ---------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0x9a0b_e471), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(64) })]

    #[test]
    fn gaussian_marginal_is_the_sub_block(seed in any::<u64>(), d in 1usize..=5, s in 1usize..=3, k in 0usize..4) {
        let kind = kind_of(k);
        let mut rng = rng(seed);
        let rg = random_gaussian(kind, s, d, &mut rng);
        let mut perm: Vec<usize> = (0..d).collect();
        perm.shuffle(&mut rng);
        let m = rng.random_range(1..=d);
        let dims = &perm[..m];
        let marg = rg.model.marginal(dims).unwrap();
        prop_assert_eq!(marg.dim(), m);
        prop_assert_eq!(marg.n_states(), s);
        prop_assert_eq!(marg.covariance_type(), kind);
        let data: Vec<f64> = (0..5 * m).map(|_| 2.0 * normal(&mut rng)).collect();
        let ld = marg.log_density(Frames::new(&data, m).unwrap()).unwrap();
        for i in 0..s {
            let sub_mu = DVector::from_fn(m, |a, _| rg.means[i][dims[a]]);
            let sub_cov = DMatrix::from_fn(m, m, |a, b| rg.covs[i][(dims[a], dims[b])]);
            prop_assert_eq!(marg.mean(i), sub_mu.as_slice());
            assert_matrix_close(&marg.covariance(i), &sub_cov, 0.0, "marginal covariance");
            for (tt, x) in data.chunks_exact(m).enumerate() {
                let want = textbook_log_normal(x, &sub_mu, &sub_cov);
                prop_assert!(close(ld[tt * s + i], want, 1e-9), "{} vs {}", ld[tt * s + i], want);
            }
        }
    }
}

#[test]
fn gaussian_marginal_rejects_invalid_dims() {
    let mut rng = rng(3);
    for kind in KINDS {
        let g = random_gaussian(kind, 2, 3, &mut rng).model;
        for dims in [vec![], vec![0, 0], vec![2, 1, 2], vec![3], vec![0, 7]] {
            match g.marginal(&dims) {
                Err(EmissionError::InvalidDims { dims: got, dim, .. }) => {
                    assert_eq!(got, dims);
                    assert_eq!(dim, 3);
                }
                other => panic!("{kind:?} dims {dims:?}: expected InvalidDims, got {other:?}"),
            }
        }
    }
}

// ---------------------------------------------------------------------------
// M-step
// ---------------------------------------------------------------------------

fn check_m_step(kind: CovarianceType, seed: u64, d: usize, s: usize, t: usize, reg: Reg) {
    let mut rng = rng(seed);
    let mut model = random_gaussian(kind, s, d, &mut rng).model;
    let data: Vec<f64> = (0..t * d).map(|_| 1.0 + 2.0 * normal(&mut rng)).collect();
    let weights = random_weights(t, s, &mut rng);
    let xs = frame_rows(&data, d);
    let st = stats_for(&model, &data, &weights);
    let regularisation = match reg {
        Reg::None => Regularisation::none(),
        Reg::Add(r) => Regularisation::add_diagonal(r).unwrap(),
        Reg::Iw(psi, nu) => Regularisation::inverse_wishart(psi, nu).unwrap(),
    };
    let report = model.m_step(&st, &regularisation).unwrap();
    assert!(report.events.is_empty(), "{:?}", report.events);
    match reg {
        Reg::Add(r) => assert_eq!(report.added_diagonal, r),
        _ => assert_eq!(report.added_diagonal, 0.0),
    }
    let (means, covs) = expected_m_step(kind, &xs, &weights, s, reg);
    for i in 0..s {
        for k in 0..d {
            assert!(
                close(model.mean(i)[k], means[i][k], 1e-10),
                "{kind:?} {reg:?} state {i} mean {k}: {} vs {}",
                model.mean(i)[k],
                means[i][k]
            );
        }
        assert_matrix_close(
            &model.covariance(i),
            &covs[i],
            1e-10,
            &format!("{kind:?} {reg:?} state {i}"),
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0x9a0b_e471), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(32) })]

    #[test]
    fn gaussian_m_step_matches_weighted_formulas(
        seed in any::<u64>(), d in 1usize..=5, s in 1usize..=3, k in 0usize..4, extra in 0usize..20,
        r in 1e-6f64..1.0, psi in 1e-3f64..2.0, nu in 0.0f64..10.0,
    ) {
        let kind = kind_of(k);
        let t = 2 * d + 3 + extra;
        check_m_step(kind, seed, d, s, t, Reg::None);
        check_m_step(kind, seed, d, s, t, Reg::Add(r));
        check_m_step(kind, seed, d, s, t, Reg::Iw(psi, nu));
    }
}

#[test]
fn gaussian_m_step_is_accurate_far_from_the_origin() {
    // Data at 1e6 with a spread of 1e-3: raw second moments would lose every digit.
    // The statistics are accumulated about the current mean, which EM keeps close
    // to the data, so the covariance must match a two-pass computation.
    let (d, s, t) = (3, 2, 200);
    let mut rng = rng(11);
    let offset = 1e6;
    let spread = 1e-3;
    for kind in KINDS {
        let data: Vec<f64> = (0..t * d)
            .map(|_| offset + spread * normal(&mut rng))
            .collect();
        let weights = random_weights(t, s, &mut rng);
        let xs = frame_rows(&data, d);
        // Current means within a few spreads of the data (as after a previous EM iteration).
        let means: Vec<f64> = (0..s * d)
            .map(|_| offset + 3.0 * spread * normal(&mut rng))
            .collect();
        let mut model = Gaussian::new(
            kind,
            d,
            means,
            Gaussian::standard(
                kind,
                Shape {
                    n_states: s,
                    dim: d,
                },
            )
            .unwrap()
            .covariances_raw()
            .to_vec(),
        )
        .unwrap();
        let st = stats_for(&model, &data, &weights);
        model.m_step(&st, &Regularisation::none()).unwrap();
        let (want_means, want_covs) = expected_m_step(kind, &xs, &weights, s, Reg::None);
        for i in 0..s {
            for k in 0..d {
                assert!(
                    (model.mean(i)[k] - want_means[i][k]).abs() <= 1e-6 * spread,
                    "{kind:?} mean {} vs {}",
                    model.mean(i)[k],
                    want_means[i][k]
                );
            }
            let got = model.covariance(i);
            let want = &want_covs[i];
            let rel = (&got - want).amax() / want.amax();
            assert!(
                rel <= 1e-6,
                "{kind:?} state {i}: relative error {rel:e}\n{got}\n{want}"
            );
        }
    }
}

#[test]
fn inverse_wishart_full_m_step_formula_spelled_out() {
    // (scatter + ψ I) / (n + ν + D + 1) for one full state, with hand-checkable numbers.
    let data = [0.0, 0.0, 2.0, 0.0, 0.0, 2.0, 2.0, 2.0];
    let mut g = Gaussian::full(2, vec![1.0, 1.0], vec![1.0, 0.0, 0.0, 1.0]).unwrap();
    let st = stats_for(&g, &data, &[1.0; 4]);
    g.m_step(&st, &Regularisation::inverse_wishart(0.5, 3.0).unwrap())
        .unwrap();
    // mean (1, 1); scatter = [[4, 0], [0, 4]]; n = 4; denominator 4 + 3 + 2 + 1 = 10.
    assert_eq!(g.mean(0), &[1.0, 1.0]);
    assert_matrix_close(
        &g.covariance(0),
        &(DMatrix::identity(2, 2) * 0.45),
        1e-15,
        "IW",
    );
}

// ---------------------------------------------------------------------------
// Statistics merge
// ---------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0x9a0b_e471), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(24) })]

    #[test]
    fn gaussian_stats_merge_equals_one_pass(seed in any::<u64>(), d in 1usize..=4, s in 1usize..=3, k in 0usize..4, t in 2usize..30) {
        let kind = kind_of(k);
        let mut rng = rng(seed);
        let model = random_gaussian(kind, s, d, &mut rng).model;
        let data = random_frames(t, d, 2.0, &mut rng);
        let weights = random_weights(t, s, &mut rng);
        let cut = rng.random_range(1..t);
        let frames = Frames::new(&data, d).unwrap();
        let all = stats_for(&model, &data, &weights);
        let mut a = model.new_stats();
        model.accumulate(frames.slice(0..cut), &weights[..cut * s], &mut a).unwrap();
        let mut b = model.new_stats();
        model.accumulate(frames.slice(cut..t), &weights[cut * s..], &mut b).unwrap();
        a.merge(&b).unwrap();
        assert_stats_close(&a, &all, 1e-12);
        prop_assert!(close(a.total_weight(), weights.iter().sum(), 1e-12));
        for i in 0..s {
            prop_assert!(close(a.weights()[i], column(&weights, s, i).iter().sum(), 1e-12));
        }
        // The M-steps from both agree as well (when the data allow one).
        if t > d + 1 {
            let (mut m1, mut m2) = (model.clone(), model.clone());
            m1.m_step(&a, &Regularisation::add_diagonal(1e-3).unwrap()).unwrap();
            m2.m_step(&all, &Regularisation::add_diagonal(1e-3).unwrap()).unwrap();
            for i in 0..s {
                assert_matrix_close(&m1.covariance(i), &m2.covariance(i), 1e-10, "merged M-step");
            }
        }
    }
}

#[test]
fn gaussian_stats_of_another_model_are_refused() {
    let mut rng = rng(5);
    let base = random_gaussian(CovarianceType::Full, 2, 3, &mut rng).model;
    let others = [
        random_gaussian(CovarianceType::Full, 3, 3, &mut rng).model,
        random_gaussian(CovarianceType::Full, 2, 2, &mut rng).model,
        // Same number of mean values (S·D = 6), different shape.
        random_gaussian(CovarianceType::Full, 3, 2, &mut rng).model,
        random_gaussian(CovarianceType::Diagonal, 2, 3, &mut rng).model,
        random_gaussian(CovarianceType::Tied, 2, 3, &mut rng).model,
    ];
    let data = random_frames(6, 3, 1.0, &mut rng);
    let frames = Frames::new(&data, 3).unwrap();
    for other in &others {
        let mut mine = base.new_stats();
        let theirs = other.new_stats();
        let before = mine.clone();
        assert!(
            matches!(mine.merge(&theirs), Err(EmissionError::StatsMismatch(_))),
            "{other:?}"
        );
        assert_eq!(
            mine, before,
            "a failed merge must not modify the statistics"
        );
        // Accumulating into, or an M-step from, foreign statistics errors (and does not panic).
        let mut theirs = other.new_stats();
        if other.dim() == 3
            && other.covariance_type() == CovarianceType::Full
            && other.n_states() == 2
        {
            continue; // same shape, only a different reference point: accumulation is legitimate
        }
        assert!(
            base.accumulate(frames, &[0.5; 6 * 2], &mut theirs).is_err(),
            "{other:?}"
        );
        let mut m = base.clone();
        assert!(
            m.m_step(&other.new_stats(), &Regularisation::none())
                .is_err(),
            "{other:?}"
        );
        assert_eq!(model_snapshot(&m), model_snapshot(&base));
    }
}

// ---------------------------------------------------------------------------
// Degenerate data, jitter, empty states
// ---------------------------------------------------------------------------

/// Frames 0..10 go to state 0 (generic data), frames 10..20 to state 1 (degenerate).
fn degenerate_setup(
    kind: CovarianceType,
    seed: u64,
    constant_dim_only: bool,
) -> (Gaussian, Vec<f64>, Vec<f64>) {
    let (d, s, t) = (3, 2, 20);
    let mut rng = rng(seed);
    let model = random_gaussian(kind, s, d, &mut rng).model;
    let x0: Vec<f64> = (0..d).map(|_| 5.0 * normal(&mut rng)).collect();
    let mut data = Vec::new();
    for tt in 0..t {
        for k in 0..d {
            let generic = 1.0 + 2.0 * normal(&mut rng);
            data.push(if tt < 10 || (constant_dim_only && k != 1) {
                generic
            } else {
                x0[k]
            });
        }
    }
    let mut weights = vec![0.0; t * s];
    for tt in 0..t {
        weights[tt * s + usize::from(tt >= 10)] = 1.0;
    }
    (model, data, weights)
}

#[test]
fn singular_covariance_is_refused_and_jitter_rescues_it() {
    for seed in 0..40u64 {
        for kind in KINDS {
            // Tied pools all states: make one dimension constant everywhere so the
            // shared covariance is singular (the error then names state 0).
            let (model, mut data, weights) =
                degenerate_setup(kind, seed, kind == CovarianceType::Diagonal);
            let singular_state = if kind == CovarianceType::Tied {
                for x in data.chunks_exact_mut(3) {
                    x[2] = 0.25;
                }
                0
            } else {
                1
            };
            let st = stats_for(&model, &data, &weights);
            let mut m = model.clone();
            match m.m_step(&st, &Regularisation::none()) {
                Err(EmissionError::NotPositiveDefinite {
                    state, component, ..
                }) => {
                    assert_eq!(state, singular_state, "{kind:?} seed {seed}");
                    assert_eq!(component, None);
                }
                other => panic!(
                    "{kind:?} seed {seed}: expected NotPositiveDefinite, got {other:?}\n{m:?}"
                ),
            }
            assert_eq!(
                model_snapshot(&m),
                model_snapshot(&model),
                "model changed by a failed M-step"
            );

            let reg = Regularisation::none().with_max_jitter(1e-3).unwrap();
            let report = m.m_step(&st, &reg).unwrap_or_else(|e| {
                panic!("{kind:?} seed {seed}: jitter should rescue the M-step: {e}")
            });
            let jitters: Vec<_> = report
                .events
                .iter()
                .filter_map(|e| match e {
                    MStepEvent::Jitter {
                        state,
                        component,
                        amount,
                    } => Some((*state, *component, *amount)),
                    _ => None,
                })
                .collect();
            assert_eq!(jitters.len(), 1, "{kind:?}: {:?}", report.events);
            let (state, component, amount) = jitters[0];
            assert_eq!((state, component), (singular_state, None));
            assert!(amount > 0.0 && amount <= 1e-3, "{amount}");
            assert_eq!(report.total_jitter(), amount);
            // The result is usable: finite log-densities everywhere.
            let ld = m.log_density(Frames::new(&data, 3).unwrap()).unwrap();
            assert!(ld.iter().all(|v| v.is_finite()));
        }
    }
}

#[test]
fn jitter_too_small_still_errors() {
    for kind in [CovarianceType::Full, CovarianceType::Spherical] {
        let (model, data, weights) = degenerate_setup(kind, 1, false);
        let st = stats_for(&model, &data, &weights);
        let mut m = model.clone();
        let reg = Regularisation::none().with_max_jitter(1e-30).unwrap();
        assert!(matches!(
            m.m_step(&st, &reg),
            Err(EmissionError::NotPositiveDefinite { state: 1, .. })
        ));
        assert_eq!(model_snapshot(&m), model_snapshot(&model));
    }
}

#[test]
fn add_diagonal_regularises_a_degenerate_state_without_events() {
    for kind in KINDS {
        let (model, data, weights) = degenerate_setup(kind, 2, false);
        let st = stats_for(&model, &data, &weights);
        let mut m = model.clone();
        let report = m
            .m_step(&st, &Regularisation::add_diagonal(1e-4).unwrap())
            .unwrap();
        assert!(report.events.is_empty(), "{kind:?} {:?}", report.events);
        assert_eq!(report.added_diagonal, 1e-4);
        if kind != CovarianceType::Tied {
            // State 1's frames are all identical: covariance is exactly r I (up to rounding).
            assert_matrix_close(
                &m.covariance(1),
                &(DMatrix::identity(3, 3) * 1e-4),
                1e-9,
                "r I",
            );
        }
    }
}

#[test]
fn empty_state_is_kept_and_reported() {
    let mut rng = rng(9);
    for kind in KINDS {
        let (d, s, t) = (2, 3, 15);
        let model = random_gaussian(kind, s, d, &mut rng).model;
        let data = random_frames(t, d, 1.0, &mut rng);
        let mut weights = random_weights(t, s, &mut rng);
        for tt in 0..t {
            weights[tt * s + 1] = 0.0;
        }
        let st = stats_for(&model, &data, &weights);
        let mut m = model.clone();
        let report = m.m_step(&st, &Regularisation::none()).unwrap();
        assert_eq!(
            report.events,
            vec![MStepEvent::KeptEmptyState {
                state: 1,
                component: None,
                weight: 0.0
            }],
            "{kind:?}"
        );
        assert_eq!(m.mean(1), model.mean(1), "{kind:?}");
        if kind != CovarianceType::Tied {
            assert_eq!(m.covariance(1), model.covariance(1), "{kind:?}");
        } else {
            // The shared covariance pools the non-empty states only.
            let xs = frame_rows(&data, d);
            let (n0, _, s0) = weighted_moments(&xs, &column(&weights, s, 0));
            let (n2, _, s2) = weighted_moments(&xs, &column(&weights, s, 2));
            assert_matrix_close(
                &m.covariance(1),
                &((s0 + s2) / (n0 + n2)),
                1e-10,
                "tied pooled",
            );
        }
        assert_ne!(m.mean(0), model.mean(0));
        // A state below a custom minimum weight is kept too.
        let mut m2 = model.clone();
        let reg = Regularisation::none().with_min_weight(1e9).unwrap();
        let report = m2.m_step(&st, &reg).unwrap();
        assert_eq!(report.events.len(), s);
        assert_eq!(model_snapshot(&m2), model_snapshot(&model));
    }
}

// ---------------------------------------------------------------------------
// Inverse-Wishart log-prior
// ---------------------------------------------------------------------------

fn iw_term(cov: &DMatrix<f64>, psi: f64, nu: f64) -> f64 {
    let d = cov.nrows() as f64;
    let inv = cov.clone().try_inverse().unwrap();
    -0.5 * (nu + d + 1.0) * cov.determinant().ln() - 0.5 * psi * inv.trace()
}

/// Penalised objective `Σ_t Σ_i w_ti log N(x_t; μ_i, Σ_i) + log_prior`.
fn penalised_objective(g: &Gaussian, data: &[f64], weights: &[f64], reg: &Regularisation) -> f64 {
    let ld = g.log_density(Frames::new(data, g.dim()).unwrap()).unwrap();
    ld.iter().zip(weights).map(|(l, w)| l * w).sum::<f64>() + g.log_prior(reg)
}

/// Same model with every covariance replaced by `f(state, Σ)` (structure kept).
fn with_covariances(g: &Gaussian, f: impl Fn(usize, &DMatrix<f64>) -> DMatrix<f64>) -> Gaussian {
    let (s, d) = (g.n_states(), g.dim());
    let kind = g.covariance_type();
    let covs: Vec<DMatrix<f64>> = (0..s).map(|i| f(i, &g.covariance(i))).collect();
    let raw: Vec<f64> = match kind {
        CovarianceType::Full => covs.iter().flat_map(row_major).collect(),
        CovarianceType::Tied => row_major(&covs[0]),
        CovarianceType::Diagonal => covs
            .iter()
            .flat_map(|c| c.diagonal().iter().copied().collect::<Vec<_>>())
            .collect(),
        CovarianceType::Spherical => covs.iter().map(|c| c[(0, 0)]).collect(),
    };
    Gaussian::new(kind, d, g.means().to_vec(), raw).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0x9a0b_e471), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(32) })]

    #[test]
    fn inverse_wishart_log_prior_matches_formula(seed in any::<u64>(), d in 1usize..=4, s in 1usize..=3, k in 0usize..4,
                                                  psi in 1e-2f64..3.0, nu in 0.0f64..8.0) {
        let kind = kind_of(k);
        let mut rng = rng(seed);
        let rg = random_gaussian(kind, s, d, &mut rng);
        let reg = Regularisation::inverse_wishart(psi, nu).unwrap();
        // Full/diagonal/spherical: one prior per state, on the (structured) matrix;
        // tied: one prior on the shared matrix.
        let want: f64 = if kind == CovarianceType::Tied {
            iw_term(&rg.covs[0], psi, nu)
        } else {
            rg.covs.iter().map(|c| iw_term(c, psi, nu)).sum()
        };
        let got = rg.model.log_prior(&reg);
        prop_assert!(close(got, want, 1e-9), "{:?}: {} vs {}", kind, got, want);
        prop_assert_eq!(rg.model.log_prior(&Regularisation::none()), 0.0);
        prop_assert_eq!(rg.model.log_prior(&Regularisation::add_diagonal(0.1).unwrap()), 0.0);
    }

    /// The inverse-Wishart M-step is the maximiser of log-likelihood + log_prior over
    /// the covariance (means fixed at their update): any structured perturbation lowers it.
    #[test]
    fn inverse_wishart_m_step_maximises_penalised_objective(seed in any::<u64>(), d in 1usize..=4, s in 1usize..=3, k in 0usize..4,
                                                             psi in 1e-2f64..3.0, nu in 0.0f64..8.0) {
        let kind = kind_of(k);
        let mut rng = rng(seed);
        let mut g = random_gaussian(kind, s, d, &mut rng).model;
        let t = 12;
        let data = random_frames(t, d, 1.5, &mut rng);
        let weights = random_weights(t, s, &mut rng);
        let reg = Regularisation::inverse_wishart(psi, nu).unwrap();
        let st = stats_for(&g, &data, &weights);
        g.m_step(&st, &reg).unwrap();
        let best = penalised_objective(&g, &data, &weights, &reg);
        for trial in 0..6 {
            let delta = if trial % 2 == 0 { 0.02 } else { -0.02 };
            let b = random_pd(d, 0.0, &mut rng);
            let perturbed = with_covariances(&g, |_, c| {
                let p = match kind {
                    CovarianceType::Full | CovarianceType::Tied => c + (&b - DMatrix::identity(d, d) * (b.trace() / d as f64)) * (delta * c.trace() / d as f64),
                    _ => c.clone(),
                };
                // Scale every structured variance too.
                project(kind, &p) * (1.0 + delta * 0.5)
            });
            let value = penalised_objective(&perturbed, &data, &weights, &reg);
            prop_assert!(value <= best + 1e-9 * best.abs().max(1.0), "{:?} trial {}: {} > {}", kind, trial, value, best);
        }
    }
}

// ---------------------------------------------------------------------------
// Mixtures of Gaussians
// ---------------------------------------------------------------------------

fn random_weight_rows<R: Rng + ?Sized>(s: usize, m: usize, rng: &mut R) -> Vec<f64> {
    let mut w = Vec::new();
    for _ in 0..s {
        let row: Vec<f64> = (0..m).map(|_| rng.random_range(0.1..1.0)).collect();
        let sum: f64 = row.iter().sum();
        w.extend(row.iter().map(|v| v / sum));
    }
    w
}

fn random_mixture<R: Rng + ?Sized>(
    kind: CovarianceType,
    s: usize,
    m: usize,
    d: usize,
    rng: &mut R,
) -> (MixtureEmission<Gaussian>, Vec<RandomGaussian>) {
    let comps: Vec<RandomGaussian> = (0..s).map(|_| random_gaussian(kind, m, d, rng)).collect();
    let w = random_weight_rows(s, m, rng);
    let mix = MixtureEmission::new(w, comps.iter().map(|c| c.model.clone()).collect()).unwrap();
    (mix, comps)
}

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0x9a0b_e471), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(32) })]

    #[test]
    fn mixture_log_density_is_log_sum_of_weighted_components(seed in any::<u64>(), d in 1usize..=4, s in 1usize..=3, m in 1usize..=3, k in 0usize..4) {
        let kind = kind_of(k);
        let mut rng = rng(seed);
        let (mix, comps) = random_mixture(kind, s, m, d, &mut rng);
        let data = random_frames(6, d, 2.0, &mut rng);
        let ld = mix.log_density(Frames::new(&data, d).unwrap()).unwrap();
        for (tt, x) in data.chunks_exact(d).enumerate() {
            for i in 0..s {
                let direct: f64 = (0..m)
                    .map(|c| mix.weights()[i * m + c] * textbook_log_normal(x, &comps[i].means[c], &comps[i].covs[c]).exp())
                    .sum::<f64>()
                    .ln();
                prop_assert!(close(ld[tt * s + i], direct, 1e-9), "{} vs {}", ld[tt * s + i], direct);
            }
        }
        // Marginal of the mixture = mixture of the marginals.
        let mut perm: Vec<usize> = (0..d).collect();
        perm.shuffle(&mut rng);
        let md = rng.random_range(1..=d);
        let dims = &perm[..md];
        let marg = mix.marginal(dims).unwrap();
        let sub = random_frames(4, md, 2.0, &mut rng);
        let lm = marg.log_density(Frames::new(&sub, md).unwrap()).unwrap();
        for (tt, x) in sub.chunks_exact(md).enumerate() {
            for i in 0..s {
                let terms: Vec<f64> = (0..m)
                    .map(|c| {
                        let mu = DVector::from_fn(md, |a, _| comps[i].means[c][dims[a]]);
                        let cov = DMatrix::from_fn(md, md, |a, b| comps[i].covs[c][(dims[a], dims[b])]);
                        mix.weights()[i * m + c].ln() + textbook_log_normal(x, &mu, &cov)
                    })
                    .collect();
                prop_assert!(close(lm[tt * s + i], direct_log_sum_exp(&terms), 1e-9));
            }
        }
        let invalid = matches!(mix.marginal(&[d]), Err(EmissionError::InvalidDims { .. }));
        prop_assert!(invalid);
    }

    #[test]
    fn single_component_mixture_is_the_plain_gaussian(seed in any::<u64>(), d in 1usize..=4, s in 1usize..=3, k in 0usize..4) {
        let kind = kind_of(k);
        let mut rng = rng(seed);
        let plain = random_gaussian(kind, s, d, &mut rng);
        // One single-state emission per state, same parameters.
        let comps: Vec<Gaussian> = (0..s)
            .map(|i| {
                let raw = match kind {
                    CovarianceType::Full | CovarianceType::Tied => row_major(&plain.covs[i]),
                    CovarianceType::Diagonal => plain.covs[i].diagonal().iter().copied().collect(),
                    CovarianceType::Spherical => vec![plain.covs[i][(0, 0)]],
                };
                Gaussian::new(kind, d, plain.means[i].iter().copied().collect(), raw).unwrap()
            })
            .collect();
        let mut mix = MixtureEmission::new(vec![1.0; s], comps).unwrap();
        let t = 3 * d + 6;
        let data = random_frames(t, d, 2.0, &mut rng);
        let frames = Frames::new(&data, d).unwrap();
        let a = mix.log_density(frames).unwrap();
        let b = plain.model.log_density(frames).unwrap();
        for (x, y) in a.iter().zip(&b) {
            prop_assert!(close(*x, *y, 1e-12));
        }
        // M-step: per-state re-estimation is the plain one (for tied, a 1-state
        // tied component is a per-state full covariance).
        let weights = random_weights(t, s, &mut rng);
        let mut ms = mix.new_stats();
        mix.accumulate(frames, &weights, &mut ms).unwrap();
        mix.m_step(&ms, &Regularisation::none()).unwrap();
        let xs = frame_rows(&data, d);
        let ref_kind = if kind == CovarianceType::Tied { CovarianceType::Full } else { kind };
        let (means, covs) = expected_m_step(ref_kind, &xs, &weights, s, Reg::None);
        for i in 0..s {
            let c = mix.components(i);
            for kk in 0..d {
                prop_assert!(close(c.mean(0)[kk], means[i][kk], 1e-10));
            }
            assert_matrix_close(&c.covariance(0), &covs[i], 1e-10, "M = 1 mixture");
            prop_assert_eq!(mix.weights()[i], 1.0);
        }
    }

    #[test]
    fn mixture_m_step_matches_direct_em_formulas(seed in any::<u64>(), d in 1usize..=3, s in 1usize..=2, m in 1usize..=3) {
        let mut rng = rng(seed);
        let (mut mix, comps) = random_mixture(CovarianceType::Full, s, m, d, &mut rng);
        let t = 40;
        let data = random_frames(t, d, 2.0, &mut rng);
        let gamma = random_weights(t, s, &mut rng);
        let xs = frame_rows(&data, d);
        let mut st = mix.new_stats();
        let frames = Frames::new(&data, d).unwrap();
        // Accumulate in two blocks to exercise merging inside the mixture too.
        mix.accumulate(frames.slice(0..17), &gamma[..17 * s], &mut st).unwrap();
        let mut st2 = mix.new_stats();
        mix.accumulate(frames.slice(17..t), &gamma[17 * s..], &mut st2).unwrap();
        st.merge(&st2).unwrap();
        let old_w = mix.weights().to_vec();
        mix.m_step(&st, &Regularisation::none()).unwrap();
        for i in 0..s {
            // Responsibilities r_t(m) = γ_t(i) w_m N_m(x_t) / Σ_m' w_m' N_m'(x_t).
            let resp: Vec<Vec<f64>> = xs
                .iter()
                .enumerate()
                .map(|(tt, x)| {
                    let terms: Vec<f64> = (0..m)
                        .map(|c| old_w[i * m + c].ln() + textbook_log_normal(x.as_slice(), &comps[i].means[c], &comps[i].covs[c]))
                        .collect();
                    let lse = direct_log_sum_exp(&terms);
                    terms.iter().map(|v| gamma[tt * s + i] * (v - lse).exp()).collect()
                })
                .collect();
            let n_i: f64 = column(&gamma, s, i).iter().sum();
            for c in 0..m {
                let w: Vec<f64> = resp.iter().map(|r| r[c]).collect();
                let (n, mu, scatter) = weighted_moments(&xs, &w);
                prop_assert!(close(mix.weights()[i * m + c], n / n_i, 1e-9));
                let comp = mix.components(i);
                for kk in 0..d {
                    prop_assert!(close(comp.mean(c)[kk], mu[kk], 1e-8));
                }
                assert_matrix_close(&comp.covariance(c), &(scatter / n), 1e-8, "mixture component covariance");
            }
        }
    }
}

#[test]
fn mixture_m_step_errors_name_state_and_component_and_leave_model_unchanged() {
    let mut rng = rng(21);
    let (mix, _) = random_mixture(CovarianceType::Full, 2, 2, 2, &mut rng);
    // All frames identical: every component covariance is singular.
    let data = [0.3, -0.7].repeat(10);
    let frames = Frames::new(&data, 2).unwrap();
    let gamma: Vec<f64> = (0..10).flat_map(|_| [0.0, 1.0]).collect();
    let mut st = mix.new_stats();
    mix.accumulate(frames, &gamma, &mut st).unwrap();
    let mut m = mix.clone();
    match m.m_step(&st, &Regularisation::none()) {
        Err(EmissionError::NotPositiveDefinite {
            state: 1,
            component: Some(_),
            ..
        }) => {}
        other => panic!("expected NotPositiveDefinite for state 1, got {other:?}"),
    }
    assert_eq!(model_snapshot(&m), model_snapshot(&mix));
    // State 0 received no weight: kept and reported; jitter rescues state 1.
    let report = m
        .m_step(&st, &Regularisation::none().with_max_jitter(1e-2).unwrap())
        .unwrap();
    assert!(report.events.contains(&MStepEvent::KeptEmptyState {
        state: 0,
        component: None,
        weight: 0.0
    }));
    assert!(report.events.iter().any(|e| matches!(
        e,
        MStepEvent::Jitter {
            state: 1,
            component: Some(_),
            ..
        }
    )));
    assert_eq!(m.components(0).means(), mix.components(0).means());
}

#[test]
fn mixture_stats_merge_and_mismatch() {
    let mut rng = rng(4);
    let (mix, _) = random_mixture(CovarianceType::Diagonal, 2, 3, 2, &mut rng);
    let (other_m, _) = random_mixture(CovarianceType::Diagonal, 2, 2, 2, &mut rng);
    let (other_s, _) = random_mixture(CovarianceType::Diagonal, 3, 3, 2, &mut rng);
    let mut st = mix.new_stats();
    let before = st.clone();
    assert!(matches!(
        st.merge(&other_m.new_stats()),
        Err(EmissionError::StatsMismatch(_))
    ));
    assert!(matches!(
        st.merge(&other_s.new_stats()),
        Err(EmissionError::StatsMismatch(_))
    ));
    assert_eq!(st, before);
    let data = random_frames(5, 2, 1.0, &mut rng);
    assert!(mix
        .accumulate(
            Frames::new(&data, 2).unwrap(),
            &[1.0; 10],
            &mut other_s.new_stats()
        )
        .is_err());
    let mut m = mix.clone();
    assert!(m
        .m_step(&other_m.new_stats(), &Regularisation::none())
        .is_err());

    // Same shape (S, M) but a different component structure: the weights line up,
    // the inner statistics do not; a failed merge must leave the statistics untouched.
    let (same_shape, _) = random_mixture(CovarianceType::Full, 2, 3, 2, &mut rng);
    let mut a = mix.new_stats();
    mix.accumulate(Frames::new(&data, 2).unwrap(), &[1.0; 10], &mut a)
        .unwrap();
    let mut b = same_shape.new_stats();
    same_shape
        .accumulate(Frames::new(&data, 2).unwrap(), &[1.0; 10], &mut b)
        .unwrap();
    let snapshot = a.clone();
    if mix.components(0).covariance_type() != CovarianceType::Full {
        assert!(matches!(a.merge(&b), Err(EmissionError::StatsMismatch(_))));
        assert_eq!(
            a, snapshot,
            "a failed mixture merge modified the statistics"
        );
    }
}

/// Statistics about different reference points (two models of the same shape)
/// merge exactly: the M-step equals the one from a single accumulation.
#[test]
fn stats_about_different_reference_points_merge_exactly() {
    let mut rng = rng(17);
    for kind in [
        CovarianceType::Full,
        CovarianceType::Diagonal,
        CovarianceType::Spherical,
        CovarianceType::Tied,
    ] {
        let a = random_gaussian(kind, 2, 3, &mut rng).model;
        let b = random_gaussian(kind, 2, 3, &mut rng).model;
        let data = random_frames(40, 3, 1.0, &mut rng);
        let w: Vec<f64> = (0..80).map(|k| 0.1 + (k % 7) as f64 / 7.0).collect();
        let (first, second) = (
            Frames::new(&data[..60], 3).unwrap(),
            Frames::new(&data[60..], 3).unwrap(),
        );
        let mut sa = a.new_stats();
        a.accumulate(first, &w[..40], &mut sa).unwrap();
        let mut sb = b.new_stats();
        b.accumulate(second, &w[40..], &mut sb).unwrap();
        sa.merge(&sb).unwrap();
        let mut all = a.new_stats();
        a.accumulate(Frames::new(&data, 3).unwrap(), &w, &mut all)
            .unwrap();
        let reg = Regularisation::none();
        let (mut m1, mut m2) = (a.clone(), a.clone());
        m1.m_step(&sa, &reg).unwrap();
        m2.m_step(&all, &reg).unwrap();
        for i in 0..2 {
            for (x, y) in m1.mean(i).iter().zip(m2.mean(i)) {
                assert!((x - y).abs() < 1e-10, "{kind:?}: mean {x} vs {y}");
            }
            assert_matrix_close(
                &m1.covariance(i),
                &m2.covariance(i),
                1e-10,
                "re-centred merge",
            );
        }
    }
}

// ---------------------------------------------------------------------------
// Merging, for every emission type
// ---------------------------------------------------------------------------

/// Accumulating `frames` in two blocks and merging equals accumulating them at once.
fn check_merge<E>(e: &E, data: &[f64], weights: &[f64], cut: usize)
where
    E: Emission,
    E::Stats: serde::Serialize + PartialEq,
{
    let (d, s) = (e.dim(), e.n_states());
    let frames = Frames::new(data, d).unwrap();
    let t = frames.len();
    let mut all = e.new_stats();
    e.accumulate(frames, weights, &mut all).unwrap();
    let mut a = e.new_stats();
    e.accumulate(frames.slice(0..cut), &weights[..cut * s], &mut a)
        .unwrap();
    let mut b = e.new_stats();
    e.accumulate(frames.slice(cut..t), &weights[cut * s..], &mut b)
        .unwrap();
    a.merge(&b).unwrap();
    assert_stats_close(&a, &all, 1e-12);
    assert!(close(a.total_weight(), all.total_weight(), 1e-12));
    // Merging empty statistics changes nothing.
    let before = all.clone();
    all.merge(&e.new_stats()).unwrap();
    assert!(all == before);
}

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0x9a0b_e471), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(16) })]

    #[test]
    fn every_emission_merges_like_one_pass(seed in any::<u64>(), s in 1usize..=3, d in 1usize..=3, t in 2usize..25) {
        let mut rng = rng(seed);
        let cut = rng.random_range(1..t);
        let weights = random_weights(t, s, &mut rng);
        let real = random_frames(t, d, 2.0, &mut rng);
        for kind in KINDS {
            check_merge(&random_gaussian(kind, s, d, &mut rng).model, &real, &weights, cut);
            check_merge(&random_mixture(kind, s, 2, d, &mut rng).0, &real, &weights, cut);
        }
        let k = 4;
        let symbols: Vec<f64> = (0..t).map(|_| rng.random_range(0..k) as f64).collect();
        let cat = |rng: &mut rand_chacha::ChaCha8Rng, rows| phasekit_emission::Categorical::new(k, random_weight_rows(rows, k, rng)).unwrap();
        check_merge(&cat(&mut rng, s), &symbols, &weights, cut);
        let mix_cat = MixtureEmission::new(random_weight_rows(s, 2, &mut rng), (0..s).map(|_| cat(&mut rng, 2)).collect()).unwrap();
        check_merge(&mix_cat, &symbols, &weights, cut);
        let counts: Vec<f64> = (0..t * d).map(|_| rng.random_range(0..9u32) as f64).collect();
        let pois = |rng: &mut rand_chacha::ChaCha8Rng, rows: usize| {
            phasekit_emission::Poisson::new(d, (0..rows * d).map(|_| rng.random_range(0.1..8.0)).collect()).unwrap()
        };
        check_merge(&pois(&mut rng, s), &counts, &weights, cut);
        let mix_pois = MixtureEmission::new(random_weight_rows(s, 3, &mut rng), (0..s).map(|_| pois(&mut rng, 3)).collect()).unwrap();
        check_merge(&mix_pois, &counts, &weights, cut);
    }

    #[test]
    fn mixture_of_poissons_log_density_is_direct_sum(seed in any::<u64>(), s in 1usize..=3, m in 1usize..=3, d in 1usize..=3) {
        let mut rng = rng(seed);
        let rates: Vec<Vec<f64>> = (0..s).map(|_| (0..m * d).map(|_| rng.random_range(0.1..8.0)).collect()).collect();
        let w = random_weight_rows(s, m, &mut rng);
        let mix = MixtureEmission::new(w.clone(), rates.iter().map(|r| phasekit_emission::Poisson::new(d, r.clone()).unwrap()).collect()).unwrap();
        let counts: Vec<f64> = (0..5 * d).map(|_| rng.random_range(0..12u32) as f64).collect();
        let ld = mix.log_density(Frames::new(&counts, d).unwrap()).unwrap();
        for (tt, x) in counts.chunks_exact(d).enumerate() {
            for i in 0..s {
                let direct: f64 = (0..m)
                    .map(|c| {
                        let pmf: f64 = (0..d)
                            .map(|k| {
                                let lam = rates[i][c * d + k];
                                lam.powf(x[k]) * (-lam).exp() / (1..=x[k] as u64).map(|j| j as f64).product::<f64>()
                            })
                            .product();
                        w[i * m + c] * pmf
                    })
                    .sum();
                prop_assert!(close(ld[tt * s + i], direct.ln(), 1e-10), "{} vs {}", ld[tt * s + i], direct.ln());
            }
        }
    }
}

#[test]
fn gaussian_log_density_above_64_dimensions() {
    // D > 64 takes the heap path for x − μ.
    let mut rng = rng(64);
    for kind in KINDS {
        let rg = random_gaussian(kind, 2, 66, &mut rng);
        let data = random_frames(3, 66, 1.0, &mut rng);
        let ld = rg
            .model
            .log_density(Frames::new(&data, 66).unwrap())
            .unwrap();
        for (tt, x) in data.chunks_exact(66).enumerate() {
            for i in 0..2 {
                let want = textbook_log_normal(x, &rg.means[i], &rg.covs[i]);
                assert!(
                    close(ld[tt * 2 + i], want, 1e-8),
                    "{kind:?}: {} vs {want}",
                    ld[tt * 2 + i]
                );
            }
        }
    }
}

// ---------------------------------------------------------------------------
// Malformed (deserialised) statistics
// ---------------------------------------------------------------------------

/// Every array in a JSON value, by path, so that each can be truncated in turn.
fn array_paths(
    v: &serde_json::Value,
    path: &mut Vec<serde_json::Value>,
    out: &mut Vec<Vec<serde_json::Value>>,
) {
    match v {
        serde_json::Value::Array(a) => {
            if a.iter().all(|x| x.is_number()) && !a.is_empty() {
                out.push(path.clone());
            }
            for (i, x) in a.iter().enumerate() {
                path.push(serde_json::json!(i));
                array_paths(x, path, out);
                path.pop();
            }
        }
        serde_json::Value::Object(o) => {
            for (k, x) in o {
                path.push(serde_json::json!(k));
                array_paths(x, path, out);
                path.pop();
            }
        }
        _ => {}
    }
}

fn at<'a>(v: &'a mut serde_json::Value, path: &[serde_json::Value]) -> &'a mut serde_json::Value {
    path.iter().fold(v, |v, p| match p {
        serde_json::Value::String(k) => &mut v[k.as_str()],
        serde_json::Value::Number(i) => &mut v[i.as_u64().unwrap() as usize],
        _ => unreachable!(),
    })
}

/// Statistics with any one array shortened are refused by merge, accumulate and
/// the M-step with an error, never a panic, and the model is left unchanged.
fn check_malformed_stats<E>(e: &E, data: &[f64])
where
    E: Emission + serde::Serialize,
    E::Stats: serde::Serialize + serde::de::DeserializeOwned,
{
    let frames = Frames::new(data, e.dim()).unwrap();
    let weights = vec![0.5; frames.len() * e.n_states()];
    let mut good = e.new_stats();
    e.accumulate(frames, &weights, &mut good).unwrap();
    let value = serde_json::to_value(&good).unwrap();
    let mut paths = Vec::new();
    array_paths(&value, &mut Vec::new(), &mut paths);
    assert!(!paths.is_empty());
    let mut tested = 0;
    for path in paths {
        let mut v = value.clone();
        at(&mut v, &path).as_array_mut().unwrap().pop();
        let Ok(bad) = serde_json::from_value::<E::Stats>(v) else {
            continue;
        };
        let mut m = e.clone();
        assert!(
            m.m_step(&bad, &Regularisation::none()).is_err(),
            "M-step accepted stats truncated at {path:?}"
        );
        assert_eq!(model_snapshot(&m), model_snapshot(e));
        let mut b = bad.clone();
        assert!(
            e.accumulate(frames, &weights, &mut b).is_err(),
            "accumulate accepted stats truncated at {path:?}"
        );
        let mut g = good.clone();
        assert!(
            g.merge(&bad).is_err(),
            "merge accepted stats truncated at {path:?}"
        );
        let mut b = bad.clone();
        assert!(
            b.merge(&good).is_err(),
            "merge into stats truncated at {path:?}"
        );
        tested += 1;
    }
    assert!(tested > 0, "no truncated statistics could be deserialised");
}

#[test]
fn malformed_statistics_are_refused_without_panicking() {
    let mut rng = rng(77);
    let data = random_frames(6, 2, 1.0, &mut rng);
    for kind in KINDS {
        check_malformed_stats(&random_gaussian(kind, 2, 2, &mut rng).model, &data);
        check_malformed_stats(&random_mixture(kind, 2, 2, 2, &mut rng).0, &data);
    }
    let counts = [0.0, 3.0, 1.0, 2.0, 5.0, 0.0];
    check_malformed_stats(&phasekit_emission::Poisson::unit(2, 2).unwrap(), &counts);
    let symbols = [0.0, 2.0, 1.0, 1.0];
    check_malformed_stats(
        &phasekit_emission::Categorical::uniform(2, 3).unwrap(),
        &symbols,
    );
}

/// A `Gaussian::standard` template anchors its statistics at each state's first
/// weighted frame, so an M-step from it on data at 1e6 ± 1e-3 is accurate.
#[test]
fn m_step_from_a_far_template_is_accurate() {
    let mut rng = rng(12);
    let data: Vec<f64> = (0..600).map(|_| 1e6 + 1e-3 * normal(&mut rng)).collect();
    let xs = frame_rows(&data, 3);
    for kind in KINDS {
        let mut g = Gaussian::standard(
            kind,
            Shape {
                n_states: 1,
                dim: 3,
            },
        )
        .unwrap();
        let st = stats_for(&g, &data, &[1.0; 200]);
        g.m_step(&st, &Regularisation::none()).unwrap();
        let (_, want) = expected_m_step(kind, &xs, &[1.0; 200], 1, Reg::None);
        let rel = (g.covariance(0) - &want[0]).amax() / want[0].amax();
        assert!(rel <= 1e-6, "{kind:?}: relative error {rel:e}");
    }
}
