//! Parts and compositions of transition state clustering, on generated
//! two-agent interactions whose phase boundaries are known.

use phasekit_emission::{Emission, Frames, SequenceSet};
use phasekit_tsc::detect::{dilate, disagreement, label_changes, runs, Labeller, ViterbiLabeller};
use phasekit_tsc::preset::human_frames;
use phasekit_tsc::synthetic::{generate, with_velocities, Interaction};
use phasekit_tsc::tsc_hmm::{union_of, TscHmm};
use phasekit_tsc::{
    Composition, HmmSettings, KrishnanSettings, Method, Model, PresetOptions, Roles, TscSettings,
    PRESETS,
};
use proptest::prelude::*;

fn roles() -> Roles {
    Roles {
        human: vec![0, 1, 2],
        robot: vec![3, 4, 5],
    }
}

/// Roles of the 12-D features (positions and velocities of both hands).
fn roles12() -> Roles {
    Roles {
        human: (0..6).collect(),
        robot: (6..12).collect(),
    }
}

/// Standardised position+velocity features of every demonstration (so that the
/// paper's `reg = 1e-2` is small against every dimension's variance).
fn features(demos: &[Interaction]) -> Vec<Vec<f64>> {
    let feats: Vec<Vec<f64>> = demos.iter().map(with_velocities).collect();
    let all: Vec<f64> = feats.concat();
    let n = (all.len() / 12) as f64;
    let mean: Vec<f64> = (0..12)
        .map(|k| all.chunks_exact(12).map(|f| f[k]).sum::<f64>() / n)
        .collect();
    let sd: Vec<f64> = (0..12)
        .map(|k| {
            (all.chunks_exact(12)
                .map(|f| (f[k] - mean[k]).powi(2))
                .sum::<f64>()
                / n)
                .sqrt()
        })
        .collect();
    feats
        .iter()
        .map(|f| {
            f.chunks_exact(12)
                .flat_map(|x| {
                    (0..12)
                        .map(|k| (x[k] - mean[k]) / sd[k])
                        .collect::<Vec<_>>()
                })
                .collect()
        })
        .collect()
}

fn data(demos: &[Interaction]) -> SequenceSet {
    let seqs: Vec<&[f64]> = demos.iter().map(|d| &d.frames[..]).collect();
    SequenceSet::new(&seqs, 6).unwrap()
}

/// Mean over flagged frames of the distance to the nearest true boundary.
fn mean_distance_to_boundary(flags: &[usize], boundaries: &[usize]) -> f64 {
    let total: f64 = flags
        .iter()
        .map(|&t| {
            boundaries
                .iter()
                .map(|&b| (t as f64 - b as f64).abs())
                .fold(f64::INFINITY, f64::min)
        })
        .sum();
    total / flags.len().max(1) as f64
}

#[test]
fn label_changes_ignore_one_frame_flips() {
    let labels = [0, 0, 0, 1, 0, 0, 2, 2, 2, 2];
    let flags = label_changes(&labels, 2);
    let at: Vec<usize> = flags
        .iter()
        .enumerate()
        .filter_map(|(t, f)| f.then_some(t))
        .collect();
    assert_eq!(
        at,
        vec![6],
        "the one-frame flip to 1 is ignored, the change to 2 is kept"
    );
    let at1: Vec<usize> = label_changes(&labels, 1)
        .iter()
        .enumerate()
        .filter_map(|(t, f)| f.then_some(t))
        .collect();
    assert_eq!(at1, vec![3, 4, 6]);
}

proptest! {
    #[test]
    fn dilation_covers_window_and_runs_partition_flags(flags in proptest::collection::vec(any::<bool>(), 0..60), w in 0usize..4) {
        let d = dilate(&flags, w);
        for (t, f) in flags.iter().enumerate() {
            if *f {
                for k in t.saturating_sub(w)..(t + w + 1).min(flags.len()) {
                    prop_assert!(d[k]);
                }
            }
        }
        // Every dilated frame is within w of an original flag.
        for (t, f) in d.iter().enumerate() {
            if *f {
                prop_assert!((t.saturating_sub(w)..(t + w + 1).min(flags.len())).any(|k| flags[k]));
            }
        }
        // Runs are maximal, disjoint and cover exactly the flagged frames.
        let rs = runs(&d, 1);
        let covered: usize = rs.iter().map(|r| r.len()).sum();
        prop_assert_eq!(covered, d.iter().filter(|f| **f).count());
        for r in &rs {
            prop_assert!(r.start == 0 || !d[r.start - 1]);
            prop_assert!(r.end == d.len() || !d[r.end]);
        }
    }

    #[test]
    fn disagreement_flags_exactly_the_differing_frames(a in proptest::collection::vec(0usize..3, 0..40)) {
        let b: Vec<usize> = a.iter().enumerate().map(|(t, x)| if t % 3 == 0 { (x + 1) % 3 } else { *x }).collect();
        let f = disagreement(&a, &b);
        for t in 0..a.len() {
            prop_assert_eq!(f[t], t % 3 == 0);
        }
    }
}

#[test]
fn hmm_segments_land_near_true_boundaries() {
    let demos = generate(10, 1);
    let feats = features(&demos);
    let train = SequenceSet::new(&feats, 12).unwrap();
    let (hmm, _) = HmmSettings::paper(4).fit(&train).unwrap();
    let mut distances = Vec::new();
    for (d, f) in demos.iter().zip(&feats) {
        let seq = Frames::new(f, 12).unwrap();
        let labels = ViterbiLabeller(&hmm).label(seq).unwrap();
        let changes: Vec<usize> = label_changes(&labels, 2)
            .iter()
            .enumerate()
            .filter_map(|(t, f)| f.then_some(t))
            .collect();
        assert!(!changes.is_empty());
        distances.push(mean_distance_to_boundary(&changes, &d.boundaries));
    }
    let mean = distances.iter().sum::<f64>() / distances.len() as f64;
    assert!(
        mean < 4.0,
        "Viterbi state changes are on average {mean:.1} frames from a true boundary"
    );
}

#[test]
fn tsc_transition_frames_cluster_around_boundaries() {
    let demos = generate(10, 2);
    let train = SequenceSet::new(&features(&demos), 12).unwrap();
    let settings = TscSettings::paper(2, Composition::Union);
    let (_, report) = TscHmm::fit(&train, &roles12(), &settings).unwrap();
    let mut near = 0usize;
    let mut total = 0usize;
    for (d, f) in demos.iter().zip(&report.flags) {
        for (t, flagged) in f.iter().enumerate() {
            if *flagged {
                total += 1;
                near += usize::from(
                    d.boundaries
                        .iter()
                        .any(|&b| (t as i64 - b as i64).abs() <= 8),
                );
            }
        }
    }
    assert!(total > 0 && report.segments > 0);
    // Boundaries ±8 frames cover well under half of all frames, yet most flags fall there.
    let covered: usize = demos.iter().map(|d| d.boundaries.len() * 17).sum();
    let frames: usize = demos.iter().map(|d| d.phases.len()).sum();
    assert!((covered as f64) < 0.6 * frames as f64);
    assert!(
        near as f64 >= 0.8 * total as f64,
        "{near} of {total} flagged frames near a boundary"
    );
}

#[test]
fn krishnan_transitions_land_near_boundaries() {
    let demos = generate(10, 3);
    let feats = features(&demos);
    let train = SequenceSet::new(&feats, 12).unwrap();
    let settings = KrishnanSettings {
        components: Some(5),
        transition_clusters: Some(4),
        ..KrishnanSettings::default()
    };
    let tsc = settings.fit(&train).unwrap();
    assert!(!tsc.kept.is_empty());
    let mut all = Vec::new();
    for (d, f) in demos.iter().zip(&feats) {
        let seg = tsc.segment(Frames::new(f, 12).unwrap()).unwrap();
        assert_eq!(seg.labels.len(), d.phases.len());
        assert_eq!(seg.transitions.len(), seg.clusters.len());
        let kept: Vec<usize> = seg
            .transitions
            .iter()
            .zip(&seg.clusters)
            .filter_map(|(t, c)| c.map(|_| *t))
            .collect();
        all.push(mean_distance_to_boundary(&kept, &d.boundaries));
    }
    let mean = all.iter().sum::<f64>() / all.len() as f64;
    assert!(
        mean < 6.0,
        "kept transitions are on average {mean:.1} frames from a true boundary"
    );
}

fn assert_stochastic(v: &[f64], s: usize) {
    for row in v.chunks_exact(s) {
        assert!(row.iter().all(|p| *p >= 0.0));
        assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
}

#[test]
fn union_keeps_stochastic_rows_and_frozen_emissions_stay_unchanged() {
    let demos = generate(8, 4);
    let train = data(&demos);
    for composition in [Composition::Union, Composition::UnionFrozen] {
        let (m, _) = TscHmm::fit(&train, &roles(), &TscSettings::paper(2, composition)).unwrap();
        let u = m.union.as_ref().unwrap();
        assert_eq!(u.n_states(), 7);
        assert_stochastic(u.transition(), 7);
        assert_stochastic(u.start(), 7);
        let initial = union_of(&m.base, &m.transition, 0.01).unwrap();
        assert_stochastic(initial.transition(), 7);
        let (a, b) = (u.emission(), initial.emission());
        if composition == Composition::UnionFrozen {
            assert_eq!(
                a.means(),
                b.means(),
                "frozen emissions must stay bit-identical"
            );
            assert_eq!(a.covariances_raw(), b.covariances_raw());
        } else {
            assert_ne!(
                a.means(),
                b.means(),
                "warm-started emissions are re-estimated"
            );
        }
    }
}

#[test]
fn every_preset_fits_predicts_online_like_batch_and_round_trips() {
    let demos = generate(8, 5);
    let train = data(&demos);
    let test = &generate(1, 99)[0];
    let seq = Frames::new(&test.frames, 6).unwrap();
    let human = human_frames(seq, &roles());
    let human = Frames::new(&human, 3).unwrap();
    let options = PresetOptions {
        window: 2,
        ..PresetOptions::default()
    };
    for name in PRESETS {
        let method = Method::preset(name, &options).unwrap();
        let (model, summary) = method
            .fit(&train, &roles())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(!summary.log_likelihood.is_empty(), "{name}");
        let predictor = model.predictor(&roles()).unwrap();
        let batch = predictor.predict(human, true).unwrap();
        assert_eq!(batch.mean.len(), human.len() * 3);
        let cov = batch.covariance.as_ref().unwrap();
        let mut online = predictor.online();
        for (t, x) in human.iter().enumerate() {
            let m = online.step(x, true).unwrap().to_vec();
            for j in 0..3 {
                assert!(
                    (m[j] - batch.mean[t * 3 + j]).abs() < 1e-9,
                    "{name}: frame {t}"
                );
            }
            for (a, b) in online.covariance().iter().zip(&cov[t * 9..(t + 1) * 9]) {
                assert!((a - b).abs() < 1e-9, "{name}: covariance at frame {t}");
            }
        }
        // Predictions beat the constant mean pose by a wide margin on these data.
        let mean_pose: Vec<f64> = (3..6)
            .map(|k| test.frames.chunks_exact(6).map(|f| f[k]).sum::<f64>() / human.len() as f64)
            .collect();
        let (mut se, mut se0) = (0.0, 0.0);
        for (t, f) in test.frames.chunks_exact(6).enumerate() {
            for j in 0..3 {
                se += (batch.mean[t * 3 + j] - f[3 + j]).powi(2);
                se0 += (mean_pose[j] - f[3 + j]).powi(2);
            }
        }
        assert!(se < 0.5 * se0, "{name}: error {se} vs constant {se0}");
        let seg = model.segment(seq, &roles()).unwrap();
        assert_eq!(seg.labels.len(), human.len());
        let json = serde_json::to_string(&model).unwrap();
        let back: Model = serde_json::from_str(&json).unwrap();
        let again = back
            .predictor(&roles())
            .unwrap()
            .predict(human, false)
            .unwrap();
        assert_eq!(
            again.mean, batch.mean,
            "{name}: serde round trip changes predictions"
        );
    }
}

#[test]
fn unknown_preset_and_bad_roles_are_clear_errors() {
    let err = Method::preset("nope", &PresetOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("unknown preset") && err.contains("tsc-hmm"),
        "{err}"
    );
    let train = data(&generate(3, 6));
    let bad = Roles {
        human: vec![0, 1],
        robot: vec![1, 2],
    };
    let err = Method::preset("hmm", &PresetOptions::default())
        .unwrap()
        .fit(&train, &bad)
        .unwrap_err()
        .to_string();
    assert!(err.contains("both input and output"), "{err}");
}
