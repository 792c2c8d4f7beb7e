//! Baum-Welch never decreases its objective (within `1e-9` relative) for
//! every emission family besides the full Gaussian and the categorical of
//! `tests/hmm_properties.rs`: diagonal, spherical and tied Gaussians, Poisson
//! counts and Gaussian mixtures per state (GMM-HMM). The objective is
//! `log p(X)` with regularisation off, and `log p(X) + log prior` under an
//! inverse-Wishart prior (and Dirichlet pseudo-counts on the mixture weights).
//!
//! Small random models and data are drawn from a `ChaCha8Rng` seeded by
//! proptest, which itself runs from a fixed seed (override with
//! `PROPTEST_RNG_SEED`), so every run is reproducible.

use phasekit::emission::{
    CovarianceType, Emission, EmissionError, Gaussian, MixtureEmission, Poisson, Regularisation,
    SequenceSet,
};
use phasekit::hmm::{BaumWelch, Hmm, HmmError};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::with_cases(cases);
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x30e0_70e5);
    }
    c.failure_persistence = None;
    c
}

/// `rows × cols` row-stochastic matrix with entries bounded away from zero.
fn stochastic_rows(rng: &mut ChaCha8Rng, rows: usize, cols: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(rows * cols);
    for _ in 0..rows {
        let row: Vec<f64> = (0..cols).map(|_| rng.random_range(0.05..1.0)).collect();
        let total: f64 = row.iter().sum();
        out.extend(row.iter().map(|v| v / total));
    }
    out
}

fn random_chain(rng: &mut ChaCha8Rng, s: usize) -> (Vec<f64>, Vec<f64>) {
    (stochastic_rows(rng, 1, s), stochastic_rows(rng, s, s))
}

/// A random Gaussian emission of the given covariance structure, with means
/// spread over `[-spread, spread]`.
fn random_gaussian(
    rng: &mut ChaCha8Rng,
    kind: CovarianceType,
    s: usize,
    d: usize,
    spread: f64,
) -> Gaussian {
    let means: Vec<f64> = (0..s * d)
        .map(|_| rng.random_range(-spread..spread))
        .collect();
    let covs = match kind {
        CovarianceType::Diagonal => (0..s * d).map(|_| rng.random_range(0.3..2.0)).collect(),
        CovarianceType::Spherical => (0..s).map(|_| rng.random_range(0.3..2.0)).collect(),
        CovarianceType::Tied | CovarianceType::Full => {
            let blocks = if kind == CovarianceType::Tied { 1 } else { s };
            let mut out = Vec::new();
            for _ in 0..blocks {
                // L Lᵀ with a well-conditioned lower-triangular L.
                let l: Vec<f64> = (0..d * d)
                    .map(|k| {
                        let (r, c) = (k / d, k % d);
                        if r == c {
                            rng.random_range(0.6..1.4)
                        } else if c < r {
                            rng.random_range(-0.5..0.5)
                        } else {
                            0.0
                        }
                    })
                    .collect();
                for r in 0..d {
                    for c in 0..d {
                        out.push((0..d).map(|k| l[r * d + k] * l[c * d + k]).sum::<f64>());
                    }
                }
            }
            out
        }
    };
    Gaussian::new(kind, d, means, covs).unwrap()
}

fn random_poisson(rng: &mut ChaCha8Rng, s: usize, d: usize) -> Poisson {
    Poisson::new(d, (0..s * d).map(|_| rng.random_range(0.5..12.0)).collect()).unwrap()
}

/// `m` full-covariance Gaussian components per state.
fn random_mixture(rng: &mut ChaCha8Rng, s: usize, m: usize, d: usize) -> MixtureEmission<Gaussian> {
    let comps = (0..s)
        .map(|_| random_gaussian(rng, CovarianceType::Full, m, d, 4.0))
        .collect();
    MixtureEmission::new(stochastic_rows(rng, s, m), comps).unwrap()
}

/// Four sequences of 15–30 frames sampled from `truth`.
fn sample<E: Emission>(truth: &Hmm<E>, rng: &mut ChaCha8Rng) -> SequenceSet {
    let seqs: Vec<Vec<f64>> = (0..4)
        .map(|_| {
            let len = rng.random_range(15..30);
            truth.sample(len, rng).unwrap().0
        })
        .collect();
    SequenceSet::new(&seqs, truth.dim()).unwrap()
}

fn assert_monotone(objective: &[f64]) -> Result<(), TestCaseError> {
    prop_assert!(objective.len() >= 2);
    for (k, w) in objective.windows(2).enumerate() {
        prop_assert!(
            w[0].is_finite() && w[1].is_finite(),
            "objective {objective:?}"
        );
        prop_assert!(
            w[1] >= w[0] - 1e-9 * w[0].abs().max(1.0),
            "objective decreased at iteration {k}: {} -> {} ({objective:?})",
            w[0],
            w[1]
        );
    }
    Ok(())
}

fn em(reg: Regularisation) -> BaumWelch {
    BaumWelch::builder()
        .max_iter(12)
        .tol(f64::NEG_INFINITY)
        .regularisation(reg)
        .build()
        .unwrap()
}

/// Maximum likelihood: `log p(X)` is non-decreasing. Unregularised ML may
/// collapse a Gaussian onto a few points; it must then say so.
fn check_ml<E: Emission>(initial: &Hmm<E>, data: &SequenceSet) -> Result<(), TestCaseError> {
    match em(Regularisation::none()).fit_from(initial.clone(), data) {
        Ok(fitted) => {
            prop_assert_eq!(fitted.report.iterations, 12);
            prop_assert_eq!(&fitted.report.objective, &fitted.report.log_likelihood);
            assert_monotone(&fitted.report.log_likelihood)
        }
        Err(HmmError::Emission {
            source: EmissionError::NotPositiveDefinite { .. },
            ..
        }) => Ok(()),
        Err(e) => Err(TestCaseError::fail(format!("ML fit failed: {e}"))),
    }
}

/// MAP: `log p(X) + log prior` is non-decreasing, and the reported prior term
/// is the emission's `log_prior` at the returned model.
fn check_map<E: Emission>(
    initial: &Hmm<E>,
    data: &SequenceSet,
    reg: Regularisation,
) -> Result<(), TestCaseError> {
    let fitted = em(reg)
        .fit_from(initial.clone(), data)
        .map_err(|e| TestCaseError::fail(format!("MAP fit failed: {e}")))?;
    prop_assert_eq!(fitted.report.iterations, 12);
    assert_monotone(&fitted.report.objective)?;
    let prior =
        fitted.report.objective.last().unwrap() - fitted.report.log_likelihood.last().unwrap();
    let want = fitted.model.emission().log_prior(&reg);
    prop_assert!(
        (prior - want).abs() <= 1e-9 * want.abs().max(1.0),
        "{prior} vs {want}"
    );
    Ok(())
}

const KINDS: [CovarianceType; 3] = [
    CovarianceType::Diagonal,
    CovarianceType::Spherical,
    CovarianceType::Tied,
];

proptest! {
    #![proptest_config(config(32))]

    #[test]
    fn gaussian_baum_welch_never_decreases(kind in 0usize..3, s in 1usize..=3, d in 1usize..=3, scale in 0.01f64..1.0, dof in 0.0f64..4.0, seed in any::<u64>()) {
        let kind = KINDS[kind];
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (start, trans) = random_chain(&mut rng, s);
        let truth = Hmm::new(start, trans, random_gaussian(&mut rng, kind, s, d, 4.0)).unwrap();
        let data = sample(&truth, &mut rng);
        let (start, trans) = random_chain(&mut rng, s);
        let initial = Hmm::new(start, trans, random_gaussian(&mut rng, kind, s, d, 2.0)).unwrap();
        check_ml(&initial, &data)?;
        // The inverse-Wishart prior is proper for ν > D − 1; the penalised
        // objective is what EM increases either way.
        check_map(&initial, &data, Regularisation::inverse_wishart(scale, dof).unwrap())?;
    }

    #[test]
    fn poisson_baum_welch_never_decreases(s in 1usize..=3, d in 1usize..=3, seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (start, trans) = random_chain(&mut rng, s);
        let truth = Hmm::new(start, trans, random_poisson(&mut rng, s, d)).unwrap();
        let data = sample(&truth, &mut rng);
        let (start, trans) = random_chain(&mut rng, s);
        let initial = Hmm::new(start, trans, random_poisson(&mut rng, s, d)).unwrap();
        // Poisson rates have no prior here: the objective is log p(X).
        let fitted = em(Regularisation::none()).fit_from(initial, &data).unwrap();
        prop_assert_eq!(fitted.report.iterations, 12);
        prop_assert_eq!(&fitted.report.objective, &fitted.report.log_likelihood);
        assert_monotone(&fitted.report.log_likelihood)?;
    }

    #[test]
    fn gmm_hmm_baum_welch_never_decreases(s in 1usize..=3, m in 1usize..=3, d in 1usize..=2, scale in 0.05f64..1.0, dof in 0.0f64..3.0, pseudo in 0.0f64..2.0, seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (start, trans) = random_chain(&mut rng, s);
        let truth = Hmm::new(start, trans, random_mixture(&mut rng, s, m, d)).unwrap();
        let data = sample(&truth, &mut rng);
        let (start, trans) = random_chain(&mut rng, s);
        let initial = Hmm::new(start, trans, random_mixture(&mut rng, s, m, d)).unwrap();
        check_ml(&initial, &data)?;
        // Inverse-Wishart on every component and a Dirichlet(1 + a) on every
        // state's mixture weights: both are priors whose mode is the M-step.
        let reg = Regularisation::inverse_wishart(scale, dof).unwrap().with_pseudo_count(pseudo).unwrap();
        check_map(&initial, &data, reg)?;
    }
}
