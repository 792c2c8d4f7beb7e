//! The slow, obvious version of every recursion, straight from the
//! definitions in unnormalised log space (segment emissions summed frame by
//! frame, every sum a log-sum-exp, posteriors by visiting every segment), and
//! the property test of the fast windows against it on sequences long enough
//! for the windows to wrap, rescale and fall back to log space (the
//! enumeration tests in `tests/properties.rs` stop at 6 frames).

use crate::duration::Duration;
use crate::model::{Censoring, Hsmm};
use phasekit_emission::Emission;

const NEG_INF: f64 = f64::NEG_INFINITY;

fn lse(x: &[f64]) -> f64 {
    let m = x.iter().copied().fold(NEG_INF, f64::max);
    if m == NEG_INF {
        return m;
    }
    m + x.iter().map(|v| (v - m).exp()).sum::<f64>().ln()
}

/// Everything the reference computes for one sequence.
#[derive(Debug)]
pub(crate) struct Reference {
    pub(crate) log_likelihood: f64,
    pub(crate) filtered: Vec<f64>,
    pub(crate) gamma: Vec<f64>,
    pub(crate) starts: Vec<f64>,
    pub(crate) ends: Vec<f64>,
    pub(crate) transitions: Vec<f64>,
    pub(crate) durations: Vec<f64>,
    pub(crate) censored: Vec<f64>,
}

/// The reference on log-densities `log_b` (`T × S`); `None` when `p(x) = 0`.
pub(crate) fn reference<E: Emission, D: Duration>(
    m: &Hsmm<E, D>,
    log_b: &[f64],
) -> Option<Reference> {
    let (s, dm) = (m.n_states(), m.max_duration());
    let t_len = log_b.len() / s;
    let tb = &m.tables;
    let lp = |j: usize, d: usize| tb.log_pmf[j * dm + d - 1];
    let lsurv = |j: usize, d: usize| tb.log_survival[j * dm + d - 1];
    let llast = |j: usize, d: usize| tb.log_last[j * dm + d - 1];
    let la = |i: usize, k: usize| tb.log_transition[i * s + k];
    // seg[(j·T + a)·D + d − 1] = Σ_{u=a}^{a+d−1} log b_j(x_u)
    let mut seg = vec![NEG_INF; s * t_len * dm];
    for j in 0..s {
        for a in 0..t_len {
            let mut acc = 0.0;
            for d in 1..=dm.min(t_len - a) {
                acc += log_b[(a + d - 1) * s + j];
                seg[(j * t_len + a) * dm + d - 1] = acc;
            }
        }
    }
    let sg = |j: usize, a: usize, d: usize| seg[(j * t_len + a) * dm + d - 1];
    // Forward: segment starts and ends, ongoing mass.
    let mut start = vec![NEG_INF; t_len * s];
    let mut end = vec![NEG_INF; t_len * s];
    let mut filtered = vec![0.0; t_len * s];
    start[..s].copy_from_slice(&tb.log_start);
    let mut prefix = 0.0;
    for t in 0..t_len {
        let mut ongoing = vec![NEG_INF; s];
        for j in 0..s {
            let (mut e_terms, mut o_terms) = (Vec::new(), Vec::new());
            for d in 1..=dm.min(t + 1) {
                let a = t + 1 - d;
                let base = start[a * s + j] + sg(j, a, d);
                e_terms.push(base + lp(j, d));
                o_terms.push(base + lsurv(j, d));
            }
            end[t * s + j] = lse(&e_terms);
            ongoing[j] = lse(&o_terms);
        }
        prefix = lse(&ongoing);
        if prefix == NEG_INF {
            return None;
        }
        for j in 0..s {
            filtered[t * s + j] = (ongoing[j] - prefix).exp();
        }
        if t + 1 < t_len {
            for k in 0..s {
                let terms: Vec<f64> = (0..s).map(|i| end[t * s + i] + la(i, k)).collect();
                start[(t + 1) * s + k] = lse(&terms);
            }
        }
    }
    let ll = match m.censoring {
        Censoring::RightCensored => prefix,
        Censoring::EndsWithSegment => lse(&end[(t_len - 1) * s..]),
    };
    if ll == NEG_INF {
        return None;
    }
    // Backward: after an end at t, from a start at a.
    let mut after = vec![NEG_INF; t_len * s];
    let mut from = vec![NEG_INF; t_len * s];
    for t in (0..t_len).rev() {
        for j in 0..s {
            after[t * s + j] = if t == t_len - 1 {
                0.0
            } else {
                let terms: Vec<f64> = (0..s).map(|k| la(j, k) + from[(t + 1) * s + k]).collect();
                lse(&terms)
            };
        }
        for k in 0..s {
            let terms: Vec<f64> = (1..=dm.min(t_len - t))
                .map(|d| {
                    if t + d == t_len {
                        sg(k, t, d) + llast(k, d)
                    } else {
                        sg(k, t, d) + lp(k, d) + after[(t + d - 1) * s + k]
                    }
                })
                .collect();
            from[t * s + k] = lse(&terms);
        }
    }
    // Posteriors, segment by segment.
    let mut r = Reference {
        log_likelihood: ll,
        filtered,
        gamma: vec![0.0; t_len * s],
        starts: vec![0.0; t_len * s],
        ends: vec![0.0; t_len * s],
        transitions: vec![0.0; s * s],
        durations: vec![0.0; s * dm],
        censored: vec![0.0; s * dm],
    };
    for k in 0..s {
        for a in 0..t_len {
            for d in 1..=dm.min(t_len - a) {
                let last = a + d == t_len;
                let lw = start[a * s + k]
                    + sg(k, a, d)
                    + if last {
                        llast(k, d)
                    } else {
                        lp(k, d) + after[(a + d - 1) * s + k]
                    }
                    - ll;
                if lw == NEG_INF {
                    continue;
                }
                let w = lw.exp();
                for u in a..a + d {
                    r.gamma[u * s + k] += w;
                }
                r.starts[a * s + k] += w;
                r.ends[(a + d - 1) * s + k] += w;
                if last && m.censoring == Censoring::RightCensored {
                    r.censored[k * dm + d - 1] += w;
                } else {
                    r.durations[k * dm + d - 1] += w;
                }
            }
        }
    }
    for t in 0..t_len - 1 {
        for i in 0..s {
            for k in 0..s {
                let lw = end[t * s + i] + la(i, k) + from[(t + 1) * s + k] - ll;
                if lw > NEG_INF {
                    r.transitions[i * s + k] += lw.exp();
                }
            }
        }
    }
    Some(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::duration::{AnyDuration, GaussianDuration, NonParametricDuration, PoissonDuration};
    use crate::inference::{SegmentCounts, Workspace};
    use phasekit_emission::{Categorical, Frames, Gaussian};
    use proptest::prelude::*;
    use proptest::test_runner::RngSeed;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn dist(
        rng: &mut ChaCha8Rng,
        n: usize,
        zero: f64,
        allowed: impl Fn(usize) -> bool,
    ) -> Vec<f64> {
        let ok: Vec<usize> = (0..n).filter(|&j| allowed(j)).collect();
        if ok.is_empty() {
            return vec![0.0; n];
        }
        let keep = ok[rng.random_range(0..ok.len())];
        let mut v: Vec<f64> = (0..n)
            .map(|j| {
                if !allowed(j) || (j != keep && rng.random::<f64>() < zero) {
                    0.0
                } else {
                    rng.random_range(0.05..1.0)
                }
            })
            .collect();
        let total: f64 = v.iter().sum();
        v.iter_mut().for_each(|x| *x /= total);
        v
    }

    fn durations(rng: &mut ChaCha8Rng, family: usize, s: usize, dm: usize) -> AnyDuration {
        match family {
            0 => {
                let mut pmf = Vec::new();
                for _ in 0..s {
                    pmf.extend(dist(rng, dm, 0.3, |_| true));
                }
                NonParametricDuration::new(dm, pmf).unwrap().into()
            }
            1 => PoissonDuration::new(
                dm,
                (0..s)
                    .map(|_| rng.random_range(0.2..2.0 * dm as f64))
                    .collect(),
            )
            .unwrap()
            .into(),
            // Narrow Gaussians: probabilities far below the double range.
            _ => GaussianDuration::new(
                dm,
                (0..s).map(|_| rng.random_range(1.0..=dm as f64)).collect(),
                (0..s).map(|_| rng.random_range(0.2..3.0)).collect(),
            )
            .unwrap()
            .into(),
        }
    }

    fn close(what: &str, got: &[f64], want: &[f64], tol: f64) -> Result<(), TestCaseError> {
        prop_assert_eq!(got.len(), want.len());
        for (k, (g, w)) in got.iter().zip(want).enumerate() {
            prop_assert!((g - w).abs() <= tol, "{what}[{k}]: got {g}, want {w}");
        }
        Ok(())
    }

    fn config() -> ProptestConfig {
        let mut c = ProptestConfig::with_cases(1500);
        if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
            c.rng_seed = RngSeed::Fixed(0x51_de_2a);
        }
        c.failure_persistence = None;
        c
    }

    proptest! {
        #![proptest_config(config())]

        /// The windows (linear sums, rescaling, log-space fallback) against
        /// the reference on sequences of up to 70 frames, with durations,
        /// transitions and start probabilities with zeros, terminal states,
        /// Gaussian emissions whose densities differ by thousands of nats
        /// between states and frames, and categorical emissions with
        /// impossible symbols.
        #[test]
        fn windows_match_the_reference(
            seed in any::<u64>(),
            s in 1usize..=4,
            dm in 1usize..=12,
            t_len in 1usize..=70,
            family in 0usize..3,
            ends in any::<bool>(),
            categorical in any::<bool>(),
            scale in prop_oneof![Just(0.3), Just(3.0), Just(30.0)],
        ) {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let start = dist(&mut rng, s, 0.3, |_| true);
            let mut transition = Vec::new();
            for i in 0..s {
                if s == 1 || rng.random::<f64>() < 0.15 {
                    transition.extend(vec![0.0; s]);
                } else {
                    transition.extend(dist(&mut rng, s, 0.3, |j| j != i));
                }
            }
            let durations = durations(&mut rng, family, s, dm);
            let censoring = if ends { Censoring::EndsWithSegment } else { Censoring::RightCensored };
            let (log_b, frames) = if categorical {
                let mut p = Vec::new();
                for _ in 0..s {
                    p.extend(dist(&mut rng, 4, 0.3, |_| true));
                }
                let e = Categorical::new(4, p).unwrap();
                let x: Vec<f64> = (0..t_len).map(|_| rng.random_range(0..4) as f64).collect();
                let m = Hsmm::new(start.clone(), transition.clone(), durations.clone(), e).unwrap();
                (m.emission_log_densities(Frames::new(&x, 1).unwrap()).unwrap(), x)
            } else {
                let means: Vec<f64> = (0..s * 2).map(|_| rng.random_range(-2.0..2.0)).collect();
                let vars: Vec<f64> = (0..s * 2).map(|_| rng.random_range(0.1..2.0)).collect();
                let e = Gaussian::diagonal(2, means, vars).unwrap();
                let x: Vec<f64> = (0..t_len * 2).map(|_| scale * rng.random_range(-2.5..2.5)).collect();
                let m = Hsmm::new(start.clone(), transition.clone(), durations.clone(), e).unwrap();
                (m.emission_log_densities(Frames::new(&x, 2).unwrap()).unwrap(), x)
            };
            let _ = frames;
            // The recursions only read the log-densities: any emission will do.
            let m = Hsmm::new(start, transition, durations, Categorical::new(1, vec![1.0; s]).unwrap())
                .unwrap()
                .with_censoring(censoring);
            let want = reference(&m, &log_b);
            let mut ws = Workspace::default();
            ws.log_b = log_b.clone();
            match (m.forward_ws(&mut ws), want) {
                (Err(_), None) => {}
                (Ok((ll, lambda)), Some(want)) => {
                    prop_assert!((ll - want.log_likelihood).abs() <= 1e-9 * want.log_likelihood.abs().max(1.0),
                        "log-likelihood {ll} vs {}", want.log_likelihood);
                    close("filtered", &ws.gamma, &want.filtered, 1e-9)?;
                    let mut acc = SegmentCounts::zeros(m.n_states(), m.max_duration());
                    let n = log_b.len();
                    let (mut st, mut en) = (vec![0.0; n], vec![0.0; n]);
                    m.backward_ws(&mut ws, lambda, &mut acc, Some((&mut st, &mut en)));
                    close("gamma", &ws.gamma, &want.gamma, 1e-9)?;
                    close("segment starts", &st, &want.starts, 1e-9)?;
                    close("segment ends", &en, &want.ends, 1e-9)?;
                    close("transitions", &acc.transitions, &want.transitions, 1e-8)?;
                    close("durations", &acc.durations, &want.durations, 1e-8)?;
                    close("censored", &acc.censored, &want.censored, 1e-9)?;
                }
                (got, want) => {
                    return Err(TestCaseError::fail(format!(
                        "forward {:?}, reference {:?}",
                        got.map(|g| g.0),
                        want.map(|w| w.log_likelihood)
                    )));
                }
            }
        }
    }
}
