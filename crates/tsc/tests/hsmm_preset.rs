//! The `hsmm` preset (issue "Better than the paper"): a left-right HSMM on
//! joint frames with HSMM-GMR. Every emission fits; the batch prediction is
//! the online one to the bit; the model round-trips through JSON; an HSMM
//! whose durations are the HMM's (truncated) geometric ones predicts as
//! HMM-GMR; settings are checked before any fit.

use phasekit_emission::{Frames, SequenceSet};
use phasekit_gmr::{HmmRegression, HsmmRegression};
use phasekit_hsmm::Hsmm;
use phasekit_tsc::synthetic;
use phasekit_tsc::{
    DurationFamily, EmissionKind, Method, Model, Preset, PresetOptions, Roles, TscError,
};

fn data(n: usize, seed: u64) -> (SequenceSet, Vec<Vec<f64>>) {
    let demos = synthetic::generate(n, seed);
    let seqs: Vec<Vec<f64>> = demos.iter().map(|d| d.frames.clone()).collect();
    (
        SequenceSet::new(&seqs[..n - 1], 6).unwrap(),
        seqs[n - 1..].to_vec(),
    )
}

fn roles() -> Roles {
    Roles::new(vec![0, 1, 2], vec![3, 4, 5]).unwrap()
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn human_of(joint: &[f64]) -> Vec<f64> {
    joint
        .chunks_exact(6)
        .flat_map(|f| f[..3].to_vec())
        .collect()
}

#[test]
fn hsmm_fits_every_emission_and_family_predicts_online_like_batch_and_round_trips() {
    let (train, test) = data(7, 4);
    let human = human_of(&test[0]);
    let frames = Frames::new(&human, 3).unwrap();
    let cases: Vec<(EmissionKind, DurationFamily)> = ["full", "diag", "student-t", "gmm-2"]
        .iter()
        .map(|k| (k.parse().unwrap(), DurationFamily::Gaussian))
        .chain(
            [
                DurationFamily::Poisson,
                DurationFamily::NegativeBinomial,
                DurationFamily::NonParametric,
            ]
            .map(|d| ("full".parse().unwrap(), d)),
        )
        .collect();
    for (kind, family) in cases {
        let options = PresetOptions::builder()
            .max_iter(8)
            .emission(kind)
            .duration(family)
            .build()
            .unwrap();
        let method = Method::preset(Preset::Hsmm, &options).unwrap();
        let (model, summary) = method
            .fit(&train, &roles())
            .unwrap_or_else(|e| panic!("{kind} {family}: {e}"));
        assert!(summary.iterations >= 1);
        assert!(matches!(model, Model::Hsmm(_)));
        assert_eq!(model.n_states(), 4);
        let predictor = model.predictor(&roles()).unwrap();
        let batch = predictor.predict(frames, true).unwrap();
        assert!(batch.mean.iter().all(|v| v.is_finite()), "{kind} {family}");
        let mut online = predictor.online();
        for (t, x) in human.chunks_exact(3).enumerate() {
            let m = online.step(x, true).unwrap();
            assert_eq!(
                bits(m),
                bits(&batch.mean[t * 3..t * 3 + 3]),
                "{kind} {family} {t}"
            );
            assert_eq!(
                bits(online.covariance()),
                bits(&batch.covariance.as_ref().unwrap()[t * 9..t * 9 + 9]),
                "{kind} {family} {t}"
            );
        }
        // The prediction follows the robot (the synthetic robot mirrors the human):
        // better than predicting the robot's mean position.
        let o = &test[0];
        let (mut se, mut se0) = (0.0, 0.0);
        let n = o.len() / 6;
        let mean: Vec<f64> = (3..6)
            .map(|k| o.chunks_exact(6).map(|f| f[k]).sum::<f64>() / n as f64)
            .collect();
        for t in 0..n {
            for k in 0..3 {
                se += (batch.mean[t * 3 + k] - o[t * 6 + 3 + k]).powi(2);
                se0 += (mean[k] - o[t * 6 + 3 + k]).powi(2);
            }
        }
        assert!(se < 0.5 * se0, "{kind} {family}: {se} vs constant {se0}");
        // JSON round trip: the same predictions to the bit.
        let back: Model = serde_json::from_str(&serde_json::to_string(&model).unwrap()).unwrap();
        let again = back
            .predictor(&roles())
            .unwrap()
            .predict(frames, true)
            .unwrap();
        assert_eq!(bits(&again.mean), bits(&batch.mean));
        assert_eq!(
            bits(again.covariance.as_ref().unwrap()),
            bits(batch.covariance.as_ref().unwrap())
        );
        let m_json = serde_json::to_string(&method).unwrap();
        assert_eq!(serde_json::from_str::<Method>(&m_json).unwrap(), method);
        // Segmentation: one label per frame, left to right, transitions at the segment starts.
        let seg = model
            .segment(Frames::new(&test[0], 6).unwrap(), &roles())
            .unwrap();
        assert_eq!(seg.labels.len(), n);
        assert!(
            seg.labels.windows(2).all(|w| w[0] <= w[1]),
            "{:?}",
            seg.labels
        );
        for &t in &seg.transitions {
            assert_ne!(seg.labels[t], seg.labels[t - 1]);
        }
    }
}

#[test]
fn hsmm_gmr_with_geometric_durations_is_hmm_gmr() {
    // An HMM fitted on the data, and the HSMM with its geometric durations
    // (truncated at D frames, mass a_ii^D ≈ 0 beyond): the same predictions.
    let (train, test) = data(7, 5);
    let options = PresetOptions::builder().max_iter(10).build().unwrap();
    let (model, _) = Method::preset(Preset::Hmm, &options)
        .unwrap()
        .fit(&train, &roles())
        .unwrap();
    let Model::Hmm(hmm) = model else {
        panic!("hmm preset")
    };
    let d = 3000;
    let hsmm: Hsmm<_> = Hsmm::from_hmm(&hmm, d).unwrap();
    let tail = (0..hmm.n_states())
        .map(|i| hmm.transition()[i * hmm.n_states() + i].powi(d as i32))
        .fold(0.0, f64::max);
    assert!(tail < 1e-12, "{tail}");
    let human = human_of(&test[0]);
    let frames = Frames::new(&human, 3).unwrap();
    let a = HmmRegression::new(&hmm, &[0, 1, 2], &[3, 4, 5])
        .unwrap()
        .predict(frames, true)
        .unwrap();
    let b = HsmmRegression::new(&hsmm, &[0, 1, 2], &[3, 4, 5])
        .unwrap()
        .predict(frames, true)
        .unwrap();
    for (x, y) in a.mean.iter().zip(&b.mean) {
        assert!((x - y).abs() < 1e-8 * (1.0 + x.abs()), "{x} vs {y}");
    }
    for (x, y) in a.weights.iter().zip(&b.weights) {
        assert!((x - y).abs() < 1e-8, "{x} vs {y}");
    }
}

#[test]
fn hsmm_settings_are_checked_before_any_fit() {
    let parse = |o: PresetOptions, p: Preset| Method::preset(p, &o);
    // Durations are hsmm's settings only.
    let o = PresetOptions::builder()
        .duration(DurationFamily::Poisson)
        .build()
        .unwrap();
    let e = parse(o.clone(), Preset::Hmm).unwrap_err();
    assert!(
        matches!(
            e,
            TscError::InvalidSetting {
                name: "duration",
                ..
            }
        ),
        "{e}"
    );
    assert!(parse(o, Preset::Hsmm).is_ok());
    // No automatic state count, no zero-frame phase.
    let o = PresetOptions::builder().auto_states().build().unwrap();
    assert!(parse(o, Preset::Hsmm).is_err());
    let o = PresetOptions::builder()
        .max_duration(Some(0))
        .build()
        .unwrap();
    assert!(parse(o, Preset::Hsmm).is_err());
    // Names.
    assert_eq!("hsmm".parse::<Preset>().unwrap(), Preset::Hsmm);
    for d in DurationFamily::ALL {
        assert_eq!(d.name().parse::<DurationFamily>().unwrap(), d);
    }
    assert!("weibull".parse::<DurationFamily>().is_err());
}

#[test]
fn a_demonstration_longer_than_the_durations_allow_is_rejected_not_a_panic() {
    // D = 3 frames per phase, 4 phases: a demonstration of 30 frames outlasts
    // every segmentation; the frames beyond are rejected and still predicted.
    let (train, test) = data(7, 4);
    let o = PresetOptions::builder()
        .max_iter(3)
        .max_duration(Some(40))
        .build()
        .unwrap();
    let (model, _) = Method::preset(Preset::Hsmm, &o)
        .unwrap()
        .fit(&train, &roles())
        .unwrap();
    let human = human_of(&test[0]);
    let long: Vec<f64> = human.iter().chain(&human).chain(&human).copied().collect();
    let n = long.len() / 3;
    let p = model
        .predictor(&roles())
        .unwrap()
        .predict(Frames::new(&long, 3).unwrap(), true)
        .unwrap();
    assert_eq!(p.mean.len(), n * 3);
    assert!(p.mean.iter().all(|v| v.is_finite()));
    assert!(
        !p.rejected.is_empty() && p.rejected.len() < n,
        "{}",
        p.rejected.len()
    );
    // A glitch no state explains is rejected and reported.
    let mut glitch = human.clone();
    glitch[30] = 1e200;
    let p = model
        .predictor(&roles())
        .unwrap()
        .predict(Frames::new(&glitch, 3).unwrap(), false)
        .unwrap();
    assert_eq!(p.rejected, [10]);
    assert!(p.mean.iter().all(|v| v.is_finite()));
}
