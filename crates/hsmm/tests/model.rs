//! Construction, validation, serde and sampling of HSMMs.

use crate::common;

use common::*;
use phasekit_emission::{Categorical, Emission, Frames, Gaussian, SequenceSet};
use phasekit_hmm::Hmm;
use phasekit_hsmm::{
    AnyDuration, Censoring, Duration, GaussianDuration, Hsmm, HsmmError, NegativeBinomialDuration,
    NonParametricDuration, PoissonDuration, HSMM_FORMAT_VERSION,
};
use proptest::prelude::*;
use rand::Rng;

fn emission2() -> Gaussian {
    Gaussian::diagonal(1, vec![0.0, 1.0], vec![1.0, 2.0]).unwrap()
}

fn uniform(s: usize, dm: usize) -> NonParametricDuration {
    NonParametricDuration::uniform(s, dm).unwrap()
}

fn err_text<T: std::fmt::Debug>(r: Result<T, HsmmError>) -> String {
    r.unwrap_err().to_string()
}

#[test]
fn construction_is_validated_with_located_errors() {
    let ok = Hsmm::new(
        vec![0.5, 0.5],
        vec![0.0, 1.0, 1.0, 0.0],
        uniform(2, 3),
        emission2(),
    );
    assert!(ok.is_ok());
    // Self-transitions are not allowed: the duration is the visit length.
    let e = err_text(Hsmm::new(
        vec![0.5, 0.5],
        vec![0.5, 0.5, 1.0, 0.0],
        uniform(2, 3),
        emission2(),
    ));
    assert!(e.contains("row 0") && e.contains("self-transitions"), "{e}");
    // A row must be a distribution or all zeros (terminal).
    let e = err_text(Hsmm::new(
        vec![0.5, 0.5],
        vec![0.0, 0.7, 1.0, 0.0],
        uniform(2, 3),
        emission2(),
    ));
    assert!(e.contains("row 0") && e.contains("0.7"), "{e}");
    let terminal = Hsmm::new(
        vec![1.0, 0.0],
        vec![0.0, 1.0, 0.0, 0.0],
        uniform(2, 3),
        emission2(),
    )
    .unwrap();
    assert!(terminal.is_terminal(1) && !terminal.is_terminal(0));
    // Shapes.
    let e = err_text(Hsmm::new(
        vec![1.0],
        vec![0.0, 1.0, 1.0, 0.0],
        uniform(2, 3),
        emission2(),
    ));
    assert!(e.contains("start"), "{e}");
    let e = err_text(Hsmm::new(
        vec![0.5, 0.5],
        vec![0.0, 1.0, 1.0, 0.0],
        uniform(3, 3),
        emission2(),
    ));
    assert!(e.contains("3 duration distributions"), "{e}");
    let e = err_text(Hsmm::new(
        vec![0.5, 0.5],
        vec![0.0, 1.0, 1.0],
        uniform(2, 3),
        emission2(),
    ));
    assert!(e.contains("transition"), "{e}");
    let e = err_text(Hsmm::new(
        vec![0.5, f64::NAN],
        vec![0.0, 1.0, 1.0, 0.0],
        uniform(2, 3),
        emission2(),
    ));
    assert!(e.contains("entry 1"), "{e}");
    // Duration families.
    let e = err_text(NonParametricDuration::new(3, vec![0.5, 0.5, 0.5]));
    assert!(e.contains("state 0") && e.contains("sum to 1.5"), "{e}");
    let e = err_text(NonParametricDuration::new(3, vec![0.5, 0.5]));
    assert!(e.contains("rows of max_duration = 3"), "{e}");
    let e = err_text(NonParametricDuration::new(2, vec![1.5, -0.5]));
    assert!(e.contains("state 0, duration 2"), "{e}");
    assert!(NonParametricDuration::new(0, vec![]).is_err());
    let e = err_text(PoissonDuration::new(5, vec![1.0, 0.0]));
    assert!(e.contains("state 1"), "{e}");
    let e = err_text(GaussianDuration::new(5, vec![1.0, 2.0], vec![1.0, -1.0]));
    assert!(e.contains("state 1"), "{e}");
    let e = err_text(NegativeBinomialDuration::new(5, vec![1.0], vec![1.0]));
    assert!(e.contains("state 0"), "{e}");
    // log_pmf_into checks its arguments.
    let d = PoissonDuration::new(4, vec![1.0]).unwrap();
    assert!(d.log_pmf_into(1, &mut [0.0; 4]).is_err());
    assert!(d.log_pmf_into(0, &mut [0.0; 3]).is_err());
    // Sequences.
    let m = ok.unwrap();
    assert!(matches!(
        m.log_likelihood(Frames::new(&[], 1).unwrap()),
        Err(HsmmError::EmptySequence { .. })
    ));
    let e = err_text(m.log_likelihood(Frames::new(&[1.0, 2.0], 2).unwrap()));
    assert!(e.contains("dimension"), "{e}");
    let set = SequenceSet::new(&[vec![0.0, 1.0], vec![0.0; 2]], 1).unwrap();
    assert!(m.check_sequences(&set).is_ok());
    let cat = Categorical::new(2, vec![0.5, 0.5, 0.5, 0.5]).unwrap();
    let mc = Hsmm::new(vec![1.0, 0.0], vec![0.0, 1.0, 1.0, 0.0], uniform(2, 2), cat).unwrap();
    let e = err_text(
        mc.log_likelihood_all(&SequenceSet::new(&[vec![0.0], vec![0.0, 7.0]], 1).unwrap()),
    );
    assert!(e.contains("sequence 1"), "{e}");
}

fn all_families(s: usize, dm: usize) -> Vec<AnyDuration> {
    let mut r = rng(1);
    let mut pmf = Vec::new();
    for _ in 0..s {
        pmf.extend(random_distribution(&mut r, dm, 0.3, |_| true));
    }
    vec![
        NonParametricDuration::new(dm, pmf).unwrap().into(),
        PoissonDuration::new(dm, (0..s).map(|i| 1.5 + i as f64).collect())
            .unwrap()
            .into(),
        GaussianDuration::new(dm, (0..s).map(|i| 3.0 + i as f64).collect(), vec![1.3; s])
            .unwrap()
            .into(),
        NegativeBinomialDuration::new(
            dm,
            vec![2.5; s],
            (0..s).map(|i| 0.3 + 0.1 * i as f64).collect(),
        )
        .unwrap()
        .into(),
    ]
}

/// A model saved and loaded again is bit-identical (every duration family,
/// both censorings); a file of another version or with a bad parameter is refused.
#[test]
fn json_round_trip_is_exact_and_checked() {
    for durations in all_families(3, 7) {
        for censoring in [Censoring::RightCensored, Censoring::EndsWithSegment] {
            let family = durations.family();
            let m = Hsmm::new(
                vec![0.2, 0.3, 0.5],
                vec![0.0, 0.4, 0.6, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                durations.clone(),
                Gaussian::diagonal(2, vec![0.1, 0.2, 1.0, 1.1, -1.0, 0.3], vec![0.5; 6]).unwrap(),
            )
            .unwrap()
            .with_censoring(censoring);
            let json = serde_json::to_string(&m).unwrap();
            assert!(json.contains(&format!("\"family\":\"{family}\"")), "{json}");
            let back: Hsmm<Gaussian> = serde_json::from_str(&json).unwrap();
            assert_eq!(serde_json::to_string(&back).unwrap(), json);
            assert_eq!(back.censoring(), censoring);
            let data = [0.3, 0.1, 1.2, 0.9, -0.5, 0.0, 0.2, 0.2];
            let seq = Frames::new(&data, 2).unwrap();
            assert_eq!(
                back.log_likelihood(seq).unwrap().to_bits(),
                m.log_likelihood(seq).unwrap().to_bits(),
                "{family}"
            );
            let v = json.replace(
                &format!("\"format_version\":{HSMM_FORMAT_VERSION}"),
                "\"format_version\":99",
            );
            let e = serde_json::from_str::<Hsmm<Gaussian>>(&v)
                .unwrap_err()
                .to_string();
            assert!(e.contains("format version 99"), "{e}");
        }
    }
    let m = Hsmm::new(
        vec![1.0, 0.0],
        vec![0.0, 1.0, 1.0, 0.0],
        all_families(2, 4).remove(1),
        emission2(),
    )
    .unwrap();
    let json = serde_json::to_string(&m).unwrap();
    for (from, to, what) in [
        (
            "\"transition\":[0.0,1.0,1.0,0.0]",
            "\"transition\":[0.5,0.5,1.0,0.0]",
            "self-transitions",
        ),
        ("\"rates\":[1.5,2.5]", "\"rates\":[1.5,-2.5]", "state 1"),
        (
            "\"family\":\"poisson\"",
            "\"family\":\"weibull\"",
            "weibull",
        ),
    ] {
        assert!(json.contains(from), "{json}");
        let e = serde_json::from_str::<Hsmm<Gaussian>>(&json.replace(from, to))
            .unwrap_err()
            .to_string();
        assert!(e.contains(what), "{what}: {e}");
    }
}

/// Tables derived from the durations: pmfs sum to 1, survival is the tail
/// sum, means are `Σ d p(d)`, and the parameter count follows the zeros.
#[test]
fn derived_quantities() {
    for durations in all_families(2, 6) {
        let m = Hsmm::new(
            vec![1.0, 0.0],
            vec![0.0, 1.0, 1.0, 0.0],
            durations.clone(),
            emission2(),
        )
        .unwrap();
        for i in 0..2 {
            let lp = m.duration_log_pmf(i).unwrap();
            let ls = m.duration_log_survival(i).unwrap();
            let p: Vec<f64> = lp.iter().map(|v| v.exp()).collect();
            assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            for d in 0..6 {
                let tail: f64 = p[d..].iter().sum();
                assert!((ls[d].exp() - tail).abs() < 1e-12, "{}", durations.family());
            }
            let mean: f64 = p.iter().enumerate().map(|(k, p)| (k + 1) as f64 * p).sum();
            assert!((m.mean_durations()[i] - mean).abs() < 1e-12);
        }
        assert!(m.duration_log_pmf(2).is_err());
        // π has one free entry fewer than its support; both rows have one entry.
        let expected = durations.n_parameters() + m.emission().n_parameters();
        assert_eq!(m.n_parameters(), expected, "{}", durations.family());
    }
    let np = NonParametricDuration::new(3, vec![0.5, 0.0, 0.5, 0.2, 0.3, 0.5]).unwrap();
    assert_eq!(np.n_parameters(), 1 + 2);
    let set = SequenceSet::new(&[vec![0.0; 10], vec![0.0; 20]], 1).unwrap();
    assert_eq!(phasekit_hsmm::suggested_max_duration(&set, 4), 15);
    assert_eq!(phasekit_hsmm::suggested_max_duration(&set, 1), 20);
    assert_eq!(phasekit_hsmm::suggested_max_duration(&set, 100), 1);
}

proptest! {
    #![proptest_config(config(64))]

    /// Samples follow the model: segments tile the sample, consecutive
    /// segments differ, every length is possible under the durations, and
    /// the empirical mean duration of a long run matches.
    #[test]
    fn samples_follow_the_model(seed in any::<u64>(), len in 1usize..60) {
        let mut r = rng(seed);
        let (start, transition, durations) = random_chain(&mut r, 3, 5, 0.2, 0.0);
        let m = Hsmm::new(start, transition, durations, random_gaussian(&mut r, 3, 1)).unwrap();
        let (frames, states, segments) = m.sample(len, &mut r).unwrap();
        prop_assert_eq!(frames.len(), len);
        prop_assert_eq!(states.len(), len);
        let mut t = 0;
        for (k, g) in segments.iter().enumerate() {
            prop_assert_eq!(g.start, t);
            t += g.len;
            prop_assert!(m.durations().pmf()[g.state * 5 + g.len - 1] > 0.0 || k + 1 == segments.len());
            if k > 0 {
                prop_assert!(segments[k - 1].state != g.state);
            }
        }
        prop_assert_eq!(t, len);
        // Every sample is possible under the model.
        prop_assert!(m.log_likelihood(Frames::new(&frames, 1).unwrap()).unwrap() > f64::NEG_INFINITY);
    }
}

#[test]
fn sampled_durations_have_the_model_mean() {
    let m = Hsmm::new(
        vec![0.5, 0.5],
        vec![0.0, 1.0, 1.0, 0.0],
        AnyDuration::from(PoissonDuration::new(30, vec![4.0, 9.0]).unwrap()),
        emission2(),
    )
    .unwrap();
    let mut r = rng(5);
    let (_, _, segments) = m.sample(200_000, &mut r).unwrap();
    let means = m.mean_durations();
    for (i, want) in means.iter().enumerate() {
        let lens: Vec<f64> = segments[..segments.len() - 1]
            .iter()
            .filter(|g| g.state == i)
            .map(|g| g.len as f64)
            .collect();
        let mean = lens.iter().sum::<f64>() / lens.len() as f64;
        assert!((mean - want).abs() < 0.1, "state {i}: {mean} vs {want}");
    }
}

/// The geometric HSMM stays equal to the HMM on a long sequence (2 000
/// frames, D = 2 000): the windowed log-space recursions keep their
/// precision where cumulative sums over the whole sequence would not.
#[test]
fn long_sequences_keep_precision() {
    let mut r = rng(17);
    let hmm = Hmm::new(
        vec![0.6, 0.3, 0.1],
        vec![0.95, 0.03, 0.02, 0.01, 0.98, 0.01, 0.05, 0.05, 0.9],
        Gaussian::diagonal(
            2,
            vec![0.0, 0.0, 3.0, 1.0, -2.0, 2.0],
            vec![1.0, 0.5, 0.7, 0.8, 0.4, 1.2],
        )
        .unwrap(),
    )
    .unwrap();
    let (frames, _) = hmm.sample(2000, &mut r).unwrap();
    let hsmm: Hsmm<Gaussian, NonParametricDuration> = Hsmm::from_hmm(&hmm, 2000).unwrap();
    let seq = Frames::new(&frames, 2).unwrap();
    let (a, b) = (
        hmm.log_likelihood(seq).unwrap(),
        hsmm.log_likelihood(seq).unwrap(),
    );
    assert!((a - b).abs() < 1e-10 * a.abs(), "{a} vs {b}");
    let (pa, pb) = (hmm.posteriors(seq).unwrap(), hsmm.posteriors(seq).unwrap());
    let worst = pa
        .gamma
        .iter()
        .zip(&pb.gamma)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-10, "largest gamma difference {worst}");
    // A glitch frame 40 standard deviations off rules out every state by far
    // more than e^{−745}; the recursion must not lose the path.
    let mut glitched = frames.clone();
    glitched[2000] = 40.0;
    let seq = Frames::new(&glitched, 2).unwrap();
    let (a, b) = (
        hmm.log_likelihood(seq).unwrap(),
        hsmm.log_likelihood(seq).unwrap(),
    );
    assert!((a - b).abs() < 1e-10 * a.abs(), "{a} vs {b}");
    let _ = r.random::<u8>();
}
