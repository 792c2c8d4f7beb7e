//! Mergeable E-step statistics: phasekit's `ExpectedStatistics` (HMMs) and
//! `MixtureStatistics` (the mixture), their merge in a fixed order, a compact
//! binary form for shipping them between processes (Dask workers), and their
//! moments as NumPy arrays for the M-steps the Python estimators run with
//! hmmlearn's and scikit-learn's formulas.

use crate::arrays::{array1, array2, array_dyn, runtime_error, value_error};
use numpy::ndarray::Array1;
use numpy::IntoPyArray;
use phasekit::emission::{
    CategoricalStats, CovarianceType, GaussianStats, MixtureEmissionStats, PoissonStats,
    SufficientStatistics,
};
use phasekit::gmm::MixtureStatistics;
use phasekit::hmm::ExpectedStatistics;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// [`ExpectedStatistics`] in a serialisable form (same fields).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Exp<S> {
    log_likelihood: f64,
    start: Vec<f64>,
    transitions: Vec<f64>,
    emission: S,
    n_sequences: usize,
    n_frames: usize,
}

impl<S> From<ExpectedStatistics<S>> for Exp<S> {
    fn from(e: ExpectedStatistics<S>) -> Self {
        Exp {
            log_likelihood: e.log_likelihood,
            start: e.start,
            transitions: e.transitions,
            emission: e.emission,
            n_sequences: e.n_sequences,
            n_frames: e.n_frames,
        }
    }
}

impl<S> From<Exp<S>> for ExpectedStatistics<S> {
    fn from(e: Exp<S>) -> Self {
        ExpectedStatistics {
            log_likelihood: e.log_likelihood,
            start: e.start,
            transitions: e.transitions,
            emission: e.emission,
            n_sequences: e.n_sequences,
            n_frames: e.n_frames,
        }
    }
}

/// `a + b` by phasekit's [`ExpectedStatistics::merge`] (shape-checked).
fn merge_exp<S: SufficientStatistics>(a: &Exp<S>, b: &Exp<S>) -> PyResult<Exp<S>> {
    let mut total: ExpectedStatistics<S> = a.clone().into();
    total.merge(&b.clone().into()).map_err(value_error)?;
    Ok(total.into())
}

/// E-step statistics of one of the HMMs.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub enum HmmStats {
    /// GaussianHMM.
    Gaussian(Exp<GaussianStats>),
    /// CategoricalHMM.
    Categorical(Exp<CategoricalStats>),
    /// PoissonHMM.
    Poisson(Exp<PoissonStats>),
    /// GMMHMM.
    Mixture(Exp<MixtureEmissionStats<GaussianStats>>),
}

/// [`MixtureStatistics`] in a serialisable form.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GmmStats {
    log_likelihood: f64,
    counts: Vec<f64>,
    components: GaussianStats,
    n_frames: usize,
}

impl GmmStats {
    /// Statistics with these parts.
    pub fn new(
        log_likelihood: f64,
        counts: Vec<f64>,
        components: GaussianStats,
        n_frames: usize,
    ) -> Self {
        GmmStats {
            log_likelihood,
            counts,
            components,
            n_frames,
        }
    }
}

impl From<MixtureStatistics<GaussianStats>> for GmmStats {
    fn from(m: MixtureStatistics<GaussianStats>) -> Self {
        GmmStats {
            log_likelihood: m.log_likelihood,
            counts: m.counts,
            components: m.components,
            n_frames: m.n_frames,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
enum Inner {
    Hmm(HmmStats),
    Gmm(GmmStats),
}

/// Statistics of an E-step over some of the data: merge those of disjoint
/// parts (in a fixed order for results independent of the partitioning),
/// pickle them (a compact binary form), read their moments as arrays.
#[pyclass(module = "phasekit._core", frozen)]
pub struct Statistics {
    inner: Inner,
}

/// Magic bytes and format version of the binary form.
const MAGIC: &[u8; 4] = b"PKS1";

impl Statistics {
    /// Wraps HMM statistics.
    pub fn hmm(s: HmmStats) -> Self {
        Statistics {
            inner: Inner::Hmm(s),
        }
    }

    /// Wraps mixture statistics.
    pub fn gmm(s: GmmStats) -> Self {
        Statistics {
            inner: Inner::Gmm(s),
        }
    }

    fn merged(&self, other: &Statistics) -> PyResult<Statistics> {
        let mismatch = || PyValueError::new_err("cannot merge statistics of different model kinds");
        let inner = match (&self.inner, &other.inner) {
            (Inner::Hmm(a), Inner::Hmm(b)) => Inner::Hmm(match (a, b) {
                (HmmStats::Gaussian(a), HmmStats::Gaussian(b)) => {
                    HmmStats::Gaussian(merge_exp(a, b)?)
                }
                (HmmStats::Categorical(a), HmmStats::Categorical(b)) => {
                    HmmStats::Categorical(merge_exp(a, b)?)
                }
                (HmmStats::Poisson(a), HmmStats::Poisson(b)) => HmmStats::Poisson(merge_exp(a, b)?),
                (HmmStats::Mixture(a), HmmStats::Mixture(b)) => HmmStats::Mixture(merge_exp(a, b)?),
                _ => return Err(mismatch()),
            }),
            (Inner::Gmm(a), Inner::Gmm(b)) => {
                if a.counts.len() != b.counts.len() {
                    return Err(PyValueError::new_err(format!(
                        "cannot merge statistics of mixtures with {} and {} components",
                        a.counts.len(),
                        b.counts.len()
                    )));
                }
                let mut components = a.components.clone();
                components.merge(&b.components).map_err(value_error)?;
                Inner::Gmm(GmmStats {
                    log_likelihood: a.log_likelihood + b.log_likelihood,
                    counts: a.counts.iter().zip(&b.counts).map(|(x, y)| x + y).collect(),
                    components,
                    n_frames: a.n_frames + b.n_frames,
                })
            }
            _ => return Err(mismatch()),
        };
        Ok(Statistics { inner })
    }

    fn to_bytes_vec(&self) -> PyResult<Vec<u8>> {
        let version = env!("CARGO_PKG_VERSION").as_bytes();
        let mut out = Vec::with_capacity(64);
        out.extend_from_slice(MAGIC);
        out.push(version.len() as u8);
        out.extend_from_slice(version);
        bincode::serialize_into(&mut out, &self.inner).map_err(runtime_error)?;
        Ok(out)
    }
}

/// Field-by-field view of phasekit's Gaussian statistics (read through their
/// serde form, the public, versioned face of the type): per state `i`, the
/// weight `n_i = Σ γ`, the reference point `c_i`, `s_i = Σ γ (x − c_i)` and
/// `Q_i = Σ γ (x − c_i)(x − c_i)ᵀ` (lower triangle; the diagonal for
/// diagonal and spherical structures).
#[derive(Deserialize)]
struct GaussianView {
    kind: CovarianceType,
    dim: usize,
    shift: Vec<f64>,
    weight: Vec<f64>,
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
}

#[derive(Deserialize)]
struct MixtureView {
    weight: Vec<f64>,
    inner: Vec<GaussianView>,
}

#[derive(Deserialize)]
struct CategoricalView {
    n_symbols: usize,
    counts: Vec<f64>,
}

#[derive(Deserialize)]
struct PoissonView {
    dim: usize,
    weight: Vec<f64>,
    sum: Vec<f64>,
}

/// Reads statistics through their serde form into a view.
fn view<T: Serialize, V: DeserializeOwned>(stats: &T, what: &str) -> PyResult<V> {
    serde_json::to_value(stats)
        .and_then(serde_json::from_value)
        .map_err(|e| {
            runtime_error(format!(
                "cannot read phasekit's {what} statistics (their fields changed?): {e}"
            ))
        })
}

impl GaussianView {
    fn full(&self) -> bool {
        matches!(self.kind, CovarianceType::Full | CovarianceType::Tied)
    }

    /// `Q` of every state as full symmetric `D × D` matrices (full/tied) or diagonals.
    fn sum_sq_filled(&self) -> Vec<f64> {
        let d = self.dim;
        if !self.full() {
            return self.sum_sq.clone();
        }
        let mut q = self.sum_sq.clone();
        for m in q.chunks_exact_mut(d * d) {
            for r in 0..d {
                for c in 0..r {
                    m[c * d + r] = m[r * d + c];
                }
            }
        }
        q
    }
}

fn put_common(d: &Bound<'_, PyDict>, ll: f64, n_frames: usize, n_sequences: usize) -> PyResult<()> {
    d.set_item("log_likelihood", ll)?;
    d.set_item("n_frames", n_frames)?;
    d.set_item("n_sequences", n_sequences)?;
    Ok(())
}

fn put_chain<S>(py: Python<'_>, d: &Bound<'_, PyDict>, e: &Exp<S>) -> PyResult<()> {
    let s = e.start.len();
    put_common(d, e.log_likelihood, e.n_frames, e.n_sequences)?;
    d.set_item("start", array1(py, e.start.clone()))?;
    d.set_item("trans", array2(py, e.transitions.clone(), s, s)?)?;
    Ok(())
}

/// `post`, `shift`, `sum`, `sum_sq` of Gaussian statistics, with leading shape `lead`.
fn put_gaussian(
    py: Python<'_>,
    d: &Bound<'_, PyDict>,
    views: &[GaussianView],
    lead: &[usize],
) -> PyResult<()> {
    let dim = views.first().map_or(0, |v| v.dim);
    let full = views.first().is_some_and(|v| v.full());
    let cat =
        |f: &dyn Fn(&GaussianView) -> Vec<f64>| views.iter().flat_map(f).collect::<Vec<f64>>();
    let with = |tail: &[usize]| [lead, tail].concat();
    d.set_item("post", array_dyn(py, cat(&|v| v.weight.clone()), lead)?)?;
    d.set_item(
        "shift",
        array_dyn(py, cat(&|v| v.shift.clone()), &with(&[dim]))?,
    )?;
    d.set_item(
        "sum",
        array_dyn(py, cat(&|v| v.sum.clone()), &with(&[dim]))?,
    )?;
    let sq_shape = if full {
        with(&[dim, dim])
    } else {
        with(&[dim])
    };
    d.set_item(
        "sum_sq",
        array_dyn(py, cat(&|v| v.sum_sq_filled()), &sq_shape)?,
    )?;
    Ok(())
}

#[pymethods]
impl Statistics {
    /// `Σ log p` of the data the statistics were gathered on.
    #[getter]
    fn log_likelihood(&self) -> f64 {
        match &self.inner {
            Inner::Hmm(HmmStats::Gaussian(e)) => e.log_likelihood,
            Inner::Hmm(HmmStats::Categorical(e)) => e.log_likelihood,
            Inner::Hmm(HmmStats::Poisson(e)) => e.log_likelihood,
            Inner::Hmm(HmmStats::Mixture(e)) => e.log_likelihood,
            Inner::Gmm(g) => g.log_likelihood,
        }
    }

    /// Number of frames.
    #[getter]
    fn n_frames(&self) -> usize {
        match &self.inner {
            Inner::Hmm(HmmStats::Gaussian(e)) => e.n_frames,
            Inner::Hmm(HmmStats::Categorical(e)) => e.n_frames,
            Inner::Hmm(HmmStats::Poisson(e)) => e.n_frames,
            Inner::Hmm(HmmStats::Mixture(e)) => e.n_frames,
            Inner::Gmm(g) => g.n_frames,
        }
    }

    /// Number of sequences (1 per call for a mixture).
    #[getter]
    fn n_sequences(&self) -> usize {
        match &self.inner {
            Inner::Hmm(HmmStats::Gaussian(e)) => e.n_sequences,
            Inner::Hmm(HmmStats::Categorical(e)) => e.n_sequences,
            Inner::Hmm(HmmStats::Poisson(e)) => e.n_sequences,
            Inner::Hmm(HmmStats::Mixture(e)) => e.n_sequences,
            Inner::Gmm(_) => 1,
        }
    }

    /// The statistics of both parts' data: `self + other`.
    fn merge(&self, other: &Statistics) -> PyResult<Statistics> {
        self.merged(other)
    }

    /// The merge of `parts` in list order (phasekit's merges are exact
    /// re-centrings and additions: the order only moves the last bits, and a
    /// fixed order makes the result reproducible).
    #[staticmethod]
    fn merge_all(parts: Vec<PyRef<'_, Statistics>>) -> PyResult<Statistics> {
        let mut iter = parts.iter();
        let first = iter
            .next()
            .ok_or_else(|| PyValueError::new_err("merge_all: no statistics given"))?;
        let mut total = Statistics {
            inner: first.inner.clone(),
        };
        for p in iter {
            total = total.merged(p)?;
        }
        Ok(total)
    }

    /// The compact binary form (`PKS1`, the phasekit version, bincode of the statistics).
    fn to_bytes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        Ok(PyBytes::new(py, &self.to_bytes_vec()?))
    }

    /// Reads [`Statistics::to_bytes`]; refuses another format or phasekit version.
    #[staticmethod]
    fn from_bytes(data: &[u8]) -> PyResult<Statistics> {
        let bad = |why: &str| PyValueError::new_err(format!("not phasekit statistics: {why}"));
        if data.len() < 5 || &data[..4] != MAGIC {
            return Err(bad("wrong header"));
        }
        let n = data[4] as usize;
        let version = data.get(5..5 + n).ok_or_else(|| bad("truncated"))?;
        if version != env!("CARGO_PKG_VERSION").as_bytes() {
            return Err(PyValueError::new_err(format!(
                "statistics written by phasekit {} cannot be read by phasekit {} (every Dask worker must run the same phasekit)",
                String::from_utf8_lossy(version),
                env!("CARGO_PKG_VERSION")
            )));
        }
        let inner: Inner = bincode::deserialize(&data[5 + n..]).map_err(|e| bad(&e.to_string()))?;
        Ok(Statistics { inner })
    }

    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
    ) -> PyResult<(Bound<'py, PyAny>, (Bound<'py, PyBytes>,))> {
        let py = slf.py();
        let ctor = py.get_type::<Statistics>().getattr("from_bytes")?;
        Ok((ctor, (slf.get().to_bytes(py)?,)))
    }

    /// The statistics as NumPy arrays, for the M-step.
    ///
    /// Every model: `log_likelihood`, `n_frames`, `n_sequences`; HMMs: `start`
    /// `(S,)` (`Σ_k γ^k_0`), `trans` `(S, S)` (`Σ ξ`). Gaussian emissions and
    /// the mixture: `post` `(S,)` (`Σ γ`), `shift` `(S, D)` (each state's
    /// reference point `c`), `sum` `(S, D)` (`Σ γ (x − c)`), `sum_sq`
    /// `(S, D, D)` for full and tied structures, `(S, D)` otherwise
    /// (`Σ γ (x − c)(x − c)ᵀ` or its diagonal). GMMHMM: the same with a
    /// component axis, `(S, M, …)`, and `post_mix` `(S, M)`. Categorical:
    /// `counts` `(S, K)`. Poisson: `post` `(S,)`, `obs` `(S, D)` (`Σ γ x`).
    fn arrays<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        match &self.inner {
            Inner::Hmm(HmmStats::Gaussian(e)) => {
                put_chain(py, &d, e)?;
                let v: GaussianView = view(&e.emission, "Gaussian")?;
                let s = v.weight.len();
                put_gaussian(py, &d, &[v], &[s])?;
            }
            Inner::Hmm(HmmStats::Mixture(e)) => {
                put_chain(py, &d, e)?;
                let v: MixtureView = view(&e.emission, "mixture")?;
                let s = v.inner.len();
                let m = v.weight.len() / s.max(1);
                d.set_item("post_mix", array2(py, v.weight, s, m)?)?;
                put_gaussian(py, &d, &v.inner, &[s, m])?;
            }
            Inner::Hmm(HmmStats::Categorical(e)) => {
                put_chain(py, &d, e)?;
                let v: CategoricalView = view(&e.emission, "categorical")?;
                let s = e.start.len();
                d.set_item("counts", array2(py, v.counts, s, v.n_symbols)?)?;
            }
            Inner::Hmm(HmmStats::Poisson(e)) => {
                put_chain(py, &d, e)?;
                let v: PoissonView = view(&e.emission, "Poisson")?;
                let s = v.weight.len();
                d.set_item("post", Array1::from_vec(v.weight).into_pyarray(py))?;
                d.set_item("obs", array2(py, v.sum, s, v.dim)?)?;
            }
            Inner::Gmm(g) => {
                put_common(&d, g.log_likelihood, g.n_frames, 1)?;
                d.set_item("counts", array1(py, g.counts.clone()))?;
                let v: GaussianView = view(&g.components, "Gaussian")?;
                let k = v.weight.len();
                put_gaussian(py, &d, &[v], &[k])?;
            }
        }
        Ok(d)
    }

    fn __repr__(&self) -> String {
        format!(
            "Statistics({} frames in {} sequences, log-likelihood {})",
            self.n_frames(),
            self.n_sequences(),
            self.log_likelihood()
        )
    }
}
