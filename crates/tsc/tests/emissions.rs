//! The compositions over every emission the command can choose
//! ([`EmissionKind`]): the union's states and transitions are its two parts',
//! every preset fits, predicts online exactly as in batch and round-trips
//! through JSON; and the TSC-HMM's detector and union need only marginals
//! and state concatenation (a Poisson emission, which has no conditional, is
//! segmented).

use phasekit_emission::rand::SeedableRng;
use phasekit_emission::{Emission, Frames, Poisson, SequenceSet};
use phasekit_hmm::Hmm;
use phasekit_tsc::synthetic;
use phasekit_tsc::tsc_hmm::union_of;
use phasekit_tsc::{
    AnyEmission, EmissionKind, HmmSettings, Method, Model, Preset, PresetOptions, Roles, TscHmm,
    TscSettings,
};
use rand_chacha::ChaCha8Rng;

fn kinds() -> Vec<EmissionKind> {
    ["full", "diag", "spherical", "tied", "student-t", "gmm-2"]
        .iter()
        .map(|s| s.parse().unwrap())
        .collect()
}

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

#[test]
fn emission_names_round_trip_and_bad_ones_are_refused() {
    for k in kinds() {
        assert_eq!(k.to_string().parse::<EmissionKind>().unwrap(), k);
        let json = serde_json::to_string(&k).unwrap();
        assert_eq!(serde_json::from_str::<EmissionKind>(&json).unwrap(), k);
    }
    assert_eq!(
        "diagonal".parse::<EmissionKind>().unwrap().to_string(),
        "diag"
    );
    for bad in [
        "",
        "gauss",
        "gmm-",
        "gmm-0",
        "gmm-65",
        "student_t",
        "gmm-2x",
    ] {
        let e = bad.parse::<EmissionKind>().unwrap_err();
        assert!(e.contains("emission"), "{bad}: {e}");
    }
}

#[test]
fn the_union_holds_both_parts_states_and_transitions_for_every_emission() {
    let (train, test) = data(6, 1);
    let frames = Frames::new(&test[0], 6).unwrap();
    for kind in kinds() {
        let settings = |s| {
            HmmSettings::builder()
                .states(s)
                .emission(kind)
                .max_iter(5)
                .build()
                .unwrap()
        };
        let (a, _) = settings(4).fit(&train).unwrap();
        let (b, _) = settings(3).fit(&train).unwrap();
        let eps = 0.01;
        let u = union_of(&a, &b, eps).unwrap();
        // Two tied models share no covariance: their union has full ones.
        let union_kind = if kind.to_string() == "tied" {
            "full".parse().unwrap()
        } else {
            kind
        };
        assert_eq!(u.emission().kind(), union_kind);
        assert_eq!((u.n_states(), u.dim()), (7, 6));
        // Emissions: the union's states are a's then b's, to the last bit.
        let (la, lb, lu) = (
            a.emission().log_density(frames).unwrap(),
            b.emission().log_density(frames).unwrap(),
            u.emission().log_density(frames).unwrap(),
        );
        for t in 0..frames.len() {
            let mut want = la[t * 4..(t + 1) * 4].to_vec();
            want.extend_from_slice(&lb[t * 3..(t + 1) * 3]);
            assert_eq!(
                bits(&lu[t * 7..(t + 1) * 7]),
                bits(&want),
                "{kind} frame {t}"
            );
        }
        // Transitions: each part's block scaled by 1 − ε, ε spread over the other block.
        for i in 0..7 {
            for j in 0..7 {
                let want = match (i < 4, j < 4) {
                    (true, true) => (1.0 - eps) * a.transition()[i * 4 + j],
                    (false, false) => (1.0 - eps) * b.transition()[(i - 4) * 3 + (j - 4)],
                    (true, false) => eps / 3.0,
                    (false, true) => eps / 4.0,
                };
                assert_eq!(u.transition()[i * 7 + j], want, "{kind} a[{i}][{j}]");
            }
        }
        for i in 0..7 {
            let want = if i < 4 {
                (1.0 - eps) * a.start()[i]
            } else {
                eps / 3.0
            };
            assert_eq!(u.start()[i], want, "{kind} π[{i}]");
        }
    }
    // Two different emissions cannot be one union.
    let fit = |k: &str| {
        HmmSettings::builder()
            .states(2)
            .emission(k.parse().unwrap())
            .max_iter(2)
            .build()
            .unwrap()
            .fit(&train)
            .unwrap()
            .0
    };
    let err = union_of(&fit("full"), &fit("student-t"), 0.01).unwrap_err();
    assert!(err.to_string().contains("cannot join"), "{err}");
}

#[test]
fn every_preset_fits_every_emission_predicts_online_like_batch_and_round_trips() {
    let (train, test) = data(7, 4);
    let human: Vec<f64> = test[0]
        .chunks_exact(6)
        .flat_map(|f| f[..3].to_vec())
        .collect();
    let frames = Frames::new(&human, 3).unwrap();
    for kind in kinds() {
        for preset in [
            Preset::Hmm,
            Preset::TscHmm,
            Preset::TscHmmGated,
            Preset::TscHmmFrozen,
            Preset::Gmm,
            Preset::GmmTsc,
        ] {
            let options = PresetOptions::builder()
                .max_iter(8)
                .emission(kind)
                .build()
                .unwrap();
            let method = Method::preset(preset, &options).unwrap();
            let (model, summary) = method
                .fit(&train, &roles())
                .unwrap_or_else(|e| panic!("{preset} {kind}: {e}"));
            assert!(summary.iterations >= 1);
            let predictor = model.predictor(&roles()).unwrap();
            let batch = predictor.predict(frames, true).unwrap();
            assert!(
                batch.mean.iter().all(|v| v.is_finite()),
                "{preset} {kind}: a prediction is not finite"
            );
            let mut online = predictor.online();
            for (t, x) in human.chunks_exact(3).enumerate() {
                let m = online.step(x, true).unwrap();
                assert_eq!(
                    bits(m),
                    bits(&batch.mean[t * 3..t * 3 + 3]),
                    "{preset} {kind} frame {t}"
                );
            }
            // JSON round trip: the same model, the same predictions to the bit.
            let json = serde_json::to_string(&model).unwrap();
            let back: Model = serde_json::from_str(&json).unwrap();
            let again = back
                .predictor(&roles())
                .unwrap()
                .predict(frames, true)
                .unwrap();
            assert_eq!(bits(&again.mean), bits(&batch.mean), "{preset} {kind}");
            assert_eq!(
                bits(again.covariance.as_ref().unwrap()),
                bits(batch.covariance.as_ref().unwrap()),
                "{preset} {kind}"
            );
            // The method's settings record the emission, and read back.
            let m_json = serde_json::to_string(&method).unwrap();
            assert_eq!(
                m_json.contains("\"emission\""),
                !kind.is_default(),
                "{m_json}"
            );
            assert_eq!(serde_json::from_str::<Method>(&m_json).unwrap(), method);
            // Segmentation runs on every emission.
            let seg = model
                .segment(Frames::new(&test[0], 6).unwrap(), &roles())
                .unwrap();
            assert_eq!(seg.labels.len(), test[0].len() / 6);
        }
    }
}

#[test]
fn a_full_gaussian_is_written_as_before_and_old_settings_read_as_gaussians() {
    let (train, _) = data(5, 2);
    let (hmm, _) = HmmSettings::paper(3).unwrap().fit(&train).unwrap();
    let json = serde_json::to_value(&hmm).unwrap();
    // The emission is the Gaussian's own form, no tag.
    assert!(json["emission"]["covariance_type"].is_string(), "{json}");
    assert!(json["emission"].get("emission").is_none());
    let back: Hmm<AnyEmission> = serde_json::from_value(json).unwrap();
    assert!(back.emission().as_gaussian().is_some());
    // Settings written before the emission existed: a diagonal covariance is a diagonal Gaussian.
    let settings = r#"{"states":3,"reg":0.01,"max_iter":40,"tol":0.0001,"restarts":1,"seed":0,"covariance":"diagonal"}"#;
    let s: HmmSettings = serde_json::from_str(settings).unwrap();
    assert_eq!(s.emission().to_string(), "diag");
    // A tag that disagrees with the parameters is refused.
    let (t, _) = HmmSettings::builder()
        .states(2)
        .emission("gmm-2".parse().unwrap())
        .max_iter(2)
        .build()
        .unwrap()
        .fit(&train)
        .unwrap();
    let text = serde_json::to_string(t.emission())
        .unwrap()
        .replace("gmm-2", "gmm-3");
    let err = serde_json::from_str::<AnyEmission>(&text).unwrap_err();
    assert!(err.to_string().contains("gmm-3"), "{err}");
}

/// Counts: the human's two channels do not tell states 1 and 2 apart, the
/// robot's do, so the human-only filter and the joint one disagree there.
fn count_data(seed: u64) -> SequenceSet {
    let truth = Hmm::new(
        vec![1.0, 0.0, 0.0, 0.0],
        vec![
            0.9, 0.1, 0.0, 0.0, //
            0.0, 0.9, 0.1, 0.0, //
            0.0, 0.0, 0.9, 0.1, //
            0.0, 0.0, 0.0, 1.0,
        ],
        Poisson::new(
            4,
            vec![
                1.0, 1.0, 1.0, 1.0, //
                8.0, 8.0, 2.0, 2.0, //
                8.0, 8.0, 12.0, 12.0, //
                2.0, 15.0, 5.0, 1.0,
            ],
        )
        .unwrap(),
    )
    .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let seqs: Vec<Vec<f64>> = (0..8)
        .map(|_| truth.sample(60, &mut rng).unwrap().0)
        .collect();
    SequenceSet::new(&seqs, 4).unwrap()
}

#[test]
fn an_emission_without_a_conditional_is_segmented_by_the_tsc_hmm() {
    let data = count_data(3);
    let roles = Roles::new(vec![0, 1], vec![2, 3]).unwrap();
    let settings = TscSettings::builder()
        .base(HmmSettings::paper(4).unwrap())
        .tsc_states(2)
        .window(1)
        .build()
        .unwrap();
    let (m, report) =
        TscHmm::fit_with(&data, &roles, &settings, Poisson::unit).unwrap_or_else(|e| panic!("{e}"));
    assert!(report.segments >= 1);
    assert_eq!(m.union().unwrap().n_states(), 6);
    let seq = data.iter().next().unwrap();
    assert_eq!(
        m.union().unwrap().viterbi(seq).unwrap().states.len(),
        seq.len()
    );
    // The worst-prediction detector predicts the robot, which needs a conditional.
    let worst = settings
        .to_builder()
        .detector(phasekit_tsc::Detector::WorstPrediction { fraction: 0.2 })
        .build()
        .unwrap();
    let err = TscHmm::fit_with(&data, &roles, &worst, Poisson::unit).unwrap_err();
    assert!(err.to_string().contains("conditional"), "{err}");
}

#[test]
fn the_mixture_presets_fit_every_emission_in_every_mixture() {
    let (train, _) = data(7, 4);
    for kind in kinds() {
        let options = PresetOptions::builder()
            .max_iter(8)
            .emission(kind)
            .build()
            .unwrap();
        let (model, _) = Method::preset(Preset::GmmTsc, &options)
            .unwrap()
            .fit(&train, &roles())
            .unwrap_or_else(|e| panic!("gmm-tsc {kind}: {e}"));
        let Model::GmmTsc { tsc, mixture } = &model else {
            panic!("gmm-tsc fitted {model:?}")
        };
        // The frame mixture, the transition clusters and the joined mixture
        // that predicts are all of the chosen emission.
        assert_eq!(mixture.components().kind(), kind);
        assert_eq!(tsc.mixture().components().kind(), kind);
        assert_eq!(tsc.transition_mixture().components().kind(), kind);
        assert_eq!(
            mixture.n_components(),
            tsc.mixture().n_components() + tsc.kept().len(),
            "{kind}: the joined mixture holds the frame components and the kept transitions"
        );
        let (model, _) = Method::preset(Preset::Gmm, &options)
            .unwrap()
            .fit(&train, &roles())
            .unwrap();
        let Model::Gmm(g) = &model else {
            panic!("gmm fitted {model:?}")
        };
        assert_eq!(g.components().kind(), kind);
    }
}

/// Static GMR on data whose demonstrations hold gross marker glitches: a
/// Student-t mixture down-weights them, a Gaussian one widens its components
/// around them, so the Student-t's prediction of clean test data is better.
#[test]
fn a_student_t_mixture_predicts_through_glitches_better_than_a_gaussian_one() {
    let (train, test) = data(9, 11);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let glitched: Vec<Vec<f64>> = train
        .iter()
        .map(|s| {
            let mut f = s.as_slice().to_vec();
            for v in f.chunks_exact_mut(6) {
                if rand::Rng::random::<f64>(&mut rng) < 0.05 {
                    // A marker swap: the robot's hand jumps by a metre.
                    v[3 + rand::Rng::random_range(&mut rng, 0..3)] += 1.0;
                }
            }
            f
        })
        .collect();
    let train = SequenceSet::new(&glitched, 6).unwrap();
    let mse = |kind: &str| {
        let options = PresetOptions::builder()
            .states(6)
            .emission(kind.parse().unwrap())
            .build()
            .unwrap();
        let (model, _) = Method::preset(Preset::Gmm, &options)
            .unwrap()
            .fit(&train, &roles())
            .unwrap();
        let predictor = model.predictor(&roles()).unwrap();
        let (mut sum, mut n) = (0.0, 0);
        for seq in &test {
            let human: Vec<f64> = seq.chunks_exact(6).flat_map(|f| f[..3].to_vec()).collect();
            let p = predictor
                .predict(Frames::new(&human, 3).unwrap(), false)
                .unwrap();
            for (f, m) in seq.chunks_exact(6).zip(p.mean.chunks_exact(3)) {
                sum += (0..3).map(|j| (f[3 + j] - m[j]).powi(2)).sum::<f64>();
                n += 1;
            }
        }
        sum / n as f64
    };
    let (gaussian, student) = (mse("full"), mse("student-t"));
    eprintln!("static GMR through glitches, MSE (m²): full {gaussian:.6}, student-t {student:.6}");
    assert!(
        student < 0.8 * gaussian,
        "Student-t MSE {student} is not clearly below the Gaussian's {gaussian}"
    );
}
