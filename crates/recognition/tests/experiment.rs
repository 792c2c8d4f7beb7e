//! The recognition experiment on generated interactions: its oracle is the
//! prediction experiment's prediction on the same subsets, and its tables
//! hold what they say.

use crate::common;

use common::{demos, hmm, roles};
use phasekit_emission::{Frames, SequenceSet};
use phasekit_recognition::experiment::{run, subset, ActionSplit, Dataset, ExperimentSettings};
use phasekit_tsc::synthetic::Kind;

fn dataset() -> Dataset {
    let actions = [Kind::Handshake, Kind::Wave, Kind::Handover]
        .into_iter()
        .map(|k| {
            let all = demos(k, 9, 11);
            ActionSplit {
                name: k.name().into(),
                train: all[..7].to_vec(),
                test: all[7..].to_vec(),
            }
        })
        .collect();
    Dataset {
        actions,
        dim: 12,
        roles: roles(),
        scored: vec![0, 1, 2],
        unit_scale: 100.0,
    }
}

#[test]
fn the_oracle_is_the_prediction_experiment_and_the_tables_are_complete() {
    let ds = dataset();
    let mut s = ExperimentSettings::default();
    s.seeds = 2;
    s.stream_length = 4;
    let methods = vec![("hmm".to_string(), hmm())];
    let calls = std::sync::atomic::AtomicUsize::new(0);
    let r = run(&ds, &methods, &s, &|| {
        calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    })
    .unwrap();
    assert_eq!(calls.into_inner(), 2);
    assert!(r.failures.is_empty(), "{:?}", r.failures);
    assert_eq!(r.recognition.len(), 4 * 10);
    // Generated interactions are told apart by the end.
    for row in r.recognition.iter().filter(|x| x.fraction == 1.0) {
        assert_eq!(row.accuracy, 1.0, "{row:?}");
    }
    // The oracle MSE of each action: the method fitted on the seed's subset (the
    // prediction experiment's), predicting the test demonstrations, in cm².
    for (a, action) in ds.actions.iter().enumerate() {
        let per_seed: Vec<f64> = (0..2)
            .map(|seed| {
                let idx = subset(seed, 7, 5);
                let train: Vec<Vec<f64>> = idx.iter().map(|&i| action.train[i].clone()).collect();
                let (model, _) = hmm()
                    .fit(&SequenceSet::new(&train, 12).unwrap(), &roles())
                    .unwrap();
                let p = model.predictor(&roles()).unwrap();
                let (mut se, mut n) = (0.0, 0);
                for t in &action.test {
                    let h = common::human(t);
                    let m = p.predict(Frames::new(&h, 6).unwrap(), false).unwrap().mean;
                    for (f, x) in t.chunks_exact(12).enumerate() {
                        se += (0..3)
                            .map(|j| ((m[f * 6 + j] - x[6 + j]) * 100.0).powi(2))
                            .sum::<f64>();
                        n += 1;
                    }
                }
                se / n as f64
            })
            .collect();
        let row = r
            .end_to_end
            .iter()
            .find(|x| x.action == action.name)
            .unwrap();
        let mean = per_seed.iter().sum::<f64>() / 2.0;
        assert!(
            (row.oracle.mean - mean).abs() < 1e-9 * mean,
            "{}: {} vs {mean}",
            action.name,
            row.oracle.mean
        );
        let _ = a;
    }
    // Every table is there: unknown rows for each left-out action, all and none, three tests.
    assert_eq!(r.unknown.len(), 3 * (1 + 3 + 1));
    assert_eq!(r.streams.len(), 4);
    assert_eq!(r.confusion.len(), 2);
    assert_eq!(r.calibration.len(), 1);
    let waves_left_out = r
        .unknown
        .iter()
        .find(|x| {
            x.left_out == "wave"
                && x.rejection == phasekit_recognition::Rejection::LikelihoodPerFrame
        })
        .unwrap();
    assert_eq!(waves_left_out.unknown_rejected, Some(1.0));
    // Streams with resets at the true starts recognise every interaction.
    let oracle_reset = &r.streams[2];
    assert_eq!(oracle_reset.never, 0.0);
    // Same seeds, same numbers.
    let again = run(&ds, &methods, &s, &|| ()).unwrap();
    assert_eq!(again, r);
}

#[test]
fn subsets_are_the_prediction_experiments() {
    // The prediction experiment (`phasekit evaluate`) draws seed s's subset
    // with ChaCha8Rng::seed_from_u64(s) and rand's index sampling, sorted.
    assert_eq!(subset(0, 8, 6).len(), 6);
    assert_eq!(subset(3, 5, 9), vec![0, 1, 2, 3, 4]);
    let s = subset(7, 9, 7);
    assert!(s.windows(2).all(|w| w[0] < w[1]) && s.iter().all(|&i| i < 9));
    assert_eq!(subset(7, 9, 7), s);
}
