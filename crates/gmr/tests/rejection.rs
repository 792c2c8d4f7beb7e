//! A frame that no state can explain (a glitch of 1e200 whose density
//! underflows under every state) must not collapse the prediction: it is
//! reported, taken as not observed (the belief takes its transition step only)
//! and every later frame is predicted exactly as if that frame's inputs had
//! been missing — in batch and online alike, for HMM and static GMR.

use phasekit_emission::{Frames, Gaussian};
use phasekit_gmm::Gmm;
use phasekit_gmr::{GmmRegression, HmmRegression};
use phasekit_hmm::Hmm;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const INPUT: [usize; 3] = [3, 0, 2];
const OUTPUT: [usize; 2] = [4, 1];

/// A sticky 4-state HMM over 5 joint dims with well separated states.
fn hmm() -> Hmm<Gaussian> {
    let mut r = ChaCha8Rng::seed_from_u64(7);
    let (s, d) = (4, 5);
    let means: Vec<f64> = (0..s * d).map(|_| r.random_range(-3.0..3.0)).collect();
    let mut covs = Vec::new();
    for k in 0..s {
        for i in 0..d {
            for j in 0..d {
                covs.push(if i == j { 0.3 + 0.1 * k as f64 } else { 0.05 });
            }
        }
    }
    let mut a = vec![0.05; s * s];
    (0..s).for_each(|i| a[i * s + i] = 0.85);
    Hmm::new(
        vec![0.4, 0.3, 0.2, 0.1],
        a,
        Gaussian::full(d, means, covs).unwrap(),
    )
    .unwrap()
}

fn inputs(h: &Hmm<Gaussian>, len: usize) -> Vec<f64> {
    let (joint, _) = h.sample(len, &mut ChaCha8Rng::seed_from_u64(8)).unwrap();
    joint
        .chunks(5)
        .flat_map(|f| INPUT.iter().map(move |&i| f[i]))
        .collect()
}

/// `xs` with frame `t`'s first input replaced by `v`, and the same with the whole frame missing.
fn glitched(xs: &[f64], t: usize, v: f64) -> (Vec<f64>, Vec<f64>) {
    let mut bad = xs.to_vec();
    bad[3 * t] = v;
    let mut missing = xs.to_vec();
    missing[3 * t..3 * t + 3].fill(f64::NAN);
    (bad, missing)
}

#[test]
fn hmm_gmr_recovers_from_a_frame_no_state_explains() {
    let h = hmm();
    let gmr = HmmRegression::new(&h, &INPUT, &OUTPUT).unwrap();
    let xs = inputs(&h, 80);
    for v in [1e200, -3e160, 1e155] {
        let (bad, missing) = glitched(&xs, 30, v);
        let got = gmr.predict(Frames::new(&bad, 3).unwrap(), true).unwrap();
        let want = gmr
            .predict(Frames::new(&missing, 3).unwrap(), true)
            .unwrap();
        assert_eq!(got.rejected, vec![30], "{v}");
        assert!(want.rejected.is_empty());
        // Every frame, the glitch included, is predicted as with the frame missing.
        assert_eq!(got.mean, want.mean, "{v}");
        assert_eq!(got.covariance, want.covariance, "{v}");
        assert_eq!(got.weights, want.weights, "{v}");
        assert!(got.mean.iter().all(|m| m.is_finite() && *m != 0.0));
        // The evidence: −inf at the glitch, the frame's predictive density elsewhere.
        assert_eq!(got.log_predictive[30], f64::NEG_INFINITY);
        assert!(
            want.log_predictive[30].abs() < 1e-12,
            "nothing observed: density 1"
        );
        for (t, (a, b)) in got
            .log_predictive
            .iter()
            .zip(&want.log_predictive)
            .enumerate()
        {
            if t != 30 {
                assert!((a - b).abs() < 1e-9, "frame {t}: {a} vs {b}");
            }
        }
        // Online, step by step: the same predictions, the glitch reported.
        let mut online = gmr.online();
        for (t, x) in bad.chunks(3).enumerate() {
            let m = online.step_with_covariance(x).unwrap().to_vec();
            assert_eq!(m, &want.mean[2 * t..2 * t + 2], "online frame {t}");
            assert_eq!(
                online.covariance(),
                &want.covariance.as_ref().unwrap()[4 * t..4 * t + 4]
            );
            let e = online.evidence();
            assert_eq!(e.rejected, t == 30, "frame {t}");
            if t == 30 {
                assert_eq!(e.log_predictive, f64::NEG_INFINITY);
            } else {
                assert!((e.log_predictive - want.log_predictive[t]).abs() < 1e-9);
            }
        }
    }
}

#[test]
fn every_frame_a_glitch_is_every_frame_rejected_not_a_panic() {
    let h = hmm();
    let gmr = HmmRegression::new(&h, &INPUT, &OUTPUT).unwrap();
    let bad = vec![1e200; 3 * 10];
    let p = gmr.predict(Frames::new(&bad, 3).unwrap(), false).unwrap();
    assert_eq!(p.rejected, (0..10).collect::<Vec<_>>());
    // Nothing observed anywhere: the outputs' marginal under the dynamics.
    let none = vec![f64::NAN; 3 * 10];
    let q = gmr.predict(Frames::new(&none, 3).unwrap(), false).unwrap();
    assert_eq!(p.mean, q.mean);
}

#[test]
fn static_gmr_recovers_from_a_frame_no_component_explains() {
    let h = hmm();
    let gmm = Gmm::new(vec![0.1, 0.2, 0.3, 0.4], h.emission().clone()).unwrap();
    let gmr = GmmRegression::new(&gmm, &INPUT, &OUTPUT).unwrap();
    let xs = inputs(&h, 40);
    let (bad, missing) = glitched(&xs, 11, 1e200);
    let got = gmr.predict(Frames::new(&bad, 3).unwrap(), true).unwrap();
    let want = gmr
        .predict(Frames::new(&missing, 3).unwrap(), true)
        .unwrap();
    assert_eq!(got.rejected, vec![11]);
    assert_eq!(got.mean, want.mean);
    assert_eq!(got.covariance, want.covariance);
    assert_eq!(got.weights, want.weights);
    for (w, pi) in got.weights[44..48].iter().zip([0.1, 0.2, 0.3, 0.4]) {
        assert!((w - pi).abs() < 1e-15, "the prior weights");
    }
    assert_eq!(got.log_predictive[11], f64::NEG_INFINITY);
    assert!(want.log_predictive[11].abs() < 1e-12);
    // log p(x_t) of the complete frames: the mixture density.
    let score = gmm
        .marginal(&INPUT)
        .unwrap()
        .score_samples(Frames::new(&xs, 3).unwrap())
        .unwrap();
    for t in (0..40).filter(|t| *t != 11) {
        assert_eq!(got.log_predictive[t], score[t], "frame {t}");
    }
    // One frame at a time: the same, and the rejection reported.
    let (k, o) = (4, 2);
    let (mut w, mut m, mut c, mut s) = (
        vec![0.0; k],
        vec![0.0; o],
        vec![0.0; o * o],
        vec![0.0; k * o],
    );
    for (t, x) in bad.chunks(3).enumerate() {
        let e = gmr
            .predict_one_into(x, &mut w, &mut m, Some(&mut c), &mut s)
            .unwrap();
        assert_eq!(e.rejected, t == 11);
        assert_eq!(m, &want.mean[o * t..o * (t + 1)], "frame {t}");
        assert_eq!(
            c,
            &want.covariance.as_ref().unwrap()[o * o * t..o * o * (t + 1)]
        );
    }
}
