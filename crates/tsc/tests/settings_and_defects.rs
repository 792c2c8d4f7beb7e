//! Validated settings, the errors that name parameters, and the defects of
//! issue 20 in this crate, each with a regression test:
//!
//! * `gmm-tsc:window=0` is refused (it silently became 1);
//! * an automatic number of states stops at what the data support, and says so
//!   (`max_states = 1000` used to try every count up to the shortest demonstration);
//! * a TSC-HMM whose regularisation swamps the data says so (it blamed the window);
//! * a G-means count above the range is refused (it returned the cap);
//! * the segmentation of a TSC-HMM labels by the predicting model's states and
//!   keeps the base HMM's beside them;
//! * cross-validation keeps why a candidate failed (it became infinity).

use phasekit_emission::{Frames, SequenceSet};
use phasekit_hmm::{max_supported_states, StateLimit};
use phasekit_tsc::select::mixture_components;
use phasekit_tsc::synthetic::generate;
use phasekit_tsc::tsc_hmm::TscHmm;
use phasekit_tsc::{
    cross_validate, AutoStates, Composition, CrossValidation, HmmSettings, KrishnanSettings,
    Method, Model, NoTransitionCause, Preset, PresetOptions, Roles, Selector, TimeClustering,
    TscError, TscSettings,
};

fn roles() -> Roles {
    Roles::new(vec![0, 1, 2], vec![3, 4, 5]).unwrap()
}

fn data(n: usize, seed: u64) -> SequenceSet {
    let demos = generate(n, seed);
    let seqs: Vec<&[f64]> = demos.iter().map(|d| &d.frames[..]).collect();
    SequenceSet::new(&seqs, 6).unwrap()
}

fn setting_name(e: TscError) -> &'static str {
    match e {
        TscError::InvalidSetting { name, .. } => name,
        other => panic!("expected an invalid setting, got {other:?}"),
    }
}

#[test]
fn gmm_tsc_refuses_a_window_of_zero() {
    let o = PresetOptions::builder().window(0).build().unwrap();
    let err = Method::preset(Preset::GmmTsc, &o).unwrap_err();
    let msg = err.to_string();
    assert_eq!(setting_name(err), "window");
    assert!(msg.contains("1..=64") && msg.contains("got 0"), "{msg}");
    // The TSC-HMM's window 0 means no dilation, and is accepted.
    assert!(Method::preset(Preset::TscHmm, &o).is_ok());
    let one = PresetOptions::builder().window(1).build().unwrap();
    match Method::preset(Preset::GmmTsc, &one).unwrap() {
        Method::GmmTsc { tsc, .. } => assert_eq!(tsc.window(), 1),
        other => panic!("{other:?}"),
    }
}

#[test]
fn automatic_states_stop_at_what_the_data_support_and_say_so() {
    let train = data(3, 3);
    let auto = AutoStates::new(2, 1000, Selector::Bic).unwrap();
    let settings = HmmSettings::builder().auto_states(auto).build().unwrap();
    let (supported, limit) = max_supported_states(
        |k| {
            phasekit_emission::Gaussian::standard(
                phasekit_emission::CovarianceType::Full,
                phasekit_emission::Shape {
                    n_states: k,
                    dim: 6,
                },
            )
        },
        &train,
    )
    .unwrap();
    let shortest = train.lengths().min().unwrap();
    assert!(supported < shortest, "{supported} vs {shortest}");
    assert!(matches!(limit, StateLimit::Parameters { .. }), "{limit:?}");
    let (hmm, _, report) = settings.fit_selected(&train).unwrap();
    let report = report.unwrap();
    assert_eq!(report.range, 2..=supported);
    assert_eq!(report.lowered, Some((1000, limit)));
    assert_eq!(
        report.scores.iter().map(|s| s.0).collect::<Vec<_>>(),
        (2..=supported).collect::<Vec<_>>()
    );
    assert_eq!(hmm.n_states(), report.best);
    let summary = report.summary();
    assert!(
        summary.contains(&format!("at most {supported} states of the 1000 asked for"))
            && summary.contains("free parameters"),
        "{summary}"
    );
    // Through a preset, the fit summary says it too; an unlowered choice reads as before.
    let o = PresetOptions::builder()
        .auto_states()
        .max_states(1000)
        .build()
        .unwrap();
    let (_, fit) = Method::preset(Preset::Hmm, &o)
        .unwrap()
        .fit(&train, &roles())
        .unwrap();
    assert!(fit.chosen.unwrap().contains("of the 1000 asked for"));
    let o = o.to_builder().max_states(3).build().unwrap();
    let (_, fit) = Method::preset(Preset::Hmm, &o)
        .unwrap()
        .fit(&train, &roles())
        .unwrap();
    assert!(fit.chosen.unwrap().ends_with("(BIC)"));
}

#[test]
fn a_regularisation_that_swamps_the_data_is_named_not_the_window() {
    let train = data(6, 7);
    let o = PresetOptions::builder().reg(1e10).build().unwrap();
    let err = Method::preset(Preset::TscHmm, &o)
        .unwrap()
        .fit(&train, &roles())
        .unwrap_err();
    match &err {
        TscError::NoTransitions {
            cause:
                NoTransitionCause::NothingFlagged {
                    swamped: Some((reg, var)),
                },
            ..
        } => assert!(*reg == 1e10 && *var > 0.0 && *var < 1.0, "{err:?}"),
        other => panic!("{other:?}"),
    }
    let msg = err.to_string();
    assert!(
        msg.contains("`reg = 1e10`") && msg.contains("exceeds the variance"),
        "{msg}"
    );
    assert!(!msg.contains("window"), "{msg}");
    // A front end names the parameters its own way.
    let flags = err.describe(&|p, v| match v {
        Some(v) => format!("--{} {v}", p.replace('_', "-")),
        None => format!("--{}", p.replace('_', "-")),
    });
    assert!(
        flags.contains("--reg 1e10") && flags.contains("use a --reg well below"),
        "{flags}"
    );
}

#[test]
fn too_short_transition_segments_name_window_and_tsc_states() {
    // λ_T with more states than any transition segment has frames.
    let train = data(6, 7);
    let o = PresetOptions::builder().tsc_states(40).build().unwrap();
    let err = Method::preset(Preset::TscHmm, &o)
        .unwrap()
        .fit(&train, &roles())
        .unwrap_err();
    assert!(
        matches!(
            err,
            TscError::TransitionModel {
                tsc_states: 40,
                window: 2,
                ..
            }
        ),
        "{err:?}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains("larger window than ±2 (e.g. `window = 4`)")
            && msg.contains("fewer transition states (`tsc_states`)"),
        "{msg}"
    );
}

#[test]
fn gmeans_counts_above_the_range_are_refused_for_mixtures_too() {
    // Trajectory frames are not a mixture of a few Gaussians: G-means keeps splitting.
    let train = data(4, 5);
    let em = phasekit_gmm::Em::default();
    let err = mixture_components(Selector::GMeans, &em, train.all_frames(), 2..=6).unwrap_err();
    match err {
        TscError::GMeansAboveRange {
            counting: "mixture components",
            found,
            max: 6,
            ..
        } => assert!(found > 6),
        other => panic!("{other:?}"),
    }
    // BIC chooses within the range.
    let count = mixture_components(Selector::Bic, &em, train.all_frames(), 2..=6).unwrap();
    assert!((2..=6).contains(&count.count) && count.lowered.is_none());
}

#[test]
fn a_tsc_hmm_segments_by_the_states_of_the_model_that_predicts() {
    let train = data(8, 4);
    let test = &generate(1, 98)[0];
    let seq = Frames::new(&test.frames, 6).unwrap();
    for composition in [Composition::Union, Composition::Gated] {
        let (m, _) = TscHmm::fit(&train, &roles(), &TscSettings::paper(2, composition)).unwrap();
        let model = Model::TscHmm {
            model: m.clone(),
            window: 2,
        };
        let seg = model.segment(seq, &roles()).unwrap();
        let base = m.base().viterbi(seq).unwrap().states;
        assert_eq!(seg.base_labels.as_ref(), Some(&base), "{composition:?}");
        match m.union() {
            Some(u) => {
                assert_eq!(seg.labels, u.viterbi(seq).unwrap().states);
                // The transition states (4..7) label some frames.
                assert!(seg.labels.iter().any(|&s| s >= 4), "{:?}", seg.labels);
                assert!(seg.labels.iter().all(|&s| s < model.n_states()));
            }
            None => assert_eq!(seg.labels, base),
        }
    }
    // Other models have no base labels.
    let (hmm, _) = Method::preset(Preset::Hmm, &PresetOptions::default())
        .unwrap()
        .fit(&train, &roles())
        .unwrap();
    assert_eq!(hmm.segment(seq, &roles()).unwrap().base_labels, None);
}

#[test]
fn cross_validation_keeps_why_a_candidate_failed() {
    let train = data(6, 8);
    let hmm = |s: usize| Method::Hmm(HmmSettings::paper(s).unwrap());
    // 400 states: more than any demonstration has frames, so k-bins fails on every fold.
    let candidates = vec![
        ("hmm:states=3".to_string(), hmm(3)),
        ("hmm:states=400".to_string(), hmm(400)),
    ];
    let scores = cross_validate(&candidates, 3, &train, &roles()).unwrap();
    assert!(scores[0].as_ref().is_ok_and(|e| e.is_finite()));
    let failed = scores[1].as_ref().unwrap_err();
    assert!(
        matches!(
            failed,
            TscError::InFold {
                fold: 0,
                folds: 3,
                ..
            }
        ),
        "{failed:?}"
    );
    assert!(failed.to_string().starts_with("fold 1 of 3: "), "{failed}");
    // The method chooses among those that could be scored, and reports the others.
    let cv = Method::CrossValidated(CrossValidation::new(candidates.clone(), 3).unwrap());
    let (model, summary) = cv.fit(&train, &roles()).unwrap();
    assert_eq!(model.n_states(), 3);
    assert_eq!(summary.chosen.as_deref(), Some("hmm:states=3"));
    assert_eq!(summary.cv_errors.len(), 1);
    assert_eq!(summary.cv_failures.len(), 1);
    assert_eq!(summary.cv_failures[0].0, "hmm:states=400");
    assert!(
        summary.cv_failures[0].1.contains("fold 1 of 3"),
        "{:?}",
        summary.cv_failures
    );
    // None could be scored: an error naming every candidate and why.
    let none = Method::CrossValidated(
        CrossValidation::new(vec![("hmm:states=400".to_string(), hmm(400))], 3).unwrap(),
    );
    let err = none.fit(&train, &roles()).unwrap_err();
    assert!(matches!(err, TscError::NoCandidate { .. }), "{err:?}");
    assert!(
        err.to_string().contains("hmm:states=400: fold 1 of 3"),
        "{err}"
    );
    // Refused when made: no candidate, one fold.
    assert_eq!(
        setting_name(CrossValidation::new(vec![], 3).unwrap_err()),
        "candidates"
    );
    assert_eq!(
        setting_name(CrossValidation::new(candidates, 1).unwrap_err()),
        "folds"
    );
}

#[test]
fn every_settings_builder_names_the_bad_parameter() {
    assert_eq!(setting_name(HmmSettings::paper(0).unwrap_err()), "states");
    let h = HmmSettings::builder();
    assert_eq!(
        setting_name(h.clone().reg(-1.0).build().unwrap_err()),
        "reg"
    );
    assert_eq!(
        setting_name(h.clone().tol(f64::NAN).build().unwrap_err()),
        "tol"
    );
    assert_eq!(
        setting_name(h.clone().max_iter(0).build().unwrap_err()),
        "max_iter"
    );
    assert_eq!(setting_name(h.restarts(0).build().unwrap_err()), "restarts");
    assert_eq!(
        setting_name(AutoStates::new(3, 2, Selector::Bic).unwrap_err()),
        "max_states"
    );
    let t = TscSettings::builder();
    assert_eq!(
        setting_name(t.clone().tsc_states(0).build().unwrap_err()),
        "tsc_states"
    );
    assert_eq!(
        setting_name(t.clone().min_run(0).build().unwrap_err()),
        "min_run"
    );
    assert_eq!(
        setting_name(
            t.detector(phasekit_tsc::Detector::WorstPrediction { fraction: 0.0 })
                .build()
                .unwrap_err()
        ),
        "fraction"
    );
    let k = KrishnanSettings::builder();
    assert_eq!(
        setting_name(k.clone().window(65).build().unwrap_err()),
        "window"
    );
    assert_eq!(
        setting_name(k.clone().prune_fraction(1.5).build().unwrap_err()),
        "rho"
    );
    assert_eq!(
        setting_name(k.clone().components(Some(0)).build().unwrap_err()),
        "components"
    );
    assert_eq!(
        setting_name(k.clone().max_components(1).build().unwrap_err()),
        "max_states"
    );
    assert_eq!(setting_name(k.restarts(0).build().unwrap_err()), "restarts");
    assert_eq!(
        setting_name(TimeClustering::new(0, 1e-4).unwrap_err()),
        "time_clusters"
    );
    let o = PresetOptions::builder();
    assert_eq!(
        setting_name(o.clone().states(0).build().unwrap_err()),
        "states"
    );
    assert_eq!(
        setting_name(o.clone().max_states(1).build().unwrap_err()),
        "max_states"
    );
    assert_eq!(
        setting_name(o.clone().reg(f64::INFINITY).build().unwrap_err()),
        "reg"
    );
    assert_eq!(setting_name(o.max_iter(0).build().unwrap_err()), "max_iter");
    assert_eq!(
        setting_name(Roles::new(vec![], vec![1]).unwrap_err()),
        "roles"
    );
    assert_eq!(
        setting_name(Roles::new(vec![0, 0], vec![1]).unwrap_err()),
        "roles"
    );
    assert_eq!(
        setting_name("nope".parse::<Preset>().unwrap_err()),
        "method"
    );
    assert_eq!(
        setting_name("aic".parse::<Selector>().unwrap_err()),
        "select"
    );
    // Names and parsing agree.
    for p in Preset::ALL {
        assert_eq!(p.to_string().parse::<Preset>().unwrap(), p);
    }
    assert!(Preset::names().starts_with("hmm, hmm-cv, tsc-hmm-cv, tsc-hmm,"));
    for s in [Selector::Bic, Selector::GMeans] {
        assert_eq!(s.to_string().parse::<Selector>().unwrap(), s);
    }
}

#[test]
fn settings_read_from_a_file_are_validated_as_in_code() {
    let refuse = |json: serde_json::Value, needle: &str| {
        let err = serde_json::from_value::<Method>(json)
            .unwrap_err()
            .to_string();
        assert!(err.contains(needle), "{needle}: {err}");
    };
    let mut hmm = serde_json::to_value(Method::Hmm(HmmSettings::default())).unwrap();
    assert_eq!(hmm["method"], "hmm");
    hmm["states"] = 0.into();
    refuse(hmm, "`states`");
    let mut tsc = serde_json::to_value(Method::TscHmm(TscSettings::default())).unwrap();
    tsc["tsc_states"] = 0.into();
    refuse(tsc.clone(), "`tsc_states`");
    tsc["tsc_states"] = 3.into();
    tsc["base"]["reg"] = (-1.0).into();
    refuse(tsc, "`reg`");
    let o = PresetOptions::default();
    let gt = Method::preset(Preset::GmmTsc, &o).unwrap();
    let mut v = serde_json::to_value(&gt).unwrap();
    v["tsc"]["window"] = 0.into();
    refuse(v, "1..=64");
    let cv = Method::preset(Preset::HmmCv, &o).unwrap();
    let mut v = serde_json::to_value(&cv).unwrap();
    v["folds"] = 1.into();
    refuse(v.clone(), "`folds`");
    v["folds"] = 5.into();
    assert_eq!(serde_json::from_value::<Method>(v).unwrap(), cv);
    let mut opts = serde_json::to_value(&o).unwrap();
    assert_eq!(
        serde_json::from_value::<PresetOptions>(opts.clone()).unwrap(),
        o
    );
    opts["rho"] = 2.0.into();
    assert!(serde_json::from_value::<PresetOptions>(opts).is_err());
    let roles = serde_json::json!({"human": [0, 1], "robot": [1]});
    let err = serde_json::from_value::<Roles>(roles)
        .unwrap_err()
        .to_string();
    assert!(err.contains("both input and output"), "{err}");
}

#[test]
fn helpers_refuse_inputs_of_the_wrong_shape() {
    use phasekit_tsc::detect::disagreement;
    use phasekit_tsc::tsc_hmm::transition_sequences;
    let train = data(2, 1);
    // One flag per frame of every sequence, or an error (it sliced out of range).
    let err = transition_sequences(&train, &vec![vec![true; 3]; 2], 1).unwrap_err();
    assert_eq!(setting_name(err), "flags");
    let all: Vec<Vec<bool>> = train.lengths().map(|n| vec![true; n]).collect();
    assert_eq!(transition_sequences(&train, &all, 1).unwrap().len(), 2);
    // Nothing flagged, and runs too short, are told apart.
    let none: Vec<Vec<bool>> = train.lengths().map(|n| vec![false; n]).collect();
    assert!(matches!(
        transition_sequences(&train, &none, 2).unwrap_err(),
        TscError::NoTransitions {
            cause: NoTransitionCause::NothingFlagged { swamped: None },
            ..
        }
    ));
    let single: Vec<Vec<bool>> = train
        .lengths()
        .map(|n| (0..n).map(|t| t == 5).collect())
        .collect();
    assert!(matches!(
        transition_sequences(&train, &single, 2).unwrap_err(),
        TscError::NoTransitions {
            min_run: 2,
            cause: NoTransitionCause::RunsTooShort {
                flagged: 2,
                longest: 1
            }
        }
    ));
    // Two labellings of different lengths are not of the same frames.
    assert_eq!(
        setting_name(disagreement(&[0, 1], &[0]).unwrap_err()),
        "labels"
    );
    // The predictor's input: roles outside the frames are an error, not a panic.
    let frames = [0.0; 8];
    let seq = Frames::new(&frames, 4).unwrap();
    assert!(phasekit_tsc::human_frames(seq, &roles()).is_err());
}
