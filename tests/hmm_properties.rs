//! Property tests of the HMM algorithms against slow, obvious versions.
//!
//! Small random models (`S = 1..=4` states, `T = 1..=6` frames, 1–2-D Gaussians
//! with random full covariances, and categorical emissions), with structural
//! zeros in `π`, `A` and the categorical probabilities, are checked against a
//! brute-force enumeration of all `S^T` state paths in log space, with
//! emission log-densities computed independently (`nalgebra` inverse and
//! determinant for the Gaussian). Every model is drawn from a `ChaCha8Rng`
//! seeded by proptest, and proptest itself runs from a fixed seed (override
//! with `PROPTEST_RNG_SEED`), so every run is reproducible.

use nalgebra::{DMatrix, DVector};
use phasekit::emission::{
    Categorical, Emission, Frames, Gaussian, GaussianStats, Regularisation, SequenceSet,
};
use phasekit::hmm::{BaumWelch, ExpectedStatistics, ForwardFilter, Hmm, HmmError};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const TOL: f64 = 1e-9;

fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::with_cases(cases);
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x9a5e_417e);
    }
    c.failure_persistence = None;
    c
}

// ---------------------------------------------------------------------------
// Random models
// ---------------------------------------------------------------------------

/// `rows × cols` row-stochastic matrix; each entry is a structural zero with
/// probability `zero_prob`, but every row keeps at least one positive entry.
fn stochastic_rows(rng: &mut ChaCha8Rng, rows: usize, cols: usize, zero_prob: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(rows * cols);
    for _ in 0..rows {
        let keep = rng.random_range(0..cols);
        let mut row: Vec<f64> = (0..cols)
            .map(|j| {
                if j != keep && rng.random::<f64>() < zero_prob {
                    0.0
                } else {
                    rng.random_range(0.05..1.0)
                }
            })
            .collect();
        let total: f64 = row.iter().sum();
        row.iter_mut().for_each(|v| *v /= total);
        out.extend(row);
    }
    out
}

/// Random SPD matrix `L Lᵀ` (row-major), well enough conditioned for the data range used.
fn random_covariance(rng: &mut ChaCha8Rng, d: usize) -> DMatrix<f64> {
    let l = DMatrix::from_fn(d, d, |r, c| {
        if r == c {
            rng.random_range(0.5..1.5)
        } else if c < r {
            rng.random_range(-0.8..0.8)
        } else {
            0.0
        }
    });
    let cov = &l * l.transpose();
    (&cov + cov.transpose()) * 0.5
}

fn row_major(m: &DMatrix<f64>) -> Vec<f64> {
    m.transpose().iter().copied().collect()
}

/// A random full-covariance Gaussian emission and its parameters for the reference density.
struct RandomGaussian {
    emission: Gaussian,
    means: Vec<DVector<f64>>,
    covs: Vec<DMatrix<f64>>,
}

fn random_gaussian(rng: &mut ChaCha8Rng, s: usize, d: usize) -> RandomGaussian {
    let means: Vec<DVector<f64>> = (0..s)
        .map(|_| DVector::from_fn(d, |_, _| rng.random_range(-2.0..2.0)))
        .collect();
    let covs: Vec<DMatrix<f64>> = (0..s).map(|_| random_covariance(rng, d)).collect();
    let emission = Gaussian::full(
        d,
        means.iter().flat_map(|m| m.iter().copied()).collect(),
        covs.iter().flat_map(row_major).collect(),
    )
    .unwrap();
    RandomGaussian {
        emission,
        means,
        covs,
    }
}

/// The textbook density, with an explicit inverse and determinant.
fn ref_gaussian_log_density(mean: &DVector<f64>, cov: &DMatrix<f64>, x: &[f64]) -> f64 {
    let d = mean.len();
    let diff = DVector::from_column_slice(x) - mean;
    let inv = cov.clone().try_inverse().unwrap();
    let maha = (diff.transpose() * inv * &diff)[(0, 0)];
    -0.5 * (d as f64 * (2.0 * std::f64::consts::PI).ln() + cov.determinant().ln() + maha)
}

fn ref_gaussian_log_b(g: &RandomGaussian, frames: &[f64], dims: &[usize]) -> Vec<f64> {
    let d_full = g.means[0].len();
    let mut out = Vec::new();
    for x in frames.chunks_exact(d_full) {
        let xs: Vec<f64> = dims.iter().map(|&k| x[k]).collect();
        for (m, c) in g.means.iter().zip(&g.covs) {
            let ms = DVector::from_iterator(dims.len(), dims.iter().map(|&k| m[k]));
            let cs = DMatrix::from_fn(dims.len(), dims.len(), |r, q| c[(dims[r], dims[q])]);
            out.push(ref_gaussian_log_density(&ms, &cs, &xs));
        }
    }
    out
}

// ---------------------------------------------------------------------------
// Brute force over all S^T paths (log space)
// ---------------------------------------------------------------------------

fn lse(xs: &[f64]) -> f64 {
    let m = xs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    m + xs.iter().map(|v| (v - m).exp()).sum::<f64>().ln()
}

fn decode(mut idx: usize, s: usize, len: usize) -> Vec<usize> {
    let mut z = vec![0; len];
    for slot in z.iter_mut() {
        *slot = idx % s;
        idx /= s;
    }
    z
}

/// `log p(z, x)` of a whole path.
fn path_log_prob(start: &[f64], trans: &[f64], log_b: &[f64], s: usize, z: &[usize]) -> f64 {
    let mut lp = start[z[0]].ln() + log_b[z[0]];
    for t in 1..z.len() {
        lp += trans[z[t - 1] * s + z[t]].ln() + log_b[t * s + z[t]];
    }
    lp
}

struct Brute {
    log_p: f64,
    gamma: Vec<f64>,
    xi: Vec<f64>,
    best: f64,
    log_alpha: Vec<f64>,
    log_beta: Vec<f64>,
}

fn brute_force(start: &[f64], trans: &[f64], log_b: &[f64], s: usize) -> Brute {
    let t_len = log_b.len() / s;
    let n_paths = s.pow(t_len as u32);
    let paths: Vec<Vec<usize>> = (0..n_paths).map(|k| decode(k, s, t_len)).collect();
    let lps: Vec<f64> = paths
        .iter()
        .map(|z| path_log_prob(start, trans, log_b, s, z))
        .collect();
    let log_p = lse(&lps);
    let best = lps.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut gamma = vec![0.0; t_len * s];
    let mut xi = vec![0.0; s * s];
    if log_p > f64::NEG_INFINITY {
        for (z, lp) in paths.iter().zip(&lps) {
            let w = (lp - log_p).exp();
            for t in 0..t_len {
                gamma[t * s + z[t]] += w;
                if t + 1 < t_len {
                    xi[z[t] * s + z[t + 1]] += w;
                }
            }
        }
    }
    // α_t(i): all prefixes z_0..z_t ending in i.
    let mut log_alpha = vec![f64::NEG_INFINITY; t_len * s];
    for t in 0..t_len {
        for i in 0..s {
            let terms: Vec<f64> = (0..s.pow(t as u32))
                .map(|k| {
                    let mut z = decode(k, s, t);
                    z.push(i);
                    path_log_prob(start, trans, &log_b[..(t + 1) * s], s, &z)
                })
                .collect();
            log_alpha[t * s + i] = lse(&terms);
        }
    }
    // β_t(i): all suffixes z_{t+1}..z_{T-1} after i.
    let mut log_beta = vec![0.0; t_len * s];
    for t in 0..t_len {
        let rest = t_len - 1 - t;
        for i in 0..s {
            let terms: Vec<f64> = (0..s.pow(rest as u32))
                .map(|k| {
                    let z = decode(k, s, rest);
                    let mut lp = 0.0;
                    let mut prev = i;
                    for (u, zu) in z.iter().enumerate() {
                        lp += trans[prev * s + zu].ln() + log_b[(t + 1 + u) * s + zu];
                        prev = *zu;
                    }
                    lp
                })
                .collect();
            log_beta[t * s + i] = lse(&terms);
        }
    }
    Brute {
        log_p,
        gamma,
        xi,
        best,
        log_alpha,
        log_beta,
    }
}

// ---------------------------------------------------------------------------
// Checks
// ---------------------------------------------------------------------------

fn close_log(what: &str, got: f64, want: f64) -> Result<(), TestCaseError> {
    prop_assert!(!got.is_nan(), "{what}: NaN (want {want})");
    if want == f64::NEG_INFINITY {
        prop_assert_eq!(got, f64::NEG_INFINITY, "{}: want -inf", what);
    } else {
        prop_assert!(
            (got - want).abs() <= TOL * want.abs().max(1.0),
            "{what}: got {got}, brute force {want}"
        );
    }
    Ok(())
}

fn close_abs(what: &str, got: &[f64], want: &[f64], tol: f64) -> Result<(), TestCaseError> {
    prop_assert_eq!(got.len(), want.len(), "{}: length", what);
    for (k, (g, w)) in got.iter().zip(want).enumerate() {
        prop_assert!((g - w).abs() <= tol, "{what}[{k}]: got {g}, want {w}");
    }
    Ok(())
}

/// Every inference routine of `hmm` on one sequence against the brute force
/// built on the independent log-densities `log_b_ref`.
fn check_inference<E: Emission>(
    hmm: &Hmm<E>,
    data: &[f64],
    dim: usize,
    log_b_ref: &[f64],
) -> Result<(), TestCaseError> {
    let s = hmm.n_states();
    let seq = Frames::new(data, dim).unwrap();
    let t_len = seq.len();

    // Emission log-densities against the textbook formula.
    let log_b = hmm.emission_log_densities(seq).unwrap();
    for (k, (g, w)) in log_b.iter().zip(log_b_ref).enumerate() {
        close_log(&format!("log b[{k}]"), *g, *w)?;
    }

    let brute = brute_force(hmm.start(), hmm.transition(), log_b_ref, s);

    // Forward log-likelihood.
    let fwd = hmm.forward(seq).unwrap();
    let ll = fwd.log_likelihood();
    close_log("forward log-likelihood", ll, brute.log_p)?;
    prop_assert_eq!(hmm.log_likelihood(seq).unwrap().to_bits(), ll.to_bits());
    prop_assert_eq!(fwd.log_normalisers().len(), t_len);

    // Filtered rows are distributions (zero after the first impossible frame).
    let first_impossible = fwd
        .log_normalisers()
        .iter()
        .position(|v| *v == f64::NEG_INFINITY);
    for (t, row) in fwd.filtered().chunks_exact(s).enumerate() {
        prop_assert!(row.iter().all(|v| v.is_finite() && *v >= 0.0));
        let total: f64 = row.iter().sum();
        match first_impossible {
            Some(f) if t >= f => prop_assert_eq!(total, 0.0),
            _ => prop_assert!(
                (total - 1.0).abs() < 1e-12,
                "filtered row {t} sums to {total}"
            ),
        }
    }
    // The first impossible frame is where the brute-force prefix mass vanishes.
    let brute_first =
        (0..t_len).position(|t| lse(&brute.log_alpha[t * s..(t + 1) * s]) == f64::NEG_INFINITY);
    prop_assert_eq!(first_impossible, brute_first);

    // log α and log β against brute force; log p = logsumexp_i(log α_t(i) + log β_t(i)) for every t.
    let la = fwd.log_alpha();
    let lb = hmm.backward(seq).unwrap();
    prop_assert_eq!(la.len(), t_len * s);
    prop_assert_eq!(lb.len(), t_len * s);
    for k in 0..t_len * s {
        close_log(&format!("log beta[{k}]"), lb[k], brute.log_beta[k])?;
        let row_lse = lse(&brute.log_alpha[k / s * s..(k / s + 1) * s]);
        if brute.log_alpha[k] > f64::NEG_INFINITY && brute.log_alpha[k] - row_lse < -690.0 {
            // Documented on `Forward::log_alpha`: a state holding less than ~1e-300
            // of the frame's filtered mass is not represented exactly (below
            // ~1e-323 it is -inf). It must stay negligible.
            prop_assert!(
                la[k] == f64::NEG_INFINITY || la[k] - row_lse < -600.0,
                "log alpha[{k}] = {}, brute force {} (frame total {row_lse})",
                la[k],
                brute.log_alpha[k]
            );
            continue;
        }
        close_log(&format!("log alpha[{k}]"), la[k], brute.log_alpha[k])?;
    }
    for t in 0..t_len {
        let terms: Vec<f64> = (0..s).map(|i| la[t * s + i] + lb[t * s + i]).collect();
        prop_assert!(terms.iter().all(|v| !v.is_nan()));
        close_log(
            &format!("logsumexp(alpha + beta) at t = {t}"),
            lse(&terms),
            ll,
        )?;
    }

    // Posteriors and expected transitions.
    match hmm.posteriors(seq) {
        Ok(post) => {
            prop_assert!(
                brute.log_p > f64::NEG_INFINITY,
                "posteriors of an impossible sequence"
            );
            close_log(
                "posteriors log-likelihood",
                post.log_likelihood,
                brute.log_p,
            )?;
            for (t, row) in post.gamma.chunks_exact(s).enumerate() {
                let total: f64 = row.iter().sum();
                prop_assert!((total - 1.0).abs() < 1e-12, "gamma row {t} sums to {total}");
            }
            close_abs("gamma", &post.gamma, &brute.gamma, TOL)?;
            close_abs(
                "expected transitions",
                &post.expected_transitions,
                &brute.xi,
                TOL,
            )?;
            let xi_total: f64 = post.expected_transitions.iter().sum();
            prop_assert!((xi_total - (t_len - 1) as f64).abs() < 1e-9);
            // Forbidden transitions are never expected.
            for (x, a) in post.expected_transitions.iter().zip(hmm.transition()) {
                if *a == 0.0 {
                    prop_assert_eq!(*x, 0.0);
                }
            }
        }
        Err(HmmError::ImpossibleSequence { frame, .. }) => {
            prop_assert_eq!(brute.log_p, f64::NEG_INFINITY);
            prop_assert_eq!(Some(frame), brute_first);
        }
        Err(e) => {
            return Err(TestCaseError::fail(format!(
                "posteriors: unexpected error {e}"
            )))
        }
    }

    // Viterbi.
    let v = hmm.viterbi(seq).unwrap();
    prop_assert_eq!(v.states.len(), t_len);
    prop_assert!(v.states.iter().all(|z| *z < s));
    close_log("viterbi log-probability", v.log_probability, brute.best)?;
    if brute.best > f64::NEG_INFINITY {
        let achieved = path_log_prob(hmm.start(), hmm.transition(), log_b_ref, s, &v.states);
        close_log(
            "log-probability of the returned Viterbi path",
            achieved,
            brute.best,
        )?;
    }

    // Online filter, frame by frame, against the batch filter.
    let mut filter = ForwardFilter::new(hmm.clone());
    check_filter(&mut filter, seq, &fwd)?;
    Ok(())
}

/// Steps `filter` through `seq` and compares with the batch forward pass `fwd`.
fn check_filter<E: Emission>(
    filter: &mut ForwardFilter<E>,
    seq: Frames<'_>,
    fwd: &phasekit::hmm::Forward,
) -> Result<(), TestCaseError> {
    let s = filter.model().n_states();
    let mut partial = 0.0;
    for t in 0..seq.len() {
        let lc = fwd.log_normalisers()[t];
        let before = filter.belief().to_vec();
        match filter.step(seq.frame(t)) {
            Ok(belief) => {
                prop_assert!(lc > f64::NEG_INFINITY);
                close_abs(
                    &format!("online belief at t = {t}"),
                    belief,
                    &fwd.filtered()[t * s..(t + 1) * s],
                    1e-12,
                )?;
                partial += lc;
                prop_assert!(
                    (filter.log_likelihood() - partial).abs() <= 1e-12 * partial.abs().max(1.0)
                );
                prop_assert_eq!(filter.frames_seen(), t + 1);
            }
            Err(HmmError::ImpossibleSequence { frame, .. }) => {
                prop_assert_eq!(lc, f64::NEG_INFINITY);
                prop_assert_eq!(frame, t);
                // The belief is left unchanged so that a controller can skip the frame.
                prop_assert_eq!(filter.belief(), &before[..]);
                break;
            }
            Err(e) => {
                return Err(TestCaseError::fail(format!(
                    "filter step: unexpected error {e}"
                )))
            }
        }
    }
    Ok(())
}

fn random_chain(rng: &mut ChaCha8Rng, s: usize) -> (Vec<f64>, Vec<f64>) {
    (
        stochastic_rows(rng, 1, s, 0.35),
        stochastic_rows(rng, s, s, 0.35),
    )
}

proptest! {
    #![proptest_config(config(160))]

    #[test]
    fn gaussian_inference_matches_brute_force(s in 1usize..=4, t_len in 1usize..=6, d in 1usize..=2, far in prop::bool::weighted(0.3), seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (start, trans) = random_chain(&mut rng, s);
        let g = random_gaussian(&mut rng, s, d);
        let hmm = Hmm::new(start, trans, g.emission.clone()).unwrap();
        // `far`: frames up to ~40σ out, where density ratios between states reach
        // and pass e^-745 (the scaled passes must shift, or fall back to log space).
        let range = if far { 40.0 } else { 3.0 };
        let data: Vec<f64> = (0..t_len * d).map(|_| rng.random_range(-range..range)).collect();
        let dims: Vec<usize> = (0..d).collect();
        check_inference(&hmm, &data, d, &ref_gaussian_log_b(&g, &data, &dims))?;

        // Marginal models (the human's dimensions): batch and online filter agree,
        // and the marginal likelihood is the brute force over marginal densities.
        if d == 2 {
            for dims in [vec![0], vec![1], vec![1, 0]] {
                let marginal = hmm.marginal(&dims).unwrap();
                let sel: Vec<f64> = data.chunks_exact(d).flat_map(|x| dims.iter().map(|&k| x[k]).collect::<Vec<_>>()).collect();
                let seq = Frames::new(&sel, dims.len()).unwrap();
                let fwd = marginal.forward(seq).unwrap();
                let log_b_ref = ref_gaussian_log_b(&g, &data, &dims);
                let brute = brute_force(marginal.start(), marginal.transition(), &log_b_ref, s);
                close_log("marginal log-likelihood", fwd.log_likelihood(), brute.log_p)?;
                let mut filter = ForwardFilter::on_dims(&hmm, &dims).unwrap();
                check_filter(&mut filter, seq, &fwd)?;
            }
        }
    }

    #[test]
    fn categorical_inference_matches_brute_force(s in 1usize..=4, t_len in 1usize..=6, k in 2usize..=4, seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (start, trans) = random_chain(&mut rng, s);
        let probs = stochastic_rows(&mut rng, s, k, 0.3);
        let hmm = Hmm::new(start, trans, Categorical::new(k, probs.clone()).unwrap()).unwrap();
        let data: Vec<f64> = (0..t_len).map(|_| rng.random_range(0..k) as f64).collect();
        let log_b_ref: Vec<f64> = data.iter().flat_map(|x| (0..s).map(|i| probs[i * k + *x as usize].ln()).collect::<Vec<_>>()).collect();
        check_inference(&hmm, &data, 1, &log_b_ref)?;
    }
}

/// A symbol reachable only through a forbidden transition: `−inf`, never NaN,
/// everywhere, and the errors name the first impossible frame.
#[test]
fn forbidden_transition_gives_minus_infinity_not_nan() {
    // State i emits symbol i only; 0 → 1 is forbidden (0 → 2 → 1 is allowed).
    let probs = vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let trans = vec![0.5, 0.0, 0.5, 0.0, 1.0, 0.0, 0.2, 0.4, 0.4];
    let hmm = Hmm::new(
        vec![1.0, 0.0, 0.0],
        trans,
        Categorical::new(3, probs).unwrap(),
    )
    .unwrap();
    let possible = [0.0, 2.0, 1.0, 1.0];
    let impossible = [0.0, 2.0, 0.0, 1.0, 1.0];
    let seq = Frames::new(&possible, 1).unwrap();
    let ll = hmm.log_likelihood(seq).unwrap();
    assert!((ll - (0.5f64.ln() + 0.4f64.ln())).abs() < 1e-12, "{ll}");

    let seq = Frames::new(&impossible, 1).unwrap();
    let fwd = hmm.forward(seq).unwrap();
    assert_eq!(fwd.log_likelihood(), f64::NEG_INFINITY);
    assert!(fwd.log_normalisers()[..3].iter().all(|v| v.is_finite()));
    assert!(fwd.log_normalisers()[3..]
        .iter()
        .all(|v| *v == f64::NEG_INFINITY));
    assert!(fwd.filtered().iter().all(|v| v.is_finite()));
    let la = fwd.log_alpha();
    let lb = hmm.backward(seq).unwrap();
    assert!(la.iter().chain(&lb).all(|v| !v.is_nan()));
    assert!(la[3 * 3..].iter().all(|v| *v == f64::NEG_INFINITY));
    for t in 0..5 {
        let terms: Vec<f64> = (0..3).map(|i| la[t * 3 + i] + lb[t * 3 + i]).collect();
        assert_eq!(lse(&terms), f64::NEG_INFINITY, "t = {t}");
    }
    let v = hmm.viterbi(seq).unwrap();
    assert_eq!(v.log_probability, f64::NEG_INFINITY);
    assert!(
        matches!(
            hmm.posteriors(seq),
            Err(HmmError::ImpossibleSequence { frame: 3, .. })
        ),
        "{:?}",
        hmm.posteriors(seq)
    );
    let mut filter = hmm.filter();
    for x in &impossible[..3] {
        filter.step(&[*x]).unwrap();
    }
    let before = filter.belief().to_vec();
    assert!(matches!(
        filter.step(&[1.0]),
        Err(HmmError::ImpossibleSequence { frame: 3, .. })
    ));
    assert_eq!(filter.belief(), &before[..]);
    assert!(filter.log_likelihood().is_finite());

    // Fitting data that contain the impossible sequence names it.
    let data = SequenceSet::new(&[&possible[..], &impossible[..]], 1).unwrap();
    let err = hmm.expected_statistics(&data).unwrap_err();
    assert!(
        matches!(
            err,
            HmmError::ImpossibleSequence {
                sequence: 1,
                frame: 3
            }
        ),
        "{err:?}"
    );
    assert!(err.to_string().contains("sequence 1"), "{err}");
}

// ---------------------------------------------------------------------------
// Baum-Welch monotonicity
// ---------------------------------------------------------------------------

/// Training data sampled from a random 1–2-D full-covariance Gaussian HMM.
fn sampled_data(rng: &mut ChaCha8Rng, s: usize, d: usize, n_seq: usize) -> SequenceSet {
    let (start, trans) = (
        stochastic_rows(rng, 1, s, 0.0),
        stochastic_rows(rng, s, s, 0.2),
    );
    let mut g = random_gaussian(rng, s, d).emission;
    // Spread the true means so that the states are distinguishable.
    let means: Vec<f64> = g.means().iter().map(|m| 2.0 * m).collect();
    g = Gaussian::full(d, means, g.covariances_raw().to_vec()).unwrap();
    let truth = Hmm::new(start[..s].to_vec(), trans, g).unwrap();
    let seqs: Vec<Vec<f64>> = (0..n_seq)
        .map(|_| {
            let len = rng.random_range(15..30);
            truth.sample(len, rng).unwrap().0
        })
        .collect();
    SequenceSet::new(&seqs, d).unwrap()
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

fn em(max_iter: usize, reg: Regularisation) -> BaumWelch {
    BaumWelch::builder()
        .max_iter(max_iter)
        .tol(f64::NEG_INFINITY)
        .regularisation(reg)
        .build()
        .unwrap()
}

proptest! {
    #![proptest_config(config(48))]

    #[test]
    fn baum_welch_never_decreases_its_objective(s in 1usize..=3, d in 1usize..=2, scale in 0.01f64..1.0, dof in 0.0f64..3.0, seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let data = sampled_data(&mut rng, s, d, 4);
        let (start, trans) = random_chain(&mut rng, s);
        let initial = Hmm::new(start, trans, random_gaussian(&mut rng, s, d).emission).unwrap();

        // Pure maximum likelihood: log p(X) is non-decreasing.
        match em(12, Regularisation::none()).fit_from(initial.clone(), &data) {
            Ok(fitted) => {
                prop_assert_eq!(fitted.report.iterations, 12);
                prop_assert_eq!(&fitted.report.objective, &fitted.report.log_likelihood);
                assert_monotone(&fitted.report.log_likelihood)?;
            }
            // Unregularised ML may legitimately collapse a state onto a few points;
            // it must then say so, not panic or return garbage.
            Err(HmmError::Emission { source: phasekit::emission::EmissionError::NotPositiveDefinite { .. }, .. }) => {}
            Err(e) => return Err(TestCaseError::fail(format!("ML fit failed: {e}"))),
        }

        // MAP under an inverse-Wishart prior: the penalised objective is non-decreasing.
        let reg = Regularisation::inverse_wishart(scale, dof).unwrap();
        let fitted = em(12, reg).fit_from(initial.clone(), &data).unwrap();
        prop_assert_eq!(fitted.report.iterations, 12);
        assert_monotone(&fitted.report.objective)?;
        let prior = fitted.report.objective.last().unwrap() - fitted.report.log_likelihood.last().unwrap();
        prop_assert!((prior - fitted.model.emission().log_prior(&reg)).abs() <= 1e-9 * prior.abs().max(1.0));

        // add_diagonal is not the mode of a posterior (no monotonicity claim): it just runs.
        let fitted = em(12, Regularisation::add_diagonal(1e-3).unwrap()).fit_from(initial, &data).unwrap();
        prop_assert!(fitted.report.log_likelihood.iter().all(|v| v.is_finite()));
        prop_assert_eq!(fitted.report.m_steps[0].added_diagonal, 1e-3);
    }

    #[test]
    fn baum_welch_categorical_never_decreases(s in 1usize..=3, k in 2usize..=4, seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let truth = Hmm::new(stochastic_rows(&mut rng, 1, s, 0.0), stochastic_rows(&mut rng, s, s, 0.3),
            Categorical::new(k, stochastic_rows(&mut rng, s, k, 0.0)).unwrap()).unwrap();
        let seqs: Vec<Vec<f64>> = (0..4).map(|_| truth.sample(rng.random_range(5..25), &mut rng).unwrap().0).collect();
        let data = SequenceSet::new(&seqs, 1).unwrap();
        let (start, trans) = random_chain(&mut rng, s);
        let initial = Hmm::new(start, trans, Categorical::new(k, stochastic_rows(&mut rng, s, k, 0.0)).unwrap()).unwrap();
        // A random chain may make the data impossible; then the fit must say so.
        match em(12, Regularisation::none()).fit_from(initial, &data) {
            Ok(fitted) => assert_monotone(&fitted.report.log_likelihood)?,
            Err(HmmError::ImpossibleSequence { .. }) => {}
            Err(e) => return Err(TestCaseError::fail(format!("fit failed: {e}"))),
        }
    }
}

// ---------------------------------------------------------------------------
// Thread-count independence of the E-step and of a whole fit
// ---------------------------------------------------------------------------

fn pool<T: Send>(n: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .unwrap()
        .install(f)
}

/// 16 sequences × 800 frames: 12 800 frames, so ≥ 3 blocks of ≥ 4096 frames.
fn many_sequences() -> (Hmm<Gaussian>, SequenceSet) {
    let g = Gaussian::full(
        2,
        vec![0.0, 0.0, 3.0, 0.0, 0.0, 3.0],
        [1.0, 0.3, 0.3, 1.0].repeat(3),
    )
    .unwrap();
    let truth = Hmm::new(
        vec![0.5, 0.3, 0.2],
        vec![0.9, 0.05, 0.05, 0.05, 0.9, 0.05, 0.05, 0.05, 0.9],
        g,
    )
    .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let seqs: Vec<Vec<f64>> = (0..16)
        .map(|_| truth.sample(800, &mut rng).unwrap().0)
        .collect();
    let data = SequenceSet::new(&seqs, 2).unwrap();
    assert!(data.total_frames() >= 3 * 4096);
    // Start the E-step from a perturbed model so that the statistics are not trivial.
    let g0 = Gaussian::full(
        2,
        vec![0.5, -0.2, 2.5, 0.4, -0.3, 2.0],
        [1.5, 0.0, 0.0, 1.5].repeat(3),
    )
    .unwrap();
    let hmm = Hmm::new(vec![1.0 / 3.0; 3], vec![1.0 / 3.0; 9], g0).unwrap();
    (hmm, data)
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn e_step_is_bit_identical_on_1_and_4_threads() {
    let (hmm, data) = many_sequences();
    let one: ExpectedStatistics<GaussianStats> =
        pool(1, || hmm.expected_statistics(&data)).unwrap();
    let four: ExpectedStatistics<GaussianStats> =
        pool(4, || hmm.expected_statistics(&data)).unwrap();
    assert_eq!(one.log_likelihood.to_bits(), four.log_likelihood.to_bits());
    assert_eq!(bits(&one.start), bits(&four.start));
    assert_eq!(bits(&one.transitions), bits(&four.transitions));
    assert_eq!(one.emission, four.emission);
    assert_eq!(
        (one.n_sequences, one.n_frames),
        (four.n_sequences, four.n_frames)
    );
    assert_eq!((one.n_sequences, one.n_frames), (16, 12_800));

    // And the merged statistics are the per-sequence sums (slow obvious version).
    let mut ll = 0.0;
    let mut start = [0.0; 3];
    let mut trans = [0.0; 9];
    let mut weight = [0.0; 3];
    for seq in data.iter() {
        let p = hmm.posteriors(seq).unwrap();
        ll += p.log_likelihood;
        for i in 0..3 {
            start[i] += p.gamma[i];
            weight[i] += p.gamma.chunks_exact(3).map(|r| r[i]).sum::<f64>();
        }
        for (a, x) in trans.iter_mut().zip(&p.expected_transitions) {
            *a += x;
        }
    }
    assert!((one.log_likelihood - ll).abs() <= 1e-9 * ll.abs());
    for (a, b) in one.start.iter().zip(&start) {
        assert!((a - b).abs() <= 1e-9, "{a} vs {b}");
    }
    for (a, b) in one.transitions.iter().zip(&trans) {
        assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0), "{a} vs {b}");
    }
    for (a, b) in one.emission.weights().iter().zip(&weight) {
        assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0), "{a} vs {b}");
    }
}

#[test]
fn fit_is_bit_identical_on_1_and_4_threads() {
    let (hmm, data) = many_sequences();
    let fit = |n: usize| {
        BaumWelch::builder()
            .max_iter(5)
            .tol(f64::NEG_INFINITY)
            .threads(n)
            .build()
            .unwrap()
            .fit_from(hmm.clone(), &data)
            .unwrap()
    };
    let (one, four) = (fit(1), fit(4));
    assert_eq!(one.report.iterations, 5);
    assert_eq!(
        bits(&one.report.log_likelihood),
        bits(&four.report.log_likelihood)
    );
    assert_eq!(bits(one.model.start()), bits(four.model.start()));
    assert_eq!(bits(one.model.transition()), bits(four.model.transition()));
    assert_eq!(
        bits(one.model.emission().means()),
        bits(four.model.emission().means())
    );
    assert_eq!(
        bits(one.model.emission().covariances_raw()),
        bits(four.model.emission().covariances_raw())
    );
    // The fit moved away from the start (so the comparison is not trivial).
    assert!(one.report.log_likelihood[5] > one.report.log_likelihood[0] + 100.0);

    // The same with initialisation and restarts (`fit`).
    let fit = |n: usize| {
        BaumWelch::builder()
            .max_iter(3)
            .restarts(2)
            .seed(11)
            .threads(n)
            .build()
            .unwrap()
            .fit(hmm.emission(), &data)
            .unwrap()
    };
    let (one, four) = (fit(1), fit(4));
    assert_eq!(
        bits(&one.report.log_likelihood),
        bits(&four.report.log_likelihood)
    );
    assert_eq!(one.report.best_restart, four.report.best_restart);
    assert_eq!(bits(one.model.transition()), bits(four.model.transition()));
    assert_eq!(
        bits(one.model.emission().means()),
        bits(four.model.emission().means())
    );
    assert_eq!(
        bits(one.model.emission().covariances_raw()),
        bits(four.model.emission().covariances_raw())
    );
}

// ---------------------------------------------------------------------------
// Long sequences at extreme scales: the hybrid linear/log recursions
// ---------------------------------------------------------------------------

/// Log-space forward-backward with every frame's messages re-centred:
/// `(log p, γ, Σ_t ξ_t)`, the obvious `O(T S²)` version with `S²` exponentials
/// per frame.
fn log_space_reference(
    start: &[f64],
    trans: &[f64],
    log_b: &[f64],
    s: usize,
) -> (f64, Vec<f64>, Vec<f64>) {
    let t_len = log_b.len() / s;
    let ln = |p: f64| if p > 0.0 { p.ln() } else { f64::NEG_INFINITY };
    let la_tr: Vec<f64> = trans.iter().map(|a| ln(*a)).collect();
    let mut la = vec![0.0; t_len * s];
    let mut lb = vec![0.0; t_len * s];
    let mut ll = 0.0;
    let mut terms = vec![0.0; s];
    for t in 0..t_len {
        for j in 0..s {
            la[t * s + j] = if t == 0 {
                ln(start[j])
            } else {
                for i in 0..s {
                    terms[i] = la[(t - 1) * s + i] + la_tr[i * s + j];
                }
                lse(&terms)
            } + log_b[t * s + j];
        }
        let c = lse(&la[t * s..(t + 1) * s]);
        ll += c;
        la[t * s..(t + 1) * s].iter_mut().for_each(|v| *v -= c);
    }
    for t in (0..t_len - 1).rev() {
        for i in 0..s {
            for j in 0..s {
                terms[j] = la_tr[i * s + j] + log_b[(t + 1) * s + j] + lb[(t + 1) * s + j];
            }
            lb[t * s + i] = lse(&terms);
        }
        let c = lse(&lb[t * s..(t + 1) * s]);
        lb[t * s..(t + 1) * s].iter_mut().for_each(|v| *v -= c);
    }
    let mut gamma = vec![0.0; t_len * s];
    for t in 0..t_len {
        let row: Vec<f64> = (0..s).map(|i| la[t * s + i] + lb[t * s + i]).collect();
        let z = lse(&row);
        for i in 0..s {
            gamma[t * s + i] = (row[i] - z).exp();
        }
    }
    let mut xi = vec![0.0; s * s];
    let mut all = vec![0.0; s * s];
    for t in 0..t_len - 1 {
        for i in 0..s {
            for j in 0..s {
                all[i * s + j] =
                    la[t * s + i] + la_tr[i * s + j] + log_b[(t + 1) * s + j] + lb[(t + 1) * s + j];
            }
        }
        let z = lse(&all);
        for (x, v) in xi.iter_mut().zip(&all) {
            *x += (v - z).exp();
        }
    }
    (ll, gamma, xi)
}

proptest! {
    #![proptest_config(config(300))]

    /// Sequences of up to 150 frames that visit well-separated 1-D states
    /// (log-density gaps of hundreds to thousands of nats), with glitch frames
    /// and transitions that are structurally zero or as small as 1e-300: the
    /// forward and backward passes switch between their linear and log forms
    /// many times, and must still agree with the plain log-space recursion.
    #[test]
    fn long_sequences_at_extreme_scales_match_log_space(s in 2usize..=6, t_len in 20usize..=150, spread in 2.0f64..80.0, tiny in prop::bool::ANY, seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (start, mut trans) = random_chain(&mut rng, s);
        if tiny {
            // Replace some positive off-diagonal entries by 1e-307..1e-200.
            for i in 0..s {
                for j in 0..s {
                    if i != j && trans[i * s + j] > 0.0 && rng.random_bool(0.4) {
                        let small = 10f64.powf(-rng.random_range(200.0..307.0));
                        let moved = trans[i * s + j] - small;
                        trans[i * s + j] = small;
                        trans[i * s + i] += moved;
                    }
                }
            }
        }
        let means: Vec<f64> = (0..s).map(|k| k as f64 * spread).collect();
        let vars: Vec<f64> = (0..s).map(|_| rng.random_range(0.2..2.0)).collect();
        let g = Gaussian::diagonal(1, means.clone(), vars.clone()).unwrap();
        let hmm = Hmm::new(start, trans, g).unwrap();
        // A path that dwells in a state and jumps (a glitch frame 5% of the time).
        let mut state = rng.random_range(0..s);
        let mut x = Vec::with_capacity(t_len);
        for _ in 0..t_len {
            if rng.random_bool(0.1) {
                state = rng.random_range(0..s);
            }
            let k = if rng.random_bool(0.05) { rng.random_range(0..s) } else { state };
            x.push(means[k] + vars[k].sqrt() * rng.random_range(-2.0..2.0));
        }
        let log_b: Vec<f64> = x
            .iter()
            .flat_map(|v| (0..s).map(|k| -0.5 * ((v - means[k]).powi(2) / vars[k] + (2.0 * std::f64::consts::PI * vars[k]).ln())).collect::<Vec<_>>())
            .collect();
        let (ll, gamma, xi) = log_space_reference(hmm.start(), hmm.transition(), &log_b, s);
        let seq = Frames::new(&x, 1).unwrap();
        match hmm.posteriors(seq) {
            Err(HmmError::ImpossibleSequence { .. }) => prop_assert!(ll == f64::NEG_INFINITY, "refused a possible sequence (log p = {ll})"),
            Err(e) => prop_assert!(false, "unexpected error {e}"),
            Ok(post) => {
                prop_assert!(ll.is_finite());
                close_log("log-likelihood", post.log_likelihood, ll)?;
                close_abs("γ", &post.gamma, &gamma, 1e-9)?;
                close_abs("Σξ", &post.expected_transitions, &xi, 1e-9 * t_len as f64)?;
                let fwd = hmm.forward(seq).unwrap();
                close_log("forward log-likelihood", fwd.log_likelihood(), ll)?;
                let mut filter = ForwardFilter::new(hmm.clone());
                check_filter(&mut filter, seq, &fwd)?;
            }
        }
    }
}

/// The E-step runs groups of up to eight sequences through the lane form
/// (one sequence per SIMD lane) when the model has at most 12 states, every
/// `a_ij > 0` and every `π_i ≥ 1e-290`; its statistics must be the
/// per-sequence path's to the bit. Sequences of unequal lengths (one frame,
/// two frames, longer than the lane form takes), missing values, `S = 1`,
/// `S` not a multiple of the lane width, one sequence impossible to explain
/// quickly (a frame far below every state), full and diagonal Gaussians.
#[test]
fn e_step_through_the_lanes_is_the_per_sequence_sum_to_the_bit() {
    for (case, (s, d, kind)) in [
        (1, 1, "diag"),
        (2, 1, "diag"),
        (3, 2, "full"),
        (5, 1, "diag"),
        (9, 2, "diag"),
        (16, 3, "full"),
    ]
    .into_iter()
    .enumerate()
    {
        let mut rng = ChaCha8Rng::seed_from_u64(40 + case as u64);
        let means: Vec<f64> = (0..s * d).map(|_| rng.random_range(-2.0..2.0)).collect();
        let g = if kind == "full" {
            let covs: Vec<f64> = (0..s)
                .flat_map(|_| {
                    let mut c = vec![0.0; d * d];
                    for k in 0..d {
                        c[k * d + k] = rng.random_range(0.5..1.5);
                    }
                    c
                })
                .collect();
            Gaussian::full(d, means, covs).unwrap()
        } else {
            let vars: Vec<f64> = (0..s * d).map(|_| rng.random_range(0.5..1.5)).collect();
            Gaussian::diagonal(d, means, vars).unwrap()
        };
        let row = |rng: &mut ChaCha8Rng| {
            let r: Vec<f64> = (0..s).map(|_| rng.random_range(0.1..1.0)).collect();
            let t: f64 = r.iter().sum();
            r.into_iter().map(|v| v / t).collect::<Vec<f64>>()
        };
        let start = row(&mut rng);
        let a: Vec<f64> = (0..s).flat_map(|_| row(&mut rng)).collect();
        let hmm = Hmm::new(start, a, g).unwrap();
        let lens = [1usize, 2, 37, 100, 100, 5, 100, 64, 3, 1, 80, 4100, 90, 17];
        let seqs: Vec<Vec<f64>> = lens
            .iter()
            .enumerate()
            .map(|(k, t)| {
                let mut x: Vec<f64> = (0..t * d).map(|_| rng.random_range(-3.0..3.0)).collect();
                if k == 3 {
                    x[10 * d] = f64::NAN; // a missing value
                }
                if k == 6 {
                    x[50 * d] = 1e5; // far below every state
                }
                x
            })
            .collect();
        let data = SequenceSet::new(&seqs, d).unwrap();
        let stats: ExpectedStatistics<GaussianStats> =
            pool(1, || hmm.expected_statistics(&data)).unwrap();
        // The per-sequence path, in the E-step's blocks (≥ 4096 frames each).
        let mut blocks: Vec<ExpectedStatistics<GaussianStats>> = Vec::new();
        let mut frames = 4096;
        for seq in data.iter() {
            if frames >= 4096 {
                blocks.push(ExpectedStatistics {
                    log_likelihood: 0.0,
                    start: vec![0.0; s],
                    transitions: vec![0.0; s * s],
                    emission: hmm.emission().new_stats(),
                    n_sequences: 0,
                    n_frames: 0,
                });
                frames = 0;
            }
            frames += seq.len();
            let b = blocks.last_mut().unwrap();
            let p = hmm.posteriors(seq).unwrap();
            b.log_likelihood += p.log_likelihood;
            for (x, g) in b.start.iter_mut().zip(&p.gamma) {
                *x += g;
            }
            for (x, v) in b.transitions.iter_mut().zip(&p.expected_transitions) {
                *x += v;
            }
            b.n_sequences += 1;
            b.n_frames += seq.len();
            hmm.emission()
                .accumulate(seq, &p.gamma, &mut b.emission)
                .unwrap();
        }
        let mut want = blocks.remove(0);
        for b in &blocks {
            want.merge(b).unwrap();
        }
        assert_eq!(
            stats.log_likelihood.to_bits(),
            want.log_likelihood.to_bits(),
            "S = {s}"
        );
        assert_eq!(bits(&stats.start), bits(&want.start), "S = {s}");
        assert_eq!(bits(&stats.transitions), bits(&want.transitions), "S = {s}");
        assert_eq!(stats.emission, want.emission, "S = {s}");
    }
}
