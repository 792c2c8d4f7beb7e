//! The formulas of the HMM and their fast paths (`phasekit::hmm::inference`).
//!
//! 1. Every reference function of `inference::formulas` (forward and backward
//!    variables, state and transition posteriors, likelihood, Viterbi
//!    variable, M-step of `π` and `A`) against the enumeration of every state
//!    path, on small random chains with structural zeros and impossible frames.
//! 2. Every fast path (the scaled forward filter, the interleaved
//!    forward–backward with its posteriors, Viterbi, the M-step, the online
//!    filter) against those references, on longer sequences at extreme scales
//!    (density gaps of thousands of nats, transitions down to 1e-300), where
//!    the recursions switch between their linear and log forms.
//! 3. The same bits with every instruction set the CPU offers (portable,
//!    AVX2 + FMA, AVX-512): forward, posteriors, Viterbi, the E-step and a
//!    whole fit.
//! 4. The online filter on frames with missing values: the batch forward
//!    pass on the same frames, to the bit.
//!
//! proptest runs from a fixed seed (override with `PROPTEST_RNG_SEED`).
// The enumerations index several arrays by the same state, as the formulas
// are written.
#![allow(clippy::needless_range_loop)]

use phasekit::emission::linalg::{simd_level, with_simd_level, SimdLevel};
use phasekit::emission::{Categorical, Frames, Gaussian, Regularisation, SequenceSet};
use phasekit::hmm::inference::formulas;
use phasekit::hmm::{BaumWelch, ForwardFilter, Hmm, HmmError, Update};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::Mutex;

fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::with_cases(cases);
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x5eed_f0a1);
    }
    c.failure_persistence = None;
    c
}

fn ln0(p: f64) -> f64 {
    if p > 0.0 {
        p.ln()
    } else {
        f64::NEG_INFINITY
    }
}

fn lse(xs: &[f64]) -> f64 {
    let m = xs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    m + xs.iter().map(|v| (v - m).exp()).sum::<f64>().ln()
}

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

// ---------------------------------------------------------------------------
// 1. The formulas against the enumeration of every path
// ---------------------------------------------------------------------------

fn decode(mut idx: usize, s: usize, len: usize) -> Vec<usize> {
    let mut z = vec![0; len];
    for slot in z.iter_mut() {
        *slot = idx % s;
        idx /= s;
    }
    z
}

/// `log p(z_0 … z_{len−1}, x_0 … x_{len−1})`.
fn path_log_prob(ls: &[f64], la: &[f64], lb: &[f64], s: usize, z: &[usize]) -> f64 {
    let mut lp = ls[z[0]] + lb[z[0]];
    for t in 1..z.len() {
        lp += la[z[t - 1] * s + z[t]] + lb[t * s + z[t]];
    }
    lp
}

fn close(what: &str, got: f64, want: f64, tol: f64) -> Result<(), TestCaseError> {
    prop_assert!(!got.is_nan(), "{what}: NaN (want {want})");
    if want.is_infinite() {
        prop_assert_eq!(got, want, "{}", what);
    } else {
        prop_assert!(
            (got - want).abs() <= tol * want.abs().max(1.0),
            "{what}: got {got}, want {want}"
        );
    }
    Ok(())
}

proptest! {
    #![proptest_config(config(200))]

    /// α, β, γ, ξ, log p and δ of `formulas` against sums and maxima over
    /// all `S^T` paths, with zeros in π and A and some impossible
    /// (state, frame) pairs.
    #[test]
    fn formulas_match_the_enumeration_of_paths(s in 1usize..=4, t_len in 1usize..=6, seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let ls: Vec<f64> = stochastic_rows(&mut rng, 1, s, 0.3).into_iter().map(ln0).collect();
        let a = stochastic_rows(&mut rng, s, s, 0.3);
        let la: Vec<f64> = a.iter().map(|v| ln0(*v)).collect();
        let lb: Vec<f64> = (0..t_len * s)
            .map(|_| if rng.random_bool(0.1) { f64::NEG_INFINITY } else { rng.random_range(-30.0..5.0) })
            .collect();
        let n_paths = s.pow(t_len as u32);
        let paths: Vec<Vec<usize>> = (0..n_paths).map(|k| decode(k, s, t_len)).collect();
        let lps: Vec<f64> = paths.iter().map(|z| path_log_prob(&ls, &la, &lb, s, z)).collect();
        let log_p = lse(&lps);

        let alpha = formulas::forward_variable(&ls, &la, &lb);
        let beta = formulas::backward_variable(&la, &lb);
        close("log p", formulas::log_likelihood(&alpha, s), log_p, 1e-12)?;
        for t in 0..t_len {
            for i in 0..s {
                // α_t(i): every prefix z_0 … z_t ending in i; β_t(i): every suffix after i.
                let pre: Vec<f64> = (0..s.pow(t as u32))
                    .map(|k| {
                        let mut z = decode(k, s, t);
                        z.push(i);
                        path_log_prob(&ls, &la, &lb[..(t + 1) * s], s, &z)
                    })
                    .collect();
                close(&format!("alpha[{t}][{i}]"), alpha[t * s + i], lse(&pre), 1e-12)?;
                let rest = t_len - 1 - t;
                let post: Vec<f64> = (0..s.pow(rest as u32))
                    .map(|k| {
                        let mut lp = 0.0;
                        let mut prev = i;
                        for (u, zu) in decode(k, s, rest).into_iter().enumerate() {
                            lp += la[prev * s + zu] + lb[(t + 1 + u) * s + zu];
                            prev = zu;
                        }
                        lp
                    })
                    .collect();
                close(&format!("beta[{t}][{i}]"), beta[t * s + i], lse(&post), 1e-12)?;
            }
        }
        // δ: the best prefix ending in j.
        let delta = formulas::viterbi_variable(&ls, &la, &lb);
        for t in 0..t_len {
            for j in 0..s {
                let best = paths.iter().filter(|z| z[t] == j)
                    .map(|z| path_log_prob(&ls, &la, &lb[..(t + 1) * s], s, &z[..=t]))
                    .fold(f64::NEG_INFINITY, f64::max);
                close(&format!("delta[{t}][{j}]"), delta[t * s + j], best, 1e-12)?;
            }
        }
        if log_p == f64::NEG_INFINITY {
            return Ok(());
        }
        let gamma = formulas::state_posteriors(&alpha, &beta, s);
        let xi = formulas::expected_transitions(&alpha, &beta, &la, &lb);
        let mut g = vec![0.0; t_len * s];
        let mut x = vec![0.0; s * s];
        for (z, lp) in paths.iter().zip(&lps) {
            let w = (lp - log_p).exp();
            for t in 0..t_len {
                g[t * s + z[t]] += w;
                if t + 1 < t_len {
                    x[z[t] * s + z[t + 1]] += w;
                }
            }
        }
        for k in 0..t_len * s {
            prop_assert!((gamma[k] - g[k]).abs() <= 1e-12, "gamma[{k}]: {} vs {}", gamma[k], g[k]);
        }
        for k in 0..s * s {
            prop_assert!((xi[k] - x[k]).abs() <= 1e-12, "xi[{k}]: {} vs {}", xi[k], x[k]);
        }
        // The M-step: normalised counts, zeros kept.
        let pi = formulas::start_update(&gamma[..s]).unwrap();
        for i in 0..s {
            prop_assert!((pi[i] - g[i] / g[..s].iter().sum::<f64>()).abs() <= 1e-12);
        }
        for (i, row) in formulas::transition_update(&xi, s).into_iter().enumerate() {
            let counts = &x[i * s..(i + 1) * s];
            let total: f64 = counts.iter().sum();
            match row {
                None => prop_assert!(total <= 1e-12, "row {i} has counts {total} but no update"),
                Some(row) => {
                    for j in 0..s {
                        prop_assert!((row[j] - counts[j] / total).abs() <= 1e-9);
                        if a[i * s + j] == 0.0 {
                            prop_assert_eq!(row[j], 0.0);
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn m_step_of_start_and_transitions_handles_empty_counts() {
    assert_eq!(formulas::start_update(&[0.0, 0.0]), None);
    assert_eq!(formulas::start_update(&[1.0, 3.0]), Some(vec![0.25, 0.75]));
    let rows = formulas::transition_update(&[0.0, 0.0, 2.0, 6.0], 2);
    assert_eq!(rows, vec![None, Some(vec![0.25, 0.75])]);
}

// ---------------------------------------------------------------------------
// 2. The fast paths against the formulas
// ---------------------------------------------------------------------------

/// A 1-D Gaussian HMM whose states are `spread` apart (log-density gaps of
/// up to `spread²/2` nats), optionally with transitions as small as 1e-300,
/// and a path that dwells, jumps and glitches.
fn extreme_model(
    rng: &mut ChaCha8Rng,
    s: usize,
    t_len: usize,
    spread: f64,
    tiny: bool,
    zeros: f64,
) -> (Hmm<Gaussian>, Vec<f64>) {
    let start = stochastic_rows(rng, 1, s, zeros);
    let mut trans = stochastic_rows(rng, s, s, zeros);
    if tiny {
        for i in 0..s {
            for j in 0..s {
                if i != j && trans[i * s + j] > 0.0 && rng.random_bool(0.4) {
                    let small = 10f64.powf(-rng.random_range(200.0..300.0));
                    let moved = trans[i * s + j] - small;
                    trans[i * s + j] = small;
                    trans[i * s + i] += moved;
                }
            }
        }
    }
    let means: Vec<f64> = (0..s).map(|k| k as f64 * spread).collect();
    let vars: Vec<f64> = (0..s).map(|_| rng.random_range(0.2..2.0)).collect();
    let hmm = Hmm::new(
        start,
        trans,
        Gaussian::diagonal(1, means.clone(), vars.clone()).unwrap(),
    )
    .unwrap();
    let mut state = rng.random_range(0..s);
    let x = (0..t_len)
        .map(|_| {
            if rng.random_bool(0.1) {
                state = rng.random_range(0..s);
            }
            let k = if rng.random_bool(0.05) {
                rng.random_range(0..s)
            } else {
                state
            };
            means[k] + vars[k].sqrt() * rng.random_range(-2.0..2.0)
        })
        .collect();
    (hmm, x)
}

fn log_params<E: phasekit::emission::Emission>(hmm: &Hmm<E>) -> (Vec<f64>, Vec<f64>) {
    (
        hmm.start().iter().map(|v| ln0(*v)).collect(),
        hmm.transition().iter().map(|v| ln0(*v)).collect(),
    )
}

proptest! {
    #![proptest_config(config(150))]

    /// The scaled forward filter, the interleaved forward–backward with its
    /// posteriors, Viterbi and the backward variable against the log-space
    /// formulas, on sequences of up to 300 frames at extreme scales.
    #[test]
    fn fast_paths_match_the_formulas(s in 1usize..=7, t_len in 1usize..=300, spread in 1.0f64..80.0, tiny in prop::bool::ANY, zeros in prop::sample::select(vec![0.0, 0.3]), seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (hmm, x) = extreme_model(&mut rng, s, t_len, spread, tiny, zeros);
        let seq = Frames::new(&x, 1).unwrap();
        let lb = hmm.emission_log_densities(seq).unwrap();
        let (ls, la) = log_params(&hmm);
        let alpha = formulas::forward_variable(&ls, &la, &lb);
        let beta = formulas::backward_variable(&la, &lb);
        let ll = formulas::log_likelihood(&alpha, s);

        // Forward: log p, and h_t = α_t / Σ α_t.
        let fwd = hmm.forward(seq).unwrap();
        close("forward log p", fwd.log_likelihood(), ll, 1e-10)?;
        if ll > f64::NEG_INFINITY {
            for t in 0..t_len {
                let z = lse(&alpha[t * s..(t + 1) * s]);
                for i in 0..s {
                    let want = (alpha[t * s + i] - z).exp();
                    prop_assert!((fwd.filtered()[t * s + i] - want).abs() <= 1e-10, "h[{t}][{i}]: {} vs {want}", fwd.filtered()[t * s + i]);
                }
            }
        }
        prop_assert_eq!(hmm.log_likelihood(seq).unwrap().to_bits(), fwd.log_likelihood().to_bits());
        // The backward variable is the formula itself.
        prop_assert_eq!(hmm.backward(seq).unwrap(), beta.clone());

        match hmm.posteriors(seq) {
            Err(HmmError::ImpossibleSequence { frame, .. }) => {
                prop_assert_eq!(ll, f64::NEG_INFINITY);
                let first = (0..t_len).position(|t| lse(&alpha[t * s..(t + 1) * s]) == f64::NEG_INFINITY);
                prop_assert_eq!(Some(frame), first);
            }
            Err(e) => prop_assert!(false, "unexpected error {e}"),
            Ok(post) => {
                prop_assert!(ll.is_finite());
                close("posteriors log p", post.log_likelihood, ll, 1e-10)?;
                let gamma = formulas::state_posteriors(&alpha, &beta, s);
                for k in 0..t_len * s {
                    prop_assert!((post.gamma[k] - gamma[k]).abs() <= 1e-9, "gamma[{k}]: {} vs {}", post.gamma[k], gamma[k]);
                }
                let xi = formulas::expected_transitions(&alpha, &beta, &la, &lb);
                for k in 0..s * s {
                    prop_assert!((post.expected_transitions[k] - xi[k]).abs() <= 1e-9 * t_len as f64, "xi[{k}]: {} vs {}", post.expected_transitions[k], xi[k]);
                    if hmm.transition()[k] == 0.0 {
                        prop_assert_eq!(post.expected_transitions[k], 0.0);
                    }
                }
            }
        }

        let v = hmm.viterbi(seq).unwrap();
        let delta = formulas::viterbi_variable(&ls, &la, &lb);
        let best = delta[(t_len - 1) * s..].iter().copied().fold(f64::NEG_INFINITY, f64::max);
        prop_assert_eq!(v.log_probability.to_bits(), best.to_bits());
        if best > f64::NEG_INFINITY {
            // The path achieves δ: its log-probability is the maximum.
            let mut lp = ls[v.states[0]] + lb[v.states[0]];
            for t in 1..t_len {
                lp += la[v.states[t - 1] * s + v.states[t]] + lb[t * s + v.states[t]];
            }
            close("Viterbi path log-probability", lp, best, 1e-12)?;
        }
    }
}

/// `maximise` is the M-step formulas to the bit (with a frozen emission).
#[test]
fn the_m_step_of_pi_and_a_is_the_formula() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let s = 5;
    let (hmm, x) = extreme_model(&mut rng, s, 400, 3.0, false, 0.3);
    let data = SequenceSet::new(&[&x[..200], &x[200..]], 1).unwrap();
    let stats = hmm.expected_statistics(&data).unwrap();
    let update = Update {
        start: true,
        transition: true,
        emission: false,
    };
    let (next, _) = hmm
        .maximise(&stats, update, &Regularisation::none())
        .unwrap();
    let pi = formulas::start_update(&stats.start).unwrap();
    let rows = formulas::transition_update(&stats.transitions, s);
    // `Hmm::new` renormalises a vector only when it is off by more than rounding.
    for (a, b) in next.start().iter().zip(&pi) {
        assert!((a - b).abs() <= 1e-15);
    }
    for (i, row) in rows.iter().enumerate() {
        let want = row
            .clone()
            .unwrap_or_else(|| hmm.transition()[i * s..(i + 1) * s].to_vec());
        for (a, b) in next.transition()[i * s..(i + 1) * s].iter().zip(&want) {
            assert!((a - b).abs() <= 1e-15);
        }
    }
}

// ---------------------------------------------------------------------------
// 3. The same bits with every instruction set
// ---------------------------------------------------------------------------

/// The instruction-set cap is process-wide: tests that set it take turns.
static LEVEL: Mutex<()> = Mutex::new(());

fn levels() -> Vec<SimdLevel> {
    [SimdLevel::Portable, SimdLevel::Avx2Fma, SimdLevel::Avx512]
        .into_iter()
        .filter(|l| *l <= simd_level())
        .collect()
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn every_instruction_set_gives_the_same_bits() {
    let _turn = LEVEL.lock().unwrap_or_else(|e| e.into_inner());
    with_simd_level(SimdLevel::Portable, || {
        assert_eq!(simd_level(), SimdLevel::Portable)
    });
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    // Extreme 1-D chains (both recursions switch forms) and a 12-D full-covariance fit.
    let mut cases = Vec::new();
    for (s, spread, tiny) in [
        (3, 40.0, true),
        (6, 8.0, false),
        (9, 2.0, true),
        (16, 1.0, false),
    ] {
        cases.push(extreme_model(&mut rng, s, 500, spread, tiny, 0.2));
    }
    let reference: Vec<_> = with_simd_level(SimdLevel::Portable, || {
        cases
            .iter()
            .map(|(h, x)| {
                let seq = Frames::new(x, 1).unwrap();
                let f = h.forward(seq).unwrap();
                let p = h.posteriors(seq).ok();
                let v = h.viterbi(seq).unwrap();
                (
                    bits(f.filtered()),
                    bits(f.log_normalisers()),
                    p.map(|p| {
                        (
                            bits(&p.gamma),
                            bits(&p.expected_transitions),
                            p.log_likelihood.to_bits(),
                        )
                    }),
                    v,
                )
            })
            .collect()
    });
    let (truth, data) = generated_12d(&mut rng);
    let fit = |truth: &Hmm<Gaussian>| {
        BaumWelch::builder()
            .max_iter(4)
            .tol(f64::NEG_INFINITY)
            .threads(1)
            .regularisation(Regularisation::inverse_wishart(1e-3, 0.0).unwrap())
            .build()
            .unwrap()
            .fit_from(truth.clone(), &data)
            .unwrap()
    };
    let reference_fit = with_simd_level(SimdLevel::Portable, || fit(&truth));
    for level in levels() {
        with_simd_level(level, || {
            for ((h, x), want) in cases.iter().zip(&reference) {
                let seq = Frames::new(x, 1).unwrap();
                let f = h.forward(seq).unwrap();
                assert_eq!(bits(f.filtered()), want.0, "{level:?}: filtered");
                assert_eq!(bits(f.log_normalisers()), want.1, "{level:?}: log c");
                let p = h.posteriors(seq).ok().map(|p| {
                    (
                        bits(&p.gamma),
                        bits(&p.expected_transitions),
                        p.log_likelihood.to_bits(),
                    )
                });
                assert_eq!(&p, &want.2, "{level:?}: posteriors");
                assert_eq!(&h.viterbi(seq).unwrap(), &want.3, "{level:?}: Viterbi");
            }
            let got = fit(&truth);
            assert_eq!(
                bits(&got.report.log_likelihood),
                bits(&reference_fit.report.log_likelihood),
                "{level:?}: fit"
            );
            assert_eq!(
                bits(got.model.transition()),
                bits(reference_fit.model.transition())
            );
            assert_eq!(
                bits(got.model.emission().means()),
                bits(reference_fit.model.emission().means())
            );
            assert_eq!(
                bits(got.model.emission().covariances_raw()),
                bits(reference_fit.model.emission().covariances_raw())
            );
        });
    }
}

/// 40 sequences of 60 frames from a sticky 6-state, 12-D full-covariance HMM.
fn generated_12d(rng: &mut ChaCha8Rng) -> (Hmm<Gaussian>, SequenceSet) {
    let (s, d) = (6, 12);
    let means: Vec<f64> = (0..s * d).map(|_| rng.random_range(-2.0..2.0)).collect();
    let mut covs = Vec::new();
    for _ in 0..s {
        let l: Vec<f64> = (0..d * d)
            .map(|k| {
                if k % d == k / d {
                    rng.random_range(0.5..1.0)
                } else if k % d < k / d {
                    rng.random_range(-0.3..0.3)
                } else {
                    0.0
                }
            })
            .collect();
        for r in 0..d {
            for c in 0..d {
                covs.push((0..d).map(|k| l[r * d + k] * l[c * d + k]).sum::<f64>());
            }
        }
    }
    let mut a = vec![0.1 / (s - 1) as f64; s * s];
    for i in 0..s {
        a[i * s + i] = 0.9;
    }
    let truth = Hmm::new(
        vec![1.0 / s as f64; s],
        a,
        Gaussian::full(d, means, covs).unwrap(),
    )
    .unwrap();
    let seqs: Vec<Vec<f64>> = (0..40).map(|_| truth.sample(60, rng).unwrap().0).collect();
    (truth, SequenceSet::new(&seqs, d).unwrap())
}

// ---------------------------------------------------------------------------
// 4. The online filter follows the missing-value rule of batch inference
// ---------------------------------------------------------------------------

fn assert_filter_is_batch<E: phasekit::emission::Emission>(hmm: &Hmm<E>, x: &[f64], dim: usize) {
    let seq = Frames::new(x, dim).unwrap();
    let fwd = hmm.forward(seq).unwrap();
    let s = hmm.n_states();
    let mut filter = ForwardFilter::new(hmm.clone());
    let mut ll = 0.0;
    for t in 0..seq.len() {
        let belief = filter.step(seq.frame(t)).unwrap().to_vec();
        assert_eq!(
            bits(&belief),
            bits(&fwd.filtered()[t * s..(t + 1) * s]),
            "frame {t}"
        );
        ll += fwd.log_normalisers()[t];
        assert_eq!(filter.log_likelihood().to_bits(), ll.to_bits(), "frame {t}");
    }
}

#[test]
fn the_online_filter_marginalises_missing_values_as_batch_inference_does() {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let (truth, data) = generated_12d(&mut rng);
    let mut x = data.get(0).as_slice().to_vec();
    // Scattered values, whole frames, and a marker that stays dropped.
    for (k, v) in x.iter_mut().enumerate() {
        let (t, c) = (k / 12, k % 12);
        if rng.random_bool(0.15) || t % 17 == 5 || (20..35).contains(&t) && c < 3 {
            *v = f64::NAN;
        }
    }
    assert_filter_is_batch(&truth, &x, 12);
    // Categorical with unobserved symbols.
    let cat = Hmm::new(
        vec![0.5, 0.5],
        vec![0.9, 0.1, 0.2, 0.8],
        Categorical::new(3, vec![0.7, 0.2, 0.1, 0.1, 0.3, 0.6]).unwrap(),
    )
    .unwrap();
    let y: Vec<f64> = (0..50)
        .map(|t| if t % 7 == 3 { f64::NAN } else { (t % 3) as f64 })
        .collect();
    assert_filter_is_batch(&cat, &y, 1);
}

#[test]
fn the_online_filter_refuses_bad_frames_and_keeps_its_belief() {
    let cat = Hmm::new(
        vec![0.5, 0.5],
        vec![0.9, 0.1, 0.2, 0.8],
        Categorical::new(3, vec![0.7, 0.2, 0.1, 0.1, 0.3, 0.6]).unwrap(),
    )
    .unwrap();
    let mut filter = cat.filter();
    filter.step(&[1.0]).unwrap();
    let before = filter.belief().to_vec();
    assert!(filter.step(&[7.0]).is_err(), "a symbol outside 0..K");
    assert!(
        filter.step(&[1.0, 2.0]).is_err(),
        "a frame of the wrong length"
    );
    assert!(filter.step(&[f64::INFINITY]).is_err(), "infinity");
    assert_eq!(filter.belief(), &before[..]);
    assert_eq!(filter.frames_seen(), 1);
}
