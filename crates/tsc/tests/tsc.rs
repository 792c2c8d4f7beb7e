//! Parts and compositions of transition state clustering, on generated
//! two-agent interactions whose phase boundaries are known.

use phasekit_emission::{Frames, SequenceSet};
use phasekit_gmr::HmmRegression;
use phasekit_tsc::detect::{dilate, disagreement, label_changes, runs, Labeller, ViterbiLabeller};
use phasekit_tsc::human_frames;
use phasekit_tsc::krishnan::windowed;
use phasekit_tsc::synthetic::{generate, with_velocities, Interaction};
use phasekit_tsc::tsc_hmm::{union_of, TscHmm};
use phasekit_tsc::{
    Composition, HmmSettings, KrishnanSettings, Method, Model, Preset, PresetOptions, Roles,
    Selector, TimeClustering, TscSettings,
};
use proptest::prelude::*;

fn roles() -> Roles {
    Roles::new(vec![0, 1, 2], vec![3, 4, 5]).unwrap()
}

/// Roles of the 12-D features (positions and velocities of both hands).
fn roles12() -> Roles {
    Roles::new((0..6).collect(), (6..12).collect()).unwrap()
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

/// Mean over detected frames of the distance to the nearest true boundary;
/// `None` when nothing was detected (a missed demonstration, not a perfect one).
fn mean_distance_to_boundary(detected: &[usize], boundaries: &[usize]) -> Option<f64> {
    if detected.is_empty() {
        return None;
    }
    let total: f64 = detected
        .iter()
        .map(|&t| {
            boundaries
                .iter()
                .map(|&b| (t as f64 - b as f64).abs())
                .fold(f64::INFINITY, f64::min)
        })
        .sum();
    Some(total / detected.len() as f64)
}

/// Distance from every true boundary to the nearest detected frame (`inf` if none).
fn boundary_to_nearest_detection(detected: &[usize], boundaries: &[usize]) -> Vec<f64> {
    boundaries
        .iter()
        .map(|&b| {
            detected
                .iter()
                .map(|&t| (t as f64 - b as f64).abs())
                .fold(f64::INFINITY, f64::min)
        })
        .collect()
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
                for dk in &d[t.saturating_sub(w)..(t + w + 1).min(flags.len())] {
                    prop_assert!(*dk);
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
        let f = disagreement(&a, &b).unwrap();
        prop_assert_eq!(f.len(), a.len());
        for (t, ft) in f.iter().enumerate() {
            prop_assert_eq!(*ft, t % 3 == 0);
        }
    }
}

#[test]
fn hmm_segments_land_near_true_boundaries() {
    let demos = generate(10, 1);
    let feats = features(&demos);
    let train = SequenceSet::new(&feats, 12).unwrap();
    let (hmm, _) = HmmSettings::paper(4).unwrap().fit(&train).unwrap();
    let mut distances = Vec::new();
    for (d, f) in demos.iter().zip(&feats) {
        let seq = Frames::new(f, 12).unwrap();
        let labels = ViterbiLabeller(&hmm).label(seq).unwrap();
        let changes: Vec<usize> = label_changes(&labels, 2)
            .iter()
            .enumerate()
            .filter_map(|(t, f)| f.then_some(t))
            .collect();
        distances.push(
            mean_distance_to_boundary(&changes, &d.boundaries)
                .expect("every demonstration has a Viterbi state change"),
        );
    }
    let mean = distances.iter().sum::<f64>() / distances.len() as f64;
    assert!(
        mean < 4.0,
        "Viterbi state changes are on average {mean:.1} frames from a true boundary"
    );
}

/// A boundary is recalled when a detection lies within this many frames of it.
const RECALL_DISTANCE: f64 = 8.0;

#[test]
fn tsc_transition_frames_cluster_around_boundaries() {
    let demos = generate(10, 2);
    let feats = features(&demos);
    let train = SequenceSet::new(&feats, 12).unwrap();
    let settings = TscSettings::paper(2, Composition::Union);
    let (_, report) = TscHmm::fit(&train, &roles12(), &settings).unwrap();
    let mut near = 0usize;
    let mut total = 0usize;
    let mut recalled = 0usize;
    let mut boundaries = 0usize;
    for (d, f) in demos.iter().zip(&report.flags) {
        let flagged: Vec<usize> = f
            .iter()
            .enumerate()
            .filter_map(|(t, x)| x.then_some(t))
            .collect();
        total += flagged.len();
        near += flagged
            .iter()
            .filter(|&&t| {
                d.boundaries
                    .iter()
                    .any(|&b| (t as f64 - b as f64).abs() <= RECALL_DISTANCE)
            })
            .count();
        let dist = boundary_to_nearest_detection(&flagged, &d.boundaries);
        recalled += dist.iter().filter(|x| **x <= RECALL_DISTANCE).count();
        boundaries += dist.len();
    }
    assert!(total > 0 && report.segments > 0);
    // Precision. Boundaries ±8 frames cover well under half of all frames, yet most flags fall there.
    let covered: usize = demos.iter().map(|d| d.boundaries.len() * 17).sum();
    let frames: usize = demos.iter().map(|d| d.phases.len()).sum();
    assert!((covered as f64) < 0.6 * frames as f64);
    assert!(
        near as f64 >= 0.8 * total as f64,
        "{near} of {total} flagged frames near a boundary"
    );
    // Recall of the detector alone. The paper's transition states are only the frames where
    // the human's marginal is ambiguous, so not every boundary has one (here 31 of 40 do;
    // idle and rest look alike and 4 states cover 5 phases).
    assert!(
        recalled as f64 >= 0.75 * boundaries as f64,
        "only {recalled} of {boundaries} boundaries have a flagged frame within {RECALL_DISTANCE} frames"
    );
    // Recall of the TSC-HMM segmentation (λ's Viterbi state changes, `base_labels`, and
    // the transition frames, as `segment` reports them): every true boundary is found.
    let (model, _) = Method::TscHmm(settings).fit(&train, &roles12()).unwrap();
    for (k, (d, f)) in demos.iter().zip(&feats).enumerate() {
        let seg = model
            .segment(Frames::new(f, 12).unwrap(), &roles12())
            .unwrap();
        let base_labels = seg.base_labels.as_ref().unwrap();
        // The labels are the predicting union's states; λ's are its first 4.
        assert_eq!(seg.labels.len(), base_labels.len());
        assert!(seg.labels.iter().all(|&s| s < 7) && base_labels.iter().all(|&s| s < 4));
        let mut detected: Vec<usize> = label_changes(base_labels, 2)
            .iter()
            .enumerate()
            .filter_map(|(t, x)| x.then_some(t))
            .collect();
        detected.extend(&seg.transitions);
        for (b, dist) in d
            .boundaries
            .iter()
            .zip(boundary_to_nearest_detection(&detected, &d.boundaries))
        {
            assert!(
                dist <= RECALL_DISTANCE,
                "demonstration {k}: boundary at frame {b} is {dist} frames from the nearest detection"
            );
        }
    }
}

#[test]
fn krishnan_transitions_land_near_boundaries() {
    let demos = generate(10, 3);
    let feats = features(&demos);
    let train = SequenceSet::new(&feats, 12).unwrap();
    let settings = KrishnanSettings::builder()
        .components(Some(5))
        .transition_clusters(Some(4))
        .build()
        .unwrap();
    let (tsc, _) = settings.fit(&train).unwrap();
    assert!(!tsc.kept().is_empty());
    let mut all = Vec::new();
    for (k, (d, f)) in demos.iter().zip(&feats).enumerate() {
        let seg = tsc.segment(Frames::new(f, 12).unwrap()).unwrap();
        assert_eq!(seg.labels.len(), d.phases.len());
        assert_eq!(seg.transitions.len(), seg.clusters.len());
        let kept: Vec<usize> = seg
            .transitions
            .iter()
            .zip(&seg.clusters)
            .filter_map(|(t, c)| c.map(|_| *t))
            .collect();
        // A demonstration without any kept transition is a miss, not a perfect score.
        all.push(
            mean_distance_to_boundary(&kept, &d.boundaries)
                .unwrap_or_else(|| panic!("demonstration {k} has no kept transition")),
        );
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
        let u = m.union().unwrap();
        assert_eq!(u.n_states(), 7);
        assert_stochastic(u.transition(), 7);
        assert_stochastic(u.start(), 7);
        let initial = union_of(m.base(), m.transition(), 0.01).unwrap();
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
    let human = human_frames(seq, &roles()).unwrap();
    let human = Frames::new(&human, 3).unwrap();
    let options = PresetOptions::builder().window(2).build().unwrap();
    for preset in Preset::ALL {
        let name = preset.name();
        assert_eq!(name.parse::<Preset>().unwrap(), preset);
        assert_eq!(preset.to_string(), name);
        let method = Method::preset(preset, &options).unwrap();
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
            for (mj, bj) in m.iter().zip(&batch.mean[t * 3..(t + 1) * 3]) {
                assert!((mj - bj).abs() < 1e-9, "{name}: frame {t}");
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
    let err = "nope".parse::<Preset>().unwrap_err().to_string();
    assert!(
        err.contains("unknown preset") && err.contains("tsc-hmm"),
        "{err}"
    );
    // Roles that share a dimension are refused when made …
    let err = Roles::new(vec![0, 1], vec![1, 2]).unwrap_err().to_string();
    assert!(err.contains("both input and output"), "{err}");
    // … and roles outside the frame when fitted.
    let train = data(&generate(3, 6));
    let outside = Roles::new(vec![0, 1], vec![2, 6]).unwrap();
    let err = Method::preset(Preset::Hmm, &PresetOptions::default())
        .unwrap()
        .fit(&train, &outside)
        .unwrap_err()
        .to_string();
    assert!(err.contains("out of range"), "{err}");
}

/// Piecewise-constant 2-D demonstrations: segment `i` of a demonstration sits at
/// `levels[plan[i]]` for `durations[i]` frames (± `jitter` frames), with noise of sd 0.1.
fn piecewise(
    plans: &[Vec<usize>],
    levels: &[[f64; 2]],
    duration: usize,
    jitter: usize,
    seed: u64,
) -> Vec<Vec<f64>> {
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.1).unwrap();
    plans
        .iter()
        .map(|plan| {
            let mut out = Vec::new();
            for &l in plan {
                let n = duration - jitter + rng.random_range(0..=2 * jitter);
                for _ in 0..n {
                    out.push(levels[l][0] + noise.sample(&mut rng));
                    out.push(levels[l][1] + noise.sample(&mut rng));
                }
            }
            out
        })
        .collect()
}

const LEVELS: [[f64; 2]; 4] = [[0.0, 0.0], [5.0, 0.0], [5.0, 5.0], [0.0, 5.0]];

#[test]
fn windowed_stacks_past_frames_oldest_first_repeating_the_first() {
    let x: Vec<f64> = (0..8).map(|v| v as f64).collect(); // 4 frames of 2 dims
    let seq = Frames::new(&x, 2).unwrap();
    assert_eq!(windowed(seq, 1), x, "a window of one frame is the frame");
    let w3 = windowed(seq, 3);
    assert_eq!(w3.len(), 4 * 2 * 3);
    // Frame t holds x_{t−2}, x_{t−1}, x_t, with x_s = x_0 for s < 0.
    let expected: Vec<f64> = [[0, 0, 0], [0, 0, 1], [0, 1, 2], [1, 2, 3]]
        .iter()
        .flat_map(|frames| frames.iter().flat_map(|&f| [x[2 * f], x[2 * f + 1]]))
        .collect();
    assert_eq!(w3, expected);
}

#[test]
fn pruning_drops_clusters_supported_by_fewer_than_rho_of_the_demonstrations() {
    // All ten demonstrations go A → B → C; three of them go on to D: the C → D
    // transitions form a cluster supported by 3 of 10 demonstrations.
    let plans: Vec<Vec<usize>> = (0..10)
        .map(|k| {
            if k < 3 {
                vec![0, 1, 2, 3]
            } else {
                vec![0, 1, 2]
            }
        })
        .collect();
    let demos = piecewise(&plans, &LEVELS, 30, 3, 11);
    let train = SequenceSet::new(&demos, 2).unwrap();
    let settings = |rho: f64| {
        KrishnanSettings::builder()
            .components(Some(4))
            .transition_clusters(Some(3))
            .prune_fraction(rho)
            .build()
            .unwrap()
    };
    // Support of every cluster, counted from the segmentations of a model that keeps all.
    let (all, _) = settings(0.0).fit(&train).unwrap();
    assert_eq!(all.kept(), [0, 1, 2]);
    let mut support = [0usize; 3];
    for d in &demos {
        let seg = all.segment(Frames::new(d, 2).unwrap()).unwrap();
        let mut seen = [false; 3];
        for c in seg.clusters.iter().flatten() {
            seen[*c] = true;
        }
        for c in 0..3 {
            support[c] += usize::from(seen[c]);
        }
    }
    let mut sorted = support;
    sorted.sort_unstable();
    assert_eq!(sorted, [3, 10, 10], "support of the clusters: {support:?}");
    let rare = support.iter().position(|&s| s == 3).unwrap();
    let m = all.transition_mixture().components().mean(rare);
    assert!(
        (m[0] - 0.0).abs() < 0.5 && (m[1] - 5.0).abs() < 0.5,
        "the rare cluster is at D: {m:?}"
    );
    for rho in [0.1, 0.3, 0.31, 0.5, 0.9, 1.0] {
        let (tsc, _) = settings(rho).fit(&train).unwrap();
        let expected: Vec<usize> = (0..3)
            .filter(|&c| support[c] as f64 >= rho * 10.0)
            .collect();
        assert_eq!(tsc.kept(), expected, "ρ = {rho}");
        // Pruned clusters are reported as no cluster.
        let seg = tsc.segment(Frames::new(&demos[0], 2).unwrap()).unwrap();
        assert!(seg.clusters.iter().flatten().all(|c| expected.contains(c)));
    }
    // Through the preset key.
    let o = PresetOptions::builder().rho(0.31).build().unwrap();
    match Method::preset(Preset::GmmTsc, &o).unwrap() {
        Method::GmmTsc { tsc, .. } => assert_eq!(tsc.prune_fraction(), 0.31),
        other => panic!("{other:?}"),
    }
    // An out-of-range ρ is refused when the options are built.
    let err = PresetOptions::builder()
        .rho(1.5)
        .build()
        .unwrap_err()
        .to_string();
    assert!(err.contains("ρ") && err.contains("1.5"), "{err}");
}

#[test]
fn time_subclustering_splits_one_place_visited_at_two_moments() {
    // A → B → A → B: the transitions into B (at about 25 % and 75 % of the demonstration)
    // fall in one state-space cluster; by time they are two.
    let plans = vec![vec![0, 1, 0, 1]; 8];
    let demos = picewise_abab(&plans);
    let train = SequenceSet::new(&demos, 2).unwrap();
    let base = KrishnanSettings::builder()
        .components(Some(2))
        .transition_clusters(Some(2))
        .build()
        .unwrap();
    let timed = base
        .to_builder()
        .time_clusters(Some(TimeClustering::default()))
        .build()
        .unwrap();
    let (plain, _) = base.fit(&train).unwrap();
    let (split, _) = timed.fit(&train).unwrap();
    assert_eq!(plain.reported_clusters().len(), 2);
    assert_eq!(
        split.reported_clusters().len(),
        3,
        "{:?}",
        split.reported_clusters()
    );
    for d in &demos {
        let frames = Frames::new(d, 2).unwrap();
        let (a, b) = (
            plain.segment(frames).unwrap(),
            split.segment(frames).unwrap(),
        );
        assert_eq!(
            a.transitions, b.transitions,
            "time sub-clustering changes clusters only"
        );
        assert_eq!(a.transitions.len(), 3);
        let (pa, pb): (Vec<usize>, Vec<usize>) = (
            a.clusters.iter().map(|c| c.unwrap()).collect(),
            b.clusters.iter().map(|c| c.unwrap()).collect(),
        );
        assert_eq!(
            pa[0], pa[2],
            "without time, both entries into B share a cluster"
        );
        assert_ne!(pa[0], pa[1]);
        let mut distinct = pb.clone();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(
            distinct.len(),
            3,
            "with time, the three transitions are three clusters: {pb:?}"
        );
    }
    // The same transition of every demonstration gets the same cluster.
    let first: Vec<Vec<Option<usize>>> = demos
        .iter()
        .map(|d| split.segment(Frames::new(d, 2).unwrap()).unwrap().clusters)
        .collect();
    assert!(first.iter().all(|c| *c == first[0]), "{first:?}");
    // The preset key turns it on.
    let o = PresetOptions::builder().time_clusters(3).build().unwrap();
    match Method::preset(Preset::GmmTsc, &o).unwrap() {
        Method::GmmTsc { tsc, .. } => assert_eq!(tsc.time_clusters().unwrap().max_clusters(), 3),
        other => panic!("{other:?}"),
    }
}

fn picewise_abab(plans: &[Vec<usize>]) -> Vec<Vec<f64>> {
    piecewise(plans, &LEVELS, 30, 3, 12)
}

#[test]
fn automatic_component_counts_find_the_regimes() {
    // Three regimes, A → B → C in every demonstration.
    let plans = vec![vec![0, 1, 2]; 10];
    let demos = piecewise(&plans, &LEVELS, 40, 4, 13);
    let train = SequenceSet::new(&demos, 2).unwrap();
    for selector in [Selector::Bic, Selector::GMeans] {
        let settings = KrishnanSettings::builder()
            .components(None)
            .transition_clusters(None)
            .max_components(6)
            .selector(selector)
            .build()
            .unwrap();
        let (tsc, report) = settings.fit(&train).unwrap();
        assert_eq!(
            tsc.mixture().n_components(),
            3,
            "{selector:?}: frame mixture"
        );
        assert_eq!(
            tsc.transition_mixture().n_components(),
            2,
            "{selector:?}: the entries into B and into C"
        );
        assert_eq!(tsc.kept().len(), 2);
        // Both counts were automatic, from the whole range (the data support more).
        let frame = report.frame_components.unwrap();
        assert_eq!((frame.count, frame.range, frame.lowered), (3, 2..=6, None));
        assert_eq!(report.transition_clusters.unwrap().count, 2);
    }
    // The preset path: `gmm-tsc:states=auto,tsc-states=0,select=gmeans`.
    let o = PresetOptions::builder()
        .auto_states()
        .tsc_states(0)
        .select(Selector::GMeans)
        .max_states(6)
        .window(1)
        .build()
        .unwrap();
    let method = Method::preset(Preset::GmmTsc, &o).unwrap();
    match &method {
        Method::GmmTsc { tsc, .. } => {
            assert_eq!(tsc.components(), None);
            assert_eq!(tsc.transition_clusters(), None);
            assert_eq!(tsc.selector(), Selector::GMeans);
            assert_eq!(tsc.max_components(), 6);
        }
        other => panic!("{other:?}"),
    }
    let roles = Roles::new(vec![0], vec![1]).unwrap();
    let (model, summary) = method.fit(&train, &roles).unwrap();
    let Model::GmmTsc { tsc, mixture } = &model else {
        panic!("{model:?}")
    };
    // The GMM it extends follows the chosen count: 3 components plus the 2 kept clusters.
    assert_eq!(tsc.mixture().n_components(), 3);
    assert_eq!(mixture.n_components(), 3 + tsc.kept().len());
    assert!(summary.chosen.unwrap().contains("3 frame components"));
}

#[test]
fn automatic_hmm_states_take_the_lowest_bic() {
    let train = data(&generate(6, 21));
    let o = PresetOptions::builder()
        .auto_states()
        .max_states(6)
        .build()
        .unwrap();
    let (model, summary) = Method::preset(Preset::Hmm, &o)
        .unwrap()
        .fit(&train, &roles())
        .unwrap();
    let scores = &summary.bic;
    assert_eq!(
        scores.iter().map(|s| s.0).collect::<Vec<_>>(),
        (2..=6).collect::<Vec<_>>()
    );
    let best = scores.iter().min_by(|a, b| a.1.total_cmp(&b.1)).unwrap().0;
    assert_eq!(model.n_states(), best);
    assert_eq!(
        summary.chosen.as_deref(),
        Some(&*format!("states={best} (BIC)"))
    );
    // The chosen model is the fixed-count fit, and its BIC is the reported score.
    let (fixed, _) = HmmSettings::paper(best).unwrap().fit(&train).unwrap();
    let Model::Hmm(h) = &model else { panic!() };
    assert_eq!(h.emission().means(), fixed.emission().means());
    let bic = fixed.bic(&train).unwrap();
    assert_eq!(scores.iter().find(|s| s.0 == best).unwrap().1, bic);
    // A TSC-HMM's λ can be chosen the same way.
    let (tsc, summary) = Method::preset(Preset::TscHmm, &o)
        .unwrap()
        .fit(&train, &roles())
        .unwrap();
    let Model::TscHmm { model: m, .. } = &tsc else {
        panic!()
    };
    assert_eq!(m.base().n_states(), best);
    assert_eq!(tsc.n_states(), best + 3);
    assert!(!summary.bic.is_empty());
    // G-means chooses λ's states too, when its count of the pooled frames lies
    // within the range. On these trajectories it finds far more Gaussian clusters
    // than 6 (27): the count would only be the cap, so it is refused, saying so.
    let g = o.to_builder().select(Selector::GMeans).build().unwrap();
    let err = Method::preset(Preset::Hmm, &g)
        .unwrap()
        .fit(&train, &roles())
        .unwrap_err();
    let found = phasekit_gmm::gmeans(train.all_frames(), phasekit_gmm::GMeans::default())
        .unwrap()
        .k;
    assert!(found > 6, "G-means finds {found} clusters");
    assert!(
        matches!(err, phasekit_tsc::TscError::GMeansAboveRange { max: 6, .. }),
        "{err:?}"
    );
    let msg = err.to_string();
    assert!(msg.contains("more than the 6 HMM states allowed"), "{msg}");
    // On frames that are a mixture of a few Gaussians (a 3-state HMM with
    // well-separated 2-D states), G-means' count is the choice, whatever the cap
    // (it used to be the cap: 10 → 10, 30 → 30), fitted and scored by its BIC.
    let truth = phasekit_hmm::Hmm::new(
        vec![1.0 / 3.0; 3],
        vec![0.9, 0.05, 0.05, 0.05, 0.9, 0.05, 0.05, 0.05, 0.9],
        phasekit_emission::Gaussian::spherical(
            2,
            vec![0.0, 0.0, 10.0, 0.0, 0.0, 10.0],
            vec![1.0; 3],
        )
        .unwrap(),
    )
    .unwrap();
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(11);
    let seqs: Vec<Vec<f64>> = (0..10)
        .map(|_| truth.sample(120, &mut rng).unwrap().0)
        .collect();
    let blobs = SequenceSet::new(&seqs, 2).unwrap();
    let xy = Roles::new(vec![0], vec![1]).unwrap();
    for max in [10, 30] {
        let g = g.to_builder().max_states(max).build().unwrap();
        let (gm, gsummary) = Method::preset(Preset::Hmm, &g)
            .unwrap()
            .fit(&blobs, &xy)
            .unwrap();
        assert_eq!(gm.n_states(), 3, "max {max}");
        let Model::Hmm(gh) = &gm else { panic!() };
        assert_eq!(gsummary.bic, vec![(3, gh.bic(&blobs).unwrap())]);
        assert_eq!(gsummary.chosen.as_deref(), Some("states=3 (G-means)"));
    }
    // Refused at construction: auto states for the CV presets and gmm.
    for preset in [Preset::HmmCv, Preset::TscHmmCv, Preset::Gmm] {
        let err = Method::preset(preset, &o).unwrap_err().to_string();
        assert!(err.contains("states=auto"), "{preset}: {err}");
    }
}

/// `log p(o_t | o_{1:t−1})` per frame from first principles: the filtered belief of
/// the previous frame pushed through the transitions, times the emission densities.
fn predictive_log_likelihoods(
    hmm: &phasekit_hmm::Hmm<phasekit_emission::Gaussian>,
    seq: Frames<'_>,
) -> Vec<f64> {
    let s = hmm.n_states();
    let log_b = hmm.emission_log_densities(seq).unwrap();
    let filtered = hmm.forward(seq).unwrap().filtered().to_vec();
    (0..seq.len())
        .map(|t| {
            let prior: Vec<f64> = if t == 0 {
                hmm.start().to_vec()
            } else {
                (0..s)
                    .map(|j| {
                        (0..s)
                            .map(|i| filtered[(t - 1) * s + i] * hmm.transition()[i * s + j])
                            .sum()
                    })
                    .collect()
            };
            prior
                .iter()
                .zip(&log_b[t * s..(t + 1) * s])
                .map(|(p, lb)| p * lb.exp())
                .sum::<f64>()
                .ln()
        })
        .collect()
}

#[test]
fn gated_prediction_takes_the_transition_model_where_it_explains_the_human_better() {
    let demos = generate(8, 31);
    let train = data(&demos);
    let (m, _) = TscHmm::fit(&train, &roles(), &TscSettings::paper(2, Composition::Gated)).unwrap();
    assert!(m.union().is_none());
    let model = Model::TscHmm {
        model: m.clone(),
        window: 2,
    };
    let predictor = model.predictor(&roles()).unwrap();
    let base = HmmRegression::new(m.base(), &[0, 1, 2], &[3, 4, 5]).unwrap();
    let transition = HmmRegression::new(m.transition(), &[0, 1, 2], &[3, 4, 5]).unwrap();
    let (mut from_t, mut from_b) = (0, 0);
    for test in generate(3, 32) {
        let seq = Frames::new(&test.frames, 6).unwrap();
        let human = human_frames(seq, &roles()).unwrap();
        let human = Frames::new(&human, 3).unwrap();
        let gated = predictor.predict(human, true).unwrap();
        let pb = base.predict(human, true).unwrap();
        let pt = transition.predict(human, true).unwrap();
        let lb = predictive_log_likelihoods(&m.base().marginal(&[0, 1, 2]).unwrap(), human);
        let lt = predictive_log_likelihoods(&m.transition().marginal(&[0, 1, 2]).unwrap(), human);
        for t in 0..human.len() {
            if (lt[t] - lb[t]).abs() < 1e-9 * (1.0 + lb[t].abs()) {
                continue; // a tie up to rounding: either model may be taken
            }
            let (src, count) = if lt[t] > lb[t] {
                (&pt, &mut from_t)
            } else {
                (&pb, &mut from_b)
            };
            *count += 1;
            assert_eq!(
                gated.mean[t * 3..(t + 1) * 3],
                src.mean[t * 3..(t + 1) * 3],
                "frame {t}"
            );
            assert_eq!(
                gated.covariance.as_ref().unwrap()[t * 9..(t + 1) * 9],
                src.covariance.as_ref().unwrap()[t * 9..(t + 1) * 9],
                "frame {t}"
            );
        }
    }
    assert!(
        from_t > 0 && from_b > 0,
        "both models predict somewhere: λ_T {from_t}, λ {from_b} frames"
    );
}

#[test]
fn inconsistent_models_and_windows_are_refused() {
    let train = data(&generate(6, 41));
    let (m, _) = TscHmm::fit(&train, &roles(), &TscSettings::paper(2, Composition::Union)).unwrap();
    // A union composition without its union HMM (as a hand-edited model file may have):
    // refused when made, and when read.
    let err = TscHmm::new(
        m.base().clone(),
        m.transition().clone(),
        None,
        Composition::Union,
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("no union HMM"), "{err}");
    let model = Model::TscHmm {
        model: m.clone(),
        window: 2,
    };
    let mut json: serde_json::Value = serde_json::to_value(&model).unwrap();
    json["model"]["union"] = serde_json::Value::Null;
    let err = serde_json::from_value::<Model>(json)
        .unwrap_err()
        .to_string();
    assert!(err.contains("no union HMM"), "{err}");
    // The gate holds no union HMM.
    assert!(TscHmm::new(
        m.base().clone(),
        m.transition().clone(),
        m.union().cloned(),
        Composition::Gated
    )
    .is_err());
    // A dilation as long as a demonstration flags all of it.
    let shortest = train.iter().map(|s| s.len()).min().unwrap();
    let err = TscHmm::fit(
        &train,
        &roles(),
        &TscSettings::paper(shortest, Composition::Union),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("not shorter than demonstration"), "{err}");
    // Windows of gmm-tsc: at most MAX_WINDOW frames, and no longer than a demonstration.
    let too_wide = PresetOptions::builder()
        .window(phasekit_tsc::krishnan::MAX_WINDOW + 1)
        .build()
        .unwrap();
    let err = Method::preset(Preset::GmmTsc, &too_wide)
        .unwrap_err()
        .to_string();
    assert!(err.contains("1..=64"), "{err}");
    let short =
        SequenceSet::new(&piecewise(&vec![vec![0, 1, 2]; 3], &LEVELS, 6, 0, 42), 2).unwrap();
    let long = KrishnanSettings::builder()
        .window(19)
        .components(Some(3))
        .build()
        .unwrap();
    let err = long.fit(&short).unwrap_err().to_string();
    assert!(err.contains("longer than demonstration"), "{err}");
    // Dilation never overflows.
    assert_eq!(dilate(&[false, true, false], usize::MAX), vec![true; 3]);
}
