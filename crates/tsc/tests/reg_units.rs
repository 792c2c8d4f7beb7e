//! The relative regularisation (`reg-units=relative`, `reg-rel=R`, issue 17):
//! the analytic one-state fit, equivariance under a change of units of the
//! features (which the absolute regularisation breaks), the mapping of every
//! model, the errors for emissions a scaling cannot map, and the settings'
//! files (the unit kept; files without it absolute).

use phasekit_emission::{Frames, SequenceSet};
use phasekit_tsc::synthetic;
use phasekit_tsc::{
    feature_variances, scale_model, EmissionKind, HmmSettings, Method, Model, Preset,
    PresetOptions, RegUnits, Roles,
};
use proptest::prelude::*;

const D: usize = 6;

/// Column factors of a change of units: m → cm, one unchanged, rad → deg,
/// m → hm, and two more.
const A: [f64; D] = [100.0, 1.0, 57.3, 0.01, 3.0, 1.0];

fn data(n: usize, seed: u64) -> (Vec<Vec<f64>>, Vec<f64>) {
    let demos = synthetic::generate(n, seed);
    let seqs: Vec<Vec<f64>> = demos.iter().map(|d| d.frames.clone()).collect();
    (seqs[..n - 1].to_vec(), seqs[n - 1].clone())
}

pub(crate) fn scaled(seq: &[f64], a: &[f64]) -> Vec<f64> {
    seq.iter()
        .enumerate()
        .map(|(k, v)| v * a[k % a.len()])
        .collect()
}

fn roles() -> Roles {
    Roles::new(vec![0, 1, 2], vec![3, 4, 5]).unwrap()
}

fn human_of(joint: &[f64]) -> Vec<f64> {
    joint
        .chunks_exact(D)
        .flat_map(|f| f[..3].to_vec())
        .collect()
}

fn options(reg: f64, units: RegUnits) -> PresetOptions {
    PresetOptions::builder()
        .reg(reg)
        .reg_units(units)
        .max_iter(10)
        .build()
        .unwrap()
}

/// `|a − b| / (1 + |a|)`, largest over two JSON values of one shape.
/// Largest `|a − b| / (1 + |a|)` over two JSON values (infinite where their
/// shapes differ).
pub(crate) fn json_difference(a: &serde_json::Value, b: &serde_json::Value) -> f64 {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            (x - y).abs() / (1.0 + x.abs())
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .map(|(x, y)| json_difference(x, y))
            .fold(0.0, f64::max),
        (Value::Object(x), Value::Object(y)) if x.len() == y.len() => x
            .iter()
            .map(|(k, v)| y.get(k).map_or(f64::INFINITY, |w| json_difference(v, w)))
            .fold(0.0, f64::max),
        _ if a == b => 0.0,
        _ => f64::INFINITY,
    }
}

/// Where two JSON values differ most (for the failure message).
fn worst_path(a: &serde_json::Value, b: &serde_json::Value, path: String) -> (f64, String) {
    use serde_json::Value;
    match (a, b) {
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .enumerate()
            .map(|(i, (x, y))| worst_path(x, y, format!("{path}[{i}]")))
            .fold((0.0, path.clone()), |p, q| if q.0 > p.0 { q } else { p }),
        (Value::Object(x), Value::Object(y)) if x.len() == y.len() => x
            .iter()
            .filter_map(|(k, v)| y.get(k).map(|w| worst_path(v, w, format!("{path}.{k}"))))
            .fold((0.0, path.clone()), |p, q| if q.0 > p.0 { q } else { p }),
        _ => (json_difference(a, b), format!("{path}: {a} vs {b}")),
    }
}

/// Removes the `durations` of a serialised HSMM (wherever they are).
fn take_durations(v: &mut serde_json::Value) -> Option<serde_json::Value> {
    match v {
        serde_json::Value::Object(m) => m
            .remove("durations")
            .or_else(|| m.values_mut().find_map(take_durations)),
        _ => None,
    }
}

/// The model in units where every training feature has variance 1 (so that
/// one tolerance fits every parameter, whatever the features' units).
fn normalised(model: &Model, train: &SequenceSet) -> serde_json::Value {
    let s: Vec<f64> = feature_variances(train)
        .iter()
        .map(|v| 1.0 / v.sqrt())
        .collect();
    serde_json::to_value(scale_model(model, &s).unwrap()).unwrap()
}

/// The frames' mean and population covariance, by the obvious formulas
/// (independent of the library).
pub(crate) fn sample_moments(train: &[Vec<f64>], d: usize) -> (Vec<f64>, Vec<Vec<f64>>) {
    let all: Vec<&[f64]> = train.iter().flat_map(|q| q.chunks_exact(d)).collect();
    let n = all.len() as f64;
    let mean: Vec<f64> = (0..d)
        .map(|j| all.iter().map(|x| x[j]).sum::<f64>() / n)
        .collect();
    let cov = (0..d)
        .map(|i| {
            (0..d)
                .map(|j| {
                    all.iter()
                        .map(|x| (x[i] - mean[i]) * (x[j] - mean[j]))
                        .sum::<f64>()
                        / n
                })
                .collect()
        })
        .collect();
    (mean, cov)
}

/// The Gaussian emission of a one-state HMM or one-component GMM.
pub(crate) fn gaussian_of(model: &Model) -> phasekit_emission::Gaussian {
    match model {
        Model::Hmm(h) => h.emission().as_gaussian().unwrap().clone(),
        Model::Gmm(g) => g.components().as_gaussian().unwrap().clone(),
        _ => panic!("not an hmm or gmm"),
    }
}

#[test]
fn one_state_covariance_is_the_sample_covariance_plus_r_times_the_variances() {
    let (train, _) = data(5, 3);
    let train: Vec<Vec<f64>> = train.iter().map(|q| scaled(q, &A)).collect();
    let set = SequenceSet::new(&train, D).unwrap();
    let (mean, cov) = sample_moments(&train, D);
    let cov = |i: usize, j: usize| cov[i][j];
    let r = 0.05;
    for preset in [Preset::Hmm, Preset::Gmm] {
        let o = options(r, RegUnits::Relative)
            .to_builder()
            .states(1)
            .build()
            .unwrap();
        let (model, summary) = Method::preset(preset, &o)
            .unwrap()
            .fit(&set, &roles())
            .unwrap();
        let g = gaussian_of(&model);
        let got = g.covariance(0);
        for i in 0..D {
            for j in 0..D {
                let want = cov(i, j) + if i == j { r * cov(i, i) } else { 0.0 };
                let tol = 1e-12 * (cov(i, i) * cov(j, j)).sqrt();
                assert!(
                    (got[(i, j)] - want).abs() <= tol,
                    "{preset} ({i}, {j}): {} vs {want}",
                    got[(i, j)]
                );
            }
            assert!((g.mean(0)[i] - mean[i]).abs() <= 1e-12 * cov(i, i).sqrt());
            assert!(
                (summary.regularisation_per_feature[i] - r * cov(i, i)).abs() <= 1e-12 * cov(i, i)
            );
        }
        // The absolute unit adds r to every diagonal: a different covariance.
        let (abs_model, _) = Method::preset(
            preset,
            &o.to_builder()
                .reg_units(RegUnits::Absolute)
                .build()
                .unwrap(),
        )
        .unwrap()
        .fit(&set, &roles())
        .unwrap();
        let ga = match &abs_model {
            Model::Hmm(h) => h.emission().as_gaussian().unwrap().covariance(0),
            Model::Gmm(g) => g.components().as_gaussian().unwrap().covariance(0),
            _ => unreachable!(),
        };
        assert!((ga[(0, 0)] - (cov(0, 0) + r)).abs() <= 1e-9 * cov(0, 0));
        assert!((ga[(0, 0)] - got[(0, 0)]).abs() > 1.0);
    }
}

#[test]
fn feature_variances_skip_missing_values_and_give_one_to_constant_features() {
    let nan = f64::NAN;
    // Feature 0: values 1, 3, 5 (one missing); feature 1 constant; feature 2 never observed.
    let a = vec![1.0, 7.0, nan, nan, 7.0, nan];
    let b = vec![5.0, 7.0, nan, 3.0, 7.0, nan];
    let v = feature_variances(&SequenceSet::new(&[a, b], 3).unwrap());
    assert_eq!(v[1], 1.0);
    assert_eq!(v[2], 1.0);
    assert!((v[0] - 8.0 / 3.0).abs() < 1e-15);
}

/// Fits `preset` with `units` on the data and on the data in other units
/// (columns × `A`); returns the largest parameter difference (normalised
/// units), the largest prediction difference (× `A`, relative to the robot's
/// spread) and whether the segmentations agree.
fn change_of_units(preset: Preset, units: RegUnits, reg: f64) -> (f64, f64, bool) {
    let (train, test) = data(6, 11);
    let set = SequenceSet::new(&train, D).unwrap();
    let train_a: Vec<Vec<f64>> = train.iter().map(|q| scaled(q, &A)).collect();
    let set_a = SequenceSet::new(&train_a, D).unwrap();
    let method = Method::preset(preset, &options(reg, units)).unwrap();
    let (m, _) = method.fit(&set, &roles()).unwrap();
    let (ma, _) = method.fit(&set_a, &roles()).unwrap();
    let (mut na, mut nb) = (normalised(&m, &set), normalised(&ma, &set_a));
    // The HSMM's duration distributions are in frames, not in the features'
    // units: they are compared on their own, to 1e-6 (the last state's
    // censored duration amplifies the rounding of x·a / (s·a) ≠ x / s to ~5e-8
    // in ten EM iterations).
    if let (Some(da), Some(db)) = (take_durations(&mut na), take_durations(&mut nb)) {
        let dd = json_difference(&da, &db);
        assert!(
            dd < 1e-6,
            "{preset}: durations {:?}",
            worst_path(&da, &db, String::new())
        );
    }
    let params = json_difference(&na, &nb);
    if params > 1e-9 {
        eprintln!("{preset}: worst {:?}", worst_path(&na, &nb, String::new()));
    }
    let human = human_of(&test);
    let human_a = human_of(&scaled(&test, &A));
    let p = m
        .predictor(&roles())
        .unwrap()
        .predict(Frames::new(&human, 3).unwrap(), false)
        .unwrap();
    let pa = ma
        .predictor(&roles())
        .unwrap()
        .predict(Frames::new(&human_a, 3).unwrap(), false)
        .unwrap();
    let sd = feature_variances(&set);
    let pred = p
        .mean
        .iter()
        .zip(&pa.mean)
        .enumerate()
        .map(|(k, (x, y))| (x * A[3 + k % 3] - y).abs() / (A[3 + k % 3] * sd[3 + k % 3].sqrt()))
        .fold(0.0, f64::max);
    let seg = m.segment(Frames::new(&test, D).unwrap(), &roles()).unwrap();
    let test_a = scaled(&test, &A);
    let seg_a = ma
        .segment(Frames::new(&test_a, D).unwrap(), &roles())
        .unwrap();
    (
        params,
        pred,
        seg.labels == seg_a.labels && seg.transitions == seg_a.transitions,
    )
}

#[test]
fn relative_regularisation_is_equivariant_under_a_change_of_units() {
    for preset in [Preset::Hmm, Preset::TscHmm, Preset::Hsmm, Preset::Gmm] {
        let (params, pred, same_segments) = change_of_units(preset, RegUnits::Relative, 0.05);
        assert!(params < 1e-9, "{preset}: parameters differ by {params:e}");
        // HSMM-GMR's weights carry the durations' ~5e-8 (see `change_of_units`).
        let tol = if preset == Preset::Hsmm { 1e-7 } else { 1e-9 };
        assert!(pred < tol, "{preset}: predictions differ by {pred:e}");
        assert!(
            same_segments,
            "{preset}: the segmentation changed with the units"
        );
    }
}

#[test]
fn absolute_regularisation_is_not_equivariant() {
    // The test above would fail for the paper's absolute reg: the same r is a
    // different amount of each feature's variance in other units.
    for preset in [Preset::Hmm, Preset::Gmm] {
        let (params, pred, _) = change_of_units(preset, RegUnits::Absolute, 0.05);
        assert!(
            params > 1e-3,
            "{preset}: parameters differ by only {params:e}"
        );
        assert!(pred > 1e-3, "{preset}: predictions differ by only {pred:e}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(6))]

    /// Mapping a fitted model by `s` then `1/s` gives it back, for every
    /// model variant (gmm-tsc's windowed mixture and time sub-clusters too).
    #[test]
    fn scale_model_then_its_inverse_is_the_identity(
        which in 0usize..5,
        log_s in proptest::collection::vec(-3.0f64..3.0, D),
    ) {
        let (train, _) = data(6, 2);
        let set = SequenceSet::new(&train, D).unwrap();
        let preset = [Preset::Hmm, Preset::TscHmm, Preset::Hsmm, Preset::Gmm, Preset::GmmTsc][which];
        let o = options(0.01, RegUnits::Absolute).to_builder().time_clusters(if which == 4 { 2 } else { 0 }).build().unwrap();
        let (m, _) = Method::preset(preset, &o).unwrap().fit(&set, &roles()).unwrap();
        let s: Vec<f64> = log_s.iter().map(|v| v.exp()).collect();
        let inv: Vec<f64> = s.iter().map(|v| 1.0 / v).collect();
        let back = scale_model(&scale_model(&m, &s).unwrap(), &inv).unwrap();
        let d = json_difference(&serde_json::to_value(&m).unwrap(), &serde_json::to_value(&back).unwrap());
        prop_assert!(d < 1e-12, "{preset}: {d:e}");
    }
}

#[test]
fn gmm_tsc_with_relative_reg_is_equivariant() {
    let (train, test) = data(6, 5);
    let set = SequenceSet::new(&train, D).unwrap();
    let train_a: Vec<Vec<f64>> = train.iter().map(|q| scaled(q, &A)).collect();
    let set_a = SequenceSet::new(&train_a, D).unwrap();
    let method = Method::preset(Preset::GmmTsc, &options(0.05, RegUnits::Relative)).unwrap();
    let (m, _) = method.fit(&set, &roles()).unwrap();
    let (ma, _) = method.fit(&set_a, &roles()).unwrap();
    let d = json_difference(&normalised(&m, &set), &normalised(&ma, &set_a));
    assert!(d < 1e-9, "gmm-tsc: {d:e}");
    let seg = m.segment(Frames::new(&test, D).unwrap(), &roles()).unwrap();
    let test_a = scaled(&test, &A);
    let seg_a = ma
        .segment(Frames::new(&test_a, D).unwrap(), &roles())
        .unwrap();
    assert_eq!(seg.labels, seg_a.labels);
    assert_eq!(seg.clusters, seg_a.clusters);
}

#[test]
fn emissions_a_scaling_cannot_map_are_refused_before_the_fit() {
    let (train, _) = data(5, 1);
    let set = SequenceSet::new(&train, D).unwrap();
    let o = options(0.05, RegUnits::Relative)
        .to_builder()
        .emission("spherical".parse::<EmissionKind>().unwrap())
        .build()
        .unwrap();
    let e = Method::preset(Preset::Hmm, &o)
        .unwrap()
        .fit(&set, &roles())
        .unwrap_err();
    assert!(e.to_string().contains("spherical"), "{e}");
    // Absolute spherical fits as before.
    let o = o
        .to_builder()
        .reg_units(RegUnits::Absolute)
        .build()
        .unwrap();
    assert!(Method::preset(Preset::Hmm, &o)
        .unwrap()
        .fit(&set, &roles())
        .is_ok());
    // Every other emission fits relative.
    for kind in ["diag", "tied", "student-t", "gmm-2"] {
        let o = options(0.05, RegUnits::Relative)
            .to_builder()
            .emission(kind.parse().unwrap())
            .max_iter(3)
            .build()
            .unwrap();
        Method::preset(Preset::Hmm, &o)
            .unwrap()
            .fit(&set, &roles())
            .unwrap_or_else(|e| panic!("{kind}: {e}"));
    }
}

#[test]
fn the_unit_round_trips_and_old_settings_read_as_absolute() {
    for preset in Preset::ALL {
        let o = options(0.05, RegUnits::Relative);
        let m = Method::preset(preset, &o).unwrap();
        let text = serde_json::to_string(&m).unwrap();
        assert!(
            text.contains("\"reg_units\":\"relative\""),
            "{preset}: {text}"
        );
        let back: Method = serde_json::from_str(&text).unwrap();
        assert_eq!(back, m, "{preset}");
        // Absolute settings do not write the unit: the files of before
        // (`auto`'s default grid is unit-free: its candidates carry their own).
        let a = Method::preset(preset, &options(0.05, RegUnits::Absolute)).unwrap();
        assert!(
            preset == Preset::Auto || !serde_json::to_string(&a).unwrap().contains("reg_units"),
            "{preset}"
        );
        match back.regularisation() {
            Some((_, units, _)) => assert_eq!(units, RegUnits::Relative, "{preset}"),
            None => {
                // Cross-validated (`auto`'s unit-free grid): every candidate
                // relative to the variances, its own or its position's.
                let Method::CrossValidated(cv) = &back else {
                    unreachable!()
                };
                for (label, c) in cv.candidates() {
                    let units = c.regularisation().unwrap().1;
                    assert!(
                        matches!(units, RegUnits::Relative | RegUnits::Positions),
                        "{label}: {units:?}"
                    );
                }
            }
        }
    }
    // Settings written before the unit existed.
    let old = r#"{"states":4,"reg":0.01,"max_iter":40,"tol":0.0001,"restarts":1,"seed":0,"covariance":"full"}"#;
    let s: HmmSettings = serde_json::from_str(old).unwrap();
    assert_eq!(s.reg_units(), RegUnits::Absolute);
    let old = r#"{"states":4,"tsc_states":3,"window":2,"reg":0.01,"max_iter":40,"tol":0.0001,"restarts":1,"seed":0}"#;
    let o: PresetOptions = serde_json::from_str(old).unwrap();
    assert_eq!(o.reg_units(), RegUnits::Absolute);
    assert!("metres".parse::<RegUnits>().is_err());
}

#[test]
fn a_fitted_relative_model_round_trips_through_json() {
    let (train, test) = data(5, 8);
    let set = SequenceSet::new(&train, D).unwrap();
    let method = Method::preset(Preset::Hmm, &options(0.05, RegUnits::Relative)).unwrap();
    let (m, summary) = method.fit(&set, &roles()).unwrap();
    assert_eq!(summary.regularisation_per_feature.len(), D);
    let back: Model = serde_json::from_str(&serde_json::to_string(&m).unwrap()).unwrap();
    let human = human_of(&test);
    let f = Frames::new(&human, 3).unwrap();
    let a = m.predictor(&roles()).unwrap().predict(f, false).unwrap();
    let b = back.predictor(&roles()).unwrap().predict(f, false).unwrap();
    assert_eq!(a.mean, b.mean);
    let text = serde_json::to_string(&summary).unwrap();
    assert!(text.contains("regularisation_per_feature"));
}
