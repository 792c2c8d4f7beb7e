//! The GMM-HMM (a mixture of Gaussians per state, hmmlearn's GMMHMM) on data
//! whose three states each emit from two well-separated Gaussians
//! (`multimodal` in `tests/fixtures/hmmlearn_gmmhmm_cases.json`, made by
//! `tests/fixtures/generate.py`, with hmmlearn's results on the same data).
//!
//! Before the mixture's initialisation seeded each state's components from
//! the frames it owns, every state's components started from the same
//! template, kept equal responsibilities and never separated: the fitted
//! log-likelihood equalled the one-Gaussian model's to the last digit.

use phasekit::emission::{
    CovarianceType, Emission, Gaussian, MixtureEmission, Regularisation, SequenceSet, Shape,
};
use phasekit::hmm::{BaumWelch, Hmm};
use serde_json::Value;

fn fixture() -> Value {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/hmmlearn_gmmhmm_cases.json"
    );
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn flat(v: &Value) -> Vec<f64> {
    match v {
        Value::Array(a) => a.iter().flat_map(flat).collect(),
        Value::Number(n) => vec![n.as_f64().unwrap()],
        _ => panic!("not numeric"),
    }
}

fn data(c: &Value) -> SequenceSet {
    let seqs: Vec<Vec<f64>> = c["sequences"]
        .as_array()
        .unwrap()
        .iter()
        .map(flat)
        .collect();
    SequenceSet::new(&seqs, 2).unwrap()
}

fn fit<E: Emission>(template: &E, data: &SequenceSet) -> Hmm<E> {
    BaumWelch::builder()
        .max_iter(200)
        .tol(1e-6)
        .restarts(5)
        .seed(0)
        .regularisation(Regularisation::add_diagonal(1e-6).unwrap())
        .build()
        .unwrap()
        .fit(template, data)
        .unwrap()
        .model
}

#[test]
fn gmm_hmm_recovers_two_modes_per_state_and_beats_hmmlearn_and_one_gaussian() {
    let f = fixture();
    let c = &f["multimodal"];
    let data = data(c);
    let n = data.total_frames() as f64;
    let comp = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 2,
            dim: 2,
        },
    )
    .unwrap();
    let template = MixtureEmission::new(vec![0.5; 6], vec![comp; 3]).unwrap();
    let gmm = fit(&template, &data);
    let gauss = fit(
        &Gaussian::standard(
            CovarianceType::Full,
            Shape {
                n_states: 3,
                dim: 2,
            },
        )
        .unwrap(),
        &data,
    );
    let ll_gmm = gmm.log_likelihood_all(&data).unwrap() / n;
    let ll_gauss = gauss.log_likelihood_all(&data).unwrap() / n;

    // The six modes, each found by one component.
    let modes = flat(&c["modes"]);
    let mut used = [false; 6];
    for i in 0..3 {
        let comps = gmm.emission().components(i);
        for k in 0..2 {
            let mu = comps.mean(k);
            let (j, dist) = (0..6)
                .map(|j| {
                    (
                        j,
                        ((mu[0] - modes[2 * j]).powi(2) + (mu[1] - modes[2 * j + 1]).powi(2))
                            .sqrt(),
                    )
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            assert!(
                dist < 0.5,
                "state {i} component {k} at {mu:?}: nearest mode {j} at {dist}"
            );
            assert!(!used[j], "mode {j} found twice");
            used[j] = true;
        }
    }

    let best = |key: &str| flat(&c[key]).into_iter().fold(f64::NEG_INFINITY, f64::max);
    let (hl_gmm, hl_gauss) = (
        best("hmmlearn_gmmhmm_log_likelihood_per_frame"),
        best("hmmlearn_gaussianhmm_log_likelihood_per_frame"),
    );
    println!(
        "log-likelihood per frame (nats): phasekit GMM-HMM {ll_gmm:.6}, hmmlearn GMMHMM best of 5 {hl_gmm:.6}; \
         phasekit Gaussian HMM {ll_gauss:.6}, hmmlearn GaussianHMM best of 5 {hl_gauss:.6}"
    );
    assert!(
        ll_gmm >= hl_gmm - 1e-6,
        "phasekit {ll_gmm} below hmmlearn's best {hl_gmm}"
    );
    assert!(
        ll_gmm > ll_gauss + 0.5,
        "GMM-HMM {ll_gmm} not clearly above one Gaussian per state {ll_gauss}"
    );
    assert!(
        ll_gauss >= hl_gauss - 1e-6,
        "phasekit Gaussian {ll_gauss} below hmmlearn's {hl_gauss}"
    );
}
