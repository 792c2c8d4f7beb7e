//! Property tests of the formulas against slower obvious versions.

use phasekit_emission::Gaussian;
use phasekit_hmm::Hmm;
use phasekit_recognition::metrics::{
    correct_from_first_third, frames_observed, held_frame, median_or_never, settled_frame,
    Confusion,
};
use phasekit_recognition::rejection::quantile;
use phasekit_recognition::{action_posterior, mix_predictions, threshold_hmm, Decision};
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Bayes' rule in log space against the direct product, on likelihoods
    /// small enough not to underflow.
    #[test]
    fn posterior_is_bayes_rule(prior in prop::collection::vec(0.05f64..1.0, 2..6), seed in 0u64..1000) {
        let a = prior.len();
        let total: f64 = prior.iter().sum();
        let prior: Vec<f64> = prior.iter().map(|p| p / total).collect();
        let ll: Vec<f64> = (0..a).map(|i| -((seed as f64 * 0.37 + i as f64 * 1.3) % 20.0)).collect();
        let mut out = vec![0.0; a];
        let lz = action_posterior(&prior.iter().map(|p| p.ln()).collect::<Vec<_>>(), &ll, &mut out);
        let joint: Vec<f64> = prior.iter().zip(&ll).map(|(p, l)| p * l.exp()).collect();
        let z: f64 = joint.iter().sum();
        prop_assert!((lz - z.ln()).abs() < 1e-12);
        for (o, j) in out.iter().zip(&joint) {
            prop_assert!((o - j / z).abs() < 1e-12);
        }
        // Shifting every likelihood by a constant changes nothing (no underflow at −1e4).
        let shifted: Vec<f64> = ll.iter().map(|l| l - 1e4).collect();
        let mut out2 = vec![0.0; a];
        action_posterior(&prior.iter().map(|p| p.ln()).collect::<Vec<_>>(), &shifted, &mut out2);
        for (x, y) in out.iter().zip(&out2) {
            prop_assert!((x - y).abs() < 1e-9);
        }
    }

    /// The moment-matched mixture covariance against `E[x xᵀ] − m mᵀ` of the
    /// mixture, `E[x xᵀ] = Σ_a p_a (C_a + m_a m_aᵀ)`.
    #[test]
    fn mixture_moments(weights in prop::collection::vec(0.0f64..1.0, 1..5), seed in 0u64..1000) {
        let a = weights.len();
        let total: f64 = weights.iter().sum::<f64>() + 1e-3;
        let w: Vec<f64> = weights.iter().map(|v| v / total).chain(std::iter::once(1e-3 / total)).collect();
        let a = a + 1;
        let o = 3;
        let f = |i: usize| ((seed as f64 + 1.0) * (i as f64 + 0.5) * 0.731).sin();
        let means: Vec<f64> = (0..a * o).map(f).collect();
        // C_a = L Lᵀ + 0.1 I, symmetric positive definite.
        let mut covs = vec![0.0; a * o * o];
        for k in 0..a {
            let l: Vec<f64> = (0..o * o).map(|i| f(100 + k * 9 + i)).collect();
            for r in 0..o {
                for c in 0..o {
                    covs[k * o * o + r * o + c] = (0..o).map(|q| l[r * o + q] * l[c * o + q]).sum::<f64>()
                        + if r == c { 0.1 } else { 0.0 };
                }
            }
        }
        let (mut m, mut c) = (vec![0.0; o], vec![0.0; o * o]);
        mix_predictions(&w, &means, Some(&covs), &mut m, Some(&mut c));
        for r in 0..o {
            let expected: f64 = (0..a).map(|k| w[k] * means[k * o + r]).sum();
            prop_assert!((m[r] - expected).abs() < 1e-12);
            for q in 0..o {
                let second: f64 = (0..a)
                    .map(|k| w[k] * (covs[k * o * o + r * o + q] + means[k * o + r] * means[k * o + q]))
                    .sum();
                prop_assert!((c[r * o + q] - (second - m[r] * m[q])).abs() < 1e-10);
                prop_assert!((c[r * o + q] - c[q * o + r]).abs() < 1e-12);
            }
        }
    }

    /// The frame from which a decision stays right, against its definition.
    #[test]
    fn settled_frame_is_the_first_of_the_final_correct_run(d in prop::collection::vec(0usize..4, 1..40)) {
        let decisions: Vec<Decision> = d.iter().map(|&x| if x == 3 { Decision::Unknown } else { Decision::Action(x) }).collect();
        for truth in 0..3 {
            let brute = (0..decisions.len()).find(|&t| decisions[t..].iter().all(|x| *x == Decision::Action(truth)));
            prop_assert_eq!(settled_frame(&decisions, truth), brute);
            let third = (decisions.len() as f64 / 3.0).ceil() as usize - 1;
            prop_assert_eq!(correct_from_first_third(&decisions, truth), brute.is_some_and(|s| s <= third));
        }
    }

    /// The first frame of a right run of `hold` frames (or to the end), against its definition.
    #[test]
    fn held_frame_is_the_first_long_enough_run(d in prop::collection::vec(0usize..3, 1..40), hold in 1usize..6) {
        let decisions: Vec<Decision> = d.iter().map(|&x| Decision::Action(x)).collect();
        let n = decisions.len();
        for truth in 0..3 {
            let right = |t: usize| decisions[t] == Decision::Action(truth);
            let brute = (0..n).find(|&t| {
                let end = (t + hold).min(n);
                (t..end).all(right) && (end - t == hold || end == n)
            });
            prop_assert_eq!(held_frame(&decisions, truth, hold), brute);
        }
    }

    /// Frames observed after k/10 against the real-number ceiling.
    #[test]
    fn frames_observed_is_the_ceiling(t in 1usize..2000, k in 1usize..=10) {
        let n = frames_observed(t, k);
        prop_assert!(n >= 1 && n <= t);
        prop_assert_eq!(n, ((k * t) as f64 / 10.0).ceil().max(1.0) as usize);
    }
}

#[test]
fn median_counts_never_as_the_largest() {
    assert_eq!(median_or_never(&[]), None);
    assert_eq!(median_or_never(&[Some(3.0), None, Some(1.0)]), Some(3.0));
    assert_eq!(median_or_never(&[Some(3.0), None, None]), None);
    assert_eq!(
        median_or_never(&[Some(1.0), Some(2.0), Some(4.0), None]),
        Some(3.0)
    );
    assert_eq!(median_or_never(&[Some(1.0), Some(2.0), None, None]), None);
}

#[test]
fn quantiles_interpolate_between_order_statistics() {
    assert_eq!(quantile(&[], 0.5), None);
    assert_eq!(quantile(&[3.0, 1.0, 2.0], 0.0), Some(1.0));
    assert_eq!(quantile(&[3.0, 1.0, 2.0], 1.0), Some(3.0));
    assert_eq!(quantile(&[3.0, 1.0, 2.0, 4.0], 0.5), Some(2.5));
    assert_eq!(
        quantile(&[f64::NEG_INFINITY, 1.0], 0.0),
        Some(f64::NEG_INFINITY)
    );
}

#[test]
fn confusion_counts_unknown_and_rest_apart() {
    let mut c = Confusion::new(2);
    c.add(0, Decision::Action(0));
    c.add(0, Decision::Action(1));
    c.add(1, Decision::Unknown);
    c.add(1, Decision::Rest);
    let mut d = Confusion::new(2);
    d.merge(&c);
    d.merge(&c);
    assert_eq!(d.counts, vec![vec![2, 2, 0, 0], vec![0, 0, 2, 2]]);
}

#[test]
fn the_threshold_model_keeps_self_transitions_and_spreads_the_rest() {
    let g =
        |means: Vec<f64>| Gaussian::spherical(1, means.clone(), vec![1.0; means.len()]).unwrap();
    let a = Hmm::new(vec![1.0, 0.0], vec![0.9, 0.1, 0.2, 0.8], g(vec![0.0, 1.0])).unwrap();
    let b = Hmm::new(
        vec![0.5, 0.25, 0.25],
        vec![0.5, 0.5, 0.0, 0.0, 0.7, 0.3, 0.0, 0.0, 1.0],
        g(vec![2.0, 3.0, 4.0]),
    )
    .unwrap();
    let t = threshold_hmm(&[a, b]).unwrap();
    assert_eq!(t.n_states(), 5);
    assert_eq!(t.start(), &[0.2; 5]);
    let stay = [0.9, 0.8, 0.5, 0.7, 1.0];
    for (i, row) in t.transition().chunks_exact(5).enumerate() {
        for (j, p) in row.iter().enumerate() {
            let expected = if i == j {
                stay[i]
            } else {
                (1.0 - stay[i]) / 4.0
            };
            assert!((p - expected).abs() < 1e-15, "{i} → {j}");
        }
    }
    assert_eq!(t.emission().means(), &[0.0, 1.0, 2.0, 3.0, 4.0]);
    // Full covariances of the spherical unit variances.
    assert_eq!(t.emission().covariance(3)[(0, 0)], 1.0);
}
