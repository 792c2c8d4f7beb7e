//! The capability traits (Marginal, ConcatStates, Conditional), the
//! per-state route's own checks, the mixture's initialisation, and the
//! messages a user reads.

// Index loops mirror the formulas they check (several arrays indexed alike).
#![allow(clippy::needless_range_loop)]

use nalgebra::{DMatrix, DVector};
use phasekit_emission::{
    Categorical, ConcatStates, Conditional, ConditionalSplit, CovarianceType, Emission,
    EmissionError, Frames, Gaussian, Marginal, MixtureEmission, PerState, Poisson, Regularisation,
    Shape, StateDistribution, StudentT, StudentTDof,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

fn spd(d: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-1.0..1.0));
    let m = &a * a.transpose() / d as f64 + DMatrix::identity(d, d) * 0.4;
    (0..d * d).map(|k| m[(k / d, k % d)]).collect()
}

fn gaussian(kind: CovarianceType, s: usize, d: usize, rng: &mut ChaCha8Rng) -> Gaussian {
    let means = (0..s * d).map(|_| rng.random_range(-3.0..3.0)).collect();
    let covs = match kind {
        CovarianceType::Full => (0..s).flat_map(|_| spd(d, rng)).collect(),
        CovarianceType::Tied => spd(d, rng),
        CovarianceType::Diagonal => (0..s * d).map(|_| rng.random_range(0.3..1.5)).collect(),
        CovarianceType::Spherical => (0..s).map(|_| rng.random_range(0.3..1.5)).collect(),
    };
    Gaussian::new(kind, d, means, covs).unwrap()
}

/// `(E[x_O | x_I], Cov[x_O | x_I], log N(x_I))` by explicit inverses.
fn explicit(
    g: &Gaussian,
    i: usize,
    input: &[usize],
    output: &[usize],
    x: &[f64],
) -> (Vec<f64>, DMatrix<f64>, f64) {
    let s = g.covariance(i);
    let mu = g.mean(i);
    let sub = |r: &[usize], c: &[usize]| DMatrix::from_fn(r.len(), c.len(), |a, b| s[(r[a], c[b])]);
    let inv = sub(input, input).try_inverse().unwrap();
    let diff = DVector::from_iterator(input.len(), input.iter().zip(x).map(|(&k, v)| v - mu[k]));
    let mean = (sub(output, input) * &inv * &diff)
        .iter()
        .zip(output)
        .map(|(v, &k)| v + mu[k])
        .collect();
    let cov = sub(output, output) - sub(output, input) * &inv * sub(input, output);
    let p = input.len() as f64;
    let lp = -0.5
        * (p * (2.0 * std::f64::consts::PI).ln()
            + sub(input, input).determinant().ln()
            + (diff.transpose() * inv * &diff)[(0, 0)]);
    (mean, cov, lp)
}

#[test]
fn gaussian_conditionals_match_explicit_formulas_for_every_covariance_type() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for kind in [
        CovarianceType::Full,
        CovarianceType::Diagonal,
        CovarianceType::Spherical,
        CovarianceType::Tied,
    ] {
        let g = gaussian(kind, 3, 5, &mut rng);
        let (input, output) = ([4usize, 0, 2], [1usize, 3]);
        let mut split = g.conditional(&input, &output).unwrap();
        assert_eq!(
            (split.input_dims(), split.output_dims()),
            (&input[..], &output[..])
        );
        for i in 0..3 {
            let x: Vec<f64> = (0..3).map(|_| rng.random_range(-4.0..4.0)).collect();
            let (want_mean, want_cov, want_lp) = explicit(&g, i, &input, &output, &x);
            let (mut mean, mut cov) = (vec![0.0; 2], vec![0.0; 4]);
            split.predict(i, &x, &mut mean, &mut cov).unwrap();
            for a in 0..2 {
                assert!((mean[a] - want_mean[a]).abs() < 1e-10, "{kind:?} mean");
                for b in 0..2 {
                    assert!(
                        (cov[a * 2 + b] - want_cov[(a, b)]).abs() < 1e-10,
                        "{kind:?} cov"
                    );
                }
            }
            let lp = split.input_log_density(i, &x).unwrap();
            assert!(
                (lp - want_lp).abs() < 1e-10 * (1.0 + lp.abs()),
                "{kind:?} input density"
            );
        }
        // Checked: a bad state or buffer is an error, not a panic.
        let mut m = vec![0.0; 2];
        let mut c = vec![0.0; 4];
        assert!(split.predict(3, &[0.0; 3], &mut m, &mut c).is_err());
        assert!(split.predict(0, &[0.0; 2], &mut m, &mut c).is_err());
        assert!(split.predict(0, &[0.0; 3], &mut m, &mut c[..3]).is_err());
        assert!(
            g.conditional(&[0, 1], &[1, 2]).is_err(),
            "overlapping split"
        );
        assert!(g.conditional(&[0, 9], &[1]).is_err(), "out of range");
    }
}

/// A mixture's conditional: the moment-matched mixture of the components'
/// conditionals with weights `∝ w_m N(x_I; μ_m,I, Σ_m,II)`, against explicit
/// formulas and by Monte-Carlo (draw a component by its conditional weight,
/// then the output from that component's conditional).
#[test]
fn mixture_conditional_is_the_moment_matched_mixture() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let comps = vec![
        gaussian(CovarianceType::Full, 3, 3, &mut rng),
        gaussian(CovarianceType::Full, 3, 3, &mut rng),
    ];
    let mix = MixtureEmission::new(vec![0.2, 0.5, 0.3, 0.6, 0.3, 0.1], comps.clone()).unwrap();
    let (input, output) = ([0usize], [1usize, 2]);
    let mut split = mix.conditional(&input, &output).unwrap();
    for state in 0..2 {
        let x = [rng.random_range(-2.0..2.0)];
        let w = &mix.weights()[state * 3..state * 3 + 3];
        let parts: Vec<_> = (0..3)
            .map(|k| explicit(&comps[state], k, &input, &output, &x))
            .collect();
        let lw: Vec<f64> = parts.iter().zip(w).map(|(p, w)| w.ln() + p.2).collect();
        let m = lw.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let lse = m + lw.iter().map(|v| (v - m).exp()).sum::<f64>().ln();
        let pi: Vec<f64> = lw.iter().map(|v| (v - lse).exp()).collect();
        let mean: Vec<f64> = (0..2)
            .map(|a| (0..3).map(|k| pi[k] * parts[k].0[a]).sum())
            .collect();
        let (mut gm, mut gc) = (vec![0.0; 2], vec![0.0; 4]);
        split.predict(state, &x, &mut gm, &mut gc).unwrap();
        assert!(
            (split.input_log_density(state, &x).unwrap() - lse).abs() < 1e-12 * (1.0 + lse.abs())
        );
        for a in 0..2 {
            assert!((gm[a] - mean[a]).abs() < 1e-12);
            for b in 0..2 {
                let want: f64 = (0..3)
                    .map(|k| pi[k] * (parts[k].1[(a, b)] + parts[k].0[a] * parts[k].0[b]))
                    .sum::<f64>()
                    - mean[a] * mean[b];
                assert!((gc[a * 2 + b] - want).abs() < 1e-12);
            }
        }
        // Monte-Carlo.
        let n = 200_000;
        let chols: Vec<DMatrix<f64>> = parts
            .iter()
            .map(|p| p.1.clone().cholesky().unwrap().unpack())
            .collect();
        let (mut m1, mut m2) = (vec![0.0; 2], vec![0.0; 4]);
        for _ in 0..n {
            let k = phasekit_emission::categorical::sample_index(&pi, &mut rng);
            let z = DVector::from_iterator(2, (0..2).map(|_| rng.sample::<f64, _>(StandardNormal)));
            let y = DVector::from_vec(parts[k].0.clone()) + &chols[k] * z;
            for a in 0..2 {
                m1[a] += y[a] / n as f64;
                for b in 0..2 {
                    m2[a * 2 + b] += y[a] * y[b] / n as f64;
                }
            }
        }
        for a in 0..2 {
            assert!((m1[a] - gm[a]).abs() < 0.03 * (1.0 + gc[a * 2 + a].sqrt()));
            for b in 0..2 {
                let mc = m2[a * 2 + b] - m1[a] * m1[b];
                assert!(
                    (mc - gc[a * 2 + b]).abs() < 0.05 * (1.0 + gc[a * 2 + a]),
                    "MC {mc} vs {}",
                    gc[a * 2 + b]
                );
            }
        }
    }
}

#[test]
fn concatenated_states_keep_each_sides_densities() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let x: Vec<f64> = (0..20 * 3).map(|_| rng.random_range(-3.0..3.0)).collect();
    let frames = Frames::new(&x, 3).unwrap();
    fn check<E: ConcatStates>(a: &E, b: &E, frames: Frames<'_>) {
        let ab = a.concat_states(b).unwrap();
        assert_eq!(ab.n_states(), a.n_states() + b.n_states());
        let (la, lb, lab) = (
            a.log_density(frames).unwrap(),
            b.log_density(frames).unwrap(),
            ab.log_density(frames).unwrap(),
        );
        let (sa, sb) = (a.n_states(), b.n_states());
        for t in 0..frames.len() {
            assert_eq!(
                &lab[t * (sa + sb)..t * (sa + sb) + sa],
                &la[t * sa..(t + 1) * sa]
            );
            assert_eq!(
                &lab[t * (sa + sb) + sa..(t + 1) * (sa + sb)],
                &lb[t * sb..(t + 1) * sb]
            );
        }
    }
    for kind in [
        CovarianceType::Full,
        CovarianceType::Diagonal,
        CovarianceType::Spherical,
    ] {
        check(
            &gaussian(kind, 2, 3, &mut rng),
            &gaussian(kind, 3, 3, &mut rng),
            frames,
        );
    }
    let tied = gaussian(CovarianceType::Tied, 2, 3, &mut rng);
    check(&tied, &tied, frames);
    assert!(
        tied.concat_states(&gaussian(CovarianceType::Tied, 2, 3, &mut rng))
            .is_err(),
        "two different tied covariances"
    );
    assert!(tied
        .to_full()
        .unwrap()
        .concat_states(&gaussian(CovarianceType::Full, 1, 3, &mut rng))
        .is_ok());
    assert!(gaussian(CovarianceType::Full, 2, 3, &mut rng)
        .concat_states(&gaussian(CovarianceType::Diagonal, 2, 3, &mut rng))
        .is_err());
    let t = |rng: &mut ChaCha8Rng| {
        PerState::new(vec![
            StudentT::new(
                vec![0.0; 3],
                spd(3, rng),
                4.0,
                StudentTDof::Fixed
            )
            .unwrap();
            2
        ])
        .unwrap()
    };
    check(&t(&mut rng), &t(&mut rng), frames);
    let mix = |rng: &mut ChaCha8Rng| {
        MixtureEmission::new(
            vec![0.5; 4],
            vec![
                gaussian(CovarianceType::Full, 2, 3, rng),
                gaussian(CovarianceType::Full, 2, 3, rng),
            ],
        )
        .unwrap()
    };
    check(&mix(&mut rng), &mix(&mut rng), frames);
    let counts: Vec<f64> = (0..20 * 3).map(|_| rng.random_range(0..6) as f64).collect();
    let cf = Frames::new(&counts, 3).unwrap();
    check(
        &Poisson::new(3, vec![1.0, 2.0, 3.0]).unwrap(),
        &Poisson::new(3, vec![4.0, 2.0, 0.5, 1.0, 1.0, 1.0]).unwrap(),
        cf,
    );
    let sym: Vec<f64> = (0..20).map(|_| rng.random_range(0..3) as f64).collect();
    let sf = Frames::new(&sym, 1).unwrap();
    check(
        &Categorical::uniform(2, 3).unwrap(),
        &Categorical::new(3, vec![0.2, 0.3, 0.5]).unwrap(),
        sf,
    );
    assert!(Categorical::uniform(2, 3)
        .unwrap()
        .concat_states(&Categorical::uniform(2, 4).unwrap())
        .is_err());
}

/// The defect of the old mixture: components built from one template never
/// separated. Each state's components now start from weighted k-means++ on
/// the frames the state owns.
#[test]
fn mixture_initialisation_separates_the_components_of_every_state() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let modes = [[-6.0, 0.0], [6.0, 0.0], [0.0, 20.0], [0.0, 32.0]];
    let mut x = Vec::new();
    let mut w = Vec::new();
    for t in 0..400 {
        let m = modes[t % 4];
        x.extend([
            m[0] + rng.sample::<f64, _>(StandardNormal),
            m[1] + rng.sample::<f64, _>(StandardNormal),
        ]);
        // State 0 owns modes 0 and 1, state 1 modes 2 and 3.
        w.extend(if t % 4 < 2 { [1.0, 0.0] } else { [0.0, 1.0] });
    }
    let frames = Frames::new(&x, 2).unwrap();
    let comp = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 2,
            dim: 2,
        },
    )
    .unwrap();
    let template = MixtureEmission::new(vec![0.5; 4], vec![comp.clone(), comp]).unwrap();
    let (mix, _) = template
        .initialise(&[(frames, &w)], &Regularisation::none(), &mut rng)
        .unwrap();
    for (state, pair) in [(0, [0, 1]), (1, [2, 3])] {
        let c = mix.components(state);
        let mut found: Vec<usize> = (0..2)
            .map(|k| {
                (0..4)
                    .min_by(|&a, &b| {
                        let d = |m: [f64; 2]| {
                            (c.mean(k)[0] - m[0]).powi(2) + (c.mean(k)[1] - m[1]).powi(2)
                        };
                        d(modes[a]).total_cmp(&d(modes[b]))
                    })
                    .unwrap()
            })
            .collect();
        found.sort();
        assert_eq!(
            found,
            pair.to_vec(),
            "state {state}: components at {:?}",
            c.means()
        );
        for k in 0..2 {
            assert!((mix.weights()[state * 2 + k] - 0.5).abs() < 0.05);
        }
    }
    // The old rule, one accumulation and M-step from the template (now only
    // the default of Emission::initialise), leaves every state's components
    // equal, bit for bit: the defect this initialisation repairs.
    let (old, _) =
        phasekit_emission::fit_weighted(&template, &[(frames, &w)], &Regularisation::none())
            .unwrap();
    for state in 0..2 {
        let c = old.components(state);
        assert_eq!(c.mean(0), c.mean(1), "state {state}");
    }
    // Restarts differ through the generator; the same seed gives the same result.
    let again = template
        .initialise(
            &[(frames, &w)],
            &Regularisation::none(),
            &mut ChaCha8Rng::seed_from_u64(9),
        )
        .unwrap()
        .0;
    let same = template
        .initialise(
            &[(frames, &w)],
            &Regularisation::none(),
            &mut ChaCha8Rng::seed_from_u64(9),
        )
        .unwrap()
        .0;
    assert_eq!(
        serde_json::to_string(&again).unwrap(),
        serde_json::to_string(&same).unwrap()
    );
    // Fewer owned frames than components: an error naming the state.
    let one = [0.0, 0.0];
    let err = template.initialise(
        &[(Frames::new(&one, 2).unwrap(), &[1.0, 0.0][..])],
        &Regularisation::none(),
        &mut rng,
    );
    assert!(err.is_err());
}

/// A distribution without marginals: NaN is refused with frame and column;
/// a plug-in's own error comes back located at its state.
#[derive(Debug, Clone)]
struct NoMarginal(f64);

impl StateDistribution for NoMarginal {
    fn dim(&self) -> usize {
        1
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        -0.5 * (x[0] - self.0).powi(2)
    }
    fn sample<R: Rng + ?Sized>(&self, rng: &mut R, out: &mut [f64]) {
        out[0] = self.0 + rng.sample::<f64, _>(StandardNormal);
    }
    fn fit(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        _: &Regularisation,
        _: &mut phasekit_emission::MStepReport,
    ) -> phasekit_emission::Result<Self> {
        let n: f64 = weights.iter().sum();
        let m = frames
            .iter()
            .zip(weights)
            .map(|(x, w)| w * x[0])
            .sum::<f64>()
            / n;
        if m > 100.0 {
            return Err(EmissionError::plugin("NoMarginal", "mean above 100"));
        }
        Ok(NoMarginal(m))
    }
    fn n_parameters(&self) -> usize {
        1
    }
}

#[test]
fn per_state_route_refuses_what_it_cannot_do_and_locates_errors() {
    let e = PerState::new(vec![NoMarginal(0.0), NoMarginal(1.0)]).unwrap();
    let x = [0.5, f64::NAN, 2.0];
    let err = e.check_frames(Frames::new(&x, 1).unwrap()).unwrap_err();
    assert!(
        matches!(
            err,
            EmissionError::InvalidValue {
                frame: 1,
                column: 0,
                ..
            }
        ),
        "{err}"
    );
    assert!(e.marginal(&[0]).is_err());
    let big = [500.0, 500.0];
    let frames = Frames::new(&big, 1).unwrap();
    let mut stats = e.new_stats();
    e.accumulate(frames, &[0.0, 1.0, 0.0, 1.0], &mut stats)
        .unwrap();
    let mut m = e.clone();
    let report = m.clone().m_step(&stats, &Regularisation::none());
    let err = report.unwrap_err();
    assert_eq!(err.to_string(), "NoMarginal, state 1: mean above 100");
    // State 0 had no weight: kept and reported, state 1 fitted.
    e.accumulate(Frames::new(&[2.0], 1).unwrap(), &[0.0, 1.0], &mut stats)
        .unwrap();
    let mut stats = e.new_stats();
    e.accumulate(
        Frames::new(&[2.0, 4.0], 1).unwrap(),
        &[0.0, 1.0, 0.0, 1.0],
        &mut stats,
    )
    .unwrap();
    let report = m.m_step(&stats, &Regularisation::none()).unwrap();
    assert_eq!(report.events.len(), 1);
    assert_eq!(m.states()[1].0, 3.0);
    assert_eq!(m.states()[0].0, 0.0);
    assert!(PerState::<NoMarginal>::new(vec![]).is_err());
}

#[test]
fn messages_print_values_a_user_can_read() {
    let reg = Regularisation::add_diagonal(0.0).unwrap();
    let x = [1.0, 2.0, 1.0, 2.0, 1.0, 2.0];
    let g = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 1,
            dim: 2,
        },
    )
    .unwrap();
    let err = g
        .initialise(
            &[(Frames::new(&x, 2).unwrap(), &[1.0, 1.0, 1.0][..])],
            &reg,
            &mut ChaCha8Rng::seed_from_u64(0),
        )
        .unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("regularisation: added diagonal 0, total weight 3, no jitter allowed"),
        "{msg}"
    );
    assert!(!msg.contains("AddDiagonal"), "{msg}");
    assert_eq!(phasekit_emission::error::readable(275.0), "275");
    assert_eq!(phasekit_emission::error::readable(0.01), "0.01");
    assert_eq!(phasekit_emission::error::readable(2.391e-14), "2.391e-14");
    assert_eq!(phasekit_emission::error::readable(1.5e-14), "1.5e-14");
    assert_eq!(
        Regularisation::none().covariance().to_string(),
        "no covariance regularisation"
    );
}

/// The Gaussian's packed, blocked M-step of μ and Σ against the formula
/// (`weighted_mean_covariance`), for weights with zeros, data far from the
/// origin and dimensions on both sides of the kernels' block sizes.
#[test]
fn packed_m_step_equals_the_formula() {
    use phasekit_emission::gaussian::weighted_mean_covariance;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for d in [1, 3, 7, 13] {
        for offset in [0.0, 1e3] {
            let n = 700;
            let x: Vec<f64> = (0..n * d)
                .map(|_| offset + rng.random_range(-2.0..2.0))
                .collect();
            let w: Vec<f64> = (0..n)
                .map(|_| {
                    if rng.random::<f64>() < 0.2 {
                        0.0
                    } else {
                        rng.random::<f64>()
                    }
                })
                .collect();
            let frames = Frames::new(&x, d).unwrap();
            let (mu, cov) = weighted_mean_covariance(frames, &w).unwrap();
            for kind in [
                CovarianceType::Full,
                CovarianceType::Tied,
                CovarianceType::Diagonal,
            ] {
                let g = Gaussian::standard(
                    kind,
                    Shape {
                        n_states: 1,
                        dim: d,
                    },
                )
                .unwrap()
                .initialise(&[(frames, &w)], &Regularisation::none(), &mut rng)
                .unwrap()
                .0;
                let scale = cov.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                for k in 0..d {
                    assert!(
                        (g.mean(0)[k] - mu[k]).abs() <= 1e-12 * (1.0 + mu[k].abs()),
                        "{kind:?} D={d} mean"
                    );
                    for c in 0..d {
                        let want = if kind == CovarianceType::Diagonal && c != k {
                            0.0
                        } else {
                            cov[(k, c)]
                        };
                        assert!(
                            (g.covariance(0)[(k, c)] - want).abs() <= 1e-11 * scale,
                            "{kind:?} D={d} offset {offset} Σ[{k},{c}]"
                        );
                    }
                }
            }
        }
    }
}
