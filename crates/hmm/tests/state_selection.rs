//! Choosing the number of HMM states, and the library's default regularisation.
//!
//! * BIC picks the true number of states of a generated 3-state HMM (moved
//!   here from `phasekit-gmm`, which no longer depends on the HMM);
//! * a candidate that cannot be fitted is reported with its error, and a
//!   selection with no fitted candidate says why for each, with no Debug text;
//! * `max_supported_states` stops at the shortest sequence or at the count
//!   whose free parameters would outnumber the frames, against a direct count;
//! * `BaumWelch::default()` fits data with a constant column (its default
//!   regularisation adds `1e-6` to the covariance diagonals), which plain
//!   maximum likelihood refuses.
//!
//! Every random draw comes from a seeded `ChaCha8Rng`.

use phasekit_emission::{CovarianceType, Gaussian, Regularisation, SequenceSet, Shape};
use phasekit_hmm::{
    default_regularisation, max_supported_states, select_states_bic, BaumWelch, Hmm, HmmError,
    HmmInit, StateLimit, DEFAULT_ADDED_DIAGONAL,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

fn full(n_states: usize, dim: usize) -> phasekit_emission::Result<Gaussian> {
    Gaussian::standard(CovarianceType::Full, Shape { n_states, dim })
}

#[test]
fn bic_picks_the_true_number_of_hmm_states() {
    let emission = Gaussian::full(
        2,
        vec![0.0, 0.0, 5.0, 0.0, 0.0, 5.0],
        vec![0.5, 0.1, 0.1, 0.5, 0.6, -0.2, -0.2, 0.4, 0.5, 0.0, 0.0, 0.7],
    )
    .unwrap();
    let hmm = Hmm::new(
        vec![0.6, 0.3, 0.1],
        vec![0.9, 0.05, 0.05, 0.05, 0.9, 0.05, 0.1, 0.1, 0.8],
        emission,
    )
    .unwrap();
    let mut r = rng(17);
    let seqs: Vec<Vec<f64>> = (0..8).map(|_| hmm.sample(150, &mut r).unwrap().0).collect();
    let data = SequenceSet::new(&seqs, 2).unwrap();
    let bw = BaumWelch::builder()
        .init(HmmInit::KMeans)
        .restarts(2)
        .seed(0)
        .build()
        .unwrap();
    let sel = select_states_bic(
        &bw,
        |s| {
            Gaussian::standard(
                CovarianceType::Full,
                Shape {
                    n_states: s,
                    dim: 2,
                },
            )
        },
        &data,
        1..=5,
    )
    .unwrap();
    assert!(sel.failures.is_empty(), "{:?}", sel.failures);
    assert_eq!(sel.best, 3, "BIC scores {:?}", sel.scores);
}

#[test]
fn failed_candidates_are_reported_with_their_error() {
    let mut r = rng(3);
    let seqs: Vec<Vec<f64>> = (0..3)
        .map(|_| (0..20).map(|_| r.random::<f64>()).collect())
        .collect();
    let data = SequenceSet::new(&seqs, 1).unwrap();
    let bw = BaumWelch::default();
    // 30 states cannot be initialised from 20-frame sequences by k-bins (a
    // state gets no frame); 2 and 3 states can.
    let sel = select_states_bic(&bw, |s| full(s, 1), &data, [2, 30, 3]).unwrap();
    assert_eq!(sel.scores.iter().map(|s| s.0).collect::<Vec<_>>(), [2, 3]);
    assert_eq!(sel.failures.len(), 1);
    assert_eq!(sel.failures[0].0, 30);
    assert!(
        matches!(sel.failures[0].1, HmmError::TooFewFrames(_)),
        "{:?}",
        sel.failures
    );
    // No candidate fitted: the error names every candidate and why, in words.
    let err = select_states_bic(&bw, |s| full(s, 2), &data, [2, 3]).unwrap_err();
    let msg = err.to_string();
    assert!(
        matches!(
            err,
            HmmError::InvalidParameter {
                name: "candidates",
                ..
            }
        ),
        "{err:?}"
    );
    assert!(
        msg.contains("2 states: ") && msg.contains("3 states: "),
        "{msg}"
    );
    assert!(
        !msg.contains("InvalidParameter") && !msg.contains("DimensionMismatch"),
        "{msg}"
    );
    let err = select_states_bic(&bw, |s| full(s, 1), &data, []).unwrap_err();
    assert!(err.to_string().contains("no candidate"), "{err}");
}

/// hmmlearn's parameter count of a full-covariance Gaussian HMM, written out.
fn dense_parameters(s: usize, d: usize) -> usize {
    (s - 1) + s * (s - 1) + s * (d + d * (d + 1) / 2)
}

#[test]
fn supported_states_stop_at_the_shortest_sequence_or_the_parameter_count() {
    // 707 frames of 2-D data allow far more than 7 states by the parameter
    // count (p(8) = 96): the 7-frame sequence limits.
    let seqs = [vec![0.0; 2 * 400], vec![0.0; 2 * 7], vec![0.0; 2 * 300]];
    let data = SequenceSet::new(&seqs, 2).unwrap();
    let (max, limit) = max_supported_states(|s| full(s, 2), &data).unwrap();
    assert_eq!(max, 7);
    assert_eq!(
        limit,
        StateLimit::ShortestSequence {
            sequence: 1,
            frames: 7
        }
    );
    assert!(
        limit.to_string().contains("sequence 1 has 7 frames"),
        "{limit}"
    );
    // Long sequences of a 12-D full-covariance model: the parameter count limits.
    let d = 12;
    let seqs: Vec<Vec<f64>> = (0..8).map(|_| vec![0.0; d * 285]).collect();
    let data = SequenceSet::new(&seqs, d).unwrap();
    let n = data.total_frames();
    let expected = (1..=285)
        .take_while(|&s| dense_parameters(s, d) <= n)
        .last()
        .unwrap();
    let (max, limit) = max_supported_states(|s| full(s, d), &data).unwrap();
    assert_eq!(max, expected);
    assert_eq!(
        limit,
        StateLimit::Parameters {
            parameters: dense_parameters(expected + 1, d),
            frames: n
        }
    );
    assert!(dense_parameters(max, d) <= n && dense_parameters(max + 1, d) > n);
    // An HMM built with that many states has that many parameters (the count is the model's).
    let hmm = Hmm::new(
        vec![1.0 / max as f64; max],
        vec![1.0 / max as f64; max * max],
        full(max, d).unwrap(),
    )
    .unwrap();
    assert_eq!(hmm.n_parameters_dense(), dense_parameters(max, d));
}

#[test]
fn the_default_regularisation_fits_a_constant_column() {
    // Two regimes in x; y never moves (a marker that is constant).
    let mut r = rng(9);
    let seqs: Vec<Vec<f64>> = (0..4)
        .map(|_| {
            (0..120)
                .flat_map(|t| {
                    let x = if (t / 30) % 2 == 0 { 0.0 } else { 5.0 };
                    [x + r.random::<f64>() - 0.5, 1.0]
                })
                .collect()
        })
        .collect();
    let data = SequenceSet::new(&seqs, 2).unwrap();
    let template = full(2, 2).unwrap();
    assert_eq!(
        BaumWelch::default().regularisation(),
        &default_regularisation()
    );
    assert_eq!(
        default_regularisation(),
        Regularisation::add_diagonal(DEFAULT_ADDED_DIAGONAL).unwrap()
    );
    let fitted = BaumWelch::default().fit(&template, &data).unwrap();
    for i in 0..2 {
        // The constant column's variance is exactly the added diagonal.
        let v = fitted.model.emission().covariance(i)[(1, 1)];
        assert!((v - DEFAULT_ADDED_DIAGONAL).abs() < 1e-12, "state {i}: {v}");
    }
    let mut means: Vec<f64> = (0..2).map(|i| fitted.model.emission().mean(i)[0]).collect();
    means.sort_by(f64::total_cmp);
    assert!(
        means[0].abs() < 0.2 && (means[1] - 5.0).abs() < 0.2,
        "{means:?}"
    );
    // Plain maximum likelihood refuses the singular covariance, in words.
    let err = BaumWelch::builder()
        .regularisation(Regularisation::none())
        .build()
        .unwrap()
        .fit(&template, &data)
        .unwrap_err();
    assert!(err.to_string().contains("not positive definite"), "{err}");
    // The same from k-means initialisation.
    let km = BaumWelch::builder().init(HmmInit::KMeans).build().unwrap();
    assert!(km.fit(&template, &data).is_ok());
}
