//! Recognition on generated interactions with known actions: accuracy, the
//! oracle, unknown motions, the composed HMM, the file round trip and bad inputs.

use crate::common;

use common::{demos, fit, human, library, library_without_wave, roles};
use phasekit_emission::{Frames, SequenceSet};
use phasekit_recognition::metrics::{correct_from_first_third, settled_frame};
use phasekit_recognition::{
    ComposedHmm, ComposedRecogniser, Decision, Library, LibraryParams, LibrarySettings,
    PredictionMode, Recogniser, RecogniserSettings, RecognitionError, Rejection,
};
use phasekit_tsc::synthetic::{generate_kind, with_velocities, Interaction, Kind};
use phasekit_tsc::{Method, Preset, PresetOptions};

fn settings(rejection: Rejection, prediction: PredictionMode) -> RecogniserSettings {
    let mut s = RecogniserSettings::default();
    s.rejection = rejection;
    s.prediction = prediction;
    s
}

/// Decisions on every frame of a joint demonstration, from a fresh start.
fn run(r: &mut Recogniser, joint: &[f64]) -> Vec<Decision> {
    r.reset();
    human(joint)
        .chunks_exact(6)
        .map(|x| r.step(x).unwrap())
        .collect()
}

#[test]
fn the_right_interaction_is_recognised_from_the_first_third_on() {
    let lib = library();
    assert_eq!(lib.names(), ["handshake", "fist-bump", "wave", "handover"]);
    let mut r = Recogniser::new(lib, settings(Rejection::Off, PredictionMode::Mixture)).unwrap();
    let (mut total, mut early, mut during_reach) = (0, 0, 0);
    for (a, kind) in Kind::ALL.into_iter().enumerate() {
        // Test demonstrations from another seed than the training ones.
        for demo in generate_kind(kind, 5, 77) {
            let joint = with_velocities(&demo);
            let d = run(&mut r, &joint);
            assert_eq!(*d.last().unwrap(), Decision::Action(a), "{kind:?}");
            // Known before the hand arrives: settled during the reach.
            let settled = settled_frame(&d, a).unwrap();
            assert!(
                settled < demo.boundaries[2],
                "{kind:?}: settled at {settled}, the action phase ends at {}",
                demo.boundaries[2]
            );
            during_reach += (settled < demo.boundaries[1]) as usize;
            total += 1;
            early += correct_from_first_third(&d, a) as usize;
            // The posterior is a distribution that ends on the true action.
            let p = r.posterior();
            assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            assert!(p[a] > 0.99, "{kind:?}: {p:?}");
        }
    }
    // Known before the hand arrives: settled during the reach (the fist bump's
    // reach is short: some settle as its bump begins).
    assert!(
        during_reach >= total - 3,
        "settled during the reach on {during_reach} of {total}"
    );
    assert!(
        early >= total - 3,
        "right from the first third on {early} of {total}"
    );
}

#[test]
fn the_true_actions_track_predicts_exactly_as_the_method_told_the_action() {
    // The oracle of the end-to-end comparison is the action's own predictor:
    // the recogniser's per-action prediction must be the batch prediction, bit for bit.
    let lib = library();
    let mut r = Recogniser::new(lib, settings(Rejection::Off, PredictionMode::Mixture)).unwrap();
    let joint = &demos(Kind::Wave, 1, 5)[0];
    let h = human(joint);
    for (a, action) in lib.actions().iter().enumerate() {
        let batch = action
            .model
            .predictor(lib.roles())
            .unwrap()
            .predict(Frames::new(&h, 6).unwrap(), false)
            .unwrap();
        r.reset();
        for (t, x) in h.chunks_exact(6).enumerate() {
            r.step(x).unwrap();
            assert_eq!(
                r.action_robot(a),
                &batch.mean[t * 6..(t + 1) * 6],
                "action {a}, frame {t}"
            );
        }
    }
}

#[test]
fn the_posterior_is_bayes_rule_over_the_filters_likelihoods() {
    let lib = library()
        .with_prior(&phasekit_recognition::Prior::Given(vec![
            1.0, 2.0, 3.0, 4.0,
        ]))
        .unwrap();
    let mut r =
        Recogniser::new(&lib, settings(Rejection::Off, PredictionMode::MostProbable)).unwrap();
    let joint = &demos(Kind::Handover, 1, 9)[0];
    let h = human(joint);
    for (t, x) in h.chunks_exact(6).enumerate().take(40) {
        r.step(x).unwrap();
        // ℓ_a(t) from the action HMM's own batch forward pass on the human marginal.
        let ll: Vec<f64> = lib
            .actions()
            .iter()
            .map(|a| {
                let m = phasekit_recognition::parts::action_hmm(&a.model)
                    .unwrap()
                    .marginal(lib.roles().human())
                    .unwrap();
                m.log_likelihood(Frames::new(&h[..(t + 1) * 6], 6).unwrap())
                    .unwrap()
            })
            .collect();
        let w: Vec<f64> = ll
            .iter()
            .zip(lib.prior())
            .map(|(l, p)| p.ln() + l)
            .collect();
        let top = w.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let z: f64 = w.iter().map(|v| (v - top).exp()).sum();
        for (a, v) in w.iter().enumerate() {
            let expected = (v - top).exp() / z;
            assert!(
                (r.posterior()[a] - expected).abs() < 1e-9,
                "frame {t}, action {a}"
            );
            assert!((r.log_likelihoods()[a] - ll[a]).abs() <= 1e-9 * ll[a].abs().max(1.0));
        }
        // Most probable: the robot follows the decided action's GMR.
        let best = r.decision().action().unwrap();
        assert_eq!(r.robot(), r.action_robot(best));
    }
}

/// Decisions on `joint` under both rejection tests (likelihood per frame, threshold model).
fn last_decisions(lib: &Library, joint: &[f64]) -> [Decision; 2] {
    [Rejection::LikelihoodPerFrame, Rejection::ThresholdModel].map(|rejection| {
        let mut r = Recogniser::new(lib, settings(rejection, PredictionMode::Mixture)).unwrap();
        let d = run(&mut r, joint);
        if *d.last().unwrap() == Decision::Unknown {
            assert_eq!(
                r.robot(),
                &lib.rest_pose()[..],
                "the robot keeps its rest pose"
            );
        }
        *d.last().unwrap()
    })
}

#[test]
fn a_motion_of_no_known_type_is_rejected_and_the_robot_keeps_still() {
    // A library without the wave: every wave is rejected by the
    // likelihood-per-frame test (the hand goes where no known action goes).
    // The threshold model does not reject them: no state of any action
    // explains that pose either, so it cannot beat the action models there.
    let lib = library_without_wave();
    for joint in demos(Kind::Wave, 5, 31) {
        assert_eq!(last_decisions(lib, &joint)[0], Decision::Unknown);
    }
    let mut rejected_known = [0, 0];
    for (a, kind) in [Kind::Handshake, Kind::FistBump, Kind::Handover]
        .into_iter()
        .enumerate()
    {
        for joint in demos(kind, 4, 32) {
            for (k, d) in last_decisions(lib, &joint).into_iter().enumerate() {
                match d {
                    Decision::Unknown => rejected_known[k] += 1,
                    x => assert_eq!(x, Decision::Action(a), "{kind:?}"),
                }
            }
        }
    }
    assert!(
        rejected_known.iter().all(|&n| n <= 1),
        "{rejected_known:?} of 12 known motions rejected"
    );
}

#[test]
fn known_poses_in_an_unknown_order_are_rejected_by_the_threshold_model() {
    // A chimera: a handover's reach and hold, then a fist bump's bump and
    // retract. Every pose is one the library knows; the jump from the
    // handover's hold to the fist bump's is in no action. The threshold model
    // follows it; the action models pay for it, and the motion is rejected
    // for a while after the jump (until the evidence before it outweighs it).
    let lib = library();
    let mut s = settings(Rejection::ThresholdModel, PredictionMode::Mixture);
    s.both_statistics = true;
    let mut r = Recogniser::new(lib, s).unwrap();
    for seed in 0..4 {
        let h = &generate_kind(Kind::Handover, 1, 90 + seed)[0];
        let f = &generate_kind(Kind::FistBump, 1, 95 + seed)[0];
        let (cut_h, cut_f) = (h.boundaries[2], f.boundaries[1]);
        let mut frames = h.frames[..cut_h * 6].to_vec();
        frames.extend_from_slice(&f.frames[cut_f * 6..]);
        let chimera = Interaction {
            frames,
            phases: Vec::new(),
            boundaries: Vec::new(),
        };
        let d = run(&mut r, &with_velocities(&chimera));
        assert!(
            d[..cut_h].iter().all(|d| *d != Decision::Unknown),
            "seed {seed}: rejected before the jump"
        );
        let rejected = d[cut_h..]
            .iter()
            .filter(|d| **d == Decision::Unknown)
            .count();
        assert!(
            rejected >= 5,
            "seed {seed}: {rejected} frames rejected after the jump"
        );
    }
}

#[test]
fn rest_pose_is_the_robot_part_of_the_rest_state() {
    let lib = library();
    let rest = lib.rest();
    assert_eq!(
        rest.frames,
        4 * 10 * 10,
        "5 frames at each end of 10 demonstrations of 4 actions"
    );
    let pose = lib.rest_pose();
    assert_eq!(pose, rest.mean[6..12]);
    // The generated hands rest at the origin (σ = 4 mm noise).
    assert!(pose.iter().all(|v| v.abs() < 0.01), "{pose:?}");
    // Before any frame the robot predicts its rest pose.
    let r = Recogniser::new(lib, RecogniserSettings::default()).unwrap();
    assert_eq!(r.robot(), &pose[..]);
    assert_eq!(r.posterior(), lib.prior());
}

#[test]
fn the_composed_hmm_with_closed_actions_is_exactly_the_per_action_posterior() {
    // With every exit probability 0 the composed HMM is block-diagonal: a
    // mixture of the action HMMs (and the rest state), so its belief summed
    // over an action's states, renormalised without rest, is Bayes' rule over
    // the per-action filters. (Rest is closed too, up to a 1e-15 leak.)
    let mut p: LibraryParams = library().clone().into();
    p.actions
        .iter_mut()
        .for_each(|a| a.exit.iter_mut().for_each(|e| *e = 0.0));
    p.rest.stay = 1e15;
    let lib = Library::try_from(p).unwrap();
    let mut composed = ComposedRecogniser::new(&lib, false).unwrap();
    let mut per_action =
        Recogniser::new(&lib, settings(Rejection::Off, PredictionMode::Mixture)).unwrap();
    let joint = &demos(Kind::FistBump, 1, 4)[0];
    for x in human(joint).chunks_exact(6) {
        composed.step(x).unwrap();
        per_action.step(x).unwrap();
        let actions = 1.0 - composed.rest_probability();
        for (c, q) in composed.posterior().iter().zip(per_action.posterior()) {
            assert!((c / actions - q).abs() < 1e-9, "{c} / {actions} vs {q}");
        }
    }
}

#[test]
fn the_composed_hmm_agrees_with_per_action_filters_on_separated_segments() {
    // A stream of four interactions of different kinds, back to back. The
    // per-action filters are reset at each true start (they are told where
    // the interactions are); the composed HMM is not.
    let lib = library();
    let order = [Kind::Wave, Kind::Handshake, Kind::Handover, Kind::FistBump];
    let mut composed = ComposedRecogniser::new(lib, false).unwrap();
    let mut per_action =
        Recogniser::new(lib, settings(Rejection::Off, PredictionMode::Mixture)).unwrap();
    for (k, kind) in order.into_iter().enumerate() {
        let a = Kind::ALL.iter().position(|&x| x == kind).unwrap();
        let demo = &phasekit_tsc::synthetic::generate_kind(kind, 1, 40 + k as u64)[0];
        let joint = phasekit_tsc::synthetic::with_velocities(demo);
        per_action.reset();
        let (mut dc, mut dp) = (Vec::new(), Vec::new());
        for (t, x) in human(&joint).chunks_exact(6).enumerate() {
            dc.push(composed.step(x).unwrap());
            dp.push(per_action.step(x).unwrap());
            // In the action phase both are sure of the true action.
            if demo.phases[t] == 2 {
                assert!(
                    composed.posterior()[a] > 0.95,
                    "{kind:?} frame {t}: {:?}",
                    composed.posterior()
                );
                assert!(per_action.posterior()[a] > 0.95, "{kind:?} frame {t}");
            }
        }
        // Both settle on the true action before the action phase ends.
        let end_of_action = demo.boundaries[2];
        for d in [&dc, &dp] {
            let s = settled_frame(&d[..end_of_action], a);
            assert!(
                s.is_some_and(|s| s < demo.boundaries[1] + 10),
                "{kind:?}: {s:?}"
            );
        }
    }
}

#[test]
fn the_composed_hmm_is_a_union_with_structured_transitions() {
    let lib = library();
    let c = ComposedHmm::new(lib).unwrap();
    let n = c.hmm.n_states();
    assert_eq!(n, 4 * 4 + 1);
    assert_eq!(c.rest, n - 1);
    let a = c.hmm.transition();
    for (i, row) in a.chunks_exact(n).enumerate() {
        assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        // From an action's state: its own states or rest, never another action.
        if let Some(r) = c.actions.iter().find(|r| r.contains(&i)) {
            for (j, p) in row.iter().enumerate() {
                if !(r.contains(&j) || j == c.rest) {
                    assert_eq!(*p, 0.0);
                }
            }
        }
    }
    assert!((a[c.rest * n + c.rest] - (1.0 - 1.0 / 30.0)).abs() < 1e-15);
    // Leaving happens from where the demonstrations end, about once per stay
    // there. (The generated hands rest at one place before and after the
    // motion, so EM makes the HMMs cyclic: they end in their first state.)
    for (r, action) in c.actions.iter().zip(lib.actions()) {
        let end = (0..action.end.len())
            .max_by(|&i, &j| action.end[i].total_cmp(&action.end[j]))
            .unwrap();
        assert!(action.end[end] > 0.99, "{}: {:?}", action.name, action.end);
        for i in 0..action.end.len() {
            let e = a[(r.start + i) * n + c.rest];
            assert_eq!(e, action.exit[i]);
            if i == end {
                assert!(e > 0.01 && e < 0.1, "{}: exit {e}", action.name);
            } else {
                assert!(e < 1e-3, "{}: exit {e} from state {i}", action.name);
            }
        }
    }
}

#[test]
fn automatic_resets_recognise_each_interaction_of_a_stream() {
    let lib = library();
    let mut s = settings(Rejection::Off, PredictionMode::Mixture);
    s.auto_reset = Some(phasekit_recognition::AutoReset::default());
    let mut r = Recogniser::new(lib, s).unwrap();
    let order = [Kind::Handover, Kind::Wave, Kind::Wave, Kind::Handshake];
    let mut resets = 0;
    for (k, kind) in order.into_iter().enumerate() {
        let a = Kind::ALL.iter().position(|&x| x == kind).unwrap();
        let joint = &demos(kind, 1, 60 + k as u64)[0];
        let d: Vec<Decision> = human(joint)
            .chunks_exact(6)
            .map(|x| {
                let d = r.step(x).unwrap();
                resets += r.reset_pending() as usize;
                d
            })
            .collect();
        let middle = d.len() / 2;
        assert_eq!(d[middle], Decision::Action(a), "interaction {k} ({kind:?})");
    }
    assert!(resets >= 3, "{resets} resets");
}

#[test]
fn a_library_round_trips_through_its_file_bit_for_bit() {
    let lib = library();
    let text = serde_json::to_string(lib).unwrap();
    let back: Library = serde_json::from_str(&text).unwrap();
    assert_eq!(serde_json::to_string(&back).unwrap(), text);
    let mut s = settings(Rejection::ThresholdModel, PredictionMode::Mixture);
    s.with_covariance = true;
    s.both_statistics = true;
    let (mut r1, mut r2) = (
        Recogniser::new(lib, s.clone()).unwrap(),
        Recogniser::new(&back, s).unwrap(),
    );
    for x in human(&demos(Kind::Handshake, 1, 8)[0]).chunks_exact(6) {
        assert_eq!(r1.step(x).unwrap(), r2.step(x).unwrap());
        assert_eq!(r1.posterior(), r2.posterior());
        assert_eq!(r1.robot(), r2.robot());
        assert_eq!(r1.robot_covariance(), r2.robot_covariance());
        assert_eq!(r1.statistics(), r2.statistics());
    }
}

#[test]
fn a_library_of_static_mixtures_scores_frames_as_the_mixture_does() {
    // A `gmm` library: its likelihood is the human marginal's, frame by frame.
    let method = Method::preset(
        Preset::Gmm,
        &PresetOptions::builder().states(6).build().unwrap(),
    )
    .unwrap();
    let lib = fit(&[Kind::Wave, Kind::Handover], &method);
    let mut r = Recogniser::new(&lib, settings(Rejection::Off, PredictionMode::Mixture)).unwrap();
    let joint = &demos(Kind::Wave, 1, 3)[0];
    let h = human(joint);
    for x in h.chunks_exact(6) {
        r.step(x).unwrap();
    }
    for (a, action) in lib.actions().iter().enumerate() {
        let phasekit_tsc::Model::Gmm(g) = &action.model else {
            panic!("a gmm model")
        };
        let expected = g
            .marginal(&[0, 1, 2, 3, 4, 5])
            .unwrap()
            .log_likelihood(Frames::new(&h, 6).unwrap())
            .unwrap();
        let got = r.log_likelihoods()[a];
        assert!(
            (got - expected).abs() <= 1e-9 * expected.abs(),
            "{got} vs {expected}"
        );
    }
    assert_eq!(r.decision(), Decision::Action(0));
}

#[test]
fn missing_values_are_recognised_on_what_is_observed() {
    let lib = library();
    let mut r = Recogniser::new(lib, settings(Rejection::Off, PredictionMode::Mixture)).unwrap();
    let joint = &demos(Kind::Wave, 1, 12)[0];
    let mut h = human(joint);
    // Drop the hand's z (and its velocity) on every other frame, and one whole frame.
    for (t, x) in h.chunks_exact_mut(6).enumerate() {
        if t % 2 == 0 {
            x[2] = f64::NAN;
            x[5] = f64::NAN;
        }
        if t == 30 {
            x.fill(f64::NAN);
        }
    }
    r.reset();
    for x in h.chunks_exact(6) {
        r.step(x).unwrap();
        assert!(r.robot().iter().all(|v| v.is_finite()));
    }
    assert_eq!(r.decision(), Decision::Action(2));
    // The likelihood per frame counts the frames' worth of observed values:
    // missing values do not make a known motion look unknown.
    let mut s = settings(Rejection::LikelihoodPerFrame, PredictionMode::Mixture);
    s.both_statistics = true;
    let mut rejecting = Recogniser::new(lib, s).unwrap();
    let d = run_frames(&mut rejecting, &h);
    assert_eq!(*d.last().unwrap(), Decision::Action(2));
    assert!(d[40..].iter().all(|x| *x != Decision::Unknown));
}

#[test]
fn a_glitch_no_action_explains_is_taken_as_not_observed() {
    // A frame of 1e200 has density zero under every state of every action
    // (its squared distance overflows): the recognisers take it as not
    // observed, say so, and go on recognising; a per-action recogniser does
    // not give up every action, nor the threshold model.
    let lib = library();
    let joint = &demos(Kind::Wave, 1, 12)[0];
    let mut h = human(joint);
    let glitch = 30;
    h[glitch * 6..glitch * 6 + 6].fill(1e200);
    let mut s = settings(Rejection::Either, PredictionMode::Mixture);
    s.both_statistics = true;
    let mut r = Recogniser::new(lib, s).unwrap();
    r.reset();
    for (t, x) in h.chunks_exact(6).enumerate() {
        r.step(x).unwrap();
        assert_eq!(r.frame_rejected(), t == glitch, "frame {t}");
        assert!(r.robot().iter().all(|v| v.is_finite()));
        assert!(
            r.log_likelihoods().iter().all(|l| l.is_finite()),
            "frame {t}"
        );
    }
    assert_eq!(r.decision(), Decision::Action(2));
    let mut c = ComposedRecogniser::new(lib, false).unwrap();
    for (t, x) in h.chunks_exact(6).enumerate() {
        c.step(x).unwrap();
        assert_eq!(c.frame_rejected(), t == glitch, "frame {t}");
        assert!(c.robot().iter().all(|v| v.is_finite()));
    }
    // The demonstration ends at rest; of the actions, wave is the most probable.
    let p = c.posterior();
    assert!(p.iter().all(|&q| q <= p[2]), "{p:?}");
}

/// Decisions on every human frame, from a fresh start.
fn run_frames(r: &mut Recogniser, human: &[f64]) -> Vec<Decision> {
    r.reset();
    human.chunks_exact(6).map(|x| r.step(x).unwrap()).collect()
}

#[test]
fn bad_inputs_give_clear_errors() {
    let data = common::training(&[Kind::Handshake, Kind::Wave]);
    let m = common::hmm();
    let roles = roles();
    let s = LibrarySettings::default();
    // One action.
    let e = Library::fit(&[("handshake", &data[0].1, &m)], None, &roles, &s).unwrap_err();
    assert!(e.to_string().contains("at least 2 actions"), "{e}");
    assert!(e.to_string().contains("handshake"), "{e}");
    // Two actions of one name.
    let e = Library::fit(
        &[("a", &data[0].1, &m), ("a", &data[1].1, &m)],
        None,
        &roles,
        &s,
    )
    .unwrap_err();
    assert!(e.to_string().contains("two actions are named `a`"), "{e}");
    // Actions whose features differ.
    let narrow: Vec<Vec<f64>> = demos(Kind::Wave, 3, 1)
        .iter()
        .map(|q| {
            q.chunks_exact(12)
                .flat_map(|x| x[..11].iter().copied())
                .collect()
        })
        .collect();
    let narrow = SequenceSet::new(&narrow, 11).unwrap();
    let e = Library::fit(
        &[("handshake", &data[0].1, &m), ("wave", &narrow, &m)],
        None,
        &roles,
        &s,
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("action `wave` has 11 features, action `handshake` 12"),
        "{e}"
    );
    // A frame that does not match the library's human features.
    let lib = library();
    let mut r = Recogniser::new(lib, RecogniserSettings::default()).unwrap();
    let e = r.step(&[0.0; 5]).unwrap_err();
    assert_eq!(
        e,
        RecognitionError::DimensionMismatch {
            context: "human frame",
            expected: 6,
            found: 5
        }
    );
    assert_eq!(e.to_string(), "human frame: 5 values, expected 6");
    let e = r
        .step(&[0.0, 0.0, f64::INFINITY, 0.0, 0.0, 0.0])
        .unwrap_err();
    assert!(e.to_string().contains("value 2 is inf"), "{e}");
    assert_eq!(r.frames(), 0, "nothing was taken");
    // A corrupted file: a negative prior, a lost state of an exit vector.
    let mut p: LibraryParams = lib.clone().into();
    p.prior[0] = -0.25;
    let text = serde_json::to_string(&p).unwrap();
    let e = serde_json::from_str::<Library>(&text).unwrap_err();
    assert!(
        e.to_string()
            .contains("the prior must hold one positive probability"),
        "{e}"
    );
    let mut p: LibraryParams = lib.clone().into();
    p.actions[1].exit.pop();
    let e = Library::try_from(p).unwrap_err();
    assert!(
        e.to_string()
            .contains("action `fist-bump`: 3 exit and 4 end probabilities for 4 states"),
        "{e}"
    );
    // Settings.
    let mut bad = LibrarySettings::default();
    bad.rest_stay = 0.5;
    let e = Library::fit(
        &[("a", &data[0].1, &m), ("b", &data[1].1, &m)],
        None,
        &roles,
        &bad,
    )
    .unwrap_err();
    assert!(e.to_string().contains("rest_stay"), "{e}");
}

#[test]
fn calibration_holds_out_demonstrations() {
    let c = library().calibration();
    assert!(c.held_out);
    assert_eq!(c.demonstrations, 40);
    assert_eq!(c.failed_folds, 0);
    assert!(c.likelihood_per_frame.is_some() && c.threshold_model.is_some());
}

#[test]
fn a_second_model_can_recognise_while_the_first_predicts() {
    use phasekit_recognition::parts::action_hmm;
    let data = common::training(&[Kind::Handshake, Kind::Wave]);
    let predict = common::hmm();
    let recognise = Method::preset(
        Preset::Hmm,
        &PresetOptions::builder()
            .states(6)
            .reg(1e-3)
            .build()
            .unwrap(),
    )
    .unwrap();
    let actions: Vec<(&str, &SequenceSet, &Method)> = data
        .iter()
        .map(|(n, d)| (n.as_str(), d, &predict))
        .collect();
    let (lib, _) = Library::fit(
        &actions,
        Some(&recognise),
        &roles(),
        &LibrarySettings::default(),
    )
    .unwrap();
    let mut r = Recogniser::new(&lib, settings(Rejection::Off, PredictionMode::Mixture)).unwrap();
    let h = human(&demos(Kind::Wave, 1, 21)[0]);
    for (t, x) in h.chunks_exact(6).enumerate() {
        r.step(x).unwrap();
        if t % 20 != 0 {
            continue;
        }
        for (a, action) in lib.actions().iter().enumerate() {
            let rec = action.recognition.as_ref().expect("a recognition model");
            assert_eq!(action_hmm(rec).unwrap().n_states(), 6);
            let ll = action_hmm(rec)
                .unwrap()
                .marginal(lib.roles().human())
                .unwrap()
                .log_likelihood(Frames::new(&h[..(t + 1) * 6], 6).unwrap())
                .unwrap();
            assert!((r.log_likelihoods()[a] - ll).abs() <= 1e-9 * ll.abs().max(1.0));
            let batch = action
                .model
                .predictor(lib.roles())
                .unwrap()
                .predict(Frames::new(&h[..(t + 1) * 6], 6).unwrap(), false)
                .unwrap();
            assert_eq!(r.action_robot(a), &batch.mean[t * 6..(t + 1) * 6]);
        }
    }
    assert_eq!(r.decision(), Decision::Action(1));
}

#[test]
fn the_temperature_divides_the_evidence_and_can_be_chosen_on_held_out_demonstrations() {
    let base = library();
    let mut p: LibraryParams = base.clone().into();
    p.calibration.temperature = 4.0;
    let hot = Library::try_from(p).unwrap();
    let s = settings(Rejection::Off, PredictionMode::Mixture);
    let (mut r1, mut r4) = (
        Recogniser::new(base, s.clone()).unwrap(),
        Recogniser::new(&hot, s).unwrap(),
    );
    for x in human(&demos(Kind::Handshake, 1, 23)[0])
        .chunks_exact(6)
        .take(40)
    {
        assert_eq!(
            r1.step(x).unwrap(),
            r4.step(x).unwrap(),
            "uniform prior: same decision"
        );
        let ll = r1.log_likelihoods();
        let top = ll.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let z: f64 = ll.iter().map(|l| ((l - top) / 4.0).exp()).sum();
        for (q, l) in r4.posterior().iter().zip(ll) {
            assert!((q - ((l - top) / 4.0).exp() / z).abs() < 1e-12);
        }
        // The mixture weights are the tempered posterior.
        let mut m = [0.0; 6];
        for (a, w) in r4.posterior().iter().enumerate() {
            m.iter_mut()
                .zip(r4.action_robot(a))
                .for_each(|(m, v)| *m += w * v);
        }
        for (x, y) in m.iter().zip(r4.robot()) {
            assert!((x - y).abs() < 1e-12);
        }
    }
    // Chosen on held-out demonstrations: one of the grid, with the best log score.
    let data = common::training(&[Kind::Handshake, Kind::FistBump]);
    let m = common::hmm();
    let actions: Vec<(&str, &SequenceSet, &Method)> =
        data.iter().map(|(n, d)| (n.as_str(), d, &m)).collect();
    let mut auto = LibrarySettings::default();
    auto.temperature = None;
    let (lib, _) = Library::fit(&actions, None, &roles(), &auto).unwrap();
    let c = lib.calibration();
    assert!(phasekit_recognition::library::TEMPERATURES.contains(&c.temperature));
    for t in phasekit_recognition::library::TEMPERATURES {
        let mut fixed = LibrarySettings::default();
        fixed.temperature = Some(t);
        let (other, _) = Library::fit(&actions, None, &roles(), &fixed).unwrap();
        assert!(
            other.calibration().log_score <= c.log_score + 1e-12,
            "τ = {t}"
        );
    }
    let mut bad = LibrarySettings::default();
    bad.temperature = Some(0.5);
    assert!(Library::fit(&actions, None, &roles(), &bad)
        .unwrap_err()
        .to_string()
        .contains("temperature"));
}

#[test]
fn either_test_rejects_what_one_of_them_rejects() {
    let lib = library_without_wave();
    let mut s = settings(Rejection::Either, PredictionMode::Mixture);
    s.both_statistics = true;
    let mut r = Recogniser::new(lib, s).unwrap();
    let c = lib.calibration();
    for joint in demos(Kind::Wave, 2, 31)
        .iter()
        .chain(&demos(Kind::Handover, 2, 31))
    {
        r.reset();
        for x in human(joint).chunks_exact(6) {
            r.step(x).unwrap();
            let (pf, tm) = r.statistics();
            let expected = pf < c.likelihood_per_frame.unwrap() || tm < c.threshold_model.unwrap();
            assert_eq!(r.rejected(), expected);
            assert_eq!(r.decision() == Decision::Unknown, expected);
        }
    }
}
