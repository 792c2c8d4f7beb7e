//! The HMMs: every call into `phasekit::hmm` and the emissions the Python
//! estimators use (GaussianHMM, GMMHMM, CategoricalHMM, PoissonHMM).
//!
//! A model is rebuilt from the estimator's NumPy attributes for each call
//! (phasekit validates it then: probabilities, symmetric positive definite
//! covariances); building one costs a Cholesky factor per state, nothing next
//! to a pass over the data.

use crate::arrays::{
    array1, array2, frames_of, matrix, pool, sequence_lengths, split, value_error, Sequences,
};
use crate::stats::{HmmStats, Statistics};
use numpy::{PyArray1, PyArray2, PyReadonlyArray2, PyReadonlyArrayDyn};
use phasekit::emission::{Categorical, CovarianceType, Gaussian, MixtureEmission, Poisson};
use phasekit::hmm::Hmm;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// An HMM over one of the emissions the Python package exposes.
#[derive(Debug, Clone)]
pub enum AnyHmm {
    /// hmmlearn's GaussianHMM.
    Gaussian(Hmm<Gaussian>),
    /// hmmlearn's CategoricalHMM.
    Categorical(Hmm<Categorical>),
    /// hmmlearn's PoissonHMM.
    Poisson(Hmm<Poisson>),
    /// hmmlearn's GMMHMM.
    Mixture(Hmm<MixtureEmission<Gaussian>>),
}

/// Runs `$body` with `$h` bound to the concrete `Hmm<E>`.
macro_rules! dispatch {
    ($model:expr, $h:ident => $body:expr) => {
        match $model {
            AnyHmm::Gaussian($h) => $body,
            AnyHmm::Categorical($h) => $body,
            AnyHmm::Poisson($h) => $body,
            AnyHmm::Mixture($h) => $body,
        }
    };
}

/// The values of a C-contiguous float64 array (any shape), copied.
pub fn flat(a: &PyReadonlyArrayDyn<'_, f64>, name: &str) -> PyResult<Vec<f64>> {
    Ok(a.as_slice()
        .map_err(|_| PyValueError::new_err(format!("{name} must be C-contiguous float64")))?
        .to_vec())
}

/// hmmlearn's / scikit-learn's name of a covariance structure.
pub fn covariance_type(name: &str) -> PyResult<CovarianceType> {
    Ok(match name {
        "full" => CovarianceType::Full,
        "diag" => CovarianceType::Diagonal,
        "spherical" => CovarianceType::Spherical,
        "tied" => CovarianceType::Tied,
        other => {
            return Err(PyValueError::new_err(format!(
                "covariance_type must be one of 'spherical', 'diag', 'full', 'tied', not {other:?}"
            )))
        }
    })
}

/// A compiled HMM: scoring, decoding and the E-step of Baum-Welch.
#[pyclass(module = "phasekit._core", frozen)]
pub struct HmmCore {
    pub model: AnyHmm,
}

#[pymethods]
impl HmmCore {
    /// Gaussian states; `covars` in phasekit's native shape for `covariance_type`
    /// (full `S·D·D`, diag `S·D`, spherical `S`, tied `D·D`), flattened.
    #[staticmethod]
    fn gaussian(
        startprob: PyReadonlyArrayDyn<'_, f64>,
        transmat: PyReadonlyArrayDyn<'_, f64>,
        means: PyReadonlyArrayDyn<'_, f64>,
        covars: PyReadonlyArrayDyn<'_, f64>,
        covariance_type_: &str,
        n_features: usize,
    ) -> PyResult<Self> {
        let kind = covariance_type(covariance_type_)?;
        let emission = Gaussian::new(
            kind,
            n_features,
            flat(&means, "means")?,
            flat(&covars, "covars")?,
        )
        .map_err(value_error)?;
        let hmm = Hmm::new(
            flat(&startprob, "startprob")?,
            flat(&transmat, "transmat")?,
            emission,
        )
        .map_err(value_error)?;
        Ok(HmmCore {
            model: AnyHmm::Gaussian(hmm),
        })
    }

    /// Categorical states over `n_features` symbols.
    #[staticmethod]
    fn categorical(
        startprob: PyReadonlyArrayDyn<'_, f64>,
        transmat: PyReadonlyArrayDyn<'_, f64>,
        emissionprob: PyReadonlyArrayDyn<'_, f64>,
        n_features: usize,
    ) -> PyResult<Self> {
        let emission = Categorical::new(n_features, flat(&emissionprob, "emissionprob")?)
            .map_err(value_error)?;
        let hmm = Hmm::new(
            flat(&startprob, "startprob")?,
            flat(&transmat, "transmat")?,
            emission,
        )
        .map_err(value_error)?;
        Ok(HmmCore {
            model: AnyHmm::Categorical(hmm),
        })
    }

    /// Independent Poisson counts per feature.
    #[staticmethod]
    fn poisson(
        startprob: PyReadonlyArrayDyn<'_, f64>,
        transmat: PyReadonlyArrayDyn<'_, f64>,
        lambdas: PyReadonlyArrayDyn<'_, f64>,
        n_features: usize,
    ) -> PyResult<Self> {
        let emission = Poisson::new(n_features, flat(&lambdas, "lambdas")?).map_err(value_error)?;
        let hmm = Hmm::new(
            flat(&startprob, "startprob")?,
            flat(&transmat, "transmat")?,
            emission,
        )
        .map_err(value_error)?;
        Ok(HmmCore {
            model: AnyHmm::Poisson(hmm),
        })
    }

    /// A Gaussian mixture of `n_mix` components per state: `weights` `S·M`,
    /// `means` `S·M·D`, `covars` per state in the native shape of
    /// `covariance_type` for `M` components (tied: one `D·D` per state).
    #[staticmethod]
    #[allow(clippy::too_many_arguments)]
    fn gaussian_mixture(
        startprob: PyReadonlyArrayDyn<'_, f64>,
        transmat: PyReadonlyArrayDyn<'_, f64>,
        weights: PyReadonlyArrayDyn<'_, f64>,
        means: PyReadonlyArrayDyn<'_, f64>,
        covars: PyReadonlyArrayDyn<'_, f64>,
        covariance_type_: &str,
        n_mix: usize,
        n_features: usize,
    ) -> PyResult<Self> {
        let kind = covariance_type(covariance_type_)?;
        let start = flat(&startprob, "startprob")?;
        let s = start.len();
        let (means, covars) = (flat(&means, "means")?, flat(&covars, "covars")?);
        let (m, d) = (n_mix, n_features);
        let per_cov = kind.raw_len(m, d);
        if s == 0 || means.len() != s * m * d || covars.len() != s * per_cov {
            return Err(PyValueError::new_err(format!(
                "GMMHMM parameters: {s} states × {m} components × {d} features need {} means and {} covariance values, got {} and {}",
                s * m * d,
                s * per_cov,
                means.len(),
                covars.len()
            )));
        }
        let components = (0..s)
            .map(|i| {
                Gaussian::new(
                    kind,
                    d,
                    means[i * m * d..(i + 1) * m * d].to_vec(),
                    covars[i * per_cov..(i + 1) * per_cov].to_vec(),
                )
                .map_err(|e| {
                    value_error(format!(
                        "state {i}: {}",
                        e.to_string().replacen("state ", "component ", 1)
                    ))
                })
            })
            .collect::<PyResult<Vec<_>>>()?;
        let emission =
            MixtureEmission::new(flat(&weights, "weights")?, components).map_err(value_error)?;
        let hmm = Hmm::new(start, flat(&transmat, "transmat")?, emission).map_err(value_error)?;
        Ok(HmmCore {
            model: AnyHmm::Mixture(hmm),
        })
    }

    /// Number of states.
    #[getter]
    fn n_states(&self) -> usize {
        dispatch!(&self.model, h => h.n_states())
    }

    /// `log b_i(x_t)`, `(n_frames, n_states)`.
    fn log_density<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (data, t, d) = matrix(&x, "X")?;
        let s = self.n_states();
        let out = py.allow_threads(|| {
            let frames = frames_of(data, d, 0)?;
            dispatch!(&self.model, h => h.emission_log_densities(frames)).map_err(value_error)
        })?;
        array2(py, out, t, s)
    }

    /// `Σ_k log p(x^k)` over the sequences of `x` split by `lengths`.
    #[pyo3(signature = (x, lengths=None))]
    fn score(
        &self,
        py: Python<'_>,
        x: PyReadonlyArray2<'_, f64>,
        lengths: Option<Vec<usize>>,
    ) -> PyResult<f64> {
        let (data, t, d) = matrix(&x, "X")?;
        let lengths = sequence_lengths(lengths, t)?;
        py.allow_threads(|| {
            let mut total = 0.0;
            for (k, seq) in split(data, d, &lengths).into_iter().enumerate() {
                let frames = frames_of(seq, d, k)?;
                total += dispatch!(&self.model, h => h.log_likelihood(frames))
                    .map_err(|e| value_error(e.in_sequence(k)))?;
            }
            Ok(total)
        })
    }

    /// `(Σ_k log p(x^k), γ)` with the state posteriors `γ`, `(n_frames, n_states)`.
    #[pyo3(signature = (x, lengths=None))]
    fn posteriors<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArray2<'py, f64>,
        lengths: Option<Vec<usize>>,
    ) -> PyResult<(f64, Bound<'py, PyArray2<f64>>)> {
        let (data, t, d) = matrix(&x, "X")?;
        let lengths = sequence_lengths(lengths, t)?;
        let s = self.n_states();
        let (ll, gamma) = py.allow_threads(|| {
            let mut total = 0.0;
            let mut gamma = Vec::with_capacity(t * s);
            for (k, seq) in split(data, d, &lengths).into_iter().enumerate() {
                let frames = frames_of(seq, d, k)?;
                let p = dispatch!(&self.model, h => h.posteriors(frames))
                    .map_err(|e| value_error(e.in_sequence(k)))?;
                total += p.log_likelihood;
                gamma.extend_from_slice(&p.gamma);
            }
            PyResult::Ok((total, gamma))
        })?;
        Ok((ll, array2(py, gamma, t, s)?))
    }

    /// `(Σ_k max_z log p(z, x^k), path)`: the Viterbi path of every sequence, concatenated.
    #[pyo3(signature = (x, lengths=None))]
    fn viterbi<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArray2<'py, f64>,
        lengths: Option<Vec<usize>>,
    ) -> PyResult<(f64, Bound<'py, PyArray1<i64>>)> {
        let (data, t, d) = matrix(&x, "X")?;
        let lengths = sequence_lengths(lengths, t)?;
        let (lp, path) = py.allow_threads(|| {
            let mut total = 0.0;
            let mut path = Vec::with_capacity(t);
            for (k, seq) in split(data, d, &lengths).into_iter().enumerate() {
                let frames = frames_of(seq, d, k)?;
                let v = dispatch!(&self.model, h => h.viterbi(frames))
                    .map_err(|e| value_error(e.in_sequence(k)))?;
                total += v.log_probability;
                path.extend(v.states.iter().map(|&z| z as i64));
            }
            PyResult::Ok((total, path))
        })?;
        Ok((lp, array1(py, path)))
    }

    /// The E-step of Baum-Welch over `data` on `n_threads` threads
    /// (bit-identical for any count): mergeable expected statistics.
    #[pyo3(signature = (data, n_threads=1))]
    fn expected_statistics(
        &self,
        py: Python<'_>,
        data: &Sequences,
        n_threads: usize,
    ) -> PyResult<Statistics> {
        let pool = pool(n_threads)?;
        let set = &data.set;
        let stats = py
            .allow_threads(|| {
                pool.install(|| -> Result<HmmStats, phasekit::hmm::HmmError> {
                    Ok(match &self.model {
                        AnyHmm::Gaussian(h) => {
                            h.check_sequences(set)?;
                            HmmStats::Gaussian(h.expected_statistics(set)?.into())
                        }
                        AnyHmm::Categorical(h) => {
                            h.check_sequences(set)?;
                            HmmStats::Categorical(h.expected_statistics(set)?.into())
                        }
                        AnyHmm::Poisson(h) => {
                            h.check_sequences(set)?;
                            HmmStats::Poisson(h.expected_statistics(set)?.into())
                        }
                        AnyHmm::Mixture(h) => {
                            h.check_sequences(set)?;
                            HmmStats::Mixture(h.expected_statistics(set)?.into())
                        }
                    })
                })
            })
            .map_err(value_error)?;
        Ok(Statistics::hmm(stats))
    }

    fn __repr__(&self) -> String {
        let kind = match &self.model {
            AnyHmm::Gaussian(_) => "Gaussian",
            AnyHmm::Categorical(_) => "categorical",
            AnyHmm::Poisson(_) => "Poisson",
            AnyHmm::Mixture(_) => "Gaussian-mixture",
        };
        format!("HmmCore({} states, {kind} emissions)", self.n_states())
    }
}
