//! The duration M-steps against their definitions: the truncated maximum
//! likelihood `argmax Σ_d c(d) log p(d)`, checked by the moment conditions
//! of the exponential families and by grids over the parameters.

use crate::common;

use common::*;
use phasekit_hsmm::{
    Duration, DurationEvent, DurationRegularisation, GaussianDuration, NegativeBinomialDuration,
    NonParametricDuration, PoissonDuration,
};
use proptest::prelude::*;
use rand::Rng;

fn q_of<D: Duration>(d: &D, state: usize, counts: &[f64]) -> f64 {
    let mut lp = vec![0.0; d.max_duration()];
    d.log_pmf_into(state, &mut lp).unwrap();
    counts
        .iter()
        .zip(&lp)
        .filter(|(c, _)| **c > 0.0)
        .map(|(c, l)| c * l)
        .sum()
}

fn pmf_of<D: Duration>(d: &D, state: usize) -> Vec<f64> {
    let mut lp = vec![0.0; d.max_duration()];
    d.log_pmf_into(state, &mut lp).unwrap();
    lp.iter().map(|v| v.exp()).collect()
}

/// Random counts over `1..=dm`, with a bump somewhere and some zeros.
fn random_counts(r: &mut rand_chacha::ChaCha8Rng, dm: usize) -> Vec<f64> {
    let centre = r.random_range(1.0..=dm as f64);
    let width = r.random_range(0.5..=(dm as f64 / 2.0).max(0.5));
    (1..=dm)
        .map(|d| {
            if r.random::<f64>() < 0.2 {
                0.0
            } else {
                let z = (d as f64 - centre) / width;
                10.0 * (-0.5 * z * z).exp() * r.random_range(0.5..1.5)
            }
        })
        .collect()
}

proptest! {
    #![proptest_config(config(60))]

    /// Poisson: the fitted rate matches the truncated mean to the counts'
    /// mean (the score equation), and no rate on a grid does better.
    #[test]
    fn poisson_m_step_is_the_truncated_maximum(seed in any::<u64>(), dm in 2usize..40) {
        let mut r = rng(seed);
        let counts = random_counts(&mut r, dm);
        prop_assume!(counts.iter().sum::<f64>() > 0.0);
        let mut d = PoissonDuration::new(dm, vec![1.0]).unwrap();
        let report = d.m_step(&counts, &DurationRegularisation::none()).unwrap();
        let q = q_of(&d, 0, &counts);
        let total: f64 = counts.iter().sum();
        let mean: f64 = counts.iter().enumerate().map(|(k, c)| (k + 1) as f64 * c).sum::<f64>() / total;
        let p = pmf_of(&d, 0);
        let model_mean: f64 = p.iter().enumerate().map(|(k, p)| (k + 1) as f64 * p).sum();
        if report.events.is_empty() {
            prop_assert!((model_mean - mean).abs() < 1e-9 * mean, "{model_mean} vs {mean}");
        }
        for k in 0..200 {
            let rate = (-6.0 + 12.0 * k as f64 / 199.0_f64).exp() * dm as f64;
            let other = PoissonDuration::new(dm, vec![rate]).unwrap();
            prop_assert!(q_of(&other, 0, &counts) <= q + 1e-9 * q.abs(), "rate {rate} beats {:?}", d.rates());
        }
    }

    /// Gaussian: where `σ` is above its floor, the fitted pmf matches the
    /// counts' first two moments; no `(μ, σ ≥ min_std)` on a grid does better.
    #[test]
    fn gaussian_m_step_is_the_truncated_maximum(seed in any::<u64>(), dm in 3usize..30, min_std in 0.3f64..2.0) {
        let mut r = rng(seed);
        let counts = random_counts(&mut r, dm);
        prop_assume!(counts.iter().filter(|c| **c > 0.0).count() > 1);
        let reg = DurationRegularisation::none().with_min_std(min_std).unwrap();
        let mut d = GaussianDuration::new(dm, vec![1.0], vec![5.0]).unwrap();
        let report = d.m_step(&counts, &reg).unwrap();
        prop_assert!(d.stds()[0] >= min_std * (1.0 - 1e-12));
        let q = q_of(&d, 0, &counts);
        let total: f64 = counts.iter().sum();
        let m1: f64 = counts.iter().enumerate().map(|(k, c)| (k + 1) as f64 * c).sum::<f64>() / total;
        let p = pmf_of(&d, 0);
        let pm1: f64 = p.iter().enumerate().map(|(k, p)| (k + 1) as f64 * p).sum();
        // The mean's score equation holds at any σ; the variance's only inside.
        prop_assert!((pm1 - m1).abs() < 1e-6 * m1, "{pm1} vs {m1}: {:?} {:?} {:?} {counts:?} {report:?}", d.means(), d.stds(), min_std);
        if report.events.is_empty() {
            let m2: f64 = counts.iter().enumerate().map(|(k, c)| ((k + 1) as f64).powi(2) * c).sum::<f64>() / total;
            let pm2: f64 = p.iter().enumerate().map(|(k, p)| ((k + 1) as f64).powi(2) * p).sum();
            prop_assert!((pm2 - m2).abs() < 1e-5 * m2, "{pm2} vs {m2}");
        }
        for a in 0..40 {
            for b in 0..40 {
                let mean = -2.0 + (dm as f64 + 4.0) * a as f64 / 39.0;
                let std = min_std * (4.0 * dm as f64 / min_std).powf(b as f64 / 39.0);
                let other = GaussianDuration::new(dm, vec![mean], vec![std]).unwrap();
                prop_assert!(q_of(&other, 0, &counts) <= q + 1e-8 * q.abs(), "({mean}, {std}) beats ({:?}, {:?})", d.means(), d.stds());
            }
        }
    }

    /// Negative binomial: no `(r, q)` on a grid does better than the M-step.
    #[test]
    fn negative_binomial_m_step_is_the_truncated_maximum(seed in any::<u64>(), dm in 3usize..30) {
        let mut r = rng(seed);
        let counts = random_counts(&mut r, dm);
        prop_assume!(counts.iter().sum::<f64>() > 0.0);
        let mut d = NegativeBinomialDuration::new(dm, vec![1.0], vec![0.5]).unwrap();
        d.m_step(&counts, &DurationRegularisation::none()).unwrap();
        let q = q_of(&d, 0, &counts);
        for a in 0..30 {
            for b in 1..30 {
                let shape = (-4.0 + 12.0 * a as f64 / 29.0_f64).exp();
                let prob = b as f64 / 30.0;
                let other = NegativeBinomialDuration::new(dm, vec![shape], vec![prob]).unwrap();
                prop_assert!(q_of(&other, 0, &counts) <= q + 1e-7 * q.abs(), "({shape}, {prob}) beats ({:?}, {:?})", d.shapes(), d.probs());
            }
        }
    }

    /// Non-parametric: the normalised counts plus the pseudo-count.
    #[test]
    fn non_parametric_m_step_is_the_normalised_counts(seed in any::<u64>(), dm in 1usize..20, alpha in prop_oneof![Just(0.0), 0.0f64..2.0]) {
        let mut r = rng(seed);
        let counts = random_counts(&mut r, dm);
        let total: f64 = counts.iter().sum();
        prop_assume!(total > 0.0);
        let mut d = NonParametricDuration::uniform(1, dm).unwrap();
        d.m_step(&counts, &DurationRegularisation::none().with_pseudo_count(alpha).unwrap()).unwrap();
        for (p, c) in d.pmf().iter().zip(&counts) {
            prop_assert!((p - (c + alpha) / (total + alpha * dm as f64)).abs() < 1e-15);
        }
    }
}

/// A state without counts keeps its parameters and is reported; bad counts are refused.
#[test]
fn empty_states_and_bad_counts() {
    let mut d = PoissonDuration::new(5, vec![2.0, 3.0]).unwrap();
    let counts = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 2.0, 1.0];
    let report = d.m_step(&counts, &DurationRegularisation::none()).unwrap();
    assert_eq!(d.rates()[0], 2.0);
    assert_eq!(
        report.events,
        vec![DurationEvent::KeptEmptyState {
            state: 0,
            weight: 0.0
        }]
    );
    let e = d
        .m_step(&counts[..9], &DurationRegularisation::none())
        .unwrap_err();
    assert!(
        e.to_string().contains("expected 2 states × 5 durations"),
        "{e}"
    );
    let mut bad = counts;
    bad[7] = -1.0;
    let e = d.m_step(&bad, &DurationRegularisation::none()).unwrap_err();
    assert!(e.to_string().contains("state 1, duration 3"), "{e}");
    // All visits last one frame: the Poisson rate sits on its lower bound.
    let mut d = PoissonDuration::new(5, vec![2.0]).unwrap();
    let report = d
        .m_step(&[4.0, 0.0, 0.0, 0.0, 0.0], &DurationRegularisation::none())
        .unwrap();
    assert!(matches!(report.events[0], DurationEvent::AtBound { .. }));
    assert!(pmf_of(&d, 0)[0] > 1.0 - 1e-8);
}
