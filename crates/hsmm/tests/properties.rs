//! Property tests of the HSMM algorithms against slow, obvious versions:
//! brute-force enumeration of every segmentation of short sequences, the
//! HMM (an HSMM with geometric durations is one), the batch forward pass
//! (the online filter), and EM's monotonicity.
//!
//! Every model is drawn from a `ChaCha8Rng` seeded by proptest, and proptest
//! runs from a fixed seed (override with `PROPTEST_RNG_SEED`).

use crate::common;

use common::*;
use phasekit_emission::{Emission, Frames, Gaussian, Regularisation, SequenceSet};
use phasekit_hmm::Hmm;
use phasekit_hsmm::{
    Censoring, DurationRegularisation, Hsmm, HsmmError, HsmmUpdate, NonParametricDuration,
};
use proptest::prelude::*;
use rand::Rng;

const TOL: f64 = 1e-9;

fn close(what: &str, got: f64, want: f64, tol: f64) -> Result<(), TestCaseError> {
    prop_assert!(!got.is_nan(), "{what}: NaN (want {want})");
    prop_assert!(
        (got - want).abs() <= tol * want.abs().max(1.0),
        "{what}: got {got}, want {want}"
    );
    Ok(())
}

fn close_all(what: &str, got: &[f64], want: &[f64], tol: f64) -> Result<(), TestCaseError> {
    prop_assert_eq!(got.len(), want.len(), "{}: length", what);
    for (k, (g, w)) in got.iter().zip(want).enumerate() {
        prop_assert!((g - w).abs() <= tol, "{what}[{k}]: got {g}, want {w}");
    }
    Ok(())
}

/// Every inference routine of `m` on `seq` against the brute force.
fn check_against_brute_force<E: Emission>(
    m: &Hsmm<E, NonParametricDuration>,
    seq: Frames<'_>,
) -> Result<(), TestCaseError> {
    let s = m.n_states();
    let t_len = seq.len();
    let log_b = m.emission_log_densities(seq).unwrap();
    let brute = brute_of(m, &log_b);

    if brute.log_p == f64::NEG_INFINITY {
        let ok = matches!(m.forward(seq), Err(HsmmError::ImpossibleSequence { .. }));
        prop_assert!(ok, "forward of an impossible sequence");
        let ok = matches!(m.posteriors(seq), Err(HsmmError::ImpossibleSequence { .. }));
        prop_assert!(ok, "posteriors of an impossible sequence");
        let ok = matches!(m.viterbi(seq), Err(HsmmError::ImpossibleSequence { .. }));
        prop_assert!(ok, "viterbi of an impossible sequence");
        return Ok(());
    }

    let fwd = m.forward(seq).unwrap();
    close(
        "forward log-likelihood",
        fwd.log_likelihood(),
        brute.log_p,
        TOL,
    )?;
    for (t, row) in fwd.filtered().chunks_exact(s).enumerate() {
        let total: f64 = row.iter().sum();
        prop_assert!(
            (total - 1.0).abs() < 1e-12,
            "filtered row {t} sums to {total}"
        );
    }
    // The filtered marginals at the last frame are the smoothed ones (right-censored).
    let post = m.posteriors(seq).unwrap();
    close(
        "posteriors log-likelihood",
        post.log_likelihood,
        brute.log_p,
        TOL,
    )?;
    close_all("gamma", &post.gamma, &brute.gamma, TOL)?;
    for (t, row) in post.gamma.chunks_exact(s).enumerate() {
        let total: f64 = row.iter().sum();
        prop_assert!((total - 1.0).abs() < 1e-9, "gamma row {t} sums to {total}");
    }
    close_all("segment starts", &post.segment_starts, &brute.starts, TOL)?;
    close_all("segment ends", &post.segment_ends, &brute.ends, TOL)?;
    close_all(
        "expected transitions",
        &post.expected_transitions,
        &brute.xi,
        TOL,
    )?;
    close_all(
        "expected durations",
        &post.expected_durations,
        &brute.durations,
        TOL,
    )?;
    close_all(
        "censored durations",
        &post.censored_durations,
        &brute.censored,
        TOL,
    )?;
    // Every segment is counted once: as a duration or as the censored last one.
    let n_segments: f64 =
        post.expected_durations.iter().sum::<f64>() + post.censored_durations.iter().sum::<f64>();
    let n_transitions: f64 = post.expected_transitions.iter().sum();
    close(
        "segments = transitions + 1",
        n_segments,
        n_transitions + 1.0,
        TOL,
    )?;
    // Forbidden transitions and durations are never expected.
    for (x, a) in post.expected_transitions.iter().zip(m.transition()) {
        if *a == 0.0 {
            prop_assert_eq!(*x, 0.0);
        }
    }

    // Viterbi: the best enumerated log-probability, achieved by the returned segmentation.
    let v = m.viterbi(seq).unwrap();
    close(
        "viterbi log-probability",
        v.log_probability,
        brute.best,
        TOL,
    )?;
    prop_assert_eq!(v.states.len(), t_len);
    let segs: Vec<(usize, usize, usize)> = v
        .segments
        .iter()
        .map(|g| (g.state, g.start, g.len))
        .collect();
    let achieved = brute
        .all
        .iter()
        .find(|e| e.segments == segs)
        .map(|e| e.log_p)
        .unwrap_or(f64::NEG_INFINITY);
    close(
        "log-probability of the returned segmentation",
        achieved,
        brute.best,
        TOL,
    )?;
    for g in &v.segments {
        for u in g.start..g.start + g.len {
            prop_assert_eq!(v.states[u], g.state);
        }
    }

    // The online filter, frame by frame, is the batch forward pass to the bit.
    let mut filter = m.filter();
    let mut partial = 0.0;
    for t in 0..t_len {
        let belief = filter.step(seq.frame(t)).unwrap().to_vec();
        prop_assert_eq!(
            belief.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            fwd.filtered()[t * s..(t + 1) * s]
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>(),
            "online belief at frame {}",
            t
        );
        partial += fwd.log_normalisers()[t];
        prop_assert_eq!(filter.log_likelihood().to_bits(), partial.to_bits());
    }
    Ok(())
}

proptest! {
    #![proptest_config(config(400))]

    /// Likelihood, state, segment, transition and duration posteriors, and
    /// Viterbi, against every segmentation of sequences of 1–6 frames, with
    /// structural zeros in `π`, `A` and the durations, terminal states and
    /// both censorings; categorical emissions (with impossible symbols).
    #[test]
    fn categorical_inference_matches_enumeration(
        seed in any::<u64>(),
        s in 1usize..=3,
        t_len in 1usize..=6,
        dm in 1usize..=5,
        ends in any::<bool>(),
    ) {
        let mut rng = rng(seed);
        let (start, transition, durations) = random_chain(&mut rng, s, dm, 0.3, 0.2);
        let emission = random_categorical(&mut rng, s, 3, 0.3);
        let censoring = if ends { Censoring::EndsWithSegment } else { Censoring::RightCensored };
        let m = Hsmm::new(start, transition, durations, emission).unwrap().with_censoring(censoring);
        let data: Vec<f64> = (0..t_len).map(|_| rng.random_range(0..3) as f64).collect();
        check_against_brute_force(&m, Frames::new(&data, 1).unwrap())?;
    }

    /// The same with 2-D Gaussian emissions (no impossible frame), where
    /// densities differ by many orders of magnitude.
    #[test]
    fn gaussian_inference_matches_enumeration(
        seed in any::<u64>(),
        s in 1usize..=3,
        t_len in 1usize..=6,
        dm in 1usize..=6,
        ends in any::<bool>(),
        scale in prop_oneof![Just(1.0), Just(30.0)],
    ) {
        let mut rng = rng(seed);
        let (start, transition, durations) = random_chain(&mut rng, s, dm, 0.2, 0.2);
        let emission = random_gaussian(&mut rng, s, 2);
        let censoring = if ends { Censoring::EndsWithSegment } else { Censoring::RightCensored };
        let m = Hsmm::new(start, transition, durations, emission).unwrap().with_censoring(censoring);
        let data: Vec<f64> = (0..t_len * 2).map(|_| scale * rng.random_range(-2.5..2.5)).collect();
        check_against_brute_force(&m, Frames::new(&data, 2).unwrap())?;
    }

    /// An HSMM whose durations are geometric is the HMM: likelihood,
    /// filtered and smoothed marginals, transitions between different
    /// states, and the Viterbi log-probability agree to 1e-10.
    #[test]
    fn geometric_durations_equal_the_hmm(
        seed in any::<u64>(),
        s in 1usize..=4,
        t_len in 1usize..=9,
        extra in 0usize..=3,
    ) {
        let mut rng = rng(seed);
        let start = random_distribution(&mut rng, s, 0.3, |_| true);
        let mut transition = Vec::new();
        for _ in 0..s {
            // Self-transitions from 0 to 1 (absorbing), structural zeros.
            transition.extend(random_distribution(&mut rng, s, 0.3, |_| true));
        }
        let emission = random_gaussian(&mut rng, s, 2);
        let hmm = Hmm::new(start, transition, emission).unwrap();
        let hsmm: Hsmm<Gaussian, NonParametricDuration> =
            Hsmm::from_hmm(&hmm, t_len + extra).unwrap();
        let data: Vec<f64> = (0..t_len * 2).map(|_| rng.random_range(-3.0..3.0)).collect();
        let seq = Frames::new(&data, 2).unwrap();

        let hf = hmm.forward(seq).unwrap();
        let sf = hsmm.forward(seq).unwrap();
        close("log-likelihood", sf.log_likelihood(), hf.log_likelihood(), 1e-10)?;
        close_all("filtered", sf.filtered(), hf.filtered(), 1e-10)?;
        let hp = hmm.posteriors(seq).unwrap();
        let sp = hsmm.posteriors(seq).unwrap();
        close_all("gamma", &sp.gamma, &hp.gamma, 1e-10)?;
        for i in 0..s {
            for j in 0..s {
                if i != j {
                    close(
                        &format!("transitions {i} → {j}"),
                        sp.expected_transitions[i * s + j],
                        hp.expected_transitions[i * s + j],
                        1e-10,
                    )?;
                }
            }
        }
        close(
            "viterbi",
            hsmm.viterbi(seq).unwrap().log_probability,
            hmm.viterbi(seq).unwrap().log_probability,
            1e-10,
        )?;
    }

    /// Looking ahead from the online filter is the batch forward pass over
    /// frames that are not observed (NaN frames have density 1).
    #[test]
    fn prediction_ahead_is_the_forward_pass_over_unseen_frames(
        seed in any::<u64>(),
        s in 1usize..=3,
        seen in 1usize..=5,
        ahead in 1usize..=6,
        dm in 1usize..=6,
    ) {
        let mut rng = rng(seed);
        let (start, transition, durations) = random_chain(&mut rng, s, dm, 0.2, 0.2);
        let emission = random_gaussian(&mut rng, s, 2);
        let m = Hsmm::new(start, transition, durations, emission).unwrap();
        let mut data: Vec<f64> = (0..seen * 2).map(|_| rng.random_range(-2.0..2.0)).collect();
        let mut filter = m.filter();
        for x in data.chunks(2) {
            if filter.step(x).is_err() {
                return Ok(());
            }
        }
        let mut predicted = vec![0.0; ahead * s];
        filter.predict_states(ahead, &mut predicted).unwrap();
        data.extend(std::iter::repeat_n(f64::NAN, ahead * 2));
        if let Ok(fwd) = m.forward(Frames::new(&data, 2).unwrap()) {
            let tail = &fwd.filtered()[seen * s..];
            prop_assert_eq!(
                predicted.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                tail.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
            );
        }
        // The filter itself is unchanged by looking ahead.
        prop_assert_eq!(filter.frames_seen(), seen);
    }
}

proptest! {
    #![proptest_config(config(200))]

    /// One EM step of non-parametric durations is the brute-force expected
    /// complete-data counts, normalised: complete segments count at their
    /// length; a right-censored last segment observed for `d` frames counts
    /// at every `d' ≥ d` with probability `p(d') / P(D ≥ d)`.
    #[test]
    fn duration_m_step_is_the_enumerated_expectation(
        seed in any::<u64>(),
        s in 1usize..=3,
        n_seq in 1usize..=3,
        dm in 1usize..=5,
        ends in any::<bool>(),
    ) {
        let mut rng = rng(seed);
        let (start, transition, durations) = random_chain(&mut rng, s, dm, 0.2, 0.3);
        let emission = random_categorical(&mut rng, s, 3, 0.2);
        let censoring = if ends { Censoring::EndsWithSegment } else { Censoring::RightCensored };
        let m = Hsmm::new(start, transition, durations, emission).unwrap().with_censoring(censoring);
        let seqs: Vec<Vec<f64>> = (0..n_seq)
            .map(|_| (0..rng.random_range(1..=5)).map(|_| rng.random_range(0..3) as f64).collect())
            .collect();
        let data = SequenceSet::new(&seqs, 1).unwrap();
        let pmf = m.durations().pmf().to_vec();
        let mut counts = vec![0.0; s * dm];
        for seq in data.iter() {
            let log_b = m.emission_log_densities(seq).unwrap();
            let b = brute_of(&m, &log_b);
            if b.log_p == f64::NEG_INFINITY {
                return Ok(());
            }
            for k in 0..s {
                for d in 1..=dm {
                    counts[k * dm + d - 1] += b.durations[k * dm + d - 1];
                    let c = b.censored[k * dm + d - 1];
                    if c == 0.0 {
                        continue;
                    }
                    let surv: f64 = pmf[k * dm + d - 1..(k + 1) * dm].iter().sum();
                    for d2 in d..=dm {
                        counts[k * dm + d2 - 1] += c * pmf[k * dm + d2 - 1] / surv;
                    }
                }
            }
        }
        let stats = m.expected_statistics(&data).unwrap();
        let update = HsmmUpdate { start: false, transition: false, durations: true, emission: false };
        let (next, _, _) = m
            .maximise(&stats, update, &Regularisation::none(), &DurationRegularisation::none())
            .unwrap();
        for k in 0..s {
            let row = &counts[k * dm..(k + 1) * dm];
            let total: f64 = row.iter().sum();
            let got = &next.durations().pmf()[k * dm..(k + 1) * dm];
            if total < 1e-10 {
                prop_assert_eq!(got, &pmf[k * dm..(k + 1) * dm]);
            } else {
                let want: Vec<f64> = row.iter().map(|c| c / total).collect();
                close_all(&format!("state {k} pmf"), got, &want, 1e-9)?;
            }
        }
    }
}

/// A sequence the model cannot explain names its first impossible frame;
/// the filter refuses the frame and keeps its belief.
#[test]
fn impossible_frames_are_located() {
    // Left-right, two states, each lasting at most 2 frames: 5 frames are impossible.
    let durations = NonParametricDuration::new(2, vec![0.5, 0.5, 0.5, 0.5]).unwrap();
    let emission = Gaussian::diagonal(1, vec![0.0, 1.0], vec![1.0, 1.0]).unwrap();
    let m = Hsmm::new(
        vec![1.0, 0.0],
        vec![0.0, 1.0, 0.0, 0.0],
        durations,
        emission,
    )
    .unwrap();
    let data = [0.0, 0.1, 0.9, 1.1, 1.0];
    let err = m.forward(Frames::new(&data, 1).unwrap()).unwrap_err();
    assert_eq!(
        err,
        HsmmError::ImpossibleSequence {
            sequence: 0,
            frame: 4,
            max_duration: 2
        }
    );
    assert!(err.to_string().contains("max_duration = 2"), "{err}");
    let set = SequenceSet::new(&[&data[..4], &data[..]], 1).unwrap();
    match m.log_likelihood_all(&set) {
        Err(HsmmError::ImpossibleSequence {
            sequence: 1,
            frame: 4,
            ..
        }) => {}
        other => panic!("{other:?}"),
    }
    let mut f = m.filter();
    for x in &data[..4] {
        f.step(&[*x]).unwrap();
    }
    let before = f.belief().to_vec();
    assert!(f.step(&[1.0]).is_err());
    assert_eq!(f.belief(), &before[..]);
    assert_eq!(f.frames_seen(), 4);
    assert!(m.viterbi(Frames::new(&data, 1).unwrap()).is_err());
}

/// A duration whose probability is far below the smallest double
/// (`p_0(3) ≈ e^{−1100}`) is still a possible explanation: when the data
/// leave no other, the likelihood, posteriors and Viterbi find it exactly
/// (the linear shortcut of the forward pass falls back to log space).
#[test]
fn durations_below_the_double_range_are_not_lost() {
    use phasekit_emission::Categorical;
    use phasekit_hsmm::{AnyDuration, GaussianDuration};
    let durations = GaussianDuration::new(60, vec![50.0, 5.0], vec![1.0, 2.0]).unwrap();
    // State 0 emits symbol 0 only, state 1 symbol 1 only.
    let emission = Categorical::new(2, vec![1.0, 0.0, 0.0, 1.0]).unwrap();
    let m = Hsmm::new(
        vec![1.0, 0.0],
        vec![0.0, 1.0, 0.0, 0.0],
        AnyDuration::from(durations),
        emission,
    )
    .unwrap();
    let data = [0.0, 0.0, 0.0, 1.0];
    let seq = Frames::new(&data, 1).unwrap();
    let lp0 = m.duration_log_pmf(0).unwrap()[2];
    assert!(lp0 < -1000.0 && lp0.exp() == 0.0, "{lp0}");
    // log π_0 + log p_0(3) + log a_01 + log P(D_1 ≥ 1); every emission has probability 1.
    let want = lp0;
    let got = m.log_likelihood(seq).unwrap();
    assert!((got - want).abs() < 1e-9 * want.abs(), "{got} vs {want}");
    let post = m.posteriors(seq).unwrap();
    assert_eq!(post.gamma, vec![1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
    assert!((post.expected_durations[2] - 1.0).abs() < 1e-12);
    let v = m.viterbi(seq).unwrap();
    assert_eq!(v.states, vec![0, 0, 0, 1]);
    assert!((v.log_probability - want).abs() < 1e-9 * want.abs());
    let mut f = m.filter();
    for x in &data {
        f.step(&[*x]).unwrap();
    }
    assert_eq!(f.belief(), &[0.0, 1.0]);
}
