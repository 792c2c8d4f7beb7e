//! EM: monotone without the fixed regulariser (every duration family, both
//! censorings), monotone in the penalised objective with pseudo-counts and
//! an inverse-Wishart prior, bit-identical on 1 and 4 threads, recovering
//! known durations, and the checks of its settings and statistics.

use crate::common;

use common::*;
use phasekit_emission::{CovarianceType, Gaussian, Regularisation, SequenceSet, Shape};
use phasekit_hsmm::{
    AnyDuration, Censoring, Duration, DurationRegularisation, GaussianDuration, Hsmm, HsmmEm,
    HsmmError, HsmmInit, HsmmUpdate, NegativeBinomialDuration, NonParametricDuration,
    PoissonDuration, Structure,
};
use proptest::prelude::*;
use rand::Rng;

/// A 3-phase left-right interaction-like model with 2-D Gaussian frames.
fn truth(dm: usize) -> Hsmm<Gaussian, AnyDuration> {
    Hsmm::new(
        vec![1.0, 0.0, 0.0],
        vec![0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        GaussianDuration::new(dm, vec![8.0, 20.0, 12.0], vec![2.0, 4.0, 3.0])
            .unwrap()
            .into(),
        Gaussian::diagonal(2, vec![0.0, 0.0, 2.0, 1.0, 0.5, 2.0], vec![0.6; 6]).unwrap(),
    )
    .unwrap()
}

fn sample_set(
    m: &Hsmm<Gaussian, AnyDuration>,
    n: usize,
    len: std::ops::Range<usize>,
    seed: u64,
) -> SequenceSet {
    let mut r = rng(seed);
    let seqs: Vec<Vec<f64>> = (0..n)
        .map(|_| {
            let l = r.random_range(len.clone());
            m.sample(l, &mut r).unwrap().0
        })
        .collect();
    SequenceSet::new(&seqs, m.dim()).unwrap()
}

fn template(family: usize, s: usize, dm: usize) -> AnyDuration {
    match family {
        0 => NonParametricDuration::uniform(s, dm).unwrap().into(),
        1 => PoissonDuration::template(s, dm).unwrap().into(),
        2 => GaussianDuration::template(s, dm).unwrap().into(),
        _ => NegativeBinomialDuration::template(s, dm).unwrap().into(),
    }
}

proptest! {
    #![proptest_config(config(24))]

    /// Without regularisation EM never decreases the log-likelihood, for
    /// every duration family, both censorings, ergodic and left-right models
    /// and every initialisation.
    #[test]
    fn em_is_monotone(
        seed in any::<u64>(),
        family in 0usize..4,
        s in 2usize..=3,
        ends in any::<bool>(),
        left_right in any::<bool>(),
        init in 0usize..3,
    ) {
        let data = sample_set(&truth(30), 4, 25..45, seed);
        let censoring = if ends { Censoring::EndsWithSegment } else { Censoring::RightCensored };
        let structure = if left_right { Structure::LeftRight { skip: 1 } } else { Structure::Ergodic };
        let init = [HsmmInit::KBins { smoothing: 0.05 }, HsmmInit::KMeans, HsmmInit::Random][init];
        let em = HsmmEm::builder()
            .max_iter(8)
            .tol(f64::NEG_INFINITY)
            .structure(structure)
            .censoring(censoring)
            .init(init)
            .seed(seed)
            .regularisation(Regularisation::none().with_min_weight(1e-10).unwrap())
            .build()
            .unwrap();
        let emission = Gaussian::standard(CovarianceType::Diagonal, Shape { n_states: s, dim: 2 }).unwrap();
        let fit = match em.fit(&emission, &template(family, s, 30), &data) {
            Ok(f) => f,
            // A random start can make a sequence impossible under
            // EndsWithSegment with a left-right chain; that is reported, not a defect.
            Err(HsmmError::ImpossibleSequence { .. }) => return Ok(()),
            Err(e) => return Err(TestCaseError::fail(e.to_string())),
        };
        let ll = &fit.report.log_likelihood;
        for w in ll.windows(2) {
            prop_assert!(
                w[1] >= w[0] - 1e-9 * w[0].abs().max(1.0),
                "log-likelihood fell from {} to {} (family {family}): {ll:?}", w[0], w[1]
            );
        }
    }

    /// With a duration pseudo-count and an inverse-Wishart prior, EM
    /// increases the penalised objective `log p(X) + log prior`.
    #[test]
    fn em_with_priors_is_monotone_in_the_objective(seed in any::<u64>(), ends in any::<bool>()) {
        let data = sample_set(&truth(30), 4, 25..45, seed);
        let censoring = if ends { Censoring::EndsWithSegment } else { Censoring::RightCensored };
        let em = HsmmEm::builder()
            .max_iter(8)
            .tol(f64::NEG_INFINITY)
            .censoring(censoring)
            .regularisation(Regularisation::inverse_wishart(0.1, 4.0).unwrap())
            .duration_regularisation(DurationRegularisation::none().with_pseudo_count(0.5).unwrap())
            .build()
            .unwrap();
        let emission = Gaussian::standard(CovarianceType::Full, Shape { n_states: 3, dim: 2 }).unwrap();
        let fit = em.fit(&emission, &template(0, 3, 30), &data).unwrap();
        let obj = &fit.report.objective;
        for w in obj.windows(2) {
            prop_assert!(w[1] >= w[0] - 1e-9 * w[0].abs().max(1.0), "{obj:?}");
        }
    }
}

/// The E-step runs in blocks whose statistics are merged in a fixed order:
/// 1 and 4 threads give bit-identical fits.
#[test]
fn one_thread_and_four_threads_are_bit_identical() {
    let data = sample_set(&truth(40), 300, 30..60, 11);
    assert!(data.total_frames() > 3 * 4096, "several E-step blocks");
    let fit = |threads| {
        HsmmEm::builder()
            .max_iter(3)
            .tol(f64::NEG_INFINITY)
            .threads(threads)
            .build()
            .unwrap()
            .fit(
                &Gaussian::standard(
                    CovarianceType::Full,
                    Shape {
                        n_states: 3,
                        dim: 2,
                    },
                )
                .unwrap(),
                &template(1, 3, 40),
                &data,
            )
            .unwrap()
    };
    let (a, b) = (fit(1), fit(4));
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(
        bits(&a.report.log_likelihood),
        bits(&b.report.log_likelihood)
    );
    assert_eq!(
        serde_json::to_string(&a.model).unwrap(),
        serde_json::to_string(&b.model).unwrap()
    );
}

/// EM recovers the durations and the segmentation of generated data.
#[test]
fn em_recovers_known_durations() {
    let m = truth(40);
    let data = sample_set(&m, 40, 40..55, 3);
    for family in 0..4 {
        let fit = HsmmEm::builder()
            .structure(Structure::LeftRight { skip: 0 })
            .max_iter(60)
            .regularisation(Regularisation::add_diagonal(1e-3).unwrap())
            .duration_regularisation(
                DurationRegularisation::none()
                    .with_pseudo_count(1e-3)
                    .unwrap(),
            )
            .build()
            .unwrap()
            .fit(
                &Gaussian::standard(
                    CovarianceType::Diagonal,
                    Shape {
                        n_states: 3,
                        dim: 2,
                    },
                )
                .unwrap(),
                &template(family, 3, 40),
                &data,
            )
            .unwrap();
        let means = fit.model.mean_durations();
        // The last phase is censored by the sequence end: only the first two are identifiable.
        assert!((means[0] - 8.0).abs() < 1.5, "family {family}: {means:?}");
        assert!((means[1] - 20.0).abs() < 2.0, "family {family}: {means:?}");
        let fitted_means = fit.model.emission().means();
        assert!((fitted_means[2] - 2.0).abs() < 0.2, "{fitted_means:?}");
    }
}

/// Frozen parts stay bit for bit; statistics of another shape are refused.
#[test]
fn freezing_and_statistics_checks() {
    let m = truth(30);
    let data = sample_set(&m, 5, 30..40, 5);
    let em = HsmmEm::builder()
        .max_iter(3)
        .update(HsmmUpdate {
            durations: false,
            emission: false,
            ..HsmmUpdate::default()
        })
        .build()
        .unwrap();
    let fit = em.fit_from(m.clone(), &data).unwrap();
    assert_eq!(fit.model.durations(), m.durations());
    assert_eq!(
        serde_json::to_string(fit.model.emission()).unwrap(),
        serde_json::to_string(m.emission()).unwrap()
    );
    let mut stats = m.expected_statistics(&data).unwrap();
    stats.durations.pop();
    let err = m
        .maximise(
            &stats,
            HsmmUpdate::default(),
            &Regularisation::none(),
            &DurationRegularisation::none(),
        )
        .unwrap_err();
    assert!(err.to_string().contains("duration statistics"), "{err}");
    let mut stats = m.expected_statistics(&data).unwrap();
    stats.transitions[1] = f64::NAN;
    assert!(m
        .maximise(
            &stats,
            HsmmUpdate::default(),
            &Regularisation::none(),
            &DurationRegularisation::none()
        )
        .is_err());
    let other = truth(20).expected_statistics(&data).unwrap();
    let mut stats = m.expected_statistics(&data).unwrap();
    assert!(stats.merge(&other).is_err());
}

#[test]
fn settings_are_validated() {
    assert!(HsmmEm::builder().restarts(0).build().is_err());
    assert!(HsmmEm::builder().tol(f64::NAN).build().is_err());
    assert!(HsmmEm::builder().threads(0).build().is_err());
    assert!(HsmmEm::builder()
        .init(HsmmInit::KBins { smoothing: 1.5 })
        .build()
        .is_err());
    let em = HsmmEm::builder().max_iter(7).seed(3).build().unwrap();
    let json = serde_json::to_string(&em).unwrap();
    assert_eq!(serde_json::from_str::<HsmmEm>(&json).unwrap(), em);
    let bad = json.replace("\"restarts\":1", "\"restarts\":0");
    assert!(serde_json::from_str::<HsmmEm>(&bad).is_err());
    assert!(DurationRegularisation::none().with_min_std(0.0).is_err());
    assert!(DurationRegularisation::none()
        .with_pseudo_count(-1.0)
        .is_err());
    // A template whose state count differs from the emission's.
    let data = sample_set(&truth(30), 3, 30..40, 1);
    let err = HsmmEm::default()
        .fit(
            &Gaussian::standard(
                CovarianceType::Diagonal,
                Shape {
                    n_states: 3,
                    dim: 2,
                },
            )
            .unwrap(),
            &template(0, 2, 30),
            &data,
        )
        .unwrap_err();
    assert!(
        err.to_string().contains("2 duration distributions"),
        "{err}"
    );
}

/// Restarts keep the best run and report every run's objective.
#[test]
fn restarts_keep_the_best_run() {
    let data = sample_set(&truth(30), 6, 30..40, 9);
    let fit = HsmmEm::builder()
        .max_iter(10)
        .restarts(3)
        .build()
        .unwrap()
        .fit(
            &Gaussian::standard(
                CovarianceType::Diagonal,
                Shape {
                    n_states: 3,
                    dim: 2,
                },
            )
            .unwrap(),
            &template(1, 3, 30),
            &data,
        )
        .unwrap();
    assert_eq!(fit.report.restarts.len(), 3);
    let best = fit
        .report
        .restarts
        .iter()
        .flatten()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    assert_eq!(*fit.report.objective.last().unwrap(), best);
    assert_eq!(fit.report.restarts[fit.report.best_restart], Some(best));
    assert_eq!(fit.report.duration_steps.len(), fit.report.iterations);
    assert_eq!(fit.model.durations().n_states(), 3);
}

/// Missing values (NaN) are scored on the observed dimensions and their
/// expected statistics enter the M-step: EM stays monotone and recovers
/// the model from data with 15 % of the values missing.
#[test]
fn em_with_missing_values_is_monotone() {
    let m = truth(40);
    let mut r = rng(8);
    let seqs: Vec<Vec<f64>> = (0..30)
        .map(|_| {
            let mut x = m.sample(45, &mut r).unwrap().0;
            for v in x.iter_mut() {
                if r.random::<f64>() < 0.15 {
                    *v = f64::NAN;
                }
            }
            x
        })
        .collect();
    let data = SequenceSet::new(&seqs, 2).unwrap();
    assert!(data.has_missing());
    let fit = HsmmEm::builder()
        .structure(Structure::LeftRight { skip: 0 })
        .max_iter(25)
        .tol(f64::NEG_INFINITY)
        .build()
        .unwrap()
        .fit(
            &Gaussian::standard(
                CovarianceType::Diagonal,
                Shape {
                    n_states: 3,
                    dim: 2,
                },
            )
            .unwrap(),
            &template(0, 3, 40),
            &data,
        )
        .unwrap();
    let ll = &fit.report.log_likelihood;
    for w in ll.windows(2) {
        assert!(w[1] >= w[0] - 1e-9 * w[0].abs(), "{ll:?}");
    }
    let means = fit.model.emission().means();
    for (got, want) in means.iter().zip([0.0, 0.0, 2.0, 1.0, 0.5, 2.0]) {
        assert!((got - want).abs() < 0.25, "{means:?}");
    }
    let d = fit.model.mean_durations();
    assert!(
        (d[0] - 8.0).abs() < 1.5 && (d[1] - 20.0).abs() < 2.5,
        "{d:?}"
    );
}
