//! The regularisation relative to the positions (`reg-units=positions`,
//! `reg-pos=R`, issue 17): a velocity regularised by its position's variance
//! in its own unit (the one-state fit against the obvious formulas), the slope
//! `k` read off the data, the relative unit when there are no velocities, and
//! the same model whatever unit each feature (a position and its velocity
//! apart) is given — which neither the absolute nor the plain relative unit
//! gives with the paper's amount of velocity regularisation.

use crate::reg_units::{gaussian_of, json_difference, sample_moments, scaled};
use phasekit_emission::{Frames, SequenceSet};
use phasekit_tsc::synthetic;
use phasekit_tsc::{
    feature_variances, position_scales, scale_model, Method, Model, Preset, PresetOptions,
    RegUnits, Roles,
};

/// Human position (3), its velocity (3), robot position (3), its velocity (3).
const D: usize = 12;

/// Column factors: every feature its own unit, a position and its velocity apart.
const A: [f64; D] = [
    100.0, 1.0, 57.3, 3.0, 0.5, 20.0, 0.01, 2.0, 1.0, 7.0, 1e-3, 1.0,
];

/// The generated interactions with the velocities of both sides, as the
/// command makes them (`v_t = x_t − x_{t−1}`, `v_0 = 0`).
fn with_velocities(frames: &[f64]) -> Vec<f64> {
    let rows: Vec<&[f64]> = frames.chunks_exact(6).collect();
    let mut out = Vec::with_capacity(rows.len() * D);
    for (t, x) in rows.iter().enumerate() {
        let v = |j: usize| if t == 0 { 0.0 } else { x[j] - rows[t - 1][j] };
        out.extend_from_slice(&x[..3]);
        out.extend((0..3).map(v));
        out.extend_from_slice(&x[3..]);
        out.extend((3..6).map(v));
    }
    out
}

fn data(n: usize, seed: u64) -> (Vec<Vec<f64>>, Vec<f64>) {
    let seqs: Vec<Vec<f64>> = synthetic::generate(n, seed)
        .iter()
        .map(|d| with_velocities(&d.frames))
        .collect();
    (seqs[..n - 1].to_vec(), seqs[n - 1].clone())
}

fn roles() -> Roles {
    Roles::new(vec![0, 1, 2, 3, 4, 5], vec![6, 7, 8, 9, 10, 11])
        .unwrap()
        .with_velocities(vec![(3, 0), (4, 1), (5, 2), (9, 6), (10, 7), (11, 8)])
        .unwrap()
}

fn options(reg: f64, units: RegUnits) -> PresetOptions {
    PresetOptions::builder()
        .reg(reg)
        .reg_units(units)
        .max_iter(10)
        .build()
        .unwrap()
}

#[test]
fn a_velocity_is_regularised_by_its_positions_variance() {
    let (train, _) = data(5, 3);
    let set = SequenceSet::new(&train, D).unwrap();
    let (_, cov) = sample_moments(&train, D);
    let cov = |i: usize, j: usize| cov[i][j];
    // Feature j is regularised by R × the variance of its position (its own
    // for a position; for a velocity, the position it differences).
    let position_of = |j: usize| match j {
        3..=5 | 9..=11 => j - 3,
        _ => j,
    };
    let r = 0.05;
    for preset in [Preset::Hmm, Preset::Gmm] {
        let o = options(r, RegUnits::Positions)
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
            let reg = r * cov(position_of(i), position_of(i));
            for j in 0..D {
                let want = cov(i, j) + if i == j { reg } else { 0.0 };
                let tol = 1e-12 * (got[(i, i)] * got[(j, j)]).sqrt();
                assert!(
                    (got[(i, j)] - want).abs() <= tol,
                    "{preset} ({i}, {j}): {} vs {want}",
                    got[(i, j)]
                );
            }
            assert!((summary.regularisation_per_feature[i] - reg).abs() <= 1e-12 * reg);
        }
        // A velocity's regulariser is far above its own variance (the
        // positions move much more than they move per frame), as the
        // paper's absolute reg makes it on data in metres.
        assert!(r * cov(0, 0) > 20.0 * r * cov(3, 3));
    }
}

#[test]
fn the_velocitys_unit_is_read_off_the_data() {
    // A velocity in another unit (k = 2.5 times the difference, centred as
    // a z-score would be) and one with missing values: s = |k| √v_x; a
    // velocity of a constant position keeps its own scale √v_u.
    let nan = f64::NAN;
    let x = [0.0, 1.0, 3.0, 2.0, 5.0, 4.0, 4.5];
    let mut u: Vec<f64> = (0..x.len())
        .map(|t| {
            if t == 0 {
                0.0
            } else {
                2.5 * (x[t] - x[t - 1]) - 0.7
            }
        })
        .collect();
    u[4] = nan;
    // Columns: x, u, a constant c, its "velocity" w.
    let w = [0.3, -0.1, 0.4, 0.0, 0.2, -0.5, 0.1];
    let seq: Vec<f64> = (0..x.len()).flat_map(|t| [x[t], u[t], 1.0, w[t]]).collect();
    let set = SequenceSet::new(&[seq], 4).unwrap();
    let roles = Roles::new(vec![0, 1], vec![2, 3])
        .unwrap()
        .with_velocities(vec![(1, 0), (3, 2)])
        .unwrap();
    let v = feature_variances(&set);
    let s = position_scales(&set, &roles).unwrap();
    assert!((s[0] - v[0].sqrt()).abs() < 1e-15);
    assert!(
        (s[1] - 2.5 * v[0].sqrt()).abs() < 1e-12,
        "{} vs {}",
        s[1],
        2.5 * v[0].sqrt()
    );
    assert_eq!(s[2], 1.0);
    assert!((s[3] - v[3].sqrt()).abs() < 1e-15);
    // Roles that name a dim the data lacks: an error, not an index panic.
    let wider = Roles::new(vec![0, 1], vec![2, 4])
        .unwrap()
        .with_velocities(vec![(1, 0), (4, 2)])
        .unwrap();
    assert!(position_scales(&set, &wider).is_err());
}

#[test]
fn without_velocities_it_is_the_relative_unit() {
    let (train, _) = data(5, 7);
    let set = SequenceSet::new(&train, D).unwrap();
    let plain = Roles::new(vec![0, 1, 2, 3, 4, 5], vec![6, 7, 8, 9, 10, 11]).unwrap();
    for preset in [Preset::Hmm, Preset::TscHmm, Preset::Gmm] {
        let fit = |units| {
            let (m, _) = Method::preset(preset, &options(0.05, units))
                .unwrap()
                .fit(&set, &plain)
                .unwrap();
            serde_json::to_string(&m).unwrap()
        };
        assert_eq!(
            fit(RegUnits::Positions),
            fit(RegUnits::Relative),
            "{preset}"
        );
    }
}

/// Fits with `units` on the data and on the data with every feature in
/// another unit (× `A`); the largest parameter difference (in units where
/// every training feature has variance 1) and prediction difference
/// (relative to each robot feature's spread).
fn change_of_units(preset: Preset, units: RegUnits, reg: f64) -> (f64, f64) {
    let (train, test) = data(6, 11);
    let set = SequenceSet::new(&train, D).unwrap();
    let train_a: Vec<Vec<f64>> = train.iter().map(|q| scaled(q, &A)).collect();
    let set_a = SequenceSet::new(&train_a, D).unwrap();
    let method = Method::preset(preset, &options(reg, units)).unwrap();
    let (m, _) = method.fit(&set, &roles()).unwrap();
    let (ma, _) = method.fit(&set_a, &roles()).unwrap();
    let normalised = |model: &Model, train: &SequenceSet| {
        let s: Vec<f64> = feature_variances(train)
            .iter()
            .map(|v| 1.0 / v.sqrt())
            .collect();
        serde_json::to_value(scale_model(model, &s).unwrap()).unwrap()
    };
    let params = json_difference(&normalised(&m, &set), &normalised(&ma, &set_a));
    let human = |joint: &[f64]| -> Vec<f64> {
        joint
            .chunks_exact(D)
            .flat_map(|f| f[..6].to_vec())
            .collect()
    };
    let predict = |model: &Model, joint: &[f64]| {
        model
            .predictor(&roles())
            .unwrap()
            .predict(Frames::new(&human(joint), 6).unwrap(), false)
            .unwrap()
            .mean
    };
    let (p, pa) = (predict(&m, &test), predict(&ma, &scaled(&test, &A)));
    let sd = feature_variances(&set);
    let pred = p
        .iter()
        .zip(&pa)
        .enumerate()
        .map(|(k, (x, y))| {
            let j = 6 + k % 6;
            (x * A[j] - y).abs() / (A[j] * sd[j].sqrt())
        })
        .fold(0.0, f64::max);
    (params, pred)
}

#[test]
fn the_fit_is_the_same_in_any_unit_of_each_feature() {
    for preset in [Preset::Hmm, Preset::TscHmm, Preset::Gmm] {
        let (params, pred) = change_of_units(preset, RegUnits::Positions, 0.1);
        assert!(params < 1e-9, "{preset}: parameters differ by {params:e}");
        assert!(pred < 1e-9, "{preset}: predictions differ by {pred:e}");
    }
    // The absolute unit is not: the same r is another amount of each
    // feature's variance in other units.
    let (params, pred) = change_of_units(Preset::Hmm, RegUnits::Absolute, 1e-4);
    assert!(params > 1e-3 && pred > 1e-3, "{params:e} {pred:e}");
}

#[test]
fn velocity_pairs_are_checked_and_kept_in_files() {
    let base = || Roles::new(vec![0, 1], vec![2, 3]).unwrap();
    // Across sides, onto itself, twice, a velocity of a velocity, a dim of neither.
    for pairs in [
        vec![(1, 2)],
        vec![(1, 1)],
        vec![(1, 0), (1, 0)],
        vec![(3, 2), (2, 3)],
        vec![(5, 0)],
    ] {
        assert!(base().with_velocities(pairs.clone()).is_err(), "{pairs:?}");
    }
    let roles = base().with_velocities(vec![(1, 0), (3, 2)]).unwrap();
    let json = serde_json::to_string(&roles).unwrap();
    let back: Roles = serde_json::from_str(&json).unwrap();
    assert_eq!(back, roles);
    assert_eq!(back.velocities(), &[(1, 0), (3, 2)]);
    // Files written before the pairs existed read with none; bad pairs in a file are refused.
    let old: Roles = serde_json::from_str(r#"{"human":[0,1],"robot":[2,3]}"#).unwrap();
    assert!(old.velocities().is_empty());
    assert!(
        serde_json::from_str::<Roles>(r#"{"human":[0,1],"robot":[2,3],"velocities":[[1,2]]}"#)
            .is_err()
    );
    assert!(!serde_json::to_string(&old).unwrap().contains("velocities"));
}
