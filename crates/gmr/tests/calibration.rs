//! Scoring Gaussian predictions: χ² quantiles against closed forms and
//! published values, Mahalanobis² and log density against a hand-computed
//! case, and coverage / NLPD of samples from the predicted Gaussian (Monte Carlo).

use phasekit_gmr::calibration::{ln_gamma, regularised_gamma_p};
use phasekit_gmr::{chi_squared_cdf, chi_squared_quantile, score_gaussian};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

#[test]
fn ln_gamma_matches_factorials_and_half_integers() {
    let mut f = 1.0f64;
    for n in 1..30u32 {
        // Γ(n) = (n − 1)!
        assert!(
            (ln_gamma(n as f64) - f.ln()).abs() < 1e-12 * f.ln().abs().max(1.0),
            "n = {n}"
        );
        f *= n as f64;
    }
    // Γ(1/2) = √π.
    assert!((ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 1e-14);
}

#[test]
fn chi_squared_two_dof_is_exponential() {
    // χ²(2) = Exp(1/2): F(x) = 1 − e^{−x/2}, quantile −2 ln(1 − q).
    for &x in &[0.01, 0.5, 1.0, 3.0, 5.991, 10.0, 40.0] {
        let want = 1.0 - (-x / 2.0f64).exp();
        assert!((chi_squared_cdf(x, 2) - want).abs() < 1e-14, "x = {x}");
    }
    for q in [0.01f64, 0.5, 0.9, 0.95, 0.99, 0.999] {
        let want = -2.0 * (1.0 - q).ln();
        let got = chi_squared_quantile(q, 2).unwrap();
        assert!(
            (got - want).abs() < 1e-12 * want,
            "q = {q}: {got} vs {want}"
        );
    }
}

#[test]
fn chi_squared_quantiles_match_published_values() {
    // 95 % quantiles (R: qchisq(0.95, d)).
    let table = [
        (1, 3.841_458_820_694_124),
        (2, 5.991_464_547_107_979),
        (3, 7.814_727_903_251_178),
        (4, 9.487_729_036_781_154),
        (6, 12.591_587_243_743_977),
        (10, 18.307_038_053_275_146),
        (30, 43.772_971_825_742_19),
    ];
    for (d, want) in table {
        let got = chi_squared_quantile(0.95, d).unwrap();
        assert!(
            (got - want).abs() < 1e-10 * want,
            "d = {d}: {got} vs {want}"
        );
    }
    // One dof: P(1/2, x/2) = erf(√(x/2)); at x = 1 (one σ) 0.682689492137086.
    assert!((chi_squared_cdf(1.0, 1) - 0.682_689_492_137_086).abs() < 1e-13);
    assert!((regularised_gamma_p(3.0, 0.0)).abs() == 0.0);
}

#[test]
fn chi_squared_quantile_rejects_nonsense() {
    assert!(chi_squared_quantile(0.95, 0).is_err());
    assert!(chi_squared_quantile(1.0, 3).is_err());
    assert!(chi_squared_quantile(0.0, 3).is_err());
    assert!(chi_squared_quantile(f64::NAN, 3).is_err());
}

#[test]
fn score_matches_a_hand_computed_case() {
    // Σ = [[4, 2], [2, 3]], r = (1, 2): Σ⁻¹ = [[3, −2], [−2, 4]] / 8,
    // m² = (3·1 − 4·1·2 + 4·4) / 8 = 11/8, det Σ = 8.
    let mut scratch = [0.0; 6];
    let s = score_gaussian(&[1.0, 2.0], &[4.0, 2.0, 2.0, 3.0], &mut scratch).unwrap();
    assert!((s.mahalanobis2 - 11.0 / 8.0).abs() < 1e-15);
    let want = -0.5 * (2.0 * (2.0 * std::f64::consts::PI).ln() + 8f64.ln() + 11.0 / 8.0);
    assert!((s.log_density - want).abs() < 1e-14);
    // One dim: N(0; 1, 0.25) = exp(−2) / √(2π · 0.25).
    let s = score_gaussian(&[-1.0], &[0.25], &mut scratch).unwrap();
    assert!((s.mahalanobis2 - 4.0).abs() < 1e-15);
    let want = -2.0 - 0.5 * (2.0 * std::f64::consts::PI * 0.25).ln();
    assert!((s.log_density - want).abs() < 1e-14);
}

#[test]
fn score_refuses_a_covariance_that_is_not_one() {
    let mut scratch = [0.0; 6];
    assert!(score_gaussian(&[1.0, 2.0], &[1.0, 2.0, 2.0, 1.0], &mut scratch).is_err());
    assert!(score_gaussian(&[1.0, 2.0], &[1.0, 0.0, 0.0, f64::NAN], &mut scratch).is_err());
    assert!(score_gaussian(&[1.0, 2.0], &[1.0, 0.0, 0.0], &mut scratch).is_err());
    assert!(score_gaussian(&[1.0, 2.0], &[1.0, 0.0, 0.0, 1.0], &mut [0.0; 4]).is_err());
}

#[test]
fn samples_of_the_predicted_gaussian_are_covered_at_the_nominal_rate() {
    // Σ = A Aᵀ (3 dims, correlated); y = μ + A ε.
    let a: [f64; 9] = [1.0, 0.0, 0.0, 0.5, 2.0, 0.0, -0.3, 0.7, 0.4];
    let mut cov = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            cov[i * 3 + j] = (0..3).map(|k| a[i * 3 + k] * a[j * 3 + k]).sum();
        }
    }
    let log_det: f64 = 2.0 * (a[0] * a[4] * a[8]).abs().ln();
    let limit = chi_squared_quantile(0.95, 3).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let n = 40_000;
    let (mut inside, mut nlpd) = (0usize, 0.0);
    let mut scratch = [0.0; 12];
    for _ in 0..n {
        let e: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(&mut rng));
        let r: [f64; 3] = std::array::from_fn(|i| (0..3).map(|k| a[i * 3 + k] * e[k]).sum());
        let s = score_gaussian(&r, &cov, &mut scratch).unwrap();
        inside += usize::from(s.mahalanobis2 <= limit);
        nlpd -= s.log_density;
    }
    let coverage = inside as f64 / n as f64;
    // Binomial sd √(0.95 · 0.05 / n) ≈ 0.0011: 4 sd.
    assert!((coverage - 0.95).abs() < 0.0044, "coverage {coverage}");
    // E[−log N] = the entropy ½ (p (1 + ln 2π) + ln det Σ); sd of the mean ≈ √(p/2)/√n.
    let entropy = 0.5 * (3.0 * (1.0 + (2.0 * std::f64::consts::PI).ln()) + log_det);
    assert!(
        (nlpd / n as f64 - entropy).abs() < 4.0 * (1.5f64 / n as f64).sqrt(),
        "{nlpd}"
    );
    // A covariance twice too small covers visibly less (the check can fail).
    let small: Vec<f64> = cov.iter().map(|c| c / 2.0).collect();
    let mut inside_small = 0;
    for _ in 0..n {
        let e: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(&mut rng));
        let r: [f64; 3] = std::array::from_fn(|i| (0..3).map(|k| a[i * 3 + k] * e[k]).sum());
        let s = score_gaussian(&r, &small, &mut scratch).unwrap();
        inside_small += usize::from(s.mahalanobis2 <= limit);
    }
    assert!((inside_small as f64 / n as f64) < 0.85);
}

#[test]
fn coverage_scale_is_the_quantile_over_the_chi_squared_limit() {
    // m² = 1, 2, …, 100 (p = 1): the 95 % quantile is the 95th smallest, 95.
    let m2: Vec<f64> = (1..=100).rev().map(f64::from).collect();
    let limit = chi_squared_quantile(0.95, 1).unwrap();
    let c = phasekit_gmr::coverage_scale(&m2, 1, 0.95).unwrap();
    assert!((c - 95.0 / limit).abs() < 1e-12 * c);
    // After scaling exactly 95 of the 100 are inside; any smaller factor leaves fewer.
    let inside = |c: f64| m2.iter().filter(|&&v| v / c <= limit).count();
    assert_eq!(inside(c), 95);
    assert_eq!(inside(c * (1.0 - 1e-9)), 94);
}

#[test]
fn coverage_scale_recovers_a_known_inflation_monte_carlo() {
    // Residuals drawn from N(0, c0·Σ) scored against Σ: m² ~ c0·χ²(p), so the
    // fitted factor is c0 (to the sampling error of a 95 % quantile of 40,000
    // draws, well under 2 %).
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for (p, c0) in [(1usize, 0.25), (3, 4.0), (6, 1.0)] {
        let m2: Vec<f64> = (0..40_000)
            .map(|_| {
                (0..p)
                    .map(|_| {
                        let z: f64 = StandardNormal.sample(&mut rng);
                        c0 * z * z
                    })
                    .sum()
            })
            .collect();
        let c = phasekit_gmr::coverage_scale(&m2, p, 0.95).unwrap();
        assert!((c / c0 - 1.0).abs() < 0.02, "p = {p}: {c} vs {c0}");
    }
}

#[test]
fn coverage_scale_refuses_what_it_cannot_calibrate() {
    assert!(phasekit_gmr::coverage_scale(&[], 2, 0.95).is_err());
    assert!(phasekit_gmr::coverage_scale(&[1.0, f64::NAN], 2, 0.95).is_err());
    assert!(phasekit_gmr::coverage_scale(&[0.0; 10], 2, 0.95).is_err());
    assert!(phasekit_gmr::coverage_scale(&[1.0], 2, 1.0).is_err());
}

#[test]
fn nlpd_after_scaling_is_the_nlpd_of_the_scaled_covariance() {
    // The closed form against scoring each residual under c·Σ directly.
    let cov = [2.0, 0.3, -0.1, 0.3, 1.0, 0.2, -0.1, 0.2, 0.5];
    let residuals = [[0.5, -1.0, 0.2], [2.0, 0.1, -0.7], [-0.3, 0.4, 1.1]];
    let mut scratch = vec![0.0; 12];
    let score = |c: f64, r: &[f64], scratch: &mut [f64]| {
        let scaled: Vec<f64> = cov.iter().map(|v| v * c).collect();
        score_gaussian(r, &scaled, scratch).unwrap()
    };
    let (mut nlpd1, mut m2) = (0.0, 0.0);
    for r in &residuals {
        let s = score(1.0, r, &mut scratch);
        nlpd1 -= s.log_density / 3.0;
        m2 += s.mahalanobis2 / 3.0;
    }
    for c in [0.1, 0.7, 1.0, 3.5] {
        let direct: f64 = residuals
            .iter()
            .map(|r| -score(c, r, &mut scratch).log_density / 3.0)
            .sum();
        let closed = phasekit_gmr::nlpd_scaled(nlpd1, m2, 3, c);
        assert!(
            (closed - direct).abs() < 1e-12,
            "c = {c}: {closed} vs {direct}"
        );
    }
}

/// The `⌈level · n⌉`-th smallest of `v`: the empirical quantile the rules use.
fn level_quantile(mut v: Vec<f64>, level: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    let k = ((level * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[k - 1]
}

/// The definition of `demonstration_inflation`, counted directly: the
/// smallest `λ ≥ 1` among the candidates (1 and every ratio of a distance to
/// its left-out threshold) for which `Σ_d #{t : m²_{d,t} / Q_{−d} ≤ λ} ≥ level · n`
/// (the ratio compared, as the function does, so that a frame whose ratio is
/// `λ` counts whatever the rounding of `λ Q_{−d}`).
fn inflation_by_counting(groups: &[Vec<f64>], level: f64) -> f64 {
    let quantile = |v: Vec<f64>| level_quantile(v, level);
    let thresholds: Vec<f64> = (0..groups.len())
        .map(|d| {
            quantile(
                groups
                    .iter()
                    .enumerate()
                    .filter(|(e, _)| *e != d)
                    .flat_map(|(_, g)| g.clone())
                    .collect(),
            )
        })
        .collect();
    let n: usize = groups.iter().map(Vec::len).sum();
    let mut candidates: Vec<f64> = vec![1.0];
    for (g, t) in groups.iter().zip(&thresholds) {
        candidates.extend(g.iter().map(|v| v / t));
    }
    candidates.sort_by(f64::total_cmp);
    for &lambda in candidates.iter().filter(|&&l| l >= 1.0) {
        let mut inside = 0;
        for (g, t) in groups.iter().zip(&thresholds) {
            for v in g {
                if *v / t <= lambda {
                    inside += 1;
                }
            }
        }
        if inside as f64 >= level * n as f64 {
            return lambda;
        }
    }
    unreachable!("the largest ratio covers every frame")
}

/// `m²` of `frames` residuals of `p` dims drawn from `N(0, scale · I)` scored
/// against `I`: `scale · χ²(p)` draws.
fn scaled_chi_squared(rng: &mut ChaCha8Rng, scale: f64, p: usize, frames: usize) -> Vec<f64> {
    (0..frames)
        .map(|_| {
            (0..p)
                .map(|_| {
                    let z: f64 = StandardNormal.sample(rng);
                    scale * z * z
                })
                .sum()
        })
        .collect()
}

#[test]
fn demonstration_inflation_is_the_smallest_widening_by_its_definition() {
    // Groups of unequal sizes and scales (one unlike the others), against the
    // definition counted frame by frame.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for case in 0..40 {
        let groups: Vec<Vec<f64>> = (0..2 + case % 6)
            .map(|d| {
                let scale = if d == 0 { 1.0 + case as f64 } else { 1.0 };
                scaled_chi_squared(&mut rng, scale, 1 + case % 3, 5 + (7 * d + case) % 40)
            })
            .collect();
        let refs: Vec<&[f64]> = groups.iter().map(Vec::as_slice).collect();
        let fast = phasekit_gmr::demonstration_inflation(&refs, 0.95).unwrap();
        let slow = inflation_by_counting(&groups, 0.95);
        assert_eq!(fast, slow, "case {case}");
        assert!(fast >= 1.0);
    }
}

#[test]
fn demonstrations_that_agree_need_no_widening() {
    // Every demonstration the same distances: each left-out threshold is the
    // pooled one, which covers 95 % of every demonstration.
    let one: Vec<f64> = (1..=100).map(f64::from).collect();
    let groups = [&one[..], &one[..], &one[..], &one[..]];
    assert_eq!(
        phasekit_gmr::demonstration_inflation(&groups, 0.95).unwrap(),
        1.0
    );
}

#[test]
fn demonstration_inflation_makes_the_calibration_transfer_to_new_demonstrations() {
    // Monte Carlo of the situation it is for: each demonstration's errors
    // have their own scale s_d (log-normal, σ = 1: demonstrations unlike one
    // another), m² = s_d · χ²(3). Calibrate on 7 demonstrations of 100 frames
    // (pooled: coverage_scale; widened: × demonstration_inflation), then score
    // 3 new demonstrations, 400 times. Pooling covers the new ones at 92.4 %
    // (NumPy/SciPy simulation of the same design: 92.3 %); widening at 94.7 %
    // (94.6 %). With agreeing demonstrations (σ = 0) both are at 95 % and the
    // widening is at most a few per cent.
    let mut rng = ChaCha8Rng::seed_from_u64(2026);
    let limit = chi_squared_quantile(0.95, 3).unwrap();
    for (sigma, pooled_range, widened_range, max_mean_lambda) in [
        (1.0, (0.90, 0.935), (0.94, 0.96), f64::INFINITY),
        (0.0, (0.94, 0.96), (0.94, 0.96), 1.03),
    ] {
        let (mut pooled, mut widened, mut lambdas) = (0.0, 0.0, 0.0);
        let reps = 400;
        for _ in 0..reps {
            let demonstration = |rng: &mut ChaCha8Rng| {
                let z: f64 = StandardNormal.sample(rng);
                scaled_chi_squared(rng, (sigma * z).exp(), 3, 100)
            };
            let train: Vec<Vec<f64>> = (0..7).map(|_| demonstration(&mut rng)).collect();
            let all: Vec<f64> = train.iter().flatten().copied().collect();
            let c = phasekit_gmr::coverage_scale(&all, 3, 0.95).unwrap();
            let refs: Vec<&[f64]> = train.iter().map(Vec::as_slice).collect();
            let lambda = phasekit_gmr::demonstration_inflation(&refs, 0.95).unwrap();
            let new: Vec<f64> = (0..3).flat_map(|_| demonstration(&mut rng)).collect();
            let share = |c: f64| new.iter().filter(|&&v| v / c <= limit).count() as f64 / 300.0;
            pooled += share(c) / reps as f64;
            widened += share(c * lambda) / reps as f64;
            lambdas += lambda / reps as f64;
        }
        assert!(
            pooled > pooled_range.0 && pooled < pooled_range.1,
            "σ = {sigma}: pooled {pooled}"
        );
        assert!(
            widened > widened_range.0 && widened < widened_range.1,
            "σ = {sigma}: widened {widened}"
        );
        assert!(lambdas <= max_mean_lambda, "σ = {sigma}: mean λ {lambdas}");
    }
}

#[test]
fn demonstration_inflation_refuses_what_it_cannot_calibrate() {
    let a = [1.0, 2.0, 3.0];
    assert!(phasekit_gmr::demonstration_inflation(&[&a[..]], 0.95).is_err());
    assert!(phasekit_gmr::demonstration_inflation(&[&a[..], &[][..]], 0.95).is_err());
    assert!(phasekit_gmr::demonstration_inflation(&[&a[..], &[f64::NAN][..]], 0.95).is_err());
    assert!(phasekit_gmr::demonstration_inflation(&[&a[..], &[-1.0][..]], 0.95).is_err());
    assert!(phasekit_gmr::demonstration_inflation(&[&a[..], &a[..]], 1.0).is_err());
    assert!(phasekit_gmr::demonstration_inflation(&[&[0.0; 4][..], &a[..]], 0.95).is_err());
}

/// The `predictive` factor's definition, computed the slow obvious way:
/// every demonstration's difficulty and shapes by sorting, the log-difficulty
/// spread, and the expected coverage of a new demonstration by a fine
/// Riemann sum over the normal density (20,001 points on ±10 sd), at `f`.
fn expected_new_coverage(groups: &[Vec<f64>], level: f64, f: f64) -> f64 {
    let quantile = |v: Vec<f64>| level_quantile(v, level);
    let n = groups.len() as f64;
    let (mut logs, mut shapes) = (Vec::new(), Vec::new());
    for d in 0..groups.len() {
        let others: Vec<f64> = groups
            .iter()
            .enumerate()
            .filter(|(e, _)| *e != d)
            .flat_map(|(_, g)| g.clone())
            .collect();
        let q = quantile(others);
        let g = quantile(groups[d].iter().map(|v| v / q).collect());
        logs.push(g.ln());
        shapes.extend(groups[d].iter().map(|v| v / q / g));
    }
    let mu = logs.iter().sum::<f64>() / n;
    let sd = (logs.iter().map(|v| (v - mu).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
        * (1.0 + 1.0 / n).sqrt();
    let (mut total, mut weight) = (0.0, 0.0);
    for i in 0..=20_000 {
        let z = -10.0 + 20.0 * i as f64 / 20_000.0;
        let w = (-0.5 * z * z).exp();
        let g = (mu + sd * z).exp();
        let inside = shapes.iter().filter(|&&u| u <= f / g).count() as f64 / shapes.len() as f64;
        total += w * inside;
        weight += w;
    }
    total / weight
}

#[test]
fn the_new_demonstration_factor_is_the_smallest_with_the_expected_coverage() {
    // Groups of unequal sizes and scales, against the definition: at the
    // factor returned the expected coverage of a new demonstration reaches
    // the level, a hair below it it does not (up to the two quadratures'
    // difference, 2e-3).
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    for case in 0..24 {
        let groups: Vec<Vec<f64>> = (0..2 + case % 6)
            .map(|d| {
                let scale = if d == 0 {
                    1.0 + case as f64 / 3.0
                } else {
                    1.0 + 0.1 * d as f64
                };
                scaled_chi_squared(&mut rng, scale, 1 + case % 3, 20 + (7 * d + case) % 60)
            })
            .collect();
        let refs: Vec<&[f64]> = groups.iter().map(Vec::as_slice).collect();
        let got = phasekit_gmr::new_demonstration_factor(&refs, 0.95).unwrap();
        assert_eq!(got.demonstrations, groups.len());
        let at = expected_new_coverage(&groups, 0.95, got.factor);
        let below = expected_new_coverage(&groups, 0.95, got.factor * 0.98);
        assert!(at >= 0.95 - 2e-3, "case {case}: {at} at {got:?}");
        assert!(below < 0.95 + 2e-3, "case {case}: {below} below {got:?}");
    }
}

#[test]
fn demonstrations_that_agree_leave_the_pooled_factor() {
    // Every demonstration the same distances: every difficulty is 1, no
    // spread, and the pooled factor is right (f = 1).
    let one: Vec<f64> = (1..=100).map(f64::from).collect();
    let groups = [&one[..], &one[..], &one[..], &one[..]];
    let f = phasekit_gmr::new_demonstration_factor(&groups, 0.95).unwrap();
    assert!((f.factor - 1.0).abs() < 1e-9, "{f:?}");
    assert_eq!(f.log_difficulty_sd, 0.0);
}

#[test]
fn the_new_demonstration_factor_covers_new_demonstrations_at_the_level_monte_carlo() {
    // The Monte Carlo of `demonstration_inflation`'s test (demonstrations
    // with their own error scale, log-normal σ; 7 to calibrate on, 3 new
    // ones, 400 times): where the left-out rule stays below 95 % with
    // demonstrations unlike one another (σ = 1: 94.7 % there), this one
    // reaches it (96.1 % here; asserted 95.0–96.5 %); with agreeing ones
    // (σ = 0) both are at 95 %.
    let mut rng = ChaCha8Rng::seed_from_u64(2027);
    let limit = chi_squared_quantile(0.95, 3).unwrap();
    for (sigma, range) in [(1.0, (0.95, 0.965)), (0.0, (0.94, 0.96))] {
        let mut covered = 0.0;
        let reps = 400;
        for _ in 0..reps {
            let demonstration = |rng: &mut ChaCha8Rng| {
                let z: f64 = StandardNormal.sample(rng);
                scaled_chi_squared(rng, (sigma * z).exp(), 3, 100)
            };
            let train: Vec<Vec<f64>> = (0..7).map(|_| demonstration(&mut rng)).collect();
            let all: Vec<f64> = train.iter().flatten().copied().collect();
            let c = phasekit_gmr::coverage_scale(&all, 3, 0.95).unwrap();
            let refs: Vec<&[f64]> = train.iter().map(Vec::as_slice).collect();
            let f = phasekit_gmr::new_demonstration_factor(&refs, 0.95)
                .unwrap()
                .factor;
            let new: Vec<f64> = (0..3).flat_map(|_| demonstration(&mut rng)).collect();
            covered +=
                new.iter().filter(|&&v| v / (c * f) <= limit).count() as f64 / 300.0 / reps as f64;
        }
        assert!(
            covered > range.0 && covered < range.1,
            "σ = {sigma}: {covered}"
        );
    }
}

#[test]
fn the_new_demonstration_factor_refuses_what_it_cannot_calibrate() {
    use phasekit_gmr::new_demonstration_factor as f;
    let a = [1.0, 2.0, 3.0];
    assert!(f(&[&a[..]], 0.95).is_err());
    assert!(f(&[&a[..], &[][..]], 0.95).is_err());
    assert!(f(&[&a[..], &[f64::NAN][..]], 0.95).is_err());
    assert!(f(&[&a[..], &[-1.0][..]], 0.95).is_err());
    assert!(f(&[&a[..], &a[..]], 1.0).is_err());
    assert!(f(&[&[0.0; 4][..], &a[..]], 0.95).is_err());
    // Distances whose ratios overflow: an error, not a hang or a NaN factor.
    let mut huge = vec![1.0; 19];
    huge.push(1e10);
    assert!(f(&[&huge[..], &[1e-300; 20][..], &[2e-300; 20][..]], 0.95).is_err());
    assert!(f(&[&[1e10; 5][..], &[1e-300; 5][..], &[1e-300; 5][..]], 0.95).is_err());
    assert!(f(&[&[1e200; 5][..], &[1.0; 5][..]], 0.95).is_err());
}

/// Frames whose errors are `N(0, E)` for a fixed `E` (`p = 3`), predicted
/// with per-frame covariances `Σ_t = (1 + t mod 3) · base`: residuals and
/// covariances, row-major.
fn frames_with(
    rng: &mut ChaCha8Rng,
    error_sd: [f64; 3],
    base: [f64; 9],
    n: usize,
) -> (Vec<f64>, Vec<f64>) {
    let (mut residuals, mut covariances) = (Vec::new(), Vec::new());
    for t in 0..n {
        for sd in error_sd {
            let z: f64 = StandardNormal.sample(rng);
            residuals.push(sd * z);
        }
        covariances.extend(base.iter().map(|v| v * (1 + t % 3) as f64));
    }
    (residuals, covariances)
}

/// The pooled-scale NLPD of `Σ_t + added`, scored frame by frame.
fn nlpd_with(residuals: &[f64], covariances: &[f64], added: &[f64], p: usize) -> f64 {
    let limit = chi_squared_quantile(0.95, p).unwrap();
    let mut scratch = vec![0.0; p * (p + 1)];
    let mixed = |c: &[f64]| -> Vec<f64> { c.iter().zip(added).map(|(a, b)| a + b).collect() };
    let mut m2: Vec<f64> = residuals
        .chunks(p)
        .zip(covariances.chunks(p * p))
        .map(|(r, c)| {
            score_gaussian(r, &mixed(c), &mut scratch)
                .unwrap()
                .mahalanobis2
        })
        .collect();
    m2.sort_by(f64::total_cmp);
    let k = ((0.95 * m2.len() as f64).ceil() as usize).clamp(1, m2.len());
    let scale = m2[k - 1] / limit;
    let n = residuals.len() / p;
    -residuals
        .chunks(p)
        .zip(covariances.chunks(p * p))
        .map(|(r, c)| {
            let scaled: Vec<f64> = mixed(c).iter().map(|v| v * scale).collect();
            score_gaussian(r, &scaled, &mut scratch)
                .unwrap()
                .log_density
        })
        .sum::<f64>()
        / n as f64
}

#[test]
fn the_residual_shape_fixes_an_isotropic_covariance_against_anisotropic_errors() {
    // The model says the same in every direction (a regulariser's bands);
    // the errors are 30 times larger along x than along z. Mixing in the
    // errors' covariance lowers the held-out NLPD by more than a nat, and
    // the NLPD reported is the one scored frame by frame.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let (r, c) = frames_with(&mut rng, [3.0, 1.0, 0.1], identity, 600);
    let s = phasekit_gmr::residual_shape(&r, &c, 3, 0.95).unwrap();
    assert!(s.weight >= 1.0, "{s:?}");
    assert!(s.nlpd < s.model_nlpd - 1.0, "{s:?}");
    assert!(
        (s.nlpd - nlpd_with(&r, &c, &s.added, 3)).abs() < 1e-10,
        "{s:?}"
    );
    assert!((s.model_nlpd - nlpd_with(&r, &c, &[0.0; 9], 3)).abs() < 1e-10);
    // No weight of the grid does better (the choice is the grid's best).
    for k in -8..=8 {
        let w = 10f64.powf(k as f64 / 4.0);
        let added: Vec<f64> = s.added.iter().map(|a| a * w / s.weight).collect();
        assert!(nlpd_with(&r, &c, &added, 3) >= s.nlpd - 1e-12, "w = {w}");
    }
}

#[test]
fn the_residual_shape_keeps_a_covariance_that_is_right() {
    // Errors drawn from the predicted covariances themselves: nothing to
    // fix, the weight stays small and the NLPD gain is noise.
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let n = 900;
    let base = [4.0, 1.0, 0.0, 1.0, 2.0, 0.5, 0.0, 0.5, 1.0];
    let (_, c) = frames_with(&mut rng, [0.0; 3], base, n);
    // r_t = L_t z with L_t the Cholesky factor of Σ_t (3 × 3 by hand).
    let mut r = Vec::with_capacity(3 * n);
    for t in 0..n {
        let s = &c[9 * t..9 * t + 9];
        let l00 = s[0].sqrt();
        let l10 = s[3] / l00;
        let l11 = (s[4] - l10 * l10).sqrt();
        let l20 = s[6] / l00;
        let l21 = (s[7] - l20 * l10) / l11;
        let l22 = (s[8] - l20 * l20 - l21 * l21).sqrt();
        let z: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(&mut rng));
        r.extend([
            l00 * z[0],
            l10 * z[0] + l11 * z[1],
            l20 * z[0] + l21 * z[1] + l22 * z[2],
        ]);
    }
    let s = phasekit_gmr::residual_shape(&r, &c, 3, 0.95).unwrap();
    assert!(s.weight <= 0.1, "{s:?}");
    assert!(s.model_nlpd - s.nlpd < 0.02, "{s:?}");
}

#[test]
fn the_residual_shape_does_not_depend_on_the_units() {
    // y ↦ A y (units and a rotation): residuals A r, covariances A Σ Aᵀ. The
    // same weight is chosen and the added covariance is A (w s R) Aᵀ.
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let (r, c) = frames_with(&mut rng, [2.0, 1.0, 0.3], identity, 400);
    let a = [100.0, 0.0, 0.0, 0.6, 0.8, 0.0, 0.0, 0.0, 0.001];
    let mat = |x: &[f64], y: &[f64]| -> Vec<f64> {
        (0..9)
            .map(|k| (0..3).map(|m| x[(k / 3) * 3 + m] * y[m * 3 + k % 3]).sum())
            .collect()
    };
    let at: Vec<f64> = (0..9).map(|k| a[(k % 3) * 3 + k / 3]).collect();
    let r2: Vec<f64> = r
        .chunks(3)
        .flat_map(|v| {
            (0..3)
                .map(|i| (0..3).map(|m| a[i * 3 + m] * v[m]).sum::<f64>())
                .collect::<Vec<_>>()
        })
        .collect();
    let c2: Vec<f64> = c.chunks(9).flat_map(|s| mat(&mat(&a, s), &at)).collect();
    let s1 = phasekit_gmr::residual_shape(&r, &c, 3, 0.95).unwrap();
    let s2 = phasekit_gmr::residual_shape(&r2, &c2, 3, 0.95).unwrap();
    assert_eq!(s1.weight, s2.weight);
    assert!(s1.weight > 0.0);
    let want = mat(&mat(&a, &s1.added), &at);
    for (x, y) in s2.added.iter().zip(&want) {
        assert!((x - y).abs() <= 1e-9 * (1.0 + y.abs()) * 1e4, "{x} vs {y}");
    }
    // The NLPD moves by the log-Jacobian only: log |det A| = log(100 · 0.8 · 0.001).
    let jacobian = (100.0f64 * 0.8 * 0.001).ln();
    assert!(
        (s2.nlpd - (s1.nlpd + jacobian)).abs() < 1e-9,
        "{} {}",
        s1.nlpd,
        s2.nlpd
    );
}

#[test]
fn the_residual_shape_keeps_the_model_when_an_error_never_varies() {
    // A dim predicted without error: R is singular, nothing is mixed in.
    let r: Vec<f64> = (0..30).flat_map(|t| [t as f64 % 5.0 - 2.0, 0.0]).collect();
    let c: Vec<f64> = (0..30).flat_map(|_| [1.0, 0.0, 0.0, 1.0]).collect();
    let s = phasekit_gmr::residual_shape(&r, &c, 2, 0.95).unwrap();
    assert_eq!(s.weight, 0.0);
    assert_eq!(s.added, vec![0.0; 4]);
    assert_eq!(s.nlpd, s.model_nlpd);
}

#[test]
fn the_residual_shape_keeps_the_model_when_two_errors_are_proportional() {
    // The second dim's error is 3.7 times the first's: R is singular up to
    // rounding; nothing is mixed in (no weight from R⁻¹'s rounding noise).
    for m in [3.7, -0.2, 1e-3, 250.0] {
        let r: Vec<f64> = (0..60)
            .flat_map(|t| {
                let x = (t as f64 * 0.37).sin();
                [x, m * x]
            })
            .collect();
        let c: Vec<f64> = (0..60).flat_map(|_| [0.01, 0.0, 0.0, 0.01]).collect();
        let s = phasekit_gmr::residual_shape(&r, &c, 2, 0.95).unwrap();
        assert_eq!(s.weight, 0.0, "m = {m}: {s:?}");
        assert!(s.nlpd.is_finite());
    }
}

#[test]
fn the_residual_shape_refuses_what_it_cannot_shape() {
    use phasekit_gmr::residual_shape as f;
    assert!(f(&[], &[], 2, 0.95).is_err());
    assert!(f(&[1.0, 2.0], &[1.0, 0.0, 0.0], 2, 0.95).is_err());
    assert!(f(&[1.0, 2.0, 3.0], &[1.0; 4], 2, 0.95).is_err());
    assert!(f(&[1.0, 2.0], &[1.0, 0.0, 0.0, -1.0], 2, 0.95).is_err());
}
