//! The same generic properties for EVERY emission: Gaussian (full, diagonal,
//! spherical, tied), categorical, Poisson, Student-t (per-state route, ν
//! estimated), a mixture of Gaussians per state (GMM-HMM) and the plug-in of
//! `examples/plugin` (independent Laplace dims, written outside the workspace).
//!
//! Written once ([`check_emission`]), instantiated per emission (one `#[test]`
//! each, so a failure names the emission):
//!
//! * forward log-likelihood = brute-force enumeration of every state path;
//! * posteriors sum to 1 and equal the enumerated path marginals;
//! * Viterbi = the best enumerated path (probability and path);
//! * Baum-Welch without regularisation never lowers the log-likelihood;
//! * the online filter = the batch forward filter, bit for bit;
//! * an E-step over more than one block: 1 thread = 4 threads, bit for bit;
//! * JSON round-trip: the same model, bit for bit;
//! * the HMM initialisation and mixture EM run from a template.
//!
//! Small generated data, so the whole file runs in seconds.

use phasekit::emission::{
    Categorical, CovarianceType, Emission, Frames, Gaussian, MixtureEmission, PerState, Poisson,
    Regularisation, SequenceSet, Shape, StudentT, StudentTDof,
};
use phasekit::gmm::Em;
use phasekit::hmm::{BaumWelch, Hmm, HmmInit};
use phasekit_plugin_example::Laplace;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::de::DeserializeOwned;
use serde::Serialize;

const S: usize = 3;

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * (1.0 + a.abs().max(b.abs()))
}

fn log_sum_exp(v: &[f64]) -> f64 {
    let m = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    m + v.iter().map(|x| (x - m).exp()).sum::<f64>().ln()
}

fn random_chain(rng: &mut ChaCha8Rng) -> (Vec<f64>, Vec<f64>) {
    let row = |rng: &mut ChaCha8Rng, n: usize| -> Vec<f64> {
        let v: Vec<f64> = (0..n).map(|_| rng.random_range(0.2..1.0)).collect();
        let t: f64 = v.iter().sum();
        v.iter().map(|x| x / t).collect()
    };
    let start = row(rng, S);
    let mut trans = Vec::new();
    for i in 0..S {
        let mut r = row(rng, S);
        r[i] += 2.0;
        let t: f64 = r.iter().sum();
        trans.extend(r.iter().map(|x| x / t));
    }
    (start, trans)
}

/// Every path's `log p(z, x)`, by brute force over the `S^T` paths.
fn enumerate_paths<E: Emission>(hmm: &Hmm<E>, seq: Frames<'_>) -> Vec<(Vec<usize>, f64)> {
    let t_len = seq.len();
    let log_b = hmm.emission().log_density(seq).unwrap();
    let mut out = Vec::new();
    for code in 0..S.pow(t_len as u32) {
        let path: Vec<usize> = (0..t_len).map(|t| (code / S.pow(t as u32)) % S).collect();
        let mut lp = hmm.start()[path[0]].ln() + log_b[path[0]];
        for t in 1..t_len {
            lp += hmm.transition()[path[t - 1] * S + path[t]].ln() + log_b[t * S + path[t]];
        }
        out.push((path, lp));
    }
    out
}

/// The generic properties, for one emission: `truth` generates the data,
/// `other` (same kind, other parameters) starts Baum-Welch, `template`
/// starts the initialisations.
fn check_emission<E>(name: &str, truth: Hmm<E>, other: Hmm<E>, template: E)
where
    E: Emission + Serialize + DeserializeOwned,
{
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    // Brute force on short sequences (S^6 = 729 paths).
    for k in 0..3 {
        let (x, _) = truth.sample(6, &mut rng).unwrap();
        let seq = Frames::new(&x, truth.dim()).unwrap();
        let paths = enumerate_paths(&truth, seq);
        let lps: Vec<f64> = paths.iter().map(|p| p.1).collect();
        let brute = log_sum_exp(&lps);
        let ll = truth.log_likelihood(seq).unwrap();
        assert!(
            close(ll, brute, 1e-10),
            "{name} seq {k}: forward {ll} vs enumeration {brute}"
        );
        let post = truth.posteriors(seq).unwrap();
        for t in 0..6 {
            let row = &post.gamma[t * S..(t + 1) * S];
            let sum: f64 = row.iter().sum();
            assert!(
                close(sum, 1.0, 1e-12),
                "{name}: posteriors of frame {t} sum to {sum}"
            );
            for (i, g) in row.iter().enumerate() {
                let marg: Vec<f64> = paths.iter().filter(|p| p.0[t] == i).map(|p| p.1).collect();
                let want = (log_sum_exp(&marg) - brute).exp();
                assert!(
                    (g - want).abs() <= 1e-9,
                    "{name}: γ[{t}][{i}] {g} vs {want}"
                );
            }
        }
        let vit = truth.viterbi(seq).unwrap();
        let best = paths.iter().max_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
        assert!(
            close(vit.log_probability, best.1, 1e-10),
            "{name}: Viterbi {} vs best path {}",
            vit.log_probability,
            best.1
        );
        let on_path = paths.iter().find(|p| p.0 == vit.states).unwrap().1;
        assert!(
            close(on_path, best.1, 1e-10),
            "{name}: Viterbi path is not a best path"
        );
    }

    // Data for the fits: 4 sequences of 50 frames.
    let seqs: Vec<Vec<f64>> = (0..4)
        .map(|_| truth.sample(50, &mut rng).unwrap().0)
        .collect();
    let data = SequenceSet::new(&seqs, truth.dim()).unwrap();

    // Online filter = batch forward, bit for bit.
    for seq in data.iter() {
        let fwd = truth.forward(seq).unwrap();
        let mut filter = truth.filter();
        for (t, x) in seq.iter().enumerate() {
            let belief = filter.step(x).unwrap().to_vec();
            assert_eq!(
                bits(&belief),
                bits(&fwd.filtered()[t * S..(t + 1) * S]),
                "{name}: online filter frame {t}"
            );
        }
        assert_eq!(
            filter.log_likelihood().to_bits(),
            fwd.log_likelihood().to_bits(),
            "{name}: online log-likelihood"
        );
    }

    // Baum-Welch without regularisation is monotone.
    let bw = BaumWelch::builder()
        .max_iter(8)
        .tol(f64::NEG_INFINITY)
        .regularisation(Regularisation::none())
        .build()
        .unwrap();
    let fit = bw.fit_from(other.clone(), &data).unwrap();
    let ll = &fit.report.log_likelihood;
    for w in ll.windows(2) {
        assert!(
            w[1] >= w[0] - 1e-9 * w[0].abs().max(1.0),
            "{name}: Baum-Welch lowered the log-likelihood: {ll:?}"
        );
    }
    assert!(
        ll.last().unwrap() > ll.first().unwrap(),
        "{name}: EM did not move: {ll:?}"
    );

    // JSON round-trip: the same parameters, bit for bit.
    let json = serde_json::to_string(&fit.model).unwrap();
    let back: Hmm<E> = serde_json::from_str(&json).unwrap();
    assert_eq!(
        serde_json::to_string(&back).unwrap(),
        json,
        "{name}: JSON round-trip"
    );
    let seq = data.get(0);
    assert_eq!(
        bits(&back.emission().log_density(seq).unwrap()),
        bits(&fit.model.emission().log_density(seq).unwrap()),
        "{name}: log-densities after the round-trip"
    );

    // An E-step over several blocks (4096 frames each): 1 thread = 4 threads.
    let long: Vec<Vec<f64>> = (0..10)
        .map(|_| truth.sample(500, &mut rng).unwrap().0)
        .collect();
    let long = SequenceSet::new(&long, truth.dim()).unwrap();
    let run = |threads: usize| {
        let bw = BaumWelch::builder()
            .max_iter(2)
            .tol(f64::NEG_INFINITY)
            .threads(threads)
            .build()
            .unwrap();
        let f = bw.fit_from(other.clone(), &long).unwrap();
        (
            serde_json::to_string(&f.model).unwrap(),
            bits(&f.report.log_likelihood),
        )
    };
    assert_eq!(run(1), run(4), "{name}: 1 thread vs 4 threads");

    // The initialisations run from a template (HMM k-bins and k-means, mixture EM).
    for init in [HmmInit::KBins { smoothing: 0.01 }, HmmInit::KMeans] {
        let bw = BaumWelch::builder()
            .max_iter(3)
            .init(init)
            .regularisation(Regularisation::add_diagonal(1e-3).unwrap())
            .build()
            .unwrap();
        let f = bw.fit(&template, &data).unwrap();
        assert!(
            f.report.log_likelihood.iter().all(|v| v.is_finite()),
            "{name}: {init:?}"
        );
    }
    let em = Em::builder()
        .max_iter(5)
        .regularisation(Regularisation::add_diagonal(1e-3).unwrap())
        .build()
        .unwrap();
    let g = em.fit(&template, data.all_frames()).unwrap();
    assert!(
        g.report.log_likelihood.iter().all(|v| v.is_finite()),
        "{name}: mixture EM"
    );
}

fn random_spd(d: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let a: Vec<f64> = (0..d * d).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut m = vec![0.0; d * d];
    for r in 0..d {
        for c in 0..d {
            m[r * d + c] = (0..d).map(|k| a[r * d + k] * a[c * d + k]).sum::<f64>() / d as f64
                + if r == c { 0.3 } else { 0.0 };
        }
    }
    m
}

fn gaussian(kind: CovarianceType, d: usize, rng: &mut ChaCha8Rng) -> Gaussian {
    let means = (0..S * d).map(|_| rng.random_range(-3.0..3.0)).collect();
    let covs = match kind {
        CovarianceType::Full => (0..S).flat_map(|_| random_spd(d, rng)).collect(),
        CovarianceType::Tied => random_spd(d, rng),
        CovarianceType::Diagonal => (0..S * d).map(|_| rng.random_range(0.3..1.5)).collect(),
        CovarianceType::Spherical => (0..S).map(|_| rng.random_range(0.3..1.5)).collect(),
    };
    Gaussian::new(kind, d, means, covs).unwrap()
}

fn hmm<E: Emission>(emission: E, rng: &mut ChaCha8Rng) -> Hmm<E> {
    let (start, trans) = random_chain(rng);
    Hmm::new(start, trans, emission).unwrap()
}

fn gaussian_case(kind: CovarianceType) {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let d = 2;
    let truth = hmm(gaussian(kind, d, &mut rng), &mut rng);
    let other = hmm(gaussian(kind, d, &mut rng), &mut rng);
    let template = Gaussian::standard(
        kind,
        Shape {
            n_states: S,
            dim: d,
        },
    )
    .unwrap();
    check_emission(&format!("Gaussian {kind:?}"), truth, other, template);
}

#[test]
fn gaussian_full() {
    gaussian_case(CovarianceType::Full);
}

#[test]
fn gaussian_diagonal() {
    gaussian_case(CovarianceType::Diagonal);
}

#[test]
fn gaussian_spherical() {
    gaussian_case(CovarianceType::Spherical);
}

#[test]
fn gaussian_tied() {
    gaussian_case(CovarianceType::Tied);
}

#[test]
fn categorical() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let k = 4;
    let probs = |rng: &mut ChaCha8Rng| -> Vec<f64> {
        (0..S)
            .flat_map(|_| {
                let v: Vec<f64> = (0..k).map(|_| rng.random_range(0.1..1.0)).collect();
                let t: f64 = v.iter().sum();
                v.into_iter().map(move |x| x / t)
            })
            .collect()
    };
    let truth = hmm(Categorical::new(k, probs(&mut rng)).unwrap(), &mut rng);
    let other = hmm(Categorical::new(k, probs(&mut rng)).unwrap(), &mut rng);
    check_emission(
        "categorical",
        truth,
        other,
        Categorical::uniform(S, k).unwrap(),
    );
}

#[test]
fn poisson() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let d = 2;
    let rates = |rng: &mut ChaCha8Rng| (0..S * d).map(|_| rng.random_range(0.5..9.0)).collect();
    let truth = hmm(Poisson::new(d, rates(&mut rng)).unwrap(), &mut rng);
    let other = hmm(Poisson::new(d, rates(&mut rng)).unwrap(), &mut rng);
    check_emission("Poisson", truth, other, Poisson::unit(S, d).unwrap());
}

fn student_t(d: usize, rng: &mut ChaCha8Rng) -> PerState<StudentT> {
    PerState::new(
        (0..S)
            .map(|_| {
                let mean = (0..d).map(|_| rng.random_range(-3.0..3.0)).collect();
                let nu = rng.random_range(3.0..8.0);
                StudentT::new(mean, random_spd(d, rng), nu, StudentTDof::Estimated).unwrap()
            })
            .collect(),
    )
    .unwrap()
}

#[test]
fn student_t_estimated_dof() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let d = 2;
    let truth = hmm(student_t(d, &mut rng), &mut rng);
    let other = hmm(student_t(d, &mut rng), &mut rng);
    let template = PerState::repeat(
        StudentT::standard(d, 5.0, StudentTDof::Estimated).unwrap(),
        S,
    )
    .unwrap();
    check_emission("Student-t", truth, other, template);
}

fn mixture(d: usize, rng: &mut ChaCha8Rng) -> MixtureEmission<Gaussian> {
    let m = 2;
    let comps = (0..S)
        .map(|_| {
            let means = (0..m * d).map(|_| rng.random_range(-3.0..3.0)).collect();
            let covs = (0..m).flat_map(|_| random_spd(d, rng)).collect();
            Gaussian::full(d, means, covs).unwrap()
        })
        .collect();
    let weights = (0..S)
        .flat_map(|_| {
            let w = rng.random_range(0.3..0.7);
            [w, 1.0 - w]
        })
        .collect();
    MixtureEmission::new(weights, comps).unwrap()
}

#[test]
fn gaussian_mixture_per_state() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let d = 2;
    let truth = hmm(mixture(d, &mut rng), &mut rng);
    let other = hmm(mixture(d, &mut rng), &mut rng);
    let component = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 2,
            dim: d,
        },
    )
    .unwrap();
    let template = MixtureEmission::new(vec![0.5; 2 * S], vec![component; S]).unwrap();
    check_emission("MixtureEmission<Gaussian>", truth, other, template);
}

#[test]
fn plugin_laplace() {
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let d = 2;
    let laplace = |rng: &mut ChaCha8Rng| {
        PerState::new(
            (0..S)
                .map(|_| {
                    Laplace::new(
                        (0..d).map(|_| rng.random_range(-3.0..3.0)).collect(),
                        (0..d).map(|_| rng.random_range(0.3..1.5)).collect(),
                    )
                    .unwrap()
                })
                .collect(),
        )
        .unwrap()
    };
    let truth = hmm(laplace(&mut rng), &mut rng);
    let other = hmm(laplace(&mut rng), &mut rng);
    let template = PerState::repeat(Laplace::standard(d).unwrap(), S).unwrap();
    check_emission("plug-in Laplace", truth, other, template);
}
