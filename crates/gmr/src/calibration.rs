//! Scoring a Gaussian prediction against the truth: is the predictive
//! uncertainty calibrated?
//!
//! For a predicted mean `μ` and covariance `Σ` (`p × p`) and the true value `y`:
//!
//! * the squared Mahalanobis distance `m² = (y − μ)ᵀ Σ⁻¹ (y − μ)`, by a
//!   Cholesky solve `Σ = L Lᵀ`, `z = L⁻¹ (y − μ)`, `m² = ‖z‖²` (no inverse);
//! * `y` lies in the predicted `q` region (the χ² ellipsoid) when
//!   `m² ≤ χ²_q(p)`; over many frames of a calibrated predictor the fraction
//!   inside is `q` ([`chi_squared_quantile`] computes the quantile for any `p`);
//! * the log predictive density `log N(y; μ, Σ) = −½ (p log 2π + log det Σ + m²)`,
//!   `log det Σ = 2 Σ_i log L_ii`; its negative, averaged over frames, is the
//!   NLPD (nats; it changes by `p log u` when the data are rescaled by `u`).

use crate::error::{GmrError, Result};

/// The probability of the predicted region whose coverage is reported
/// (`evaluate`) and calibrated (`auto`): one value for both.
pub const COVERAGE_LEVEL: f64 = 0.95;

/// Copies the `p × p` block of the rows and columns `dims` (`p = dims.len()`)
/// of an `o × o` row-major covariance into `block`: the predictive covariance
/// of the scored outputs, for [`score_gaussian`].
pub fn covariance_block(covariance: &[f64], o: usize, dims: &[usize], block: &mut [f64]) {
    let p = dims.len();
    for (a, &j) in dims.iter().enumerate() {
        for (b, &jb) in dims.iter().enumerate() {
            block[a * p + b] = covariance[j * o + jb];
        }
    }
}

/// `ln Γ(x)` for `x > 0` (Lanczos, g = 7, 9 terms; relative error below 1e-15).
pub fn ln_gamma(x: f64) -> f64 {
    const G: f64 = 7.0;
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection: Γ(x) Γ(1 − x) = π / sin(πx).
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + G + 0.5;
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// The regularised lower incomplete gamma function `P(a, x) = γ(a, x) / Γ(a)`
/// (`a > 0`, `x ≥ 0`): its series for `x < a + 1`, else `1 − Q(a, x)` with
/// `Q`'s continued fraction (modified Lentz), each converging fast there.
pub fn regularised_gamma_p(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let log_prefactor = a * x.ln() - x - ln_gamma(a);
    if x < a + 1.0 {
        // P(a, x) = e^{−x} x^a / Γ(a + 1) Σ_n x^n / ((a + 1)…(a + n)).
        let (mut term, mut sum, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * 1e-17 {
                break;
            }
        }
        (sum.ln() + log_prefactor).exp().min(1.0)
    } else {
        // Q(a, x) = e^{−x} x^a / Γ(a) · 1 / (x + 1 − a − 1·(1 − a) / (x + 3 − a − …)).
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let delta = d * c;
            h *= delta;
            if (delta - 1.0).abs() < 1e-17 {
                break;
            }
        }
        (1.0 - (h.ln() + log_prefactor).exp()).max(0.0)
    }
}

/// The χ² distribution function with `dof` degrees of freedom: `P(dof/2, x/2)`.
pub fn chi_squared_cdf(x: f64, dof: usize) -> f64 {
    regularised_gamma_p(dof as f64 / 2.0, x / 2.0)
}

/// The `q` quantile of the χ² distribution with `dof ≥ 1` degrees of freedom
/// (`0 < q < 1`): the `x` with [`chi_squared_cdf`]`(x, dof) = q`, found by
/// bisection on a bracket (monotone, so it cannot miss) to the last bits.
pub fn chi_squared_quantile(q: f64, dof: usize) -> Result<f64> {
    if dof == 0 || !(q > 0.0 && q < 1.0) {
        return Err(GmrError::InvalidDims(format!(
            "χ² quantile: needs 0 < q < 1 and at least one degree of freedom, got q = {q}, dof = {dof}"
        )));
    }
    let (mut lo, mut hi) = (0.0, (dof as f64).max(1.0));
    while chi_squared_cdf(hi, dof) < q {
        lo = hi;
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if chi_squared_cdf(mid, dof) < q {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(0.5 * (lo + hi))
}

/// How well a Gaussian prediction `N(μ, Σ)` explains the true value `y`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct GaussianScore {
    /// `(y − μ)ᵀ Σ⁻¹ (y − μ)`.
    pub mahalanobis2: f64,
    /// `log N(y; μ, Σ)` (nats).
    pub log_density: f64,
}

/// Scores `y` against `N(μ, Σ)`: `residual = y − μ` (`p` values), `covariance`
/// `p × p` row-major (the lower triangle is read), `scratch` at least `p (p + 1)`
/// values (no allocation: called once per frame). Errors when the sizes
/// disagree or `Σ` is not positive definite (an uncertainty that is not one).
pub fn score_gaussian(
    residual: &[f64],
    covariance: &[f64],
    scratch: &mut [f64],
) -> Result<GaussianScore> {
    let p = residual.len();
    if p == 0 || covariance.len() != p * p || scratch.len() < p * (p + 1) {
        return Err(GmrError::InvalidDims(format!(
            "Gaussian score: residual of {p} values needs a {p} × {p} covariance ({} values given) and {} scratch values ({} given)",
            covariance.len(),
            p * (p + 1),
            scratch.len()
        )));
    }
    // Cholesky L (row-major lower triangle in scratch).
    let l = &mut scratch[..p * p];
    let mut log_det = 0.0;
    for i in 0..p {
        for j in 0..=i {
            let mut s = covariance[i * p + j];
            for k in 0..j {
                s -= l[i * p + k] * l[j * p + k];
            }
            if i == j {
                if !(s > 0.0 && s.is_finite()) {
                    return Err(GmrError::InvalidDims(format!(
                        "Gaussian score: the predictive covariance is not positive definite (pivot {i} is {s})"
                    )));
                }
                l[i * p + i] = s.sqrt();
                log_det += 2.0 * l[i * p + i].ln();
            } else {
                l[i * p + j] = s / l[j * p + j];
            }
        }
    }
    // Forward substitution L z = r, z kept after L in the scratch space.
    let (l, z) = scratch.split_at_mut(p * p);
    let mut m2 = 0.0;
    for i in 0..p {
        let mut s = residual[i];
        for k in 0..i {
            s -= l[i * p + k] * z[k];
        }
        z[i] = s / l[i * p + i];
        m2 += z[i] * z[i];
    }
    let log_density = -0.5 * (p as f64 * (2.0 * std::f64::consts::PI).ln() + log_det + m2);
    Ok(GaussianScore {
        mahalanobis2: m2,
        log_density,
    })
}

/// The factor `c` by which to multiply a predictive covariance so that a share
/// `level` of the frames scored fall inside its `level` region: with the
/// frames' squared Mahalanobis distances `m²_1…m²_n` under the unscaled
/// covariance (`p` dims each) and `q` their empirical `level` quantile (the
/// `⌈level · n⌉`-th smallest),
///
/// `c = q / χ²_level(p)`,
///
/// since `m² / c ≤ χ²_level(p)` exactly when `m² ≤ q`: after scaling, at least
/// `level · n` of the frames are inside, and any smaller `c` leaves fewer.
/// Fitted on held-out frames (cross-validation folds), it covers new frames
/// of demonstrations like those; a new demonstration unlike them is covered
/// less often, which [`demonstration_inflation`] measures. The mean is
/// unchanged.
///
/// Errors with no frame, a non-finite or negative distance, `level` outside
/// `(0, 1)`, or a quantile of zero (every frame predicted exactly: no scale
/// can be inferred).
pub fn coverage_scale(mahalanobis2: &[f64], p: usize, level: f64) -> Result<f64> {
    check_distances(mahalanobis2)?;
    let limit = chi_squared_quantile(level, p)?;
    let mut sorted = mahalanobis2.to_vec();
    sorted.sort_by(f64::total_cmp);
    let q = order_statistic(&sorted, level);
    if q <= 0.0 {
        return Err(GmrError::InvalidDims(
            "coverage calibration: the quantile of the squared distances is zero".into(),
        ));
    }
    Ok(q / limit)
}

/// Errors unless there is a distance and every one is finite and `≥ 0`.
fn check_distances(mahalanobis2: &[f64]) -> Result<()> {
    if mahalanobis2.is_empty() {
        return Err(GmrError::InvalidDims(
            "coverage calibration: no frame to calibrate on".into(),
        ));
    }
    if let Some(v) = mahalanobis2.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
        return Err(GmrError::InvalidDims(format!(
            "coverage calibration: a squared Mahalanobis distance is {v}"
        )));
    }
    Ok(())
}

/// The `⌈q · n⌉`-th smallest of `sorted` (ascending, non-empty): the empirical
/// `q` quantile that [`coverage_scale`] uses.
fn order_statistic(sorted: &[f64], q: f64) -> f64 {
    let k = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[k - 1]
}

/// How much to widen a calibration fitted on frames pooled over
/// demonstrations ([`coverage_scale`]) so that it covers a *new
/// demonstration*'s frames at `level`, estimated by leaving one demonstration
/// out at a time: with the held-out frames' squared Mahalanobis distances
/// grouped by demonstration (`groups[d]`, the frames of demonstration `d`)
/// and `Q_{−d}` the empirical `level` quantile of every other demonstration's
/// distances (the threshold a calibration without `d` would set),
///
/// `λ = max(1, Q_level({ m²_{d,t} / Q_{−d} }_{d,t}))`,
///
/// the smallest factor by which those left-out thresholds must be multiplied
/// for a share `level` of all the frames to fall below their own
/// demonstration's threshold (`Σ_d #{t : m²_{d,t} ≤ λ Q_{−d}} ≥ level · n`).
/// The calibrated factor is then `λ · c`, `c` from [`coverage_scale`] on all
/// the frames.
///
/// Why: frames of one demonstration are not independent draws. Their errors
/// share the demonstration's own offsets and timing, so the pooled `level`
/// quantile, fitted on the very demonstrations it is judged on, covers a new
/// demonstration less often than `level` — the fewer and the more unlike one
/// another the demonstrations, the less. Leaving each one out measures that
/// shortfall on the training demonstrations alone; `λ` is close to 1 when
/// the demonstrations agree (a few per cent above it from the quantiles'
/// sampling noise; never below 1: the pooled factor is the least a
/// calibration on these frames can claim).
///
/// Errors with fewer than two non-empty groups (nothing to leave out), a
/// distance that is not finite and `≥ 0`, `level` outside `(0, 1)`, or a
/// left-out quantile of zero.
pub fn demonstration_inflation(groups: &[&[f64]], level: f64) -> Result<f64> {
    let groups = demonstration_groups(groups, level)?;
    let mut ratios: Vec<f64> = Vec::with_capacity(groups.iter().map(|(_, g)| g.len()).sum());
    for (d, (index, group)) in groups.iter().enumerate() {
        let threshold = left_out_threshold(&groups, d, level);
        if threshold <= 0.0 {
            return Err(GmrError::InvalidDims(format!(
                "coverage calibration: without demonstration {index} the quantile of the squared distances is zero"
            )));
        }
        ratios.extend(group.iter().map(|v| v / threshold));
    }
    ratios.sort_by(f64::total_cmp);
    Ok(order_statistic(&ratios, level).max(1.0))
}

/// How much to widen a calibration fitted on frames pooled over
/// demonstrations so that a *new demonstration* is covered at `level` in
/// expectation, with how hard a demonstration is modelled as a random effect
/// (the `predictive` rule of `auto`; [`demonstration_inflation`] is the
/// rule that takes the held-out demonstrations as they are).
///
/// With the held-out frames' squared Mahalanobis distances grouped by
/// demonstration (`groups[d]`, `n ≥ 2` non-empty groups) and `Q_{−d}` the
/// empirical `level` quantile of every other demonstration's distances:
///
/// * demonstration `d`'s *difficulty* `g_d = Q_level({m²_{d,t} / Q_{−d}}_t)`:
///   the factor by which the threshold the others set must be multiplied for
///   `level` of `d`'s own frames to fall below it;
/// * its frames' *shape* `u_{d,t} = m²_{d,t} / (Q_{−d} g_d)`, pooled over
///   the demonstrations into one distribution `H` (`H(1) ≈ level` for each);
/// * the log-difficulties' mean `μ` and standard deviation `σ` (`n − 1` in
///   the denominator); a new demonstration's log-difficulty is predicted as
///   `N(μ, σ² (1 + 1/n))` (a new draw around a mean estimated from `n`);
/// * the factor `f` solves `E_g[H(f / g)] = level`: against the threshold
///   `Q` of all the frames (the others, for a new demonstration), the
///   expected share of a new demonstration's frames inside is `level`.
///
/// The expectation is a fixed quadrature (`z` on 321 points of `[−8, 8]`,
/// normal weights) and `f` a bisection on `ln f` to 1e-12: deterministic.
/// The calibrated factor is then `f · c`, `c` from [`coverage_scale`] on all
/// the frames. Unlike [`demonstration_inflation`], `f` may be below 1: the
/// pooled factor can be too wide when most demonstrations are easier than
/// the pooled frames make them look.
///
/// Why: demonstrations differ in how hard they are (an offset, a timing), and
/// with a handful of them the hardest one seen is not the hardest to come. A
/// rule that only replays the held-out demonstrations covers a new one less
/// often the more they differ; this one widens by their spread and by the
/// uncertainty of its mean.
///
/// Errors with fewer than two non-empty groups, a distance that is not
/// finite and `≥ 0`, `level` outside `(0, 1)`, or a quantile of zero.
pub fn new_demonstration_factor(groups: &[&[f64]], level: f64) -> Result<NewDemonstration> {
    let groups = demonstration_groups(groups, level)?;
    let n = groups.len();
    let mut log_difficulty = Vec::with_capacity(n);
    let mut shape: Vec<f64> = Vec::with_capacity(groups.iter().map(|(_, g)| g.len()).sum());
    for (d, (index, group)) in groups.iter().enumerate() {
        let threshold = left_out_threshold(&groups, d, level);
        let mut own: Vec<f64> = group.iter().map(|v| v / threshold).collect();
        own.sort_by(f64::total_cmp);
        let difficulty = order_statistic(&own, level);
        if !(threshold > 0.0 && difficulty > 0.0) {
            return Err(GmrError::InvalidDims(format!(
                "coverage calibration: demonstration {index} or the others have a quantile of zero"
            )));
        }
        // Distances so far apart that their ratios leave the floating-point
        // range (1e300 against 1e-300) cannot be calibrated.
        let shapes = own.iter().map(|x| x / difficulty);
        if !difficulty.is_finite() || shapes.clone().any(|u| !u.is_finite()) {
            return Err(GmrError::InvalidDims(format!(
                "coverage calibration: the distances of demonstration {index} against the others' \
                 quantile overflow"
            )));
        }
        log_difficulty.push(difficulty.ln());
        shape.extend(shapes);
    }
    shape.sort_by(f64::total_cmp);
    let nf = n as f64;
    let mu = log_difficulty.iter().sum::<f64>() / nf;
    let sigma = (log_difficulty.iter().map(|v| (v - mu).powi(2)).sum::<f64>() / (nf - 1.0)).sqrt();
    let spread = sigma * (1.0 + 1.0 / nf).sqrt();
    // Quadrature nodes of the new demonstration's log-difficulty.
    const NODES: usize = 321;
    let (mut nodes, mut weights) = (Vec::with_capacity(NODES), Vec::with_capacity(NODES));
    for i in 0..NODES {
        let z = -8.0 + 16.0 * i as f64 / (NODES - 1) as f64;
        nodes.push(mu + spread * z);
        weights.push((-0.5 * z * z).exp());
    }
    let total: f64 = weights.iter().sum();
    weights.iter_mut().for_each(|w| *w /= total);
    // E_g[H(f / g)] with H the shapes' empirical distribution function.
    let expected = |ln_f: f64| -> f64 {
        nodes
            .iter()
            .zip(&weights)
            .map(|(ln_g, w)| {
                let x = (ln_f - ln_g).exp();
                w * shape.partition_point(|&u| u <= x) as f64
            })
            .sum::<f64>()
            / shape.len() as f64
    };
    // Bracket: below every shape at the largest difficulty, above every shape
    // at the smallest one.
    let (lo_shape, hi_shape) = (shape[0].max(f64::MIN_POSITIVE), shape[shape.len() - 1]);
    let mut lo = lo_shape.ln() + nodes[0] - 1.0;
    let mut hi = hi_shape.ln() + nodes[NODES - 1] + 1.0;
    // At most 200 halvings (the bracket spans < 4000 in ln: 1e-12 in < 60).
    for _ in 0..200 {
        if hi - lo <= 1e-12 {
            break;
        }
        let mid = 0.5 * (lo + hi);
        if expected(mid) < level {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let factor = hi.exp();
    if !(factor.is_finite() && factor > 0.0) {
        return Err(GmrError::InvalidDims(format!(
            "coverage calibration: the factor for a new demonstration is {factor}"
        )));
    }
    Ok(NewDemonstration {
        factor,
        log_difficulty_mean: mu,
        log_difficulty_sd: sigma,
        demonstrations: n,
    })
}

/// What [`new_demonstration_factor`] found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewDemonstration {
    /// `f`: multiplies the pooled factor.
    pub factor: f64,
    /// `μ`: the mean log-difficulty of the held-out demonstrations.
    pub log_difficulty_mean: f64,
    /// `σ`: their standard deviation.
    pub log_difficulty_sd: f64,
    /// `n`: how many demonstrations had scored frames.
    pub demonstrations: usize,
}

/// The shape a calibration gives the predictive covariance before scaling
/// it: the model's covariance plus a share of the covariance of its
/// held-out errors (the `predictive` rule of `auto`).
///
/// With held-out frames' residuals `r_t = y_t − μ_t` and predictive
/// covariances `Σ_t` (`p` dims), the residuals' second moment
/// `R = (1/n) Σ_t r_t r_tᵀ`, and `s = (1/n) Σ_t tr(R⁻¹ Σ_t) / p` (so that
/// `s R` is as large as the average `Σ_t` measured by `R`: the same under any
/// invertible change of the dims' units), the calibrated shape is
///
/// `Σ_t(w) = Σ_t + w s R`,
///
/// with `w` from the grid `0, 10^{−2}, 10^{−1.75}, …, 10²` chosen for the
/// lowest held-out NLPD after the pooled scale [`coverage_scale`] of the
/// same frames (the first on ties). `w = 0` is the model's own shape; a large
/// `w` a constant covariance shaped like the errors.
///
/// Why: a model's covariance can have the wrong shape rather than the wrong
/// size. A regulariser's isotropic `(10 cm)²` is the same in every direction
/// while the errors are not; a scalar factor then has to choose between
/// covering the long direction and being honest in the short one. The
/// errors' own covariance, mixed in by held-out likelihood, fixes the shape;
/// the scalar then fixes the size.
///
/// `residuals`: `n × p` row-major; `covariances`: `n × p × p`. `w = 0` and
/// no added covariance when `R` is singular or nearly so (a dim predicted
/// without error, two dims whose errors are proportional: a Cholesky pivot
/// below 1e-10 of its diagonal).
/// Errors with no frame, sizes that disagree, or a covariance that is not
/// positive definite.
pub fn residual_shape(
    residuals: &[f64],
    covariances: &[f64],
    p: usize,
    level: f64,
) -> Result<ResidualShape> {
    let n = residuals.len().checked_div(p).unwrap_or(0);
    if n == 0 || residuals.len() != n * p || covariances.len() != n * p * p {
        return Err(GmrError::InvalidDims(format!(
            "residual shape: {} residual values and {} covariance values do not make frames of {p} dims",
            residuals.len(),
            covariances.len()
        )));
    }
    let limit = chi_squared_quantile(level, p)?;
    let mut second_moment = vec![0.0; p * p];
    for r in residuals.chunks_exact(p) {
        for i in 0..p {
            for j in 0..p {
                second_moment[i * p + j] += r[i] * r[j] / n as f64;
            }
        }
    }
    let mut scratch = vec![0.0; p * (p + 1)];
    let mut mixed = vec![0.0; p * p];
    // Scores every frame under Σ_t + a · R: the pooled-scale NLPD and the distances.
    let mut score = |added: f64, m2: &mut Vec<f64>| -> Result<f64> {
        m2.clear();
        let mut log_density = 0.0;
        for (r, cov) in residuals
            .chunks_exact(p)
            .zip(covariances.chunks_exact(p * p))
        {
            for ((m, c), a) in mixed.iter_mut().zip(cov).zip(&second_moment) {
                *m = c + added * a;
            }
            let s = score_gaussian(r, &mixed, &mut scratch)?;
            m2.push(s.mahalanobis2);
            log_density += s.log_density;
        }
        let nlpd = -log_density / n as f64;
        let mean_m2 = m2.iter().sum::<f64>() / n as f64;
        let mut sorted = m2.clone();
        sorted.sort_by(f64::total_cmp);
        let c = order_statistic(&sorted, level) / limit;
        Ok(if c > 0.0 {
            nlpd_scaled(nlpd, mean_m2, p, c)
        } else {
            f64::INFINITY
        })
    };
    let mut m2 = Vec::with_capacity(n);
    let own_nlpd = score(0.0, &mut m2)?;
    // s = mean tr(R⁻¹ Σ_t) / p, by R⁻¹'s columns from a Cholesky solve; a
    // singular R leaves the model's shape.
    let Some(inverse) = inverse_spd(&second_moment, p) else {
        return Ok(ResidualShape {
            weight: 0.0,
            added: vec![0.0; p * p],
            nlpd: own_nlpd,
            model_nlpd: own_nlpd,
        });
    };
    let size = covariances
        .chunks_exact(p * p)
        .map(|c| (0..p * p).map(|k| inverse[k] * c[k]).sum::<f64>())
        .sum::<f64>()
        / (n * p) as f64;
    let (mut best_weight, mut best_nlpd) = (0.0, own_nlpd);
    for k in -8..=8 {
        let w = 10f64.powf(k as f64 / 4.0);
        // A weight whose covariance cannot be scored is not a candidate.
        let Ok(nlpd) = score(w * size, &mut m2) else {
            continue;
        };
        if nlpd < best_nlpd {
            (best_weight, best_nlpd) = (w, nlpd);
        }
    }
    Ok(ResidualShape {
        weight: best_weight,
        added: second_moment
            .iter()
            .map(|a| best_weight * size * a)
            .collect(),
        nlpd: best_nlpd,
        model_nlpd: own_nlpd,
    })
}

/// What [`residual_shape`] chose.
#[derive(Debug, Clone, PartialEq)]
pub struct ResidualShape {
    /// `w`: the share of the held-out errors' covariance mixed in.
    pub weight: f64,
    /// `w s R`, `p × p` row-major: what is added to every `Σ_t`.
    pub added: Vec<f64>,
    /// The held-out NLPD with it, after the pooled scale (nats).
    pub nlpd: f64,
    /// The held-out NLPD of the model's own shape, after the pooled scale.
    pub model_nlpd: f64,
}

/// The inverse of a symmetric positive definite `p × p` matrix (row-major),
/// by Cholesky; `None` when it is not positive definite.
fn inverse_spd(a: &[f64], p: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0; p * p];
    for i in 0..p {
        for j in 0..=i {
            let s = a[i * p + j] - (0..j).map(|k| l[i * p + k] * l[j * p + k]).sum::<f64>();
            if i == j {
                // Numerically singular too (errors of two dims proportional):
                // a pivot below 1e-10 of its diagonal would give R⁻¹ huge
                // entries and `s` noise.
                if !(s > 1e-10 * a[i * p + i] && s.is_finite()) {
                    return None;
                }
                l[i * p + i] = s.sqrt();
            } else {
                l[i * p + j] = s / l[j * p + j];
            }
        }
    }
    let mut inverse = vec![0.0; p * p];
    let mut column = vec![0.0; p];
    for e in 0..p {
        // L y = e_e, then Lᵀ x = y.
        for i in 0..p {
            let s =
                f64::from(u8::from(i == e)) - (0..i).map(|k| l[i * p + k] * column[k]).sum::<f64>();
            column[i] = s / l[i * p + i];
        }
        for i in (0..p).rev() {
            let s = column[i] - (i + 1..p).map(|k| l[k * p + i] * column[k]).sum::<f64>();
            column[i] = s / l[i * p + i];
        }
        for i in 0..p {
            inverse[i * p + e] = column[i];
        }
    }
    Some(inverse)
}

/// The checked input of the demonstration rules: `level` in `(0, 1)`, the
/// non-empty groups (a demonstration without a scored frame is left out;
/// errors name a demonstration by its index in `groups`), at least two of
/// them, every distance finite and `≥ 0`.
fn demonstration_groups<'a>(groups: &[&'a [f64]], level: f64) -> Result<Vec<(usize, &'a [f64])>> {
    if !(level > 0.0 && level < 1.0) {
        return Err(GmrError::InvalidDims(format!(
            "coverage calibration: the level must lie in (0, 1), got {level}"
        )));
    }
    let groups: Vec<(usize, &[f64])> = groups
        .iter()
        .copied()
        .enumerate()
        .filter(|(_, g)| !g.is_empty())
        .collect();
    if groups.len() < 2 {
        return Err(GmrError::InvalidDims(
            "coverage calibration: leaving one demonstration out needs at least two".into(),
        ));
    }
    for (_, g) in &groups {
        check_distances(g)?;
    }
    Ok(groups)
}

/// `Q_{−d}`: the empirical `level` quantile of every group's distances but
/// group `d`'s (the threshold a calibration without `d` would set).
fn left_out_threshold(groups: &[(usize, &[f64])], d: usize, level: f64) -> f64 {
    let mut others: Vec<f64> = groups
        .iter()
        .enumerate()
        .filter(|(e, _)| *e != d)
        .flat_map(|(_, (_, g))| g.iter().copied())
        .collect();
    others.sort_by(f64::total_cmp);
    order_statistic(&others, level)
}

/// The mean negative log predictive density after multiplying the covariance
/// by `c`, from the unscaled one: with `p` dims and the mean `m̄²` of the
/// frames' squared Mahalanobis distances,
///
/// `NLPD(c) = NLPD(1) + (p / 2) ln c + (1 / c − 1) m̄² / 2`
///
/// (`log det(cΣ) = p ln c + log det Σ`, `m²` divides by `c`).
pub fn nlpd_scaled(nlpd: f64, mean_mahalanobis2: f64, p: usize, c: f64) -> f64 {
    nlpd + 0.5 * p as f64 * c.ln() + 0.5 * (1.0 / c - 1.0) * mean_mahalanobis2
}
