//! Categorical and Poisson emissions against direct formulas.

use crate::common;

use common::*;
use phasekit_emission::{
    Categorical, Emission, EmissionError, Frames, MStepEvent, Marginal, Poisson, Regularisation,
    SufficientStatistics,
};
use proptest::prelude::*;
use rand::Rng;

fn random_stochastic<R: Rng + ?Sized>(rows: usize, k: usize, rng: &mut R) -> Vec<f64> {
    let mut p = Vec::new();
    for _ in 0..rows {
        let row: Vec<f64> = (0..k).map(|_| rng.random_range(0.05..1.0)).collect();
        let sum: f64 = row.iter().sum();
        p.extend(row.iter().map(|v| v / sum));
    }
    p
}

fn assert_not_nan(v: &[f64]) {
    assert!(v.iter().all(|x| !x.is_nan()), "NaN in {v:?}");
}

// ---------------------------------------------------------------------------
// Categorical
// ---------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0xd15c_4e7e), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(48) })]

    #[test]
    fn categorical_log_density_is_log_probability(seed in any::<u64>(), s in 1usize..=3, k in 1usize..=6, t in 1usize..20) {
        let mut rng = rng(seed);
        let p = random_stochastic(s, k, &mut rng);
        let c = Categorical::new(k, p.clone()).unwrap();
        prop_assert_eq!(c.n_states(), s);
        let data: Vec<f64> = (0..t).map(|_| rng.random_range(0..k) as f64).collect();
        let frames = Frames::new(&data, 1).unwrap();
        c.check_frames(frames).unwrap();
        let ld = c.log_density(frames).unwrap();
        for (tt, x) in data.iter().enumerate() {
            for i in 0..s {
                prop_assert_eq!(ld[tt * s + i], p[i * k + *x as usize].ln());
            }
        }
        // Outside the support: -inf, never NaN.
        let bad = [k as f64, -1.0, 0.5, 1e300];
        let ld = c.log_density(Frames::new(&bad, 1).unwrap()).unwrap();
        prop_assert!(ld.iter().all(|v| *v == f64::NEG_INFINITY));
    }

    #[test]
    fn categorical_m_step_is_weighted_frequencies(seed in any::<u64>(), s in 1usize..=3, k in 1usize..=5, t in 1usize..40, a in 0.0f64..2.0) {
        let mut rng = rng(seed);
        let mut c = Categorical::new(k, random_stochastic(s, k, &mut rng)).unwrap();
        let data: Vec<f64> = (0..t).map(|_| rng.random_range(0..k) as f64).collect();
        let w: Vec<f64> = (0..t * s).map(|_| rng.random_range(0.0..1.0)).collect();
        let frames = Frames::new(&data, 1).unwrap();
        // Two halves merged.
        let cut = t / 2;
        let mut st = c.new_stats();
        c.accumulate(frames.slice(0..cut), &w[..cut * s], &mut st).unwrap();
        let mut st2 = c.new_stats();
        c.accumulate(frames.slice(cut..t), &w[cut * s..], &mut st2).unwrap();
        st.merge(&st2).unwrap();
        let mut all = c.new_stats();
        c.accumulate(frames, &w, &mut all).unwrap();
        prop_assert!(close(st.total_weight(), all.total_weight(), 1e-12));
        prop_assert!(close(st.total_weight(), w.iter().sum(), 1e-12));

        let reg = Regularisation::none().with_pseudo_count(a).unwrap();
        c.m_step(&st, &reg).unwrap();
        for i in 0..s {
            let n: f64 = (0..t).map(|tt| w[tt * s + i]).sum();
            for j in 0..k {
                let cnt: f64 = (0..t).filter(|&tt| data[tt] as usize == j).map(|tt| w[tt * s + i]).sum();
                let want = (cnt + a) / (n + a * k as f64);
                prop_assert!(close(c.probabilities()[i * k + j], want, 1e-12), "{} vs {}", c.probabilities()[i * k + j], want);
            }
        }
        // log_prior of the Dirichlet(α + 1) prior: α Σ ln p.
        let lp: f64 = c.probabilities().iter().map(|p| a * p.ln()).sum();
        let want_prior = if a == 0.0 { 0.0 } else { lp };
        prop_assert!(close(c.log_prior(&reg), want_prior, 1e-12));
    }
}

#[test]
fn categorical_check_frames_names_frame_and_column() {
    let c = Categorical::new(3, vec![0.2, 0.3, 0.5]).unwrap();
    for (bad, t) in [(1.5, 2), (-1.0, 0), (3.0, 4), (-0.5, 1)] {
        let mut data = vec![0.0, 1.0, 2.0, 1.0, 0.0];
        data[t] = bad;
        match c.check_frames(Frames::new(&data, 1).unwrap()) {
            Err(EmissionError::InvalidValue {
                frame,
                column,
                value,
                ..
            }) => {
                assert_eq!((frame, column, value), (t, 0, bad));
            }
            other => panic!("expected InvalidValue, got {other:?}"),
        }
    }
    let two = [0.0, 1.0];
    assert!(matches!(
        c.check_frames(Frames::new(&two, 2).unwrap()),
        Err(EmissionError::DimensionMismatch { .. })
    ));
}

#[test]
fn categorical_empty_state_kept_zero_probability_is_neg_inf_and_shapes_checked() {
    let mut c = Categorical::new(3, vec![0.5, 0.5, 0.0, 0.2, 0.3, 0.5]).unwrap();
    let before = c.clone();
    let data = [2.0, 0.0, 2.0];
    let frames = Frames::new(&data, 1).unwrap();
    let ld = c.log_density(frames).unwrap();
    assert_eq!(ld[0], f64::NEG_INFINITY);
    assert_not_nan(&ld);
    let mut st = c.new_stats();
    c.accumulate(frames, &[0.0, 1.0, 0.0, 1.0, 0.0, 1.0], &mut st)
        .unwrap();
    let report = c.m_step(&st, &Regularisation::none()).unwrap();
    assert_eq!(
        report.events,
        vec![MStepEvent::KeptEmptyState {
            state: 0,
            component: None,
            weight: 0.0
        }]
    );
    assert_eq!(&c.probabilities()[..3], &before.probabilities()[..3]);
    assert_eq!(&c.probabilities()[3..], &[1.0 / 3.0, 0.0, 2.0 / 3.0]);

    // Statistics of another shape.
    let other_k = Categorical::uniform(2, 4).unwrap();
    let other_s = Categorical::uniform(3, 3).unwrap();
    for other in [&other_k, &other_s] {
        let mut mine = c.new_stats();
        let snapshot = mine.clone();
        assert!(matches!(
            mine.merge(&other.new_stats()),
            Err(EmissionError::StatsMismatch(_))
        ));
        assert_eq!(mine, snapshot);
        let mut m = c.clone();
        assert!(m
            .m_step(&other.new_stats(), &Regularisation::none())
            .is_err());
        assert_eq!(m.probabilities(), c.probabilities());
        assert!(c
            .accumulate(frames, &[1.0; 6], &mut other.new_stats())
            .is_err());
    }
    assert!(c.marginal(&[0]).is_ok());
    assert!(matches!(
        c.marginal(&[1]),
        Err(EmissionError::InvalidDims { .. })
    ));
    assert!(matches!(
        c.marginal(&[]),
        Err(EmissionError::InvalidDims { .. })
    ));
    assert!(Categorical::uniform(0, 3).is_err());
    assert!(Categorical::uniform(2, 0).is_err());
}

// ---------------------------------------------------------------------------
// Poisson
// ---------------------------------------------------------------------------

fn direct_poisson_log_pmf(x: &[f64], rates: &[f64]) -> f64 {
    x.iter()
        .zip(rates)
        .map(|(&x, &lam)| {
            let xi = x as u64;
            if lam == 0.0 {
                if xi == 0 {
                    0.0
                } else {
                    f64::NEG_INFINITY
                }
            } else {
                x * lam.ln() - lam - log_factorial(xi)
            }
        })
        .sum()
}

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0xd15c_4e7e), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(48) })]

    #[test]
    fn poisson_log_density_matches_direct_formula(seed in any::<u64>(), s in 1usize..=3, d in 1usize..=4, t in 1usize..15) {
        let mut rng = rng(seed);
        let rates: Vec<f64> = (0..s * d).map(|_| rng.random_range(0.05..25.0)).collect();
        let p = Poisson::new(d, rates.clone()).unwrap();
        let data: Vec<f64> = (0..t * d).map(|_| rng.random_range(0..60u32) as f64).collect();
        let frames = Frames::new(&data, d).unwrap();
        p.check_frames(frames).unwrap();
        let ld = p.log_density(frames).unwrap();
        for (tt, x) in data.chunks_exact(d).enumerate() {
            for i in 0..s {
                let want = direct_poisson_log_pmf(x, &rates[i * d..(i + 1) * d]);
                prop_assert!(close(ld[tt * s + i], want, 1e-11), "{} vs {}", ld[tt * s + i], want);
            }
        }
        // Marginal: the selected rates.
        let dims: Vec<usize> = (0..d).rev().collect();
        let m = p.marginal(&dims).unwrap();
        for i in 0..s {
            for (a, &k) in dims.iter().enumerate() {
                prop_assert_eq!(m.rates()[i * d + a], rates[i * d + k]);
            }
        }
    }

    #[test]
    fn poisson_m_step_is_weighted_mean(seed in any::<u64>(), s in 1usize..=3, d in 1usize..=3, t in 2usize..30) {
        let mut rng = rng(seed);
        let p = Poisson::unit(s, d).unwrap();
        let data: Vec<f64> = (0..t * d).map(|_| rng.random_range(0..20u32) as f64).collect();
        let w: Vec<f64> = (0..t * s).map(|_| rng.random_range(0.01..1.0)).collect();
        let frames = Frames::new(&data, d).unwrap();
        let cut = rng.random_range(1..t);
        let mut st = p.new_stats();
        p.accumulate(frames.slice(0..cut), &w[..cut * s], &mut st).unwrap();
        let mut st2 = p.new_stats();
        p.accumulate(frames.slice(cut..t), &w[cut * s..], &mut st2).unwrap();
        st.merge(&st2).unwrap();
        let mut all = p.new_stats();
        p.accumulate(frames, &w, &mut all).unwrap();
        let (mut q, mut r) = (p.clone(), p.clone());
        q.m_step(&st, &Regularisation::none()).unwrap();
        r.m_step(&all, &Regularisation::none()).unwrap();
        for (a, b) in q.rates().iter().zip(r.rates()) {
            prop_assert!(close(*a, *b, 1e-12));
        }
        for i in 0..s {
            let n: f64 = (0..t).map(|tt| w[tt * s + i]).sum();
            for k in 0..d {
                let sx: f64 = (0..t).map(|tt| w[tt * s + i] * data[tt * d + k]).sum();
                prop_assert!(close(q.rates()[i * d + k], sx / n, 1e-12));
            }
        }
    }
}

#[test]
fn poisson_zero_rate_is_exact_and_never_nan() {
    let p = Poisson::new(1, vec![0.0]).unwrap();
    let ld = p
        .log_density(Frames::new(&[0.0, 1.0, 7.0], 1).unwrap())
        .unwrap();
    assert_eq!(ld, vec![0.0, f64::NEG_INFINITY, f64::NEG_INFINITY]);

    // Mixed dimensions: a zero-rate dimension contributes 0 at count 0.
    let p = Poisson::new(2, vec![0.0, 2.0]).unwrap();
    let ld = p
        .log_density(Frames::new(&[0.0, 3.0, 1.0, 3.0], 2).unwrap())
        .unwrap();
    assert!(close(ld[0], direct_poisson_log_pmf(&[3.0], &[2.0]), 1e-12));
    assert_eq!(ld[1], f64::NEG_INFINITY);

    // A zero rate reached by the M-step (all counts zero).
    let mut p = Poisson::unit(1, 2).unwrap();
    let data = [0.0, 4.0, 0.0, 6.0];
    let frames = Frames::new(&data, 2).unwrap();
    let mut st = p.new_stats();
    p.accumulate(frames, &[1.0, 1.0], &mut st).unwrap();
    p.m_step(&st, &Regularisation::none()).unwrap();
    assert_eq!(p.rates(), &[0.0, 5.0]);
    let ld = p
        .log_density(Frames::new(&[0.0, 5.0, 1.0, 5.0], 2).unwrap())
        .unwrap();
    assert_not_nan(&ld);
    assert!(ld[0].is_finite());
    assert_eq!(ld[1], f64::NEG_INFINITY);
    // Sampling a zero rate gives zero counts.
    let mut r = rng(1);
    let mut out = [9.0; 2];
    for _ in 0..10 {
        p.sample_into(0, &mut r, &mut out).unwrap();
        assert_eq!(out[0], 0.0);
    }
}

#[test]
fn poisson_check_frames_names_frame_and_column() {
    let p = Poisson::unit(2, 3).unwrap();
    for (bad, pos) in [(-1.0, 4), (2.5, 0), (-0.25, 8)] {
        let mut data = vec![1.0; 9];
        data[pos] = bad;
        match p.check_frames(Frames::new(&data, 3).unwrap()) {
            Err(EmissionError::InvalidValue {
                frame,
                column,
                value,
                ..
            }) => {
                assert_eq!((frame, column, value), (pos / 3, pos % 3, bad));
            }
            other => panic!("expected InvalidValue, got {other:?}"),
        }
        // Scoring such frames anyway gives -inf, never NaN.
        let ld = p.log_density(Frames::new(&data, 3).unwrap()).unwrap();
        assert_not_nan(&ld);
        assert_eq!(ld[(pos / 3) * 2], f64::NEG_INFINITY);
    }
    assert!(matches!(
        p.check_frames(Frames::new(&[1.0, 2.0], 2).unwrap()),
        Err(EmissionError::DimensionMismatch { .. })
    ));
}

#[test]
fn poisson_empty_state_and_shape_mismatch() {
    let mut p = Poisson::new(1, vec![2.0, 3.0]).unwrap();
    let data = [1.0, 4.0];
    let frames = Frames::new(&data, 1).unwrap();
    let mut st = p.new_stats();
    p.accumulate(frames, &[1.0, 0.0, 1.0, 0.0], &mut st)
        .unwrap();
    let report = p.m_step(&st, &Regularisation::none()).unwrap();
    assert_eq!(
        report.events,
        vec![MStepEvent::KeptEmptyState {
            state: 1,
            component: None,
            weight: 0.0
        }]
    );
    assert_eq!(p.rates(), &[2.5, 3.0]);

    let other_d = Poisson::unit(2, 2).unwrap();
    let other_s = Poisson::unit(3, 1).unwrap();
    for other in [&other_d, &other_s] {
        let mut mine = p.new_stats();
        let snapshot = mine.clone();
        assert!(matches!(
            mine.merge(&other.new_stats()),
            Err(EmissionError::StatsMismatch(_))
        ));
        assert_eq!(mine, snapshot);
        let mut m = p.clone();
        assert!(m
            .m_step(&other.new_stats(), &Regularisation::none())
            .is_err());
        assert_eq!(m.rates(), p.rates());
    }
    assert!(p
        .accumulate(frames, &[1.0; 4], &mut other_s.new_stats())
        .is_err());
    assert!(matches!(
        p.marginal(&[0, 0]),
        Err(EmissionError::InvalidDims { .. })
    ));
    for bad in [vec![], vec![-1.0], vec![f64::NAN], vec![f64::INFINITY]] {
        assert!(Poisson::new(1, bad).is_err());
    }
}
