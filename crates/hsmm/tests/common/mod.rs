//! Shared helpers of the HSMM tests: random models and the brute-force
//! enumeration of every segmentation of a short sequence.
#![allow(dead_code)]

use phasekit_emission::{Categorical, Gaussian};
use phasekit_hsmm::{Censoring, Hsmm, NonParametricDuration};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::with_cases(cases);
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x45_3e_11);
    }
    c.failure_persistence = None;
    c
}

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// A probability vector of length `n`; entries are zero with probability
/// `zero_prob` (except `keep`, which stays positive), and `mask` forces zeros.
pub fn random_distribution(
    rng: &mut ChaCha8Rng,
    n: usize,
    zero_prob: f64,
    mask: impl Fn(usize) -> bool,
) -> Vec<f64> {
    let allowed: Vec<usize> = (0..n).filter(|&j| mask(j)).collect();
    if allowed.is_empty() {
        return vec![0.0; n];
    }
    let keep = allowed[rng.random_range(0..allowed.len())];
    let mut row: Vec<f64> = (0..n)
        .map(|j| {
            if !mask(j) || (j != keep && rng.random::<f64>() < zero_prob) {
                0.0
            } else {
                rng.random_range(0.05..1.0)
            }
        })
        .collect();
    let total: f64 = row.iter().sum();
    row.iter_mut().for_each(|v| *v /= total);
    row
}

/// Random `π`, `A` (zero diagonal; a row is terminal with probability
/// `terminal_prob`) and non-parametric durations with structural zeros.
pub fn random_chain(
    rng: &mut ChaCha8Rng,
    s: usize,
    dm: usize,
    zero_prob: f64,
    terminal_prob: f64,
) -> (Vec<f64>, Vec<f64>, NonParametricDuration) {
    let start = random_distribution(rng, s, zero_prob, |_| true);
    let mut transition = Vec::with_capacity(s * s);
    for i in 0..s {
        if s == 1 || rng.random::<f64>() < terminal_prob {
            transition.extend(vec![0.0; s]);
        } else {
            transition.extend(random_distribution(rng, s, zero_prob, |j| j != i));
        }
    }
    let mut pmf = Vec::with_capacity(s * dm);
    for _ in 0..s {
        pmf.extend(random_distribution(rng, dm, zero_prob, |_| true));
    }
    (
        start,
        transition,
        NonParametricDuration::new(dm, pmf).unwrap(),
    )
}

pub fn random_categorical(rng: &mut ChaCha8Rng, s: usize, k: usize, zero_prob: f64) -> Categorical {
    let mut p = Vec::with_capacity(s * k);
    for _ in 0..s {
        p.extend(random_distribution(rng, k, zero_prob, |_| true));
    }
    Categorical::new(k, p).unwrap()
}

pub fn random_gaussian(rng: &mut ChaCha8Rng, s: usize, d: usize) -> Gaussian {
    let means: Vec<f64> = (0..s * d).map(|_| rng.random_range(-2.0..2.0)).collect();
    let vars: Vec<f64> = (0..s * d).map(|_| rng.random_range(0.3..2.0)).collect();
    Gaussian::diagonal(d, means, vars).unwrap()
}

pub fn lse(xs: &[f64]) -> f64 {
    let m = xs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    m + xs.iter().map(|v| (v - m).exp()).sum::<f64>().ln()
}

fn ln(p: f64) -> f64 {
    if p > 0.0 {
        p.ln()
    } else {
        f64::NEG_INFINITY
    }
}

/// One segmentation: `(state, start, len)` per segment, and its log-probability.
pub struct Enumerated {
    pub segments: Vec<(usize, usize, usize)>,
    pub log_p: f64,
}

/// Everything the brute force computes.
pub struct Brute {
    pub log_p: f64,
    pub gamma: Vec<f64>,
    pub starts: Vec<f64>,
    pub ends: Vec<f64>,
    pub xi: Vec<f64>,
    pub durations: Vec<f64>,
    pub censored: Vec<f64>,
    pub best: f64,
    pub all: Vec<Enumerated>,
}

/// Enumerates every segmentation of `T` frames (every composition of `T`
/// into segments of at most `D` frames, every labelling) with its
/// log-probability `log π + Σ log p(d) + Σ log a + Σ log b`, the last
/// segment scored by `P(D ≥ d)` (right-censored) or `p(d)`.
pub fn brute_force(
    start: &[f64],
    trans: &[f64],
    pmf: &[f64],
    dm: usize,
    censoring: Censoring,
    log_b: &[f64],
) -> Brute {
    let s = start.len();
    let t_len = log_b.len() / s;
    let surv = |i: usize, d: usize| -> f64 { pmf[i * dm + d - 1..(i + 1) * dm].iter().sum() };
    let mut all = Vec::new();
    let mut stack: Vec<(usize, usize, usize)> = Vec::new();
    #[allow(clippy::too_many_arguments)]
    fn rec(
        t: usize,
        prev: Option<usize>,
        lp: f64,
        stack: &mut Vec<(usize, usize, usize)>,
        all: &mut Vec<Enumerated>,
        ctx: &dyn Fn(Option<usize>, usize, usize, usize, bool) -> f64,
        s: usize,
        dm: usize,
        t_len: usize,
    ) {
        for k in 0..s {
            if prev == Some(k) {
                continue;
            }
            for d in 1..=dm.min(t_len - t) {
                let last = t + d == t_len;
                let w = ctx(prev, k, t, d, last);
                stack.push((k, t, d));
                if last {
                    all.push(Enumerated {
                        segments: stack.clone(),
                        log_p: lp + w,
                    });
                } else {
                    rec(t + d, Some(k), lp + w, stack, all, ctx, s, dm, t_len);
                }
                stack.pop();
            }
        }
    }
    let ctx = |prev: Option<usize>, k: usize, t: usize, d: usize, last: bool| -> f64 {
        let enter = match prev {
            None => ln(start[k]),
            Some(i) => ln(trans[i * s + k]),
        };
        let dur = if last && censoring == Censoring::RightCensored {
            ln(surv(k, d))
        } else {
            ln(pmf[k * dm + d - 1])
        };
        let emit: f64 = (t..t + d).map(|u| log_b[u * s + k]).sum();
        enter + dur + emit
    };
    rec(0, None, 0.0, &mut stack, &mut all, &ctx, s, dm, t_len);
    let lps: Vec<f64> = all.iter().map(|e| e.log_p).collect();
    let log_p = lse(&lps);
    let best = lps.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut b = Brute {
        log_p,
        gamma: vec![0.0; t_len * s],
        starts: vec![0.0; t_len * s],
        ends: vec![0.0; t_len * s],
        xi: vec![0.0; s * s],
        durations: vec![0.0; s * dm],
        censored: vec![0.0; s * dm],
        best,
        all: Vec::new(),
    };
    if log_p > f64::NEG_INFINITY {
        for e in &all {
            let w = (e.log_p - log_p).exp();
            for (n, &(k, t, d)) in e.segments.iter().enumerate() {
                let last = n + 1 == e.segments.len();
                for u in t..t + d {
                    b.gamma[u * s + k] += w;
                }
                b.starts[t * s + k] += w;
                b.ends[(t + d - 1) * s + k] += w;
                if !last {
                    let next = e.segments[n + 1].0;
                    b.xi[k * s + next] += w;
                }
                if last && censoring == Censoring::RightCensored {
                    b.censored[k * dm + d - 1] += w;
                } else {
                    b.durations[k * dm + d - 1] += w;
                }
            }
        }
    }
    b.all = all;
    b
}

/// The brute force of an HSMM with non-parametric durations on log-densities `log_b`.
pub fn brute_of<E: phasekit_emission::Emission>(
    m: &Hsmm<E, NonParametricDuration>,
    log_b: &[f64],
) -> Brute {
    brute_force(
        m.start(),
        m.transition(),
        m.durations().pmf(),
        m.max_duration(),
        m.censoring(),
        log_b,
    )
}
