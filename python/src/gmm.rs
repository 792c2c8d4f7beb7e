//! The Gaussian mixture: every call into `phasekit::gmm` that
//! `phasekit.mixture.GaussianMixture` makes.

use crate::arrays::{array1, array2, frames_of, matrix, pool, value_error, Sequences};
use crate::hmm::{covariance_type, flat};
use crate::stats::{GmmStats, Statistics};
use numpy::{PyArray1, PyArray2, PyReadonlyArray2, PyReadonlyArrayDyn};
use phasekit::emission::{Emission, Gaussian, Shape};
use phasekit::gmm::Gmm;
use pyo3::prelude::*;

/// A compiled Gaussian mixture: densities, responsibilities and the E-step of EM.
#[pyclass(module = "phasekit._core", frozen)]
pub struct GmmCore {
    pub model: Gmm<Gaussian>,
}

#[pymethods]
impl GmmCore {
    /// `weights` `(K,)`, `means` `(K, D)`, `covars` in phasekit's native shape
    /// for `covariance_type` (full `K·D·D`, diag `K·D`, spherical `K`, tied `D·D`).
    #[new]
    fn new(
        weights: PyReadonlyArrayDyn<'_, f64>,
        means: PyReadonlyArrayDyn<'_, f64>,
        covars: PyReadonlyArrayDyn<'_, f64>,
        covariance_type_: &str,
        n_features: usize,
    ) -> PyResult<Self> {
        let kind = covariance_type(covariance_type_)?;
        let components = Gaussian::new(
            kind,
            n_features,
            flat(&means, "means")?,
            flat(&covars, "covariances")?,
        )
        .map_err(value_error)?;
        let model = Gmm::new(flat(&weights, "weights")?, components).map_err(value_error)?;
        Ok(GmmCore { model })
    }

    /// Number of components.
    #[getter]
    fn n_components(&self) -> usize {
        self.model.n_components()
    }

    /// `log c_k(x_t)` (without the weights), `(n_frames, K)`.
    fn log_density<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (data, t, d) = matrix(&x, "X")?;
        let out = py.allow_threads(|| {
            let frames = frames_of(data, d, 0)?;
            self.model.check_frames(frames).map_err(value_error)?;
            self.model
                .components()
                .log_density(frames)
                .map_err(value_error)
        })?;
        array2(py, out, t, self.model.n_components())
    }

    /// `log p(x_t)` of every frame, `(n_frames,)`.
    fn score_samples<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let (data, _, d) = matrix(&x, "X")?;
        let out = py.allow_threads(|| {
            let frames = frames_of(data, d, 0)?;
            self.model.score_samples(frames).map_err(value_error)
        })?;
        Ok(array1(py, out))
    }

    /// Responsibilities `r_tk`, `(n_frames, K)`.
    fn responsibilities<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (data, t, d) = matrix(&x, "X")?;
        let out = py.allow_threads(|| {
            let frames = frames_of(data, d, 0)?;
            self.model.responsibilities(frames).map_err(value_error)
        })?;
        array2(py, out, t, self.model.n_components())
    }

    /// The E-step of EM over all frames of `data` on `n_threads` threads
    /// (bit-identical for any count).
    #[pyo3(signature = (data, n_threads=1))]
    fn expected_statistics(
        &self,
        py: Python<'_>,
        data: &Sequences,
        n_threads: usize,
    ) -> PyResult<Statistics> {
        let pool = pool(n_threads)?;
        let frames = data.set.all_frames();
        let stats = py
            .allow_threads(|| {
                pool.install(|| {
                    self.model.check_frames(frames)?;
                    self.model.expected_statistics(frames)
                })
            })
            .map_err(value_error)?;
        Ok(Statistics::gmm(GmmStats::from(stats)))
    }

    /// Statistics of the frames `x` weighted by fixed responsibilities `resp`
    /// `(T, K)` (an initialisation's M-step input); `log_likelihood` is NaN.
    #[staticmethod]
    fn weighted_statistics(
        py: Python<'_>,
        x: PyReadonlyArray2<'_, f64>,
        resp: PyReadonlyArray2<'_, f64>,
        covariance_type_: &str,
    ) -> PyResult<Statistics> {
        let kind = covariance_type(covariance_type_)?;
        let (data, t, d) = matrix(&x, "X")?;
        let (w, tw, k) = matrix(&resp, "resp")?;
        if tw != t || k == 0 {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "resp has shape ({tw}, {k}), X has {t} frames"
            )));
        }
        let stats = py.allow_threads(|| {
            let frames = frames_of(data, d, 0)?;
            let template = Gaussian::standard(
                kind,
                Shape {
                    n_states: k,
                    dim: d,
                },
            )
            .map_err(value_error)?;
            let mut stats = template.new_stats();
            template
                .accumulate(frames, w, &mut stats)
                .map_err(value_error)?;
            let mut counts = vec![0.0; k];
            for row in w.chunks_exact(k) {
                for (c, v) in counts.iter_mut().zip(row) {
                    *c += v;
                }
            }
            PyResult::Ok(GmmStats::new(f64::NAN, counts, stats, t))
        })?;
        Ok(Statistics::gmm(stats))
    }

    fn __repr__(&self) -> String {
        format!(
            "GmmCore({} components of dimension {})",
            self.model.n_components(),
            self.model.dim()
        )
    }
}

/// k-means (k-means++ seeding, Lloyd iterations) on the frames of `x`, best
/// inertia of `n_init` runs seeded `seed, seed + 1, …`: `(centroids (k, D),
/// labels (T,), inertia)`. The initialisation of the Python estimators' means.
#[pyfunction]
#[pyo3(signature = (x, k, seed, n_init=10, max_iter=300))]
#[allow(clippy::type_complexity)]
pub fn kmeans<'py>(
    py: Python<'py>,
    x: PyReadonlyArray2<'py, f64>,
    k: usize,
    seed: u64,
    n_init: usize,
    max_iter: usize,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<i64>>, f64)> {
    use phasekit::emission::kmeans::{kmeans, Seeding};
    use rand::SeedableRng;
    let (data, _, d) = matrix(&x, "X")?;
    if n_init == 0 {
        return Err(pyo3::exceptions::PyValueError::new_err(
            "n_init must be at least 1",
        ));
    }
    let best = py.allow_threads(|| {
        let frames = frames_of(data, d, 0)?;
        let mut best: Option<phasekit::emission::kmeans::KMeans> = None;
        for r in 0..n_init {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed.wrapping_add(r as u64));
            let km =
                kmeans(frames, k, Seeding::PlusPlus, max_iter, &mut rng).map_err(value_error)?;
            if best.as_ref().is_none_or(|b| km.inertia < b.inertia) {
                best = Some(km);
            }
        }
        PyResult::Ok(best.expect("n_init >= 1"))
    })?;
    let labels = best.labels.iter().map(|&l| l as i64).collect();
    Ok((
        array2(py, best.centroids, k, d)?,
        array1(py, labels),
        best.inertia,
    ))
}
