//! Parity with scikit-learn 1.5.2 `GaussianMixture` on the fixtures of
//! `tests/fixtures/sklearn_gmm_cases.json` (fields and conventions in
//! `tests/fixtures/README.md`).
//!
//! For every case (full, diag, spherical, tied) the mixture is rebuilt from the
//! fixture's initial parameters and checked against sklearn:
//!
//! * `score_samples` and the responsibilities under the initial parameters
//!   (`|got − want| ≤ 1e-10·(1 + |want|)`);
//! * the weights, means and covariances (native shape and full `K × D × D`)
//!   after exactly one and exactly ten EM steps from those parameters, with the
//!   covariance regularisation `Regularisation::add_diagonal(reg_covar)` (or
//!   none when `reg_covar` is 0), which is sklearn's `reg_covar`
//!   (`|got − want| ≤ 1e-8 + 1e-8·|want|`);
//! * sklearn's `lower_bound_`: it is computed in the E-step of the last
//!   iteration, i.e. under the parameters *before* the last M-step, so after
//!   one step it is our `report.log_likelihood[0] / N` and after ten steps
//!   `report.log_likelihood[9] / N`; `score(X)` after ten steps is the last
//!   entry (`log_likelihood[10] / N`);
//! * `n_parameters`, BIC and AIC of the ten-step model.
//!
//! sklearn adds `10·eps` to every component's weight sum; that changes the
//! results by about 1e-16 relative, far below the tolerances.

use phasekit_emission::{CovarianceType, Frames, Gaussian, Regularisation};
use phasekit_gmm::{Em, Gmm, GmmFit};
use serde_json::Value;
use std::sync::OnceLock;

const FIXTURE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../tests/fixtures/sklearn_gmm_cases.json"
);

/// Tolerance of quantities evaluated under given parameters (no iteration).
const TOL_EVAL: f64 = 1e-10;
/// Relative and absolute tolerance of parameters after EM steps.
const TOL_PARAM: f64 = 1e-8;

fn fixture() -> &'static Value {
    static F: OnceLock<Value> = OnceLock::new();
    F.get_or_init(|| {
        let text = std::fs::read_to_string(FIXTURE).expect("read the sklearn fixture");
        serde_json::from_str(&text).expect("parse the sklearn fixture")
    })
}

fn case(name: &str) -> &'static Value {
    fixture()["cases"]
        .as_array()
        .expect("cases array")
        .iter()
        .find(|c| c["name"] == name)
        .unwrap_or_else(|| panic!("fixture has no case {name}"))
}

/// Flattens nested JSON arrays of numbers row-major.
fn flat(v: &Value) -> Vec<f64> {
    fn go(v: &Value, out: &mut Vec<f64>) {
        match v {
            Value::Array(a) => a.iter().for_each(|x| go(x, out)),
            Value::Number(n) => out.push(n.as_f64().expect("number")),
            other => panic!("expected a number or an array, found {other}"),
        }
    }
    let mut out = Vec::new();
    go(v, &mut out);
    out
}

fn num(v: &Value) -> f64 {
    v.as_f64().expect("number")
}

fn usize_of(v: &Value) -> usize {
    v.as_u64().expect("unsigned integer") as usize
}

fn kind_of(c: &Value) -> CovarianceType {
    match c["covariance_type"].as_str().expect("covariance_type") {
        "full" => CovarianceType::Full,
        "diag" => CovarianceType::Diagonal,
        "spherical" => CovarianceType::Spherical,
        "tied" => CovarianceType::Tied,
        other => panic!("unknown covariance type {other}"),
    }
}

/// Collects every failed comparison of a case and reports them together.
struct Checker {
    case: String,
    failures: Vec<String>,
    comparisons: usize,
}

impl Checker {
    fn new(case: &str) -> Self {
        Checker {
            case: case.into(),
            failures: Vec::new(),
            comparisons: 0,
        }
    }

    /// `|got − want| ≤ atol + rtol·|want|` element-wise.
    fn close(&mut self, what: &str, got: &[f64], want: &[f64], rtol: f64, atol: f64) {
        if got.len() != want.len() {
            self.failures
                .push(format!("{what}: length {} != {}", got.len(), want.len()));
            return;
        }
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            self.comparisons += 1;
            let diff = (g - w).abs();
            // A NaN difference fails too.
            if diff.is_nan() || diff > atol + rtol * w.abs() {
                self.failures.push(format!(
                    "{what}[{i}]: got {g:e}, want {w:e} (diff {diff:e})"
                ));
            }
        }
    }

    fn scalar(&mut self, what: &str, got: f64, want: f64, rtol: f64, atol: f64) {
        self.close(what, &[got], &[want], rtol, atol);
    }

    fn equal(&mut self, what: &str, got: usize, want: usize) {
        self.comparisons += 1;
        if got != want {
            self.failures
                .push(format!("{what}: got {got}, want {want}"));
        }
    }

    fn finish(self) {
        assert!(self.comparisons > 0, "{}: nothing was compared", self.case);
        assert!(
            self.failures.is_empty(),
            "{}: {} of {} comparisons failed:\n{}",
            self.case,
            self.failures.len(),
            self.comparisons,
            self.failures.join("\n")
        );
    }
}

fn initial_model(c: &Value) -> Gmm {
    let d = usize_of(&c["n_features"]);
    let gaussian = Gaussian::new(
        kind_of(c),
        d,
        flat(&c["init_means"]),
        flat(&c["init_covariances_raw"]),
    )
    .expect("the fixture's initial components are valid");
    Gmm::new(flat(&c["init_weights"]), gaussian).expect("the fixture's initial weights are valid")
}

fn em(c: &Value, steps: usize) -> Em {
    let reg_covar = num(&c["reg_covar"]);
    let reg = if reg_covar == 0.0 {
        Regularisation::none()
    } else {
        Regularisation::add_diagonal(reg_covar).expect("valid reg_covar")
    };
    Em::builder()
        .max_iter(steps)
        .tol(f64::NEG_INFINITY)
        .regularisation(reg)
        .build()
        .expect("valid EM settings")
}

fn check_parameters(
    ck: &mut Checker,
    label: &str,
    fitted: &GmmFit<phasekit_emission::Gaussian>,
    want: &Value,
) {
    let model = &fitted.model;
    let comps = model.components();
    ck.close(
        &format!("{label}.weights"),
        model.weights(),
        &flat(&want["weights"]),
        TOL_PARAM,
        TOL_PARAM,
    );
    ck.close(
        &format!("{label}.means"),
        comps.means(),
        &flat(&want["means"]),
        TOL_PARAM,
        TOL_PARAM,
    );
    ck.close(
        &format!("{label}.covariances_raw"),
        comps.covariances_raw(),
        &flat(&want["covariances_raw"]),
        TOL_PARAM,
        TOL_PARAM,
    );
    let full: Vec<f64> = (0..model.n_components())
        .flat_map(|k| {
            let m = comps.covariance(k);
            let d = m.nrows();
            (0..d * d).map(move |i| m[(i / d, i % d)])
        })
        .collect();
    ck.close(
        &format!("{label}.covariances_full"),
        &full,
        &flat(&want["covariances_full"]),
        TOL_PARAM,
        TOL_PARAM,
    );
}

fn run_case(name: &str, kind: CovarianceType) {
    let c = case(name);
    assert_eq!(
        kind_of(c),
        kind,
        "case {name} has an unexpected covariance type"
    );
    let mut ck = Checker::new(name);
    let d = usize_of(&c["n_features"]);
    let data = flat(&c["data"]);
    let frames = Frames::new(&data, d).expect("finite data");
    let n = frames.len();
    ck.equal("n_samples", n, usize_of(&c["n_samples"]));
    let k = usize_of(&c["n_components"]);
    let model = initial_model(c);
    ck.equal("n_components", model.n_components(), k);

    // Under the initial parameters.
    let score = model.score_samples(frames).expect("score_samples");
    ck.close(
        "score_samples",
        &score,
        &flat(&c["score_samples"]),
        TOL_EVAL,
        TOL_EVAL,
    );
    let resp = model.responsibilities(frames).expect("responsibilities");
    ck.close(
        "responsibilities",
        &resp,
        &flat(&c["responsibilities"]),
        TOL_EVAL,
        TOL_EVAL,
    );
    let mean_ll = model.log_likelihood(frames).expect("log_likelihood") / n as f64;
    ck.scalar(
        "mean_log_likelihood",
        mean_ll,
        num(&c["mean_log_likelihood"]),
        TOL_EVAL,
        TOL_EVAL,
    );

    // One EM step.
    let one = em(c, 1)
        .fit_from(model.clone(), frames)
        .expect("one EM step");
    ck.equal("one step: iterations", one.report.iterations, 1);
    ck.equal("one step: E-steps", one.report.log_likelihood.len(), 2);
    check_parameters(&mut ck, "after_one_step", &one, &c["after_one_step"]);
    ck.scalar(
        "lower_bound_after_one_step",
        one.report.log_likelihood[0] / n as f64,
        num(&c["lower_bound_after_one_step"]),
        TOL_EVAL,
        TOL_EVAL,
    );

    // Ten EM steps.
    let ten = em(c, 10).fit_from(model, frames).expect("ten EM steps");
    ck.equal("ten steps: iterations", ten.report.iterations, 10);
    ck.equal("ten steps: E-steps", ten.report.log_likelihood.len(), 11);
    check_parameters(&mut ck, "after_ten_steps", &ten, &c["after_ten_steps"]);
    let ll = &ten.report.log_likelihood;
    ck.scalar(
        "lower_bound_after_ten_steps (E-step after nine M-steps)",
        ll[9] / n as f64,
        num(&c["lower_bound_after_ten_steps"]),
        TOL_PARAM,
        TOL_PARAM,
    );
    ck.scalar(
        "mean_log_likelihood_after_ten_steps (report)",
        ll[10] / n as f64,
        num(&c["mean_log_likelihood_after_ten_steps"]),
        TOL_PARAM,
        TOL_PARAM,
    );
    let final_ll = ten.model.log_likelihood(frames).expect("log_likelihood");
    ck.scalar(
        "mean_log_likelihood_after_ten_steps (model)",
        final_ll / n as f64,
        num(&c["mean_log_likelihood_after_ten_steps"]),
        TOL_PARAM,
        TOL_PARAM,
    );
    ck.equal(
        "n_parameters",
        ten.model.n_parameters(),
        usize_of(&c["n_parameters"]),
    );
    ck.scalar(
        "bic",
        ten.model.bic(frames).expect("bic"),
        num(&c["bic"]),
        TOL_PARAM,
        TOL_PARAM,
    );
    ck.scalar(
        "aic",
        ten.model.aic(frames).expect("aic"),
        num(&c["aic"]),
        TOL_PARAM,
        TOL_PARAM,
    );
    ck.finish();
}

#[test]
fn fixture_has_the_four_documented_cases() {
    let names: Vec<&str> = fixture()["cases"]
        .as_array()
        .expect("cases array")
        .iter()
        .map(|c| c["name"].as_str().expect("name"))
        .collect();
    assert_eq!(names, ["gmm_full", "gmm_diag", "gmm_spherical", "gmm_tied"]);
}

#[test]
fn gmm_full() {
    run_case("gmm_full", CovarianceType::Full);
}

#[test]
fn gmm_diag() {
    run_case("gmm_diag", CovarianceType::Diagonal);
}

#[test]
fn gmm_spherical() {
    run_case("gmm_spherical", CovarianceType::Spherical);
}

#[test]
fn gmm_tied() {
    run_case("gmm_tied", CovarianceType::Tied);
}
