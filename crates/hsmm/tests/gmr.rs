//! HSMM-GMR: the online filter's state marginals drive the existing GMR
//! mixing ([`Regression::mix_into`]) and predict the robot's hand frame by
//! frame from the human's, on generated handshake interactions.
//!
//! The online prediction equals, to the bit, the batch prediction from the
//! forward variable of the human-marginal HSMM; it beats the constant mean
//! pose by far, and is compared with HMM-GMR on the same data.

use phasekit_emission::{CovarianceType, Frames, Gaussian, Regularisation, SequenceSet, Shape};
use phasekit_gmr::{HmmRegression, Regression};
use phasekit_hmm::{BaumWelch, Convergence, HmmInit};
use phasekit_hsmm::{
    AnyDuration, Censoring, DurationRegularisation, HsmmEm, HsmmFilter, HsmmInit,
    NonParametricDuration, Structure,
};
use phasekit_tsc::synthetic::generate;

const HUMAN: [usize; 3] = [0, 1, 2];
const ROBOT: [usize; 3] = [3, 4, 5];

#[test]
fn hsmm_gmr_predicts_the_robot_frame_by_frame() {
    let train = generate(12, 21);
    let test = generate(4, 22);
    let demos: Vec<&[f64]> = train.iter().map(|i| &i.frames[..]).collect();
    let data = SequenceSet::new(&demos, 6).unwrap();
    let reg = Regularisation::add_diagonal(1e-5).unwrap();
    let n_states = 5;
    let fit = HsmmEm::builder()
        .structure(Structure::LeftRight { skip: 0 })
        .censoring(Censoring::EndsWithSegment)
        .init(HsmmInit::KBins { smoothing: 0.01 })
        .max_iter(30)
        .tol(1e-4)
        .convergence(Convergence::MeanPerSequence)
        .regularisation(reg)
        .duration_regularisation(
            DurationRegularisation::none()
                .with_pseudo_count(1e-3)
                .unwrap(),
        )
        .build()
        .unwrap()
        .fit(
            &Gaussian::standard(CovarianceType::Full, Shape { n_states, dim: 6 }).unwrap(),
            &AnyDuration::from(NonParametricDuration::uniform(n_states, 90).unwrap()),
            &data,
        )
        .unwrap();
    let model = fit.model;
    let regression = Regression::new(model.emission(), &HUMAN, &ROBOT).unwrap();
    let human_model = model.marginal(&HUMAN).unwrap();

    // An HMM-GMR with the same states, for comparison.
    let hmm = BaumWelch::builder()
        .max_iter(30)
        .tol(1e-4)
        .convergence(Convergence::MeanPerSequence)
        .regularisation(reg)
        .init(HmmInit::KBins { smoothing: 0.01 })
        .build()
        .unwrap()
        .fit(
            &Gaussian::standard(CovarianceType::Full, Shape { n_states, dim: 6 }).unwrap(),
            &data,
        )
        .unwrap()
        .model;
    let hmm_gmr = HmmRegression::new(&hmm, &HUMAN, &ROBOT).unwrap();

    let (mut se_hsmm, mut se_hmm, mut se_const, mut n) = (0.0, 0.0, 0.0, 0usize);
    let robot_mean: Vec<f64> = (0..3)
        .map(|k| {
            let v: Vec<f64> = train
                .iter()
                .flat_map(|i| i.frames.chunks(6).map(move |f| f[3 + k]))
                .collect();
            v.iter().sum::<f64>() / v.len() as f64
        })
        .collect();
    for demo in &test {
        let human: Vec<f64> = demo
            .frames
            .chunks(6)
            .flat_map(|f| f[..3].to_vec())
            .collect();
        let human_frames = Frames::new(&human, 3).unwrap();
        // Batch: the forward variable of the human-marginal HSMM, mixed per frame.
        let forward = human_model.forward(human_frames).unwrap();
        let mut online = HsmmFilter::on_dims(&model, &HUMAN).unwrap();
        let (mut mean_b, mut mean_o) = (vec![0.0; 3], vec![0.0; 3]);
        let (mut cov_b, mut cov_o) = (vec![0.0; 9], vec![0.0; 9]);
        let mut scratch = vec![0.0; n_states * 3];
        let hmm_pred = hmm_gmr.predict(human_frames, false).unwrap();
        for (t, frame) in demo.frames.chunks(6).enumerate() {
            let x = &frame[..3];
            let h_batch = &forward.filtered()[t * n_states..(t + 1) * n_states];
            regression
                .mix_into(x, h_batch, &mut mean_b, Some(&mut cov_b), &mut scratch)
                .unwrap();
            let h = online.step(x).unwrap().to_vec();
            regression
                .mix_into(x, &h, &mut mean_o, Some(&mut cov_o), &mut scratch)
                .unwrap();
            assert_eq!(h, h_batch, "frame {t}: online marginals");
            assert_eq!(mean_o, mean_b, "frame {t}: online prediction");
            assert_eq!(cov_o, cov_b, "frame {t}: online covariance");
            for k in 0..3 {
                let truth = frame[3 + k];
                se_hsmm += (mean_o[k] - truth).powi(2);
                se_hmm += (hmm_pred.mean[t * 3 + k] - truth).powi(2);
                se_const += (robot_mean[k] - truth).powi(2);
            }
            n += 1;
        }
    }
    let cm2 = |se: f64| 1e4 * se / n as f64;
    let (mse_hsmm, mse_hmm, mse_const) = (cm2(se_hsmm), cm2(se_hmm), cm2(se_const));
    println!(
        "robot hand MSE (cm² per coordinate): HSMM-GMR {mse_hsmm:.3}, HMM-GMR {mse_hmm:.3}, constant mean {mse_const:.3}"
    );
    assert!(
        mse_hsmm < 0.2 * mse_const,
        "{mse_hsmm} vs constant {mse_const}"
    );
    assert!(mse_hsmm < 1.5 * mse_hmm, "{mse_hsmm} vs HMM-GMR {mse_hmm}");
}
