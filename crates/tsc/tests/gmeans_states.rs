//! G-means for the number of HMM states, and the checked G-means settings
//! (moved here from `phasekit-gmm`: choosing HMM states by G-means needs both
//! the mixture crate and the HMM, and this crate is above both).
//!
//! * `hmm_states_gmeans` picks the true number of states of generated
//!   data from well-separated HMMs (3, 4 and 5 states), and returns the HMM
//!   fitted with it;
//! * every `GMeans` setting is validated once, by the builder and on
//!   deserialisation, with an error naming the setting.
//!
//! Every random draw comes from a seeded `ChaCha8Rng`.

use phasekit_emission::{CovarianceType, Gaussian, SequenceSet, Shape};
use phasekit_gmm::{gmeans, GMeans, GmmError};
use phasekit_hmm::{select_states_bic, BaumWelch, Hmm};
use phasekit_tsc::select::hmm_states_gmeans;
use phasekit_tsc::TscError;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// An `s`-state 2-D spherical-Gaussian HMM whose means lie on a circle of
/// radius 10 (neighbours at least ~12 apart for `s ≤ 5`, unit variance), with
/// sticky dense transitions.
fn separated_hmm(s: usize) -> Hmm<Gaussian> {
    let means: Vec<f64> = (0..s)
        .flat_map(|i| {
            let a = 2.0 * std::f64::consts::PI * i as f64 / s as f64;
            [10.0 * a.cos(), 10.0 * a.sin()]
        })
        .collect();
    let stay = 0.9;
    let trans: Vec<f64> = (0..s * s)
        .map(|k| {
            if k / s == k % s {
                stay
            } else {
                (1.0 - stay) / (s - 1) as f64
            }
        })
        .collect();
    Hmm::new(
        vec![1.0 / s as f64; s],
        trans,
        Gaussian::spherical(2, means, vec![1.0; s]).unwrap(),
    )
    .unwrap()
}

fn sample_set(hmm: &Hmm<Gaussian>, n_seq: usize, len: usize, seed: u64) -> SequenceSet {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let seqs: Vec<Vec<f64>> = (0..n_seq)
        .map(|_| hmm.sample(len, &mut r).unwrap().0)
        .collect();
    SequenceSet::new(&seqs, 2).unwrap()
}

fn template(k: usize) -> phasekit_emission::Result<Gaussian> {
    Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: k,
            dim: 2,
        },
    )
}

#[test]
fn gmeans_picks_the_true_number_of_hmm_states() {
    let bw = BaumWelch::builder().restarts(3).seed(1).build().unwrap();
    for (s, seed) in [(3, 11), (4, 12), (5, 13)] {
        let truth = separated_hmm(s);
        let data = sample_set(&truth, 10, 120, seed);
        let sel = hmm_states_gmeans(&bw, template, &data, GMeans::default(), 1..=20).unwrap();
        assert_eq!(sel.best, s, "true {s} states: {:?}", sel.clusters.k);
        assert_eq!(sel.clusters.k, s);
        assert!(!sel.clusters.capped);
        assert_eq!(sel.clusters.labels.len(), data.total_frames());

        // The fitted HMM has that many states, recovers every true mean
        // (within 0.3 for ~1200 frames of unit variance) and its BIC is the score.
        let model = &sel.fitted.model;
        assert_eq!(model.n_states(), s);
        for i in 0..s {
            let want = truth.emission().mean(i);
            let nearest = (0..s)
                .map(|j| {
                    let m = model.emission().mean(j);
                    ((m[0] - want[0]).powi(2) + (m[1] - want[1]).powi(2)).sqrt()
                })
                .fold(f64::INFINITY, f64::min);
            assert!(nearest < 0.3, "{s} states, state {i}: {nearest}");
        }
        assert_eq!(sel.bic, model.bic(&data).unwrap(), "{s} states");
        // The fit is the one the settings give for that K.
        let direct = bw.fit(&template(s).unwrap(), &data).unwrap();
        assert_eq!(
            direct.report.log_likelihood, sel.fitted.report.log_likelihood,
            "{s} states"
        );
        // BIC over a range agrees on these data.
        let bic = select_states_bic(&bw, template, &data, 1..=s + 2).unwrap();
        assert_eq!(bic.best, s);
    }
}

#[test]
fn gmeans_state_selection_reports_what_went_wrong() {
    let data = sample_set(&separated_hmm(3), 4, 60, 21);
    let bw = BaumWelch::default();
    // A template that cannot be built for the chosen K.
    let err = hmm_states_gmeans(
        &bw,
        |k| Gaussian::spherical(2, vec![0.0; 2 * k], vec![-1.0; k]),
        &data,
        GMeans::default(),
        1..=20,
    )
    .unwrap_err();
    let msg = err.to_string();
    assert!(
        matches!(err, TscError::InvalidSetting { name: "states", .. }),
        "{err:?}"
    );
    assert!(msg.contains("G-means chose 3 states"), "{msg}");
    // A template of the wrong dimension: the fit fails and says why.
    let msg = hmm_states_gmeans(
        &bw,
        |k| {
            Gaussian::standard(
                CovarianceType::Diagonal,
                Shape {
                    n_states: k,
                    dim: 3,
                },
            )
        },
        &data,
        GMeans::default(),
        1..=20,
    )
    .unwrap_err()
    .to_string();
    assert!(msg.contains("G-means chose 3 states"), "{msg}");
    assert!(msg.contains("expected 3, found 2"), "{msg}");
    // max_k caps the number of states.
    let capped = hmm_states_gmeans(
        &bw,
        template,
        &data,
        GMeans::builder().max_k(2).build().unwrap(),
        1..=20,
    )
    .unwrap();
    assert_eq!(capped.best, 2);
    assert!(
        capped.clusters.capped,
        "G-means was still splitting at max_k"
    );
    assert_eq!(capped.fitted.model.n_states(), 2);
    // So does the range, and an empty range is refused.
    let clamped = hmm_states_gmeans(&bw, template, &data, GMeans::default(), 1..=2).unwrap();
    assert_eq!((clamped.clusters.k, clamped.best), (3, 2));
    assert!(!clamped.clusters.capped);
    assert_eq!(clamped.fitted.model.n_states(), 2);
    #[allow(clippy::reversed_empty_ranges)] // the point of the test
    let empty = 3..=2;
    assert!(hmm_states_gmeans(&bw, template, &data, GMeans::default(), empty).is_err());
    // Missing values: G-means counts the same clusters (on the complete frames).
    let mut holes: Vec<Vec<f64>> = data.iter().map(|s| s.as_slice().to_vec()).collect();
    for (k, v) in holes.iter_mut().flatten().enumerate() {
        if k % 11 == 3 {
            *v = f64::NAN;
        }
    }
    let holes = phasekit_emission::SequenceSet::new(&holes, 2).unwrap();
    let sel = hmm_states_gmeans(&bw, template, &holes, GMeans::default(), 1..=20).unwrap();
    assert_eq!(sel.best, 3);
    assert!(sel
        .fitted
        .model
        .emission()
        .means()
        .iter()
        .all(|v| v.is_finite()));
}

#[test]
fn every_gmeans_setting_is_validated_once() {
    let name_of = |r: Result<GMeans, GmmError>| match r {
        Err(GmmError::InvalidParameter { name, reason }) => (name, reason),
        other => panic!("expected an invalid parameter, got {other:?}"),
    };
    for (b, name, needle) in [
        (GMeans::builder().alpha(0.0), "alpha", "(0, 1)"),
        (GMeans::builder().alpha(1.0), "alpha", "got 1"),
        (GMeans::builder().alpha(-0.5), "alpha", "got -0.5"),
        (GMeans::builder().alpha(f64::NAN), "alpha", "NaN"),
        (GMeans::builder().alpha(f64::INFINITY), "alpha", "inf"),
        (GMeans::builder().max_k(0), "max_k", "at least one cluster"),
        (
            GMeans::builder().min_cluster(0),
            "min_cluster",
            "at least 3",
        ),
        (GMeans::builder().min_cluster(2), "min_cluster", "got 2"),
        (
            GMeans::builder().max_iter(0),
            "max_iter",
            "at least one Lloyd",
        ),
    ] {
        let (n, reason) = name_of(b.build());
        assert_eq!(n, name);
        assert!(reason.contains(needle), "{name}: {reason}");
    }
    let g = GMeans::builder()
        .alpha(1e-3)
        .max_k(7)
        .min_cluster(3)
        .max_iter(1)
        .build()
        .unwrap();
    assert_eq!(
        (g.alpha(), g.max_k(), g.min_cluster(), g.max_iter()),
        (1e-3, 7, 3, 1)
    );
    let d = GMeans::default();
    assert_eq!(
        (d.alpha(), d.max_k(), d.min_cluster(), d.max_iter()),
        (1e-4, 32, 8, 100)
    );
    assert_eq!(GMeans::builder().build().unwrap(), d);

    // Serde: a round trip, and the same checks on deserialisation.
    let json = serde_json::to_string(&g).unwrap();
    assert_eq!(serde_json::from_str::<GMeans>(&json).unwrap(), g);
    let value: serde_json::Value = serde_json::from_str(&json).unwrap();
    for (field, bad, needle) in [
        ("alpha", serde_json::json!(1.5), "`alpha`"),
        ("max_k", serde_json::json!(0), "`max_k`"),
        ("min_cluster", serde_json::json!(1), "`min_cluster`"),
        ("max_iter", serde_json::json!(0), "`max_iter`"),
    ] {
        let mut v = value.clone();
        v[field] = bad;
        let err = serde_json::from_value::<GMeans>(v).unwrap_err().to_string();
        assert!(err.contains(needle), "{field}: {err}");
    }

    // min_cluster larger than the data: nothing is split.
    let data = sample_set(&separated_hmm(3), 2, 30, 31);
    let one = gmeans(
        data.all_frames(),
        GMeans::builder().min_cluster(1000).build().unwrap(),
    )
    .unwrap();
    assert_eq!(one.k, 1);
    let three = gmeans(data.all_frames(), GMeans::default()).unwrap();
    assert_eq!(three.k, 3);
}
