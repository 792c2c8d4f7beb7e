//! Monte-Carlo checks of sampling, serde round-trips and refusals, k-means and
//! frame validation.

// Index loops mirror the formulas they check (several arrays indexed alike).
#![allow(clippy::needless_range_loop)]

use crate::common;

use common::*;
use nalgebra::{DMatrix, DVector};
use phasekit_emission::kmeans::{kmeans, lloyd, Seeding};
use phasekit_emission::{
    Categorical, CovarianceType, Emission, EmissionError, Frames, Gaussian, MixtureEmission,
    Poisson, SequenceSet, Shape,
};
use proptest::prelude::*;
use rand::Rng;

const N: usize = 20_000;
/// Every Monte-Carlo estimate must lie within this many standard errors.
const Z: f64 = 4.5;

fn draw<E: Emission>(e: &E, state: usize, n: usize, seed: u64) -> Vec<DVector<f64>> {
    let mut r = rng(seed);
    let mut buf = vec![0.0; e.dim()];
    (0..n)
        .map(|_| {
            e.sample_into(state, &mut r, &mut buf).unwrap();
            DVector::from_column_slice(&buf)
        })
        .collect()
}

fn sample_moments(xs: &[DVector<f64>]) -> (DVector<f64>, DMatrix<f64>) {
    let n = xs.len() as f64;
    let d = xs[0].len();
    let mean = xs.iter().fold(DVector::zeros(d), |a, x| a + x) / n;
    let cov = xs.iter().fold(DMatrix::zeros(d, d), |a, x| {
        let e = x - &mean;
        a + &e * e.transpose()
    }) / (n - 1.0);
    (mean, cov)
}

// ---------------------------------------------------------------------------
// Sampling
// ---------------------------------------------------------------------------

#[test]
fn gaussian_samples_have_the_model_mean_and_covariance() {
    let mut r = rng(100);
    for kind in KINDS {
        let rg = random_gaussian(kind, 2, 3, &mut r);
        for state in 0..2 {
            let xs = draw(&rg.model, state, N, 7 + state as u64);
            let (mean, cov) = sample_moments(&xs);
            let sigma = &rg.covs[state];
            let n = N as f64;
            for k in 0..3 {
                let se = (sigma[(k, k)] / n).sqrt();
                assert!(
                    (mean[k] - rg.means[state][k]).abs() <= Z * se,
                    "{kind:?} state {state} mean {k}: {} vs {} (se {se})",
                    mean[k],
                    rg.means[state][k]
                );
            }
            for a in 0..3 {
                for b in 0..3 {
                    // Var of a Gaussian sample covariance entry: (Σ_aa Σ_bb + Σ_ab²) / n.
                    let se = ((sigma[(a, a)] * sigma[(b, b)] + sigma[(a, b)].powi(2)) / n).sqrt();
                    assert!(
                        (cov[(a, b)] - sigma[(a, b)]).abs() <= Z * se,
                        "{kind:?} state {state} cov ({a},{b}): {} vs {} (se {se})",
                        cov[(a, b)],
                        sigma[(a, b)]
                    );
                }
            }
        }
        let mut out = vec![0.0; 3];
        assert!(rg.model.sample_into(2, &mut r, &mut out).is_err());
        assert!(rg.model.sample_into(0, &mut r, &mut [0.0; 2]).is_err());
    }
}

#[test]
fn categorical_sample_frequencies_match_probabilities() {
    let p = vec![0.1, 0.2, 0.3, 0.4, 0.7, 0.0, 0.25, 0.05];
    let c = Categorical::new(4, p.clone()).unwrap();
    for state in 0..2 {
        let xs = draw(&c, state, N, 3 + state as u64);
        for j in 0..4 {
            let pj = p[state * 4 + j];
            let freq = xs.iter().filter(|x| x[0] == j as f64).count() as f64 / N as f64;
            let se = (pj * (1.0 - pj) / N as f64).sqrt();
            assert!(
                (freq - pj).abs() <= Z * se,
                "state {state} symbol {j}: {freq} vs {pj}"
            );
            if pj == 0.0 {
                assert_eq!(freq, 0.0, "a zero-probability symbol was drawn");
            }
        }
    }
    assert!(c.sample_into(2, &mut rng(0), &mut [0.0]).is_err());
    assert!(c.sample_into(0, &mut rng(0), &mut [0.0; 2]).is_err());
}

#[test]
fn poisson_sample_means_and_variances_match_rates() {
    let rates = vec![0.3, 4.0, 25.0, 1.0, 0.0, 150.0];
    let p = Poisson::new(3, rates.clone()).unwrap();
    for state in 0..2 {
        let xs = draw(&p, state, N, 11 + state as u64);
        let (mean, cov) = sample_moments(&xs);
        let n = N as f64;
        for k in 0..3 {
            let lam = rates[state * 3 + k];
            assert!(xs.iter().all(|x| x[k] >= 0.0 && x[k].fract() == 0.0));
            assert!(
                (mean[k] - lam).abs() <= Z * (lam / n).sqrt(),
                "mean {} vs rate {lam}",
                mean[k]
            );
            // Var of the sample variance of a Poisson: (λ + 2 λ²) / n (fourth central moment λ + 3λ²).
            let se = ((lam + 2.0 * lam * lam) / n).sqrt();
            assert!(
                (cov[(k, k)] - lam).abs() <= Z * se,
                "variance {} vs rate {lam}",
                cov[(k, k)]
            );
        }
    }
}

#[test]
fn mixture_samples_have_the_mixture_mean_and_covariance() {
    let mut r = rng(55);
    let comps: Vec<RandomGaussian> = (0..2)
        .map(|_| random_gaussian(CovarianceType::Full, 3, 2, &mut r))
        .collect();
    let w = vec![0.2, 0.5, 0.3, 0.6, 0.0, 0.4];
    let mix =
        MixtureEmission::new(w.clone(), comps.iter().map(|c| c.model.clone()).collect()).unwrap();
    for state in 0..2 {
        let c = &comps[state];
        let ws = &w[state * 3..(state + 1) * 3];
        let mean: DVector<f64> = (0..3).fold(DVector::zeros(2), |a, m| a + &c.means[m] * ws[m]);
        // Law of total covariance.
        let cov: DMatrix<f64> = (0..3).fold(DMatrix::zeros(2, 2), |a, m| {
            let e = &c.means[m] - &mean;
            a + (&c.covs[m] + &e * e.transpose()) * ws[m]
        });
        let xs = draw(&mix, state, N, 9 + state as u64);
        let (m_hat, c_hat) = sample_moments(&xs);
        let n = N as f64;
        for k in 0..2 {
            assert!(
                (m_hat[k] - mean[k]).abs() <= Z * (cov[(k, k)] / n).sqrt(),
                "mean {} vs {}",
                m_hat[k],
                mean[k]
            );
        }
        // Variances: the sample variance has standard error sqrt((μ4 − σ⁴)/n); bound μ4
        // from the samples themselves.
        for k in 0..2 {
            let mu4 = xs.iter().map(|x| (x[k] - mean[k]).powi(4)).sum::<f64>() / n;
            let se = ((mu4 - cov[(k, k)].powi(2)).max(0.0) / n).sqrt();
            assert!(
                (c_hat[(k, k)] - cov[(k, k)]).abs() <= Z * se,
                "var {} vs {}",
                c_hat[(k, k)],
                cov[(k, k)]
            );
        }
    }
    assert!(mix.sample_into(2, &mut r, &mut [0.0; 2]).is_err());
}

// ---------------------------------------------------------------------------
// Serde
// ---------------------------------------------------------------------------

fn roundtrip<E>(e: &E, frames: Frames<'_>)
where
    E: Emission + serde::Serialize + serde::de::DeserializeOwned,
{
    let json = serde_json::to_string(e).unwrap();
    let back: E = serde_json::from_str(&json).unwrap();
    let (a, b) = (
        e.log_density(frames).unwrap(),
        back.log_density(frames).unwrap(),
    );
    for (x, y) in a.iter().zip(&b) {
        assert!(
            x.to_bits() == y.to_bits(),
            "log-density changed by a JSON round-trip: {x} vs {y}\n{json}"
        );
    }
    assert_eq!(serde_json::to_string(&back).unwrap(), json);
    assert_eq!(back.n_states(), e.n_states());
    assert_eq!(back.dim(), e.dim());
}

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0x5a3b_11e0), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(24) })]

    #[test]
    fn serde_roundtrip_preserves_log_densities(seed in any::<u64>(), d in 1usize..=4, s in 1usize..=3) {
        let mut r = rng(seed);
        let data = random_frames(8, d, 2.0, &mut r);
        let frames = Frames::new(&data, d).unwrap();
        for kind in KINDS {
            let g = random_gaussian(kind, s, d, &mut r).model;
            roundtrip(&g, frames);
            let comps: Vec<Gaussian> = (0..s).map(|_| random_gaussian(kind, 2, d, &mut r).model).collect();
            let w: Vec<f64> = (0..s).flat_map(|_| { let a = r.random_range(0.05..0.95); [a, 1.0 - a] }).collect();
            roundtrip(&MixtureEmission::new(w, comps).unwrap(), frames);
        }
        let k = d + 2;
        let mut probs = Vec::new();
        for _ in 0..s {
            let row: Vec<f64> = (0..k).map(|_| r.random_range(0.01..1.0)).collect();
            let sum: f64 = row.iter().sum();
            probs.extend(row.iter().map(|v| v / sum));
        }
        let symbols: Vec<f64> = (0..10).map(|_| r.random_range(0..k) as f64).collect();
        roundtrip(&Categorical::new(k, probs).unwrap(), Frames::new(&symbols, 1).unwrap());
        let rates: Vec<f64> = (0..s * d).map(|_| r.random_range(0.0..10.0)).collect();
        let counts: Vec<f64> = (0..8 * d).map(|_| r.random_range(0..12u32) as f64).collect();
        roundtrip(&Poisson::new(d, rates).unwrap(), Frames::new(&counts, d).unwrap());
    }
}

fn refused<E: serde::de::DeserializeOwned + std::fmt::Debug>(json: serde_json::Value, why: &str) {
    let text = json.to_string();
    match serde_json::from_str::<E>(&text) {
        Err(_) => {}
        Ok(v) => panic!("{why}: accepted {text} as {v:?}"),
    }
}

#[test]
fn serde_refuses_invalid_parameters() {
    use serde_json::json;
    let g = |kind: &str, dim: usize, means: serde_json::Value, covs: serde_json::Value| json!({"covariance_type": kind, "n_states": means.as_array().unwrap().len() / dim.max(1), "dim": dim, "means": means, "covariances": covs});
    // Sanity: the well-formed versions are accepted (also the "diag" alias).
    for (kind, covs) in [
        ("full", json!([2.0, 0.5, 0.5, 1.0])),
        ("tied", json!([2.0, 0.5, 0.5, 1.0])),
        ("diagonal", json!([2.0, 1.0])),
        ("diag", json!([2.0, 1.0])),
        ("spherical", json!([2.0])),
    ] {
        serde_json::from_value::<Gaussian>(g(kind, 2, json!([0.0, 1.0]), covs)).unwrap();
    }
    refused::<Gaussian>(
        g("full", 2, json!([0.0, 1.0]), json!([1.0, 2.0, 2.0, 1.0])),
        "not positive definite",
    );
    refused::<Gaussian>(
        g("full", 2, json!([0.0, 1.0]), json!([1.0, 0.0, 0.0, 0.0])),
        "singular",
    );
    refused::<Gaussian>(
        g("full", 2, json!([0.0, 1.0]), json!([2.0, 0.5, 0.4, 1.0])),
        "asymmetric",
    );
    refused::<Gaussian>(
        g("tied", 2, json!([0.0, 1.0]), json!([2.0, 0.5, -0.5, 1.0])),
        "asymmetric tied",
    );
    refused::<Gaussian>(
        g("diagonal", 2, json!([0.0, 1.0]), json!([2.0, -1.0])),
        "negative variance",
    );
    refused::<Gaussian>(
        g("diagonal", 2, json!([0.0, 1.0]), json!([2.0, 0.0])),
        "zero variance",
    );
    refused::<Gaussian>(
        g("spherical", 2, json!([0.0, 1.0]), json!([-2.0])),
        "negative spherical variance",
    );
    refused::<Gaussian>(
        g("full", 2, json!([0.0, 1.0]), json!([2.0, 0.5, 0.5])),
        "wrong covariance length",
    );
    refused::<Gaussian>(
        g(
            "full",
            2,
            json!([0.0, 1.0, 2.0]),
            json!([2.0, 0.5, 0.5, 1.0]),
        ),
        "ragged means",
    );
    refused::<Gaussian>(
        g("full", 2, json!([0.0, null]), json!([2.0, 0.5, 0.5, 1.0])),
        "null mean",
    );
    refused::<Gaussian>(g("full", 0, json!([]), json!([])), "zero dimension");
    refused::<Gaussian>(
        g("banana", 2, json!([0.0, 1.0]), json!([2.0])),
        "unknown covariance type",
    );
    refused::<Gaussian>(
        json!({"covariance_type": "full", "n_states": 2, "dim": 2, "means": [0.0, 1.0], "covariances": [1.0, 0.0, 0.0, 1.0]}),
        "n_states disagrees with the means",
    );
    assert!(serde_json::from_str::<Gaussian>(
        r#"{"covariance_type": "full", "n_states": 1, "dim": 2, "means": [0.0, 1e400], "covariances": [1.0, 0.0, 0.0, 1.0]}"#
    )
    .is_err());

    serde_json::from_value::<Categorical>(json!({"n_symbols": 2, "probabilities": [0.25, 0.75]}))
        .unwrap();
    refused::<Categorical>(
        json!({"n_symbols": 2, "probabilities": [0.25, 0.7]}),
        "row does not sum to 1",
    );
    refused::<Categorical>(
        json!({"n_symbols": 2, "probabilities": [1.25, -0.25]}),
        "negative probability",
    );
    refused::<Categorical>(
        json!({"n_symbols": 2, "probabilities": [0.5, 0.5, 1.0]}),
        "ragged rows",
    );
    refused::<Categorical>(json!({"n_symbols": 0, "probabilities": []}), "no symbols");

    serde_json::from_value::<Poisson>(json!({"dim": 2, "rates": [0.0, 3.0]})).unwrap();
    refused::<Poisson>(json!({"dim": 2, "rates": [-1.0, 3.0]}), "negative rate");
    refused::<Poisson>(json!({"dim": 2, "rates": [1.0, 3.0, 2.0]}), "ragged rates");
    refused::<Poisson>(json!({"dim": 0, "rates": []}), "zero dimension");

    let comp = serde_json::to_value(
        Gaussian::standard(
            CovarianceType::Diagonal,
            Shape {
                n_states: 2,
                dim: 1,
            },
        )
        .unwrap(),
    )
    .unwrap();
    let comp3 = serde_json::to_value(
        Gaussian::standard(
            CovarianceType::Diagonal,
            Shape {
                n_states: 3,
                dim: 1,
            },
        )
        .unwrap(),
    )
    .unwrap();
    let comp_d2 = serde_json::to_value(
        Gaussian::standard(
            CovarianceType::Diagonal,
            Shape {
                n_states: 2,
                dim: 2,
            },
        )
        .unwrap(),
    )
    .unwrap();
    serde_json::from_value::<MixtureEmission<Gaussian>>(
        json!({"weights": [0.5, 0.5], "components": [comp]}),
    )
    .unwrap();
    refused::<MixtureEmission<Gaussian>>(
        json!({"weights": [0.5, 0.6], "components": [comp]}),
        "weights do not sum to 1",
    );
    refused::<MixtureEmission<Gaussian>>(
        json!({"weights": [0.5, 0.5], "components": []}),
        "no states",
    );
    refused::<MixtureEmission<Gaussian>>(
        json!({"weights": [0.5, 0.5, 0.2, 0.3, 0.5], "components": [comp, comp3]}),
        "different component counts",
    );
    refused::<MixtureEmission<Gaussian>>(
        json!({"weights": [0.5, 0.5, 0.5, 0.5], "components": [comp, comp_d2]}),
        "different component dimensions",
    );
    let mut bad_comp = comp.clone();
    bad_comp["covariances"] = json!([1.0, -1.0]);
    refused::<MixtureEmission<Gaussian>>(
        json!({"weights": [0.5, 0.5], "components": [bad_comp]}),
        "invalid component",
    );
}

#[test]
fn constructors_refuse_invalid_parameters() {
    assert!(Gaussian::full(2, vec![0.0, 0.0], vec![1.0, 2.0, 2.0, 1.0]).is_err());
    assert!(matches!(
        Gaussian::diagonal(2, vec![0.0; 4], vec![1.0, 1.0, 1.0, -3.0]),
        Err(EmissionError::NotPositiveDefinite { state: 1, .. })
    ));
    assert!(matches!(
        Gaussian::full(
            2,
            vec![0.0; 4],
            vec![1.0, 0.0, 0.0, 1.0, 1.0, 2.0, 2.0, 1.0]
        ),
        Err(EmissionError::NotPositiveDefinite { state: 1, .. })
    ));
    assert!(Gaussian::spherical(2, vec![f64::NAN, 0.0], vec![1.0]).is_err());
    assert!(Gaussian::spherical(2, vec![0.0, 0.0], vec![f64::INFINITY]).is_err());
    assert!(Gaussian::tied(2, vec![], vec![1.0, 0.0, 0.0, 1.0]).is_err());
    assert!(Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 0,
            dim: 2
        }
    )
    .is_err());
    assert!(Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 2,
            dim: 0
        }
    )
    .is_err());
    assert!(Categorical::new(2, vec![0.5, f64::NAN]).is_err());
    assert!(MixtureEmission::<Gaussian>::new(vec![], vec![]).is_err());
    assert!(phasekit_emission::Regularisation::add_diagonal(-1.0).is_err());
    assert!(phasekit_emission::Regularisation::add_diagonal(f64::NAN).is_err());
    assert!(phasekit_emission::Regularisation::inverse_wishart(0.0, 1.0).is_err());
    assert!(phasekit_emission::Regularisation::inverse_wishart(1.0, -1.0).is_err());
    assert!(phasekit_emission::Regularisation::none()
        .with_max_jitter(f64::INFINITY)
        .is_err());
}

// ---------------------------------------------------------------------------
// k-means
// ---------------------------------------------------------------------------

/// `k` blobs of `per` points (spread 1) around centres 100 apart; returns the data and true blob of each frame.
fn blobs<R: Rng + ?Sized>(k: usize, per: usize, d: usize, rng: &mut R) -> (Vec<f64>, Vec<usize>) {
    let centres: Vec<Vec<f64>> = (0..k)
        .map(|j| {
            (0..d)
                .map(|c| {
                    if c == 0 {
                        100.0 * j as f64
                    } else {
                        rng.random_range(-10.0..10.0)
                    }
                })
                .collect()
        })
        .collect();
    let mut order: Vec<usize> = (0..k * per).map(|i| i % k).collect();
    rand::seq::SliceRandom::shuffle(order.as_mut_slice(), rng);
    let data = order
        .iter()
        .flat_map(|&j| {
            centres[j]
                .iter()
                .map(|c| c + normal(rng))
                .collect::<Vec<_>>()
        })
        .collect();
    (data, order)
}

fn check_consistent(frames: Frames<'_>, res: &phasekit_emission::kmeans::KMeans, k: usize) {
    let d = frames.dim();
    assert_eq!(res.centroids.len(), k * d);
    assert_eq!(res.labels.len(), frames.len());
    let dist = |x: &[f64], j: usize| -> f64 {
        x.iter()
            .zip(&res.centroids[j * d..(j + 1) * d])
            .map(|(a, b)| (a - b).powi(2))
            .sum()
    };
    let mut inertia = 0.0;
    for (t, x) in frames.iter().enumerate() {
        let own = dist(x, res.labels[t]);
        for j in 0..k {
            assert!(
                own <= dist(x, j) * (1.0 + 1e-12),
                "frame {t} is closer to centroid {j} than to its label {}",
                res.labels[t]
            );
        }
        inertia += own;
    }
    assert!(
        close(res.inertia, inertia, 1e-9),
        "inertia {} vs recomputed {inertia}",
        res.inertia
    );
}

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0x5a3b_11e0), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(24) })]

    #[test]
    fn kmeans_recovers_separated_blobs(seed in any::<u64>(), k in 1usize..=4, d in 1usize..=3) {
        let mut r = rng(seed);
        let per = 15;
        let (data, truth) = blobs(k, per, d, &mut r);
        let frames = Frames::new(&data, d).unwrap();
        let res = kmeans(frames, k, Seeding::PlusPlus, 100, &mut rng(seed ^ 1)).unwrap();
        // Labels equal the truth up to a permutation.
        let mut map = vec![usize::MAX; k];
        for (t, &j) in truth.iter().enumerate() {
            if map[j] == usize::MAX {
                map[j] = res.labels[t];
            }
            prop_assert_eq!(map[j], res.labels[t], "blob {} split", j);
        }
        let mut seen = map.clone();
        seen.sort_unstable();
        seen.dedup();
        prop_assert_eq!(seen.len(), k, "two blobs merged");
        // Each centroid is the mean of its blob.
        for j in 0..k {
            let members: Vec<usize> = (0..truth.len()).filter(|&t| truth[t] == j).collect();
            for c in 0..d {
                let m = members.iter().map(|&t| data[t * d + c]).sum::<f64>() / members.len() as f64;
                prop_assert!(close(res.centroids[map[j] * d + c], m, 1e-9));
            }
        }
        check_consistent(frames, &res, k);
        // Same seed, same result (both seedings).
        for seeding in [Seeding::PlusPlus, Seeding::Random] {
            let a = kmeans(frames, k, seeding, 100, &mut rng(seed ^ 2)).unwrap();
            let b = kmeans(frames, k, seeding, 100, &mut rng(seed ^ 2)).unwrap();
            prop_assert_eq!(&a, &b);
            check_consistent(frames, &a, k);
        }
    }

    /// Whatever the iteration budget, the result is self-consistent: every label is
    /// the nearest returned centroid and the inertia is their summed squared distance.
    #[test]
    fn kmeans_result_is_consistent_for_any_iteration_budget(seed in any::<u64>(), k in 1usize..=5, max_iter in 0usize..4, random in any::<bool>()) {
        let mut r = rng(seed);
        let data = random_frames(30, 2, 1.0, &mut r);
        let frames = Frames::new(&data, 2).unwrap();
        let seeding = if random { Seeding::Random } else { Seeding::PlusPlus };
        let res = kmeans(frames, k, seeding, max_iter, &mut r).unwrap();
        check_consistent(frames, &res, k);
        prop_assert!(res.iterations >= 1 && res.iterations <= max_iter.max(1));
        // Lloyd iterations from given centroids (the first k frames).
        let init = data[..2 * k].to_vec();
        let res = lloyd(frames, init, max_iter).unwrap();
        check_consistent(frames, &res, k);
    }
}

#[test]
fn kmeans_refuses_too_few_frames_and_handles_duplicates() {
    let data = [0.0, 1.0, 2.0];
    let frames = Frames::new(&data, 1).unwrap();
    assert!(matches!(
        kmeans(frames, 4, Seeding::PlusPlus, 10, &mut rng(0)),
        Err(EmissionError::InvalidParameter { .. })
    ));
    assert!(kmeans(frames, 4, Seeding::Random, 10, &mut rng(0)).is_err());
    assert!(kmeans(frames, 0, Seeding::PlusPlus, 10, &mut rng(0)).is_err());
    let none: [f64; 0] = [];
    assert!(kmeans(
        Frames::new(&none, 2).unwrap(),
        1,
        Seeding::PlusPlus,
        10,
        &mut rng(0)
    )
    .is_err());
    // All frames identical: no panic, zero inertia.
    let same = [1.5; 10];
    for seeding in [Seeding::PlusPlus, Seeding::Random] {
        let res = kmeans(Frames::new(&same, 2).unwrap(), 3, seeding, 10, &mut rng(1)).unwrap();
        assert_eq!(res.inertia, 0.0);
        check_consistent(Frames::new(&same, 2).unwrap(), &res, 3);
    }
}

// ---------------------------------------------------------------------------
// Frames and sequence sets
// ---------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig { rng_seed: match std::env::var_os("PROPTEST_RNG_SEED") { None => proptest::test_runner::RngSeed::Fixed(0x5a3b_11e0), Some(_) => ProptestConfig::default().rng_seed }, ..ProptestConfig::with_cases(48) })]

    #[test]
    fn frames_report_the_first_non_finite_value(t in 1usize..20, d in 1usize..5, pos_seed in any::<u64>(), which in 0usize..2) {
        let mut r = rng(pos_seed);
        let mut data = random_frames(t, d, 1.0, &mut r);
        let pos = r.random_range(0..t * d);
        let bad = [f64::INFINITY, f64::NEG_INFINITY][which];
        data[pos] = bad;
        if pos > 0 {
            data[0] = f64::NAN; // an earlier missing value (NaN) is not an error
        }
        if pos + 1 < t * d {
            data[t * d - 1] = f64::INFINITY; // a later bad value must not be the one reported
        }
        match Frames::new(&data, d) {
            Err(EmissionError::InvalidValue { frame, column, value, .. }) => {
                prop_assert_eq!((frame, column), (pos / d, pos % d));
                prop_assert!(value.to_bits() == bad.to_bits());
            }
            other => prop_assert!(false, "expected InvalidValue, got {:?}", other),
        }
        // The same data wrapped in a sequence set names the sequence as well.
        let good = vec![0.0; d];
        let err = SequenceSet::new(&[good, data], d).unwrap_err();
        let msg = err.to_string();
        let needle = format!("sequence 1, frame {}, column {}", pos / d, pos % d);
        prop_assert!(msg.contains(&needle), "{}", msg);
    }
}

#[test]
fn frames_and_sequence_sets_refuse_bad_shapes() {
    assert!(matches!(
        Frames::new(&[1.0, 2.0, 3.0], 2),
        Err(EmissionError::DimensionMismatch { found: 3, .. })
    ));
    assert!(matches!(
        Frames::new(&[1.0], 0),
        Err(EmissionError::InvalidParameter { .. })
    ));
    assert!(Frames::new(&[], 3).unwrap().is_empty());
    let f = Frames::new(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], 3).unwrap();
    assert_eq!((f.len(), f.dim()), (2, 3));
    assert_eq!(f.frame(1), &[4.0, 5.0, 6.0]);
    assert_eq!(f.slice(1..2).as_slice(), &[4.0, 5.0, 6.0]);

    assert!(SequenceSet::new(&[vec![1.0, 2.0], vec![1.0, 2.0, 3.0]], 2)
        .unwrap_err()
        .to_string()
        .contains("sequence 1"));
    assert!(SequenceSet::new(&[vec![1.0, 2.0], vec![]], 2)
        .unwrap_err()
        .to_string()
        .contains("sequence 1 is empty"));
    assert!(SequenceSet::new(&[vec![1.0]], 0).is_err());
    assert!(SequenceSet::new::<Vec<f64>>(&[], 0).is_err());

    let set = SequenceSet::new(&[vec![1.0, 2.0, 3.0, 4.0], vec![5.0, 6.0]], 2).unwrap();
    assert_eq!(set.len(), 2);
    assert_eq!(set.total_frames(), 3);
    assert_eq!(set.lengths().collect::<Vec<_>>(), vec![2, 1]);
    assert_eq!(set.get(1).as_slice(), &[5.0, 6.0]);
    assert_eq!(set.all_frames().as_slice(), &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    let cols = set.select_columns(&[1, 0]).unwrap();
    assert_eq!(
        cols.all_frames().as_slice(),
        &[2.0, 1.0, 4.0, 3.0, 6.0, 5.0]
    );
    assert_eq!(cols.lengths().collect::<Vec<_>>(), vec![2, 1]);
    assert!(matches!(
        set.select_columns(&[0, 0]),
        Err(EmissionError::InvalidDims { .. })
    ));
    assert!(matches!(
        set.select_columns(&[2]),
        Err(EmissionError::InvalidDims { .. })
    ));
    let sub = set.subset(&[1, 0]).unwrap();
    assert_eq!(sub.all_frames().as_slice(), &[5.0, 6.0, 1.0, 2.0, 3.0, 4.0]);
    assert!(set.subset(&[2]).is_err());
}
