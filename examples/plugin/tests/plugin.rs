//! The plug-in, from outside the workspace's crates: Baum-Welch, mixture EM,
//! the online filter (also on a marginal and with missing values) and the
//! regression capability, with nothing but phasekit's public API.

use phasekit_emission::rand::SeedableRng;
use phasekit_emission::{
    Conditional, ConditionalSplit, Emission, Frames, PerState, Regularisation, SequenceSet,
};
use phasekit_gmm::Em;
use phasekit_hmm::{BaumWelch, ForwardFilter, Hmm};
use phasekit_plugin_example::{own_rand_seed, Laplace};

/// A seeded generator from phasekit's `rand` re-export.
type Rng = phasekit_emission::rand::rngs::StdRng;

fn truth() -> Hmm<PerState<Laplace>> {
    let states = vec![
        Laplace::new(vec![-5.0, 0.0], vec![0.5, 1.0]).unwrap(),
        Laplace::new(vec![5.0, 3.0], vec![1.0, 0.5]).unwrap(),
    ];
    Hmm::new(
        vec![0.6, 0.4],
        vec![0.9, 0.1, 0.2, 0.8],
        PerState::new(states).unwrap(),
    )
    .unwrap()
}

fn sample(n_seq: usize, len: usize, seed: u64) -> SequenceSet {
    let mut rng = Rng::seed_from_u64(seed);
    let t = truth();
    let seqs: Vec<Vec<f64>> = (0..n_seq)
        .map(|_| t.sample(len, &mut rng).unwrap().0)
        .collect();
    SequenceSet::new(&seqs, 2).unwrap()
}

#[test]
fn baum_welch_recovers_the_states() {
    let data = sample(6, 200, 1);
    let template = PerState::repeat(Laplace::standard(2).unwrap(), 2).unwrap();
    let fit = BaumWelch::builder()
        .max_iter(50)
        .build()
        .unwrap()
        .fit(&template, &data)
        .unwrap();
    let ll = &fit.report.log_likelihood;
    assert!(
        ll.windows(2).all(|w| w[1] >= w[0] - 1e-9 * w[0].abs()),
        "{ll:?}"
    );
    let mut locs: Vec<f64> = fit
        .model
        .emission()
        .states()
        .iter()
        .map(|s| s.location()[0])
        .collect();
    locs.sort_by(f64::total_cmp);
    assert!(
        (locs[0] + 5.0).abs() < 0.3 && (locs[1] - 5.0).abs() < 0.3,
        "{locs:?}"
    );
    // serde through the route
    let json = serde_json::to_string(&fit.model).unwrap();
    let back: Hmm<PerState<Laplace>> = serde_json::from_str(&json).unwrap();
    assert_eq!(serde_json::to_string(&back).unwrap(), json);
}

#[test]
fn mixture_em_runs_on_the_plugin() {
    let data = sample(4, 150, 2);
    let template = PerState::repeat(Laplace::standard(2).unwrap(), 2).unwrap();
    let em = Em::builder().max_iter(30).build().unwrap();
    let fit = em.fit(&template, data.all_frames()).unwrap();
    assert!(fit.report.log_likelihood.iter().all(|v| v.is_finite()));
}

#[test]
fn online_filter_with_marginals_and_missing_values() {
    let t = truth();
    let data = sample(1, 100, 3);
    let seq = data.get(0);
    let batch = t.forward(seq).unwrap();
    let mut filter = t.filter();
    for (k, x) in seq.iter().enumerate() {
        assert_eq!(
            filter.step(x).unwrap(),
            &batch.filtered()[k * 2..(k + 1) * 2]
        );
    }
    // The human-only filter: the marginal on dim 0.
    let mut on0 = ForwardFilter::on_dims(&t, &[0]).unwrap();
    let mut with_nan = t.filter();
    for x in seq.iter() {
        let a = on0.step(&x[..1]).unwrap().to_vec();
        let b = with_nan.step(&[x[0], f64::NAN]).unwrap().to_vec();
        assert_eq!(a, b, "a missing value is the marginal on the observed ones");
    }
    // And a fit with missing values runs.
    let mut x = data.get(0).as_slice().to_vec();
    for v in x.iter_mut().step_by(7) {
        *v = f64::NAN;
    }
    let holes = SequenceSet::single(&x, 2).unwrap();
    let fit = BaumWelch::builder()
        .max_iter(5)
        .build()
        .unwrap()
        .fit_from(t, &holes)
        .unwrap();
    assert!(fit.report.log_likelihood.iter().all(|v| v.is_finite()));
}

#[test]
fn regression_capability() {
    let t = truth();
    let mut split = t.emission().conditional(&[0], &[1]).unwrap();
    let (mut mean, mut cov) = ([0.0], [0.0]);
    split.predict(1, &[4.0], &mut mean, &mut cov).unwrap();
    assert_eq!((mean[0], cov[0]), (3.0, 0.5));
    let lp = split.input_log_density(0, &[-5.0]).unwrap();
    assert!((lp - (-(1.0f64).ln())).abs() < 1e-12);
    assert!(split.predict(2, &[0.0], &mut mean, &mut cov).is_err());
}

#[test]
fn own_rand_lives_beside_phasekits() {
    let _ = own_rand_seed();
    let e = PerState::repeat(Laplace::standard(1).unwrap(), 1).unwrap();
    let mut out = [0.0];
    e.sample_into(0, &mut Rng::seed_from_u64(0), &mut out)
        .unwrap();
    assert!(out[0].is_finite());
    assert!(e
        .check_frames(Frames::new(&[1.0, f64::NAN], 1).unwrap())
        .is_ok());
    let _ = Regularisation::none();
}

/// Three states whose first dim ("the human") cannot tell states 1 and 2
/// apart; the second ("the robot") can.
fn ambiguous_truth() -> Hmm<PerState<Laplace>> {
    let states = vec![
        Laplace::new(vec![-5.0, 0.0], vec![0.5, 0.5]).unwrap(),
        Laplace::new(vec![5.0, 4.0], vec![0.5, 0.5]).unwrap(),
        Laplace::new(vec![5.0, -4.0], vec![0.5, 0.5]).unwrap(),
    ];
    Hmm::new(
        vec![1.0, 0.0, 0.0],
        vec![0.9, 0.1, 0.0, 0.0, 0.9, 0.1, 0.1, 0.0, 0.9],
        PerState::new(states).unwrap(),
    )
    .unwrap()
}

#[test]
fn gmr_predicts_with_the_plugin_online_as_in_batch() {
    let t = truth();
    let gmr = phasekit_gmr::HmmRegression::new(&t, &[0], &[1]).unwrap();
    let mut rng = Rng::seed_from_u64(4);
    let (frames, _) = t.sample(80, &mut rng).unwrap();
    let human: Vec<f64> = frames.chunks_exact(2).map(|f| f[0]).collect();
    let batch = gmr.predict(Frames::new(&human, 1).unwrap(), true).unwrap();
    let mut online = gmr.online();
    for (k, x) in human.iter().enumerate() {
        let m = online.step_with_covariance(&[*x]).unwrap()[0];
        assert_eq!(m.to_bits(), batch.mean[k].to_bits(), "frame {k}");
        // Independent dims: the prediction is the belief's mix of the robot locations.
        let h = online.belief();
        let want = h[0] * 0.0 + h[1] * 3.0;
        assert!((m - want).abs() < 1e-12, "frame {k}: {m} vs {want}");
    }
}

#[test]
fn the_tsc_hmm_union_runs_on_the_plugin() {
    let truth = ambiguous_truth();
    let mut rng = Rng::seed_from_u64(9);
    let seqs: Vec<Vec<f64>> = (0..8)
        .map(|_| truth.sample(80, &mut rng).unwrap().0)
        .collect();
    let data = SequenceSet::new(&seqs, 2).unwrap();
    let roles = phasekit_tsc::Roles::new(vec![0], vec![1]).unwrap();
    let settings = phasekit_tsc::TscSettings::builder()
        .base(phasekit_tsc::HmmSettings::paper(3).unwrap())
        .tsc_states(2)
        .window(1)
        // The frames λ predicts worst (a detector that needs the plug-in's conditional).
        .detector(phasekit_tsc::Detector::WorstPrediction { fraction: 0.2 })
        .build()
        .unwrap();
    let template = |s, d| PerState::repeat(Laplace::standard(d)?, s);
    let (m, report) =
        phasekit_tsc::TscHmm::fit_with_regression(&data, &roles, &settings, template).unwrap();
    assert!(report.segments >= 1);
    let union = m.union().unwrap();
    assert_eq!(union.n_states(), 5);
    // The union's first states are λ's, the last λ_T's, each unchanged at the warm start.
    let warm = phasekit_tsc::tsc_hmm::union_of(m.base(), m.transition(), 0.01).unwrap();
    let x = Frames::new(&seqs[0][..2], 2).unwrap();
    let (lb, lt, lw) = (
        m.base().emission().log_density(x).unwrap(),
        m.transition().emission().log_density(x).unwrap(),
        warm.emission().log_density(x).unwrap(),
    );
    assert_eq!(&lw[..3], &lb[..]);
    assert_eq!(&lw[3..], &lt[..]);
    // And it predicts the robot.
    let gmr = phasekit_gmr::HmmRegression::new(union, &[0], &[1]).unwrap();
    let human: Vec<f64> = seqs[0].chunks_exact(2).map(|f| f[0]).collect();
    let p = gmr.predict(Frames::new(&human, 1).unwrap(), false).unwrap();
    assert!(p.mean.iter().all(|v| v.is_finite()));
}
