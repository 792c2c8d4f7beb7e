//! Behaviour of the HMM crate as a user sees it: parameter recovery, numerical
//! stability at extreme scales, structural zeros and freezing, k-bins
//! initialisation, serialisation, error messages, information criteria and
//! mixture emissions. Every random draw is a `ChaCha8Rng` with a fixed seed.

use nalgebra::{DMatrix, DVector};
use phasekit::emission::{
    Categorical, CovarianceType, Emission, EmissionError, Frames, Gaussian, MixtureEmission,
    Poisson, Regularisation, SequenceSet, Shape,
};
use phasekit::hmm::{
    initialise, kbins_edges, BaumWelch, Hmm, HmmError, HmmInit, Update, MODEL_FORMAT_VERSION,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{de::DeserializeOwned, Serialize};

/// A standard normal draw (Box–Muller), so that the test needs no extra crate.
fn standard_normal<R: Rng>(rng: &mut R) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

// ---------------------------------------------------------------------------
// Reference implementations (log space, obvious)
// ---------------------------------------------------------------------------

fn lse(xs: &[f64]) -> f64 {
    let m = xs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    m + xs.iter().map(|v| (v - m).exp()).sum::<f64>().ln()
}

/// Log-space forward-backward: `(log p, γ)` from `T × S` log-densities.
///
/// Every frame's log α and log β are re-centred (the offsets of α are summed
/// into `log p`), so that long sequences keep full precision: plain log α grows
/// like `T` and loses absolute precision, which `exp` turns into relative error.
fn log_space_posteriors(start: &[f64], trans: &[f64], log_b: &[f64], s: usize) -> (f64, Vec<f64>) {
    let t_len = log_b.len() / s;
    let la_trans: Vec<f64> = trans.iter().map(|a| a.ln()).collect();
    let mut la = vec![0.0; t_len * s];
    let mut lb = vec![0.0; t_len * s];
    let mut terms = vec![0.0; s];
    let mut ll = 0.0;
    for t in 0..t_len {
        for j in 0..s {
            la[t * s + j] = if t == 0 {
                start[j].ln()
            } else {
                for i in 0..s {
                    terms[i] = la[(t - 1) * s + i] + la_trans[i * s + j];
                }
                lse(&terms)
            } + log_b[t * s + j];
        }
        let c = lse(&la[t * s..(t + 1) * s]);
        la[t * s..(t + 1) * s].iter_mut().for_each(|v| *v -= c);
        ll += c;
    }
    for t in (0..t_len - 1).rev() {
        for i in 0..s {
            for j in 0..s {
                terms[j] = la_trans[i * s + j] + log_b[(t + 1) * s + j] + lb[(t + 1) * s + j];
            }
            lb[t * s + i] = lse(&terms);
        }
        let c = lse(&lb[t * s..(t + 1) * s]);
        lb[t * s..(t + 1) * s].iter_mut().for_each(|v| *v -= c);
    }
    let mut gamma = vec![0.0; t_len * s];
    for t in 0..t_len {
        let sum: Vec<f64> = (0..s).map(|i| la[t * s + i] + lb[t * s + i]).collect();
        let c = lse(&sum);
        for i in 0..s {
            gamma[t * s + i] = (sum[i] - c).exp();
        }
    }
    (ll, gamma)
}

/// Brute force over all `S^T` paths: `(log p, γ, Σ_t ξ_t)`.
fn brute_force(start: &[f64], trans: &[f64], log_b: &[f64], s: usize) -> (f64, Vec<f64>, Vec<f64>) {
    let t_len = log_b.len() / s;
    let paths: Vec<Vec<usize>> = (0..s.pow(t_len as u32))
        .map(|mut k| {
            (0..t_len)
                .map(|_| {
                    let z = k % s;
                    k /= s;
                    z
                })
                .collect()
        })
        .collect();
    let lps: Vec<f64> = paths
        .iter()
        .map(|z| {
            let mut lp = start[z[0]].ln() + log_b[z[0]];
            for t in 1..t_len {
                lp += trans[z[t - 1] * s + z[t]].ln() + log_b[t * s + z[t]];
            }
            lp
        })
        .collect();
    let ll = lse(&lps);
    let mut gamma = vec![0.0; t_len * s];
    let mut xi = vec![0.0; s * s];
    for (z, lp) in paths.iter().zip(&lps) {
        let w = (lp - ll).exp();
        for t in 0..t_len {
            gamma[t * s + z[t]] += w;
            if t + 1 < t_len {
                xi[z[t] * s + z[t + 1]] += w;
            }
        }
    }
    (ll, gamma, xi)
}

fn normal_1d(mean: f64, var: f64, x: f64) -> f64 {
    -0.5 * ((2.0 * std::f64::consts::PI).ln() + var.ln() + (x - mean) * (x - mean) / var)
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

// ---------------------------------------------------------------------------
// Recovery
// ---------------------------------------------------------------------------

fn three_state_truth() -> Hmm<Gaussian> {
    let g = Gaussian::full(
        2,
        vec![0.0, 0.0, 5.0, 0.0, 0.0, 5.0],
        vec![1.0, 0.3, 0.3, 0.8, 0.7, -0.2, -0.2, 1.2, 1.0, 0.0, 0.0, 1.0],
    )
    .unwrap();
    Hmm::new(
        vec![0.5, 0.3, 0.2],
        vec![0.8, 0.1, 0.1, 0.15, 0.8, 0.05, 0.1, 0.2, 0.7],
        g,
    )
    .unwrap()
}

fn sample_set<E: Emission>(
    hmm: &Hmm<E>,
    n_seq: usize,
    len: usize,
    seed: u64,
) -> (SequenceSet, Vec<Vec<usize>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (seqs, states): (Vec<Vec<f64>>, Vec<Vec<usize>>) = (0..n_seq)
        .map(|_| hmm.sample(len, &mut rng).unwrap())
        .unzip();
    (SequenceSet::new(&seqs, hmm.dim()).unwrap(), states)
}

#[test]
fn recovers_a_three_state_gaussian_hmm() {
    let truth = three_state_truth();
    let (data, _) = sample_set(&truth, 20, 200, 42);
    let template = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 3,
            dim: 2,
        },
    )
    .unwrap();
    let bw = BaumWelch::builder()
        .init(HmmInit::KMeans)
        .restarts(3)
        .seed(5)
        .max_iter(200)
        .tol(1e-6)
        .build()
        .unwrap();
    let fitted = bw.fit(&template, &data).unwrap();
    assert!(
        fitted.report.converged,
        "{:?}",
        fitted.report.log_likelihood.len()
    );
    assert_eq!(fitted.report.restarts.len(), 3);
    let model = &fitted.model;

    // Match every fitted state to the nearest true mean; it must be a permutation.
    let perm: Vec<usize> = (0..3)
        .map(|k| {
            let m = model.emission().mean(k);
            (0..3)
                .min_by(|&a, &b| {
                    let d = |i: usize| {
                        let t = truth.emission().mean(i);
                        (m[0] - t[0]).powi(2) + (m[1] - t[1]).powi(2)
                    };
                    d(a).total_cmp(&d(b))
                })
                .unwrap()
        })
        .collect();
    let mut sorted = perm.clone();
    sorted.sort_unstable();
    assert_eq!(
        sorted,
        vec![0, 1, 2],
        "labels do not match one-to-one: {perm:?}"
    );

    // Tolerances: 4000 frames, ~1300 per state: the standard error of a mean is
    // ~0.03, of a transition probability ~0.01, of a (co)variance ~0.04.
    for k in 0..3 {
        let i = perm[k];
        for (a, b) in model
            .emission()
            .mean(k)
            .iter()
            .zip(truth.emission().mean(i))
        {
            assert!((a - b).abs() < 0.15, "state {i} mean: fitted {a}, true {b}");
        }
        let diff = (model.emission().covariance(k) - truth.emission().covariance(i))
            .abs()
            .max();
        assert!(diff < 0.15, "state {i} covariance off by {diff}");
        for (l, &j) in perm.iter().enumerate() {
            let (a, b) = (model.transition()[k * 3 + l], truth.transition()[i * 3 + j]);
            assert!((a - b).abs() < 0.05, "a[{i}][{j}]: fitted {a}, true {b}");
        }
    }
    // Maximum likelihood: at least as likely as the truth.
    let ll_fit = model.log_likelihood_all(&data).unwrap();
    let ll_true = truth.log_likelihood_all(&data).unwrap();
    assert!(ll_fit >= ll_true, "fitted {ll_fit} < true {ll_true}");
    assert_eq!(ll_fit, *fitted.report.log_likelihood.last().unwrap());

    // Reproducible with the seed.
    let again = bw.fit(&template, &data).unwrap();
    assert_eq!(
        bits(again.model.emission().means()),
        bits(model.emission().means())
    );
    assert_eq!(bits(again.model.transition()), bits(model.transition()));
}

// ---------------------------------------------------------------------------
// Numerical stability
// ---------------------------------------------------------------------------

#[test]
fn million_frame_sequence_is_finite_and_matches_log_space() {
    let (means, vars) = ([-2.0, 2.0], [1.0, 1.5]);
    let g = Gaussian::diagonal(1, means.to_vec(), vars.to_vec()).unwrap();
    let hmm = Hmm::new(vec![0.5, 0.5], vec![0.95, 0.05, 0.1, 0.9], g).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (x, states) = hmm.sample(1_000_000, &mut rng).unwrap();
    let seq = Frames::new(&x, 1).unwrap();

    let ll = hmm.log_likelihood(seq).unwrap();
    assert!(ll.is_finite(), "{ll}");
    let post = hmm.posteriors(seq).unwrap();
    assert_eq!(post.log_likelihood, ll);
    for row in post.gamma.chunks_exact(2) {
        assert!(row.iter().all(|g| g.is_finite() && *g >= 0.0));
        assert!((row[0] + row[1] - 1.0).abs() < 1e-12);
    }
    assert!((post.expected_transitions.iter().sum::<f64>() - 999_999.0).abs() < 1e-6);

    // The obvious log-space forward-backward, with textbook densities.
    let log_b: Vec<f64> = x
        .iter()
        .flat_map(|v| {
            [
                normal_1d(means[0], vars[0], *v),
                normal_1d(means[1], vars[1], *v),
            ]
        })
        .collect();
    let (ll_ref, gamma_ref) = log_space_posteriors(hmm.start(), hmm.transition(), &log_b, 2);
    assert!(
        (ll - ll_ref).abs() <= 1e-9 * ll_ref.abs(),
        "{ll} vs {ll_ref}"
    );
    let err = max_abs_diff(&post.gamma, &gamma_ref);
    assert!(err < 1e-9, "posteriors differ from log space by {err}");

    let v = hmm.viterbi(seq).unwrap();
    assert!(v.log_probability.is_finite() && v.log_probability <= ll);
    let accuracy =
        v.states.iter().zip(&states).filter(|(a, b)| a == b).count() as f64 / states.len() as f64;
    assert!(accuracy > 0.95, "Viterbi accuracy {accuracy}");
}

/// A random 36-D covariance `BBᵀ/D + ½I`.
fn cov36(rng: &mut ChaCha8Rng) -> DMatrix<f64> {
    let d = 36;
    let b = DMatrix::from_fn(d, d, |_, _| standard_normal(rng));
    let c = &b * b.transpose() / d as f64 + DMatrix::identity(d, d) * 0.5;
    (&c + c.transpose()) * 0.5
}

#[test]
fn far_away_36_dim_data_stay_finite() {
    let (d, s) = (36, 3);
    let mut rng = ChaCha8Rng::seed_from_u64(36);
    // Nearly the same covariance shape and nearby means, so that at 50σ the
    // states' log-densities (all < −745) still differ by only a few nats and
    // the posteriors are not all 0/1.
    let base = cov36(&mut rng);
    let scales = [1.0, 1.0005, 1.001];
    let covs: Vec<DMatrix<f64>> = scales.iter().map(|k| &base * *k).collect();
    let means: Vec<DVector<f64>> = (0..s)
        .map(|_| DVector::from_fn(d, |_, _| 0.05 * standard_normal(&mut rng)))
        .collect();
    let g = Gaussian::full(
        d,
        means.iter().flat_map(|m| m.iter().copied()).collect(),
        covs.iter()
            .flat_map(|c| c.transpose().iter().copied().collect::<Vec<_>>())
            .collect(),
    )
    .unwrap();
    let trans = vec![0.8, 0.15, 0.05, 0.1, 0.8, 0.1, 0.05, 0.15, 0.8];
    let hmm = Hmm::new(vec![0.4, 0.3, 0.3], trans, g).unwrap();

    // Frames 50σ (Mahalanobis) away from the state that emits them.
    let t_len = 40;
    let mut z = 0;
    let mut x = Vec::new();
    for _ in 0..t_len {
        z = phasekit::emission::categorical::sample_index(
            &hmm.transition()[z * s..(z + 1) * s],
            &mut rng,
        );
        let u = DVector::from_fn(d, |_, _| standard_normal(&mut rng)).normalize();
        let l = covs[z].clone().cholesky().unwrap().unpack();
        let frame = &means[z] + l * u * 50.0;
        x.extend(frame.iter());
    }
    let seq = Frames::new(&x, d).unwrap();

    // Textbook densities: far below the exp underflow threshold.
    let log_b_ref: Vec<f64> = x
        .chunks_exact(d)
        .flat_map(|f| {
            let f = DVector::from_column_slice(f);
            (0..s)
                .map(|i| {
                    let diff = &f - &means[i];
                    let inv = covs[i].clone().try_inverse().unwrap();
                    -0.5 * (d as f64 * (2.0 * std::f64::consts::PI).ln()
                        + covs[i].determinant().ln()
                        + (diff.transpose() * inv * &diff)[(0, 0)])
                })
                .collect::<Vec<_>>()
        })
        .collect();
    assert!(
        log_b_ref.iter().all(|v| *v < -745.0),
        "test data are not extreme enough"
    );
    let log_b = hmm.emission_log_densities(seq).unwrap();
    for (a, b) in log_b.iter().zip(&log_b_ref) {
        assert!((a - b).abs() <= 1e-9 * b.abs(), "{a} vs {b}");
    }

    let ll = hmm.log_likelihood(seq).unwrap();
    assert!(ll.is_finite());
    let post = hmm.posteriors(seq).unwrap();
    let (ll_ref, gamma_ref) = log_space_posteriors(hmm.start(), hmm.transition(), &log_b, s);
    assert!(
        (ll - ll_ref).abs() <= 1e-9 * ll_ref.abs(),
        "{ll} vs {ll_ref}"
    );
    assert!(max_abs_diff(&post.gamma, &gamma_ref) < 1e-9);
    for row in post.gamma.chunks_exact(s) {
        assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
    // The posteriors are not degenerate (several states are plausible somewhere).
    assert!(
        post.gamma.iter().any(|g| *g > 0.05 && *g < 0.95),
        "posteriors are all 0/1"
    );
    assert!(hmm.viterbi(seq).unwrap().log_probability.is_finite());

    // Brute force on a short piece.
    let piece = &log_b[..5 * s];
    let (ll5, gamma5, xi5) = brute_force(hmm.start(), hmm.transition(), piece, s);
    let post5 = hmm
        .posteriors(Frames::new(&x[..5 * d], d).unwrap())
        .unwrap();
    assert!((post5.log_likelihood - ll5).abs() <= 1e-9 * ll5.abs());
    assert!(max_abs_diff(&post5.gamma, &gamma5) < 1e-9);
    assert!(max_abs_diff(&post5.expected_transitions, &xi5) < 1e-9);

    // The online filter stays finite too.
    let mut filter = hmm.filter();
    for f in x.chunks_exact(d) {
        assert!(filter.step(f).unwrap().iter().all(|v| v.is_finite()));
    }
    assert!((filter.log_likelihood() - ll).abs() <= 1e-12 * ll.abs());
}

/// Density ratios inside the subnormal range (`e^-709 … e^-745`) and
/// transition probabilities near the smallest normal number: the scaled
/// passes must not lose digits to gradual underflow.
#[test]
fn subnormal_scale_quantities_match_brute_force() {
    // State 2 can only be entered at t = 0 (its column of A is zero). Frame 1 is
    // at state 2's mean, e^-737 and e^-741 less likely under the reachable states.
    let means = [0.0, 0.1, 38.5];
    let g = Gaussian::diagonal(1, means.to_vec(), vec![1.0; 3]).unwrap();
    let trans = vec![0.6, 0.4, 0.0, 0.3, 0.7, 0.0, 0.5, 0.5, 0.0];
    let hmm = Hmm::new(vec![0.3, 0.3, 0.4], trans, g).unwrap();
    let x = [0.05, 38.5, 0.2, 0.0];
    let log_b: Vec<f64> = x
        .iter()
        .flat_map(|v| means.map(|m| normal_1d(m, 1.0, *v)))
        .collect();
    let (ll, gamma, xi) = brute_force(hmm.start(), hmm.transition(), &log_b, 3);
    let post = hmm.posteriors(Frames::new(&x, 1).unwrap()).unwrap();
    assert!(
        (post.log_likelihood - ll).abs() <= 1e-9 * ll.abs(),
        "{} vs {ll}",
        post.log_likelihood
    );
    let (eg, ex) = (
        max_abs_diff(&post.gamma, &gamma),
        max_abs_diff(&post.expected_transitions, &xi),
    );
    assert!(
        eg < 1e-9 && ex < 1e-9,
        "posteriors off by {eg}, expected transitions off by {ex}"
    );

    // A transition of probability 1e-305 that the data force.
    let g = Gaussian::diagonal(1, vec![0.0, 30.0], vec![1.0, 1.0]).unwrap();
    let hmm = Hmm::new(vec![1.0, 0.0], vec![1.0 - 1e-305, 1e-305, 0.0, 1.0], g).unwrap();
    let x = [0.0, 0.3, 30.0, 29.5, 30.2];
    let log_b: Vec<f64> = x
        .iter()
        .flat_map(|v| [normal_1d(0.0, 1.0, *v), normal_1d(30.0, 1.0, *v)])
        .collect();
    let (ll, gamma, xi) = brute_force(hmm.start(), hmm.transition(), &log_b, 2);
    let post = hmm.posteriors(Frames::new(&x, 1).unwrap()).unwrap();
    assert!(
        (post.log_likelihood - ll).abs() <= 1e-9 * ll.abs(),
        "{} vs {ll}",
        post.log_likelihood
    );
    let (eg, ex) = (
        max_abs_diff(&post.gamma, &gamma),
        max_abs_diff(&post.expected_transitions, &xi),
    );
    assert!(
        eg < 1e-9 && ex < 1e-9,
        "posteriors off by {eg}, expected transitions off by {ex}"
    );
    assert!(
        (hmm.viterbi(Frames::new(&x, 1).unwrap())
            .unwrap()
            .log_probability
            - ll)
            .abs()
            < 1e-6
    );

    // A normaliser far below 1 (the most likely state at frame 0 has predicted
    // probability 1e-250) must not magnify the rounding of underflowed terms:
    // state 2's filtered probability (~1e-97, from a term of ~1e-347) decides
    // frame 1, which favours it by e^300.
    let means = [0.0, 1200f64.sqrt(), 1320f64.sqrt()];
    let g = Gaussian::diagonal(1, means.to_vec(), vec![1.0; 3]).unwrap();
    let trans = vec![0.5, 0.5, 0.0, 0.0, 1.0 - 1e-200, 1e-200, 0.0, 0.0, 1.0];
    let hmm = Hmm::new(vec![1e-250, 1.0 - 1e-250 - 1e-60, 1e-60], trans, g).unwrap();
    let x1 = 0.5 * (means[1] + means[2]) + 300.0 / (means[2] - means[1]);
    let x = [0.0, x1, means[2]];
    let log_b: Vec<f64> = x
        .iter()
        .flat_map(|v| means.map(|m| normal_1d(m, 1.0, *v)))
        .collect();
    let (ll, gamma, xi) = brute_force(hmm.start(), hmm.transition(), &log_b, 3);
    let seq = Frames::new(&x, 1).unwrap();
    let got = hmm.log_likelihood(seq).unwrap();
    assert!((got - ll).abs() <= 1e-9 * ll.abs(), "{got} vs {ll}");
    let post = hmm.posteriors(seq).unwrap();
    let (eg, ex) = (
        max_abs_diff(&post.gamma, &gamma),
        max_abs_diff(&post.expected_transitions, &xi),
    );
    assert!(
        eg < 1e-9 && ex < 1e-9,
        "posteriors off by {eg}, expected transitions off by {ex}"
    );
}

/// A glitch frame makes the scaled forward drop a state's mass below e^-745
/// relative to the others; later frames, which favour that state by hundreds of
/// nats, must still be able to bring it back (left-right chain: the state cannot
/// be re-entered from the dominant one).
#[test]
fn a_state_ruled_out_by_a_glitch_can_come_back() {
    let g = Gaussian::diagonal(1, vec![0.0, 20.0], vec![1.0, 1.0]).unwrap();
    let hmm = Hmm::new(vec![1.0, 0.0], vec![0.9, 0.1, 0.0, 1.0], g).unwrap();
    // Frame 1 is 50σ from state 0 and 30σ from state 1 (800 nats apart); the
    // next ten frames sit on state 0 (200 nats per frame in its favour).
    let mut x = vec![0.0, 50.0];
    x.extend([0.1, -0.2, 0.3, 0.0, -0.1, 0.2, 0.0, 0.1, -0.3, 0.05]);
    let log_b: Vec<f64> = x
        .iter()
        .flat_map(|v| [normal_1d(0.0, 1.0, *v), normal_1d(20.0, 1.0, *v)])
        .collect();
    let (ll, gamma, xi) = brute_force(hmm.start(), hmm.transition(), &log_b, 2);
    let seq = Frames::new(&x, 1).unwrap();
    let got = hmm.log_likelihood(seq).unwrap();
    assert!(
        (got - ll).abs() <= 1e-9 * ll.abs(),
        "log-likelihood {got}, brute force {ll}"
    );
    let post = hmm.posteriors(seq).unwrap();
    let (eg, ex) = (
        max_abs_diff(&post.gamma, &gamma),
        max_abs_diff(&post.expected_transitions, &xi),
    );
    assert!(
        eg < 1e-9 && ex < 1e-9,
        "posteriors off by {eg}, expected transitions off by {ex}"
    );
    // The online filter agrees with the batch pass.
    let mut filter = hmm.filter();
    for v in &x {
        filter.step(&[*v]).unwrap();
    }
    assert!(
        (filter.log_likelihood() - ll).abs() <= 1e-9 * ll.abs(),
        "online {} vs {ll}",
        filter.log_likelihood()
    );
    let fwd = hmm.forward(seq).unwrap();
    assert_eq!(filter.belief(), &fwd.filtered()[fwd.filtered().len() - 2..]);

    // The same inside a long sequence: the posteriors keep full precision.
    let mut long: Vec<f64> = (0..200_000)
        .map(|t| if (t / 50) % 2 == 0 { 0.1 } else { -0.1 })
        .collect();
    long[100_001] = 50.0;
    let hmm = Hmm::new(
        vec![1.0, 0.0],
        vec![0.99, 0.01, 0.0, 1.0],
        Gaussian::diagonal(1, vec![0.0, 20.0], vec![1.0, 1.0]).unwrap(),
    )
    .unwrap();
    let log_b: Vec<f64> = long
        .iter()
        .flat_map(|v| [normal_1d(0.0, 1.0, *v), normal_1d(20.0, 1.0, *v)])
        .collect();
    let (ll_ref, gamma_ref) = log_space_posteriors(hmm.start(), hmm.transition(), &log_b, 2);
    let post = hmm.posteriors(Frames::new(&long, 1).unwrap()).unwrap();
    assert!(
        (post.log_likelihood - ll_ref).abs() <= 1e-9 * ll_ref.abs(),
        "{} vs {ll_ref}",
        post.log_likelihood
    );
    let err = max_abs_diff(&post.gamma, &gamma_ref);
    assert!(err < 1e-9, "posteriors off by {err}");
}

// ---------------------------------------------------------------------------
// Structural zeros, freezing, k-bins
// ---------------------------------------------------------------------------

fn left_right_truth() -> Hmm<Gaussian> {
    let g = Gaussian::full(
        2,
        vec![0.0, 0.0, 3.0, 1.0, 6.0, 0.0],
        [1.0, 0.2, 0.2, 0.5].repeat(3),
    )
    .unwrap();
    Hmm::new(
        vec![1.0, 0.0, 0.0],
        vec![0.93, 0.07, 0.0, 0.0, 0.95, 0.05, 0.0, 0.0, 1.0],
        g,
    )
    .unwrap()
}

#[test]
fn left_right_zeros_stay_exactly_zero() {
    let (data, _) = sample_set(&left_right_truth(), 10, 60, 9);
    let template = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 3,
            dim: 2,
        },
    )
    .unwrap();
    let init = HmmInit::KBins { smoothing: 0.0 };
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let initial = initialise(&template, &data, init, &Regularisation::none(), &mut rng).unwrap();
    let zeros_a = [(0, 2), (1, 0), (2, 0), (2, 1)];
    for (i, j) in zeros_a {
        assert_eq!(initial.transition()[i * 3 + j], 0.0, "initial a[{i}][{j}]");
    }
    assert_eq!(initial.start(), &[1.0, 0.0, 0.0]);

    let fitted = BaumWelch::builder()
        .init(init)
        .max_iter(50)
        .build()
        .unwrap()
        .fit(&template, &data)
        .unwrap();
    let model = &fitted.model;
    for (i, j) in zeros_a {
        assert_eq!(
            model.transition()[i * 3 + j].to_bits(),
            0.0f64.to_bits(),
            "a[{i}][{j}] = {}",
            model.transition()[i * 3 + j]
        );
    }
    assert_eq!(model.start(), &[1.0, 0.0, 0.0]);
    // The fit did move the other parameters and improved the likelihood.
    assert_ne!(model.transition()[0], initial.transition()[0]);
    assert!(fitted.report.log_likelihood.last().unwrap() > &fitted.report.log_likelihood[0]);
    assert!(fitted.report.iterations >= 2);
}

#[test]
fn frozen_parameters_stay_bit_identical() {
    let (data, _) = sample_set(&three_state_truth(), 6, 80, 17);
    let g0 = Gaussian::full(
        2,
        vec![0.5, 0.5, 4.0, 0.5, 0.5, 4.0],
        [1.2, 0.0, 0.0, 1.2].repeat(3),
    )
    .unwrap();
    let initial = Hmm::new(
        vec![0.2, 0.3, 0.5],
        vec![0.5, 0.25, 0.25, 0.2, 0.6, 0.2, 0.3, 0.3, 0.4],
        g0,
    )
    .unwrap();
    let fit = |update: Update| {
        BaumWelch::builder()
            .max_iter(5)
            .tol(f64::NEG_INFINITY)
            .update(update)
            .build()
            .unwrap()
            .fit_from(initial.clone(), &data)
            .unwrap()
            .model
    };
    let same_emission = |a: &Hmm<Gaussian>, b: &Hmm<Gaussian>| {
        bits(a.emission().means()) == bits(b.emission().means())
            && bits(a.emission().covariances_raw()) == bits(b.emission().covariances_raw())
    };
    let all = Update {
        start: true,
        transition: true,
        emission: true,
    };

    let m = fit(Update {
        start: false,
        ..all
    });
    assert_eq!(bits(m.start()), bits(initial.start()));
    assert_ne!(bits(m.transition()), bits(initial.transition()));
    assert!(!same_emission(&m, &initial));

    let m = fit(Update {
        transition: false,
        ..all
    });
    assert_eq!(bits(m.transition()), bits(initial.transition()));
    assert_ne!(bits(m.start()), bits(initial.start()));
    assert!(!same_emission(&m, &initial));

    let m = fit(Update {
        emission: false,
        ..all
    });
    assert!(same_emission(&m, &initial));
    assert_ne!(bits(m.transition()), bits(initial.transition()));

    let m = fit(Update {
        start: false,
        transition: false,
        emission: false,
    });
    assert_eq!(bits(m.start()), bits(initial.start()));
    assert_eq!(bits(m.transition()), bits(initial.transition()));
    assert!(same_emission(&m, &initial));
}

#[test]
fn kbins_edges_follow_numpy_round_half_even() {
    // np.round(np.linspace(0, T, S + 1)).astype(int), computed by hand:
    assert_eq!(kbins_edges(321, 4), vec![0, 80, 160, 241, 321]); // 80.25, 160.5 → 160 (even), 240.75
    assert_eq!(kbins_edges(322, 4), vec![0, 80, 161, 242, 322]); // 80.5 → 80, 241.5 → 242
    assert_eq!(kbins_edges(10, 4), vec![0, 2, 5, 8, 10]); // 2.5 → 2, 7.5 → 8
    assert_eq!(kbins_edges(6, 4), vec![0, 2, 3, 4, 6]); // 1.5 → 2, 4.5 → 4
    assert_eq!(kbins_edges(7, 3), vec![0, 2, 5, 7]);
    assert_eq!(kbins_edges(5, 5), vec![0, 1, 2, 3, 4, 5]);
    assert_eq!(kbins_edges(9, 1), vec![0, 9]);
}

#[test]
fn kbins_initialisation_uses_the_documented_bins_and_transitions() {
    // Frames carry their own index, so each state's initial mean is the mean index of its bin.
    let seqs: Vec<Vec<f64>> = [321usize, 322]
        .iter()
        .map(|&t| (0..t).map(|v| v as f64).collect())
        .collect();
    let data = SequenceSet::new(&seqs, 1).unwrap();
    let s = 4;
    let template = Gaussian::standard(
        CovarianceType::Diagonal,
        Shape {
            n_states: s,
            dim: 1,
        },
    )
    .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let hmm = initialise(
        &template,
        &data,
        HmmInit::KBins { smoothing: 0.01 },
        &Regularisation::none(),
        &mut rng,
    )
    .unwrap();

    let edges = [[0usize, 80, 160, 241, 321], [0, 80, 161, 242, 322]];
    for i in 0..s {
        let members: Vec<f64> = edges
            .iter()
            .flat_map(|e| (e[i]..e[i + 1]).map(|t| t as f64))
            .collect();
        let n = members.len() as f64;
        let mean = members.iter().sum::<f64>() / n;
        let var = members.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        assert!(
            (hmm.emission().mean(i)[0] - mean).abs() < 1e-9,
            "state {i}: mean {} vs {mean}",
            hmm.emission().mean(i)[0]
        );
        assert!((hmm.emission().covariances_raw()[i] - var).abs() < 1e-9 * var);
    }

    // 0.99·LR + 0.01/S with a_ii = 1 − S/T̄, a_{i,i+1} = S/T̄, T̄ = 321.5.
    let p = s as f64 / 321.5;
    for i in 0..s {
        for j in 0..s {
            let lr = match (i, j) {
                _ if i == s - 1 && j == i => 1.0,
                _ if j == i => 1.0 - p,
                _ if j == i + 1 => p,
                _ => 0.0,
            };
            let want = 0.99 * lr + 0.01 / s as f64;
            assert!(
                (hmm.transition()[i * s + j] - want).abs() < 1e-15,
                "a[{i}][{j}]"
            );
        }
        let want = if i == 0 { 0.99 + 0.0025 } else { 0.0025 };
        assert!((hmm.start()[i] - want).abs() < 1e-15);
    }
}

// ---------------------------------------------------------------------------
// Serialisation
// ---------------------------------------------------------------------------

fn round_trip<E>(hmm: &Hmm<E>, data: &SequenceSet)
where
    E: Emission + Serialize + DeserializeOwned,
{
    let json = serde_json::to_string(hmm).unwrap();
    let back: Hmm<E> = serde_json::from_str(&json).unwrap();
    let (a, b) = (
        hmm.log_likelihood_all(data).unwrap(),
        back.log_likelihood_all(data).unwrap(),
    );
    assert_eq!(
        a.to_bits(),
        b.to_bits(),
        "log-likelihood changed over a JSON round trip: {a} vs {b}"
    );
    assert_eq!(bits(hmm.start()), bits(back.start()));
    assert_eq!(bits(hmm.transition()), bits(back.transition()));
    // Serialising again gives the same text.
    assert_eq!(serde_json::to_string(&back).unwrap(), json);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(v["format_version"], MODEL_FORMAT_VERSION);
}

#[test]
fn json_round_trip_preserves_every_model() {
    let truth = three_state_truth();
    let (data, _) = sample_set(&truth, 3, 30, 1);
    let fitted = |kind| {
        BaumWelch::builder()
            .max_iter(3)
            .build()
            .unwrap()
            .fit(
                &Gaussian::standard(
                    kind,
                    Shape {
                        n_states: 3,
                        dim: 2,
                    },
                )
                .unwrap(),
                &data,
            )
            .unwrap()
            .model
    };
    for kind in [
        CovarianceType::Full,
        CovarianceType::Diagonal,
        CovarianceType::Spherical,
        CovarianceType::Tied,
    ] {
        round_trip(&fitted(kind), &data);
    }

    let cat = Hmm::new(
        vec![0.2, 0.8],
        vec![0.7, 0.3, 0.1, 0.9],
        Categorical::new(3, vec![0.5, 0.25, 0.25, 0.1, 0.1, 0.8]).unwrap(),
    )
    .unwrap();
    let (cat_data, _) = sample_set(&cat, 3, 25, 2);
    let cat = BaumWelch::builder()
        .max_iter(3)
        .build()
        .unwrap()
        .fit_from(cat, &cat_data)
        .unwrap()
        .model;
    round_trip(&cat, &cat_data);

    let poi = Hmm::new(
        vec![0.6, 0.4],
        vec![0.8, 0.2, 0.3, 0.7],
        Poisson::new(2, vec![1.0, 5.0, 7.0, 0.5]).unwrap(),
    )
    .unwrap();
    let (poi_data, _) = sample_set(&poi, 3, 25, 3);
    let poi = BaumWelch::builder()
        .max_iter(3)
        .build()
        .unwrap()
        .fit_from(poi, &poi_data)
        .unwrap()
        .model;
    round_trip(&poi, &poi_data);

    let comps = |shift: f64| {
        Gaussian::full(
            2,
            vec![shift, 0.0, shift + 2.0, 1.0],
            [1.0, 0.1, 0.1, 1.0].repeat(2),
        )
        .unwrap()
    };
    let mix = MixtureEmission::new(vec![0.3, 0.7, 0.5, 0.5], vec![comps(0.0), comps(4.0)]).unwrap();
    let gmm = Hmm::new(vec![0.5, 0.5], vec![0.9, 0.1, 0.2, 0.8], mix).unwrap();
    let (gmm_data, _) = sample_set(&gmm, 3, 40, 4);
    let gmm = BaumWelch::builder()
        .max_iter(3)
        .build()
        .unwrap()
        .fit_from(gmm, &gmm_data)
        .unwrap()
        .model;
    round_trip(&gmm, &gmm_data);
}

#[test]
fn invalid_model_json_is_refused() {
    let hmm = three_state_truth();
    let good = serde_json::to_value(&hmm).unwrap();
    let parse = |v: &serde_json::Value| serde_json::from_value::<Hmm<Gaussian>>(v.clone());
    assert!(parse(&good).is_ok());

    let mut v = good.clone();
    v["format_version"] = serde_json::json!(MODEL_FORMAT_VERSION + 1);
    let err = parse(&v).unwrap_err().to_string();
    assert!(err.contains("format version"), "{err}");

    let mut v = good.clone();
    v["transition"][1] = serde_json::json!(0.3); // row 0 now sums to 1.2
    let err = parse(&v).unwrap_err().to_string();
    assert!(err.contains("row 0") && err.contains("not 1"), "{err}");

    let mut v = good.clone();
    v["start"][0] = serde_json::json!(-0.1);
    assert!(parse(&v).is_err());

    let mut v = good.clone();
    // State 1's covariance [[1, 2], [2, 1]] is symmetric but indefinite.
    for (k, val) in [1.0, 2.0, 2.0, 1.0].iter().enumerate() {
        v["emission"]["covariances"][4 + k] = serde_json::json!(val);
    }
    let err = parse(&v).unwrap_err().to_string();
    assert!(
        err.contains("state 1") && err.contains("positive definite"),
        "{err}"
    );

    let mut v = good.clone();
    v["emission"]["covariances"][1] = serde_json::json!(0.9); // asymmetric
    assert!(parse(&v).is_err());

    let mut v = good.clone();
    v["emission"]["means"] = serde_json::json!([0.0, 1.0]); // 1 state, but 3 in start/A
    assert!(parse(&v).is_err());

    let mut v = good.clone();
    v.as_object_mut().unwrap().remove("format_version");
    assert!(parse(&v).is_err());

    let text = serde_json::to_string(&good).unwrap();
    assert!(serde_json::from_str::<Hmm<Gaussian>>(&text[..text.len() / 2]).is_err());

    // The other emissions validate too.
    let cat = Hmm::new(
        vec![1.0],
        vec![1.0],
        Categorical::new(2, vec![0.5, 0.5]).unwrap(),
    )
    .unwrap();
    let mut v = serde_json::to_value(&cat).unwrap();
    v["emission"]["probabilities"] = serde_json::json!([0.5, 0.6]);
    assert!(serde_json::from_value::<Hmm<Categorical>>(v).is_err());
    let poi = Hmm::new(vec![1.0], vec![1.0], Poisson::new(1, vec![2.0]).unwrap()).unwrap();
    let mut v = serde_json::to_value(&poi).unwrap();
    v["emission"]["rates"] = serde_json::json!([-2.0]);
    assert!(serde_json::from_value::<Hmm<Poisson>>(v).is_err());
}

// ---------------------------------------------------------------------------
// Errors say where
// ---------------------------------------------------------------------------

#[test]
fn errors_name_the_sequence_frame_and_column() {
    let hmm = three_state_truth();

    // Empty sequences.
    let err = hmm
        .log_likelihood(Frames::new(&[], 2).unwrap())
        .unwrap_err();
    assert!(
        matches!(err, HmmError::EmptySequence { sequence: 0 }),
        "{err:?}"
    );
    let err = SequenceSet::new(&[vec![0.0, 1.0], vec![]], 2)
        .unwrap_err()
        .to_string();
    assert!(err.contains("sequence 1") && err.contains("empty"), "{err}");

    // Infinity in the data (NaN means "not observed" and is accepted).
    let mut bad = vec![vec![0.0; 8], vec![0.0; 6], vec![0.0; 10]];
    bad[2][3 * 2 + 1] = f64::NEG_INFINITY;
    let err = SequenceSet::new(&bad, 2).unwrap_err().to_string();
    assert!(err.contains("sequence 2, frame 3, column 1"), "{err}");
    bad[2][3 * 2 + 1] = f64::NAN;
    let set = SequenceSet::new(&bad, 2).unwrap();
    assert!(set.has_missing() && set.get(2).has_missing() && !set.get(0).has_missing());
    bad[2][3 * 2 + 1] = 0.0;
    bad[1][2 * 2] = f64::INFINITY;
    let err = SequenceSet::new(&bad, 2).unwrap_err().to_string();
    assert!(err.contains("sequence 1, frame 2, column 0"), "{err}");

    // Wrong dimension.
    let data3 = SequenceSet::new(&[vec![0.0; 9], vec![0.0; 6]], 3).unwrap();
    let err = hmm.log_likelihood(data3.get(1)).unwrap_err();
    assert!(
        matches!(
            &err,
            HmmError::Emission {
                source: EmissionError::DimensionMismatch {
                    expected: 2,
                    found: 3,
                    ..
                },
                ..
            }
        ),
        "{err:?}"
    );
    let err = BaumWelch::builder()
        .build()
        .unwrap()
        .fit_from(hmm.clone(), &data3)
        .unwrap_err();
    assert!(
        err.to_string().contains("sequence 0") && err.to_string().contains("expected 2, found 3"),
        "{err}"
    );
    let err = BaumWelch::builder()
        .build()
        .unwrap()
        .fit(hmm.emission(), &data3)
        .unwrap_err();
    assert!(err.to_string().contains("expected 2, found 3"), "{err}");
    assert!(hmm.filter().step(&[0.0, 1.0, 2.0]).is_err());
    assert!(hmm.filter().step(&[]).is_err());
    assert!(hmm.filter().step(&[0.0, f64::INFINITY]).is_err());
    // NaN is "not observed": the filter runs on the observed dimension.
    assert!(hmm.filter().step(&[0.0, f64::NAN]).is_ok());
    let data1 = SequenceSet::new(&[vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]], 1).unwrap();
    assert!(hmm.log_likelihood_all(&data1).is_err());

    // Categorical symbols out of range (and not whole numbers).
    let cat = Hmm::new(
        vec![0.5, 0.5],
        vec![0.9, 0.1, 0.1, 0.9],
        Categorical::new(4, vec![0.25; 8]).unwrap(),
    )
    .unwrap();
    for bad_symbol in [4.0, 7.0, -1.0, 1.5] {
        let seqs = vec![
            vec![0.0, 1.0, 2.0],
            vec![3.0, 2.0, 1.0, 0.0, bad_symbol, 1.0],
        ];
        let data = SequenceSet::new(&seqs, 1).unwrap();
        let err = BaumWelch::builder()
            .build()
            .unwrap()
            .fit_from(cat.clone(), &data)
            .unwrap_err();
        assert!(
            matches!(
                &err,
                HmmError::Emission {
                    sequence: Some(1),
                    source: EmissionError::InvalidValue {
                        frame: 4,
                        column: 0,
                        ..
                    }
                }
            ),
            "{err:?}"
        );
        let msg = err.to_string();
        assert!(
            msg.contains("sequence 1") && msg.contains("frame 4"),
            "{msg}"
        );
        let template = Categorical::uniform(2, 4).unwrap();
        let msg = BaumWelch::builder()
            .build()
            .unwrap()
            .fit(&template, &data)
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("sequence 1") && msg.contains("frame 4"),
            "{msg}"
        );
        let msg = cat.log_likelihood_all(&data).unwrap_err().to_string();
        assert!(
            msg.contains("sequence 1") && msg.contains("frame 4"),
            "{msg}"
        );
        assert!(cat.filter().step(&[bad_symbol]).is_err());
    }

    // Poisson counts must be whole and non-negative.
    let poi = Hmm::new(
        vec![1.0],
        vec![1.0],
        Poisson::new(2, vec![1.0, 2.0]).unwrap(),
    )
    .unwrap();
    let data = SequenceSet::new(&[vec![1.0, 2.0, 3.0, -1.0]], 2).unwrap();
    let msg = poi.log_likelihood_all(&data).unwrap_err().to_string();
    assert!(
        msg.contains("sequence 0") && msg.contains("frame 1, column 1"),
        "{msg}"
    );

    // Invalid settings are refused at build time.
    assert!(BaumWelch::builder().restarts(0).build().is_err());
    assert!(BaumWelch::builder().threads(0).build().is_err());
    assert!(BaumWelch::builder().tol(f64::NAN).build().is_err());
    assert!(BaumWelch::builder()
        .init(HmmInit::KBins { smoothing: 1.5 })
        .build()
        .is_err());
    // Too few frames for the number of states.
    let tiny = SequenceSet::new(&[vec![0.0, 0.0, 1.0, 1.0]], 2).unwrap();
    assert!(matches!(
        BaumWelch::builder()
            .build()
            .unwrap()
            .fit(hmm.emission(), &tiny),
        Err(HmmError::TooFewFrames(_))
    ));
}

// ---------------------------------------------------------------------------
// AIC / BIC
// ---------------------------------------------------------------------------

#[test]
fn information_criteria_count_parameters() {
    let hmm = three_state_truth();
    let (s, d) = (3usize, 2usize);
    let p = (s - 1) + s * (s - 1) + s * d + s * d * (d + 1) / 2;
    assert_eq!(hmm.n_parameters(), p);
    assert_eq!(p, 23);

    let (data, _) = sample_set(&hmm, 2, 50, 8);
    let ll = hmm.log_likelihood_all(&data).unwrap();
    let (aic, bic) = (hmm.aic(&data).unwrap(), hmm.bic(&data).unwrap());
    assert!((aic - (-2.0 * ll + 2.0 * p as f64)).abs() < 1e-9 * aic.abs());
    assert!((bic - (-2.0 * ll + p as f64 * 100f64.ln())).abs() < 1e-9 * bic.abs());
    assert!(bic > aic, "ln(100) > 2");
    // With N = 5 frames ln N < 2, so BIC < AIC.
    let short = SequenceSet::new(&[data.get(0).slice(0..5).as_slice()], 2).unwrap();
    assert!(hmm.bic(&short).unwrap() < hmm.aic(&short).unwrap());

    // Other structures.
    let chain = (s - 1) + s * (s - 1);
    let means = vec![0.0; s * d];
    let n = |kind, covs: Vec<f64>| {
        Hmm::new(
            vec![1.0 / 3.0; 3],
            vec![1.0 / 3.0; 9],
            Gaussian::new(kind, d, means.clone(), covs).unwrap(),
        )
        .unwrap()
        .n_parameters()
    };
    assert_eq!(
        n(CovarianceType::Diagonal, vec![1.0; s * d]),
        chain + s * d + s * d
    );
    assert_eq!(
        n(CovarianceType::Spherical, vec![1.0; s]),
        chain + s * d + s
    );
    assert_eq!(
        n(CovarianceType::Tied, vec![1.0, 0.0, 0.0, 1.0]),
        chain + s * d + d * (d + 1) / 2
    );
    let cat = Hmm::new(
        vec![0.5, 0.5],
        vec![0.5; 4],
        Categorical::uniform(2, 5).unwrap(),
    )
    .unwrap();
    assert_eq!(cat.n_parameters(), 1 + 2 + 2 * 4);
    let poi = Hmm::new(vec![0.5, 0.5], vec![0.5; 4], Poisson::unit(2, 3).unwrap()).unwrap();
    assert_eq!(poi.n_parameters(), 1 + 2 + 2 * 3);
    let comp = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 2,
            dim: d,
        },
    )
    .unwrap();
    let mix = MixtureEmission::new(vec![0.5; 4], vec![comp.clone(), comp]).unwrap();
    let gmm = Hmm::new(vec![0.5, 0.5], vec![0.5; 4], mix).unwrap();
    // π and A, the S × (M − 1) weights, and M full Gaussians per state.
    let (s2, m) = (2, 2);
    assert_eq!(
        gmm.n_parameters(),
        (s2 - 1) + s2 * (s2 - 1) + s2 * (m - 1) + s2 * m * (d + d * (d + 1) / 2)
    );
}

// ---------------------------------------------------------------------------
// Mixture emissions
// ---------------------------------------------------------------------------

/// Each state as a one-component mixture.
fn as_mixture(g: &Gaussian) -> MixtureEmission<Gaussian> {
    let (s, d) = (g.n_states(), g.dim());
    let comps = (0..s)
        .map(|i| {
            let covs = match g.covariance_type() {
                CovarianceType::Full => g.covariances_raw()[i * d * d..(i + 1) * d * d].to_vec(),
                CovarianceType::Diagonal => g.covariances_raw()[i * d..(i + 1) * d].to_vec(),
                CovarianceType::Spherical => vec![g.covariances_raw()[i]],
                CovarianceType::Tied => g.covariances_raw().to_vec(),
            };
            Gaussian::new(g.covariance_type(), d, g.mean(i).to_vec(), covs).unwrap()
        })
        .collect();
    MixtureEmission::new(vec![1.0; s], comps).unwrap()
}

#[test]
fn one_component_mixture_equals_the_plain_gaussian() {
    let truth = three_state_truth();
    let (data, _) = sample_set(&truth, 4, 50, 21);
    let covs = |kind| match kind {
        CovarianceType::Full => truth.emission().covariances_raw().to_vec(),
        CovarianceType::Diagonal => vec![1.0, 0.8, 0.7, 1.2, 1.0, 1.0],
        CovarianceType::Spherical => vec![0.9, 1.1, 1.0],
        CovarianceType::Tied => vec![1.0, 0.2, 0.2, 0.9],
    };
    for kind in [
        CovarianceType::Full,
        CovarianceType::Diagonal,
        CovarianceType::Spherical,
        CovarianceType::Tied,
    ] {
        let g = Gaussian::new(kind, 2, truth.emission().means().to_vec(), covs(kind)).unwrap();
        let plain = Hmm::new(
            truth.start().to_vec(),
            truth.transition().to_vec(),
            g.clone(),
        )
        .unwrap();
        let mixed = Hmm::new(
            truth.start().to_vec(),
            truth.transition().to_vec(),
            as_mixture(&g),
        )
        .unwrap();
        let (a, b) = (
            plain.log_likelihood_all(&data).unwrap(),
            mixed.log_likelihood_all(&data).unwrap(),
        );
        assert!((a - b).abs() <= 1e-12 * a.abs(), "{kind:?}: {a} vs {b}");
        let (pa, pb) = (
            plain.posteriors(data.get(0)).unwrap(),
            mixed.posteriors(data.get(0)).unwrap(),
        );
        assert!(max_abs_diff(&pa.gamma, &pb.gamma) < 1e-12);

        // One ML step gives the same parameters (tied differs by design: a one-component
        // mixture per state re-estimates a covariance per state, not a shared one).
        if kind == CovarianceType::Tied {
            continue;
        }
        let bw = BaumWelch::builder()
            .max_iter(1)
            .tol(f64::NEG_INFINITY)
            .build()
            .unwrap();
        let (fa, fb) = (
            bw.fit_from(plain, &data).unwrap().model,
            bw.fit_from(mixed, &data).unwrap().model,
        );
        assert!(max_abs_diff(fa.transition(), fb.transition()) < 1e-12);
        assert!(max_abs_diff(fa.start(), fb.start()) < 1e-12);
        for i in 0..3 {
            let c = fb.emission().components(i);
            assert!(
                max_abs_diff(fa.emission().mean(i), c.mean(0)) < 1e-12,
                "{kind:?} state {i}"
            );
            assert!(
                (fa.emission().covariance(i) - c.covariance(0)).abs().max() < 1e-12,
                "{kind:?} state {i}"
            );
            assert_eq!(fb.emission().weights()[i], 1.0);
        }
    }
}
