//! Gaussian mixture regression: every call into `phasekit::gmr` (through the
//! TSC crate's `Predictor`, which holds the static and the HMM-based GMR and
//! their frame-by-frame forms).

use crate::arrays::{array1, array2, array3, matrix, runtime_error, value_error};
use crate::gmm::GmmCore;
use crate::hmm::{AnyHmm, HmmCore};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2};
use phasekit::emission::Frames;
use phasekit::gmr::{GmmRegression, HmmRegression};
use phasekit::tsc::{OnlinePredictor, Predictor};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// Reads one frame of `n` values: a float64 array without copying its
/// layout, or any sequence of numbers.
pub fn read_frame(frame: &Bound<'_, PyAny>, n: usize, buf: &mut Vec<f64>) -> PyResult<()> {
    buf.clear();
    if let Ok(a) = frame.downcast::<PyArray1<f64>>() {
        let ro = a.readonly();
        match ro.as_slice() {
            Ok(s) => buf.extend_from_slice(s),
            Err(_) => buf.extend(ro.as_array().iter().copied()),
        }
    } else {
        let v: Vec<f64> = frame.extract().map_err(|_| {
            PyValueError::new_err(format!(
                "a frame must be a 1-D array or sequence of {n} numbers"
            ))
        })?;
        buf.extend(v);
    }
    if buf.len() != n {
        return Err(PyValueError::new_err(format!(
            "a frame must have {n} values (the input dims), got {}",
            buf.len()
        )));
    }
    Ok(())
}

/// `(mean (O,), covariance (O, O))` of one predicted frame.
pub type MeanAndCovariance<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray2<f64>>);

/// A regression of output dims on input dims under a joint GMM or HMM.
#[pyclass(module = "phasekit._core", frozen)]
pub struct GmrCore {
    predictor: Predictor,
    n_in: usize,
}

#[pymethods]
impl GmrCore {
    /// HMM-GMR under a Gaussian HMM: frame `t`'s weights are the forward
    /// (filtered) state probabilities of the input dims `x^i_{1:t}`.
    #[staticmethod]
    fn from_hmm(hmm: &HmmCore, input: Vec<usize>, output: Vec<usize>) -> PyResult<Self> {
        let AnyHmm::Gaussian(h) = &hmm.model else {
            return Err(PyValueError::new_err(
                "Gaussian mixture regression needs a Gaussian HMM (GaussianHMM)",
            ));
        };
        let h = phasekit::tsc::emission_choice::any_hmm(h.clone()).map_err(value_error)?;
        let r = HmmRegression::new(&h, &input, &output).map_err(value_error)?;
        Ok(GmrCore {
            predictor: Predictor::hmm(r),
            n_in: input.len(),
        })
    }

    /// Static GMR under a Gaussian mixture: the weights are the responsibilities
    /// of the input marginal.
    #[staticmethod]
    fn from_gmm(gmm: &GmmCore, input: Vec<usize>, output: Vec<usize>) -> PyResult<Self> {
        let any = phasekit::gmm::Gmm::new(
            gmm.model.weights().to_vec(),
            phasekit::tsc::AnyEmission::Gaussian(gmm.model.components().clone()),
        )
        .map_err(value_error)?;
        let r = GmmRegression::new(&any, &input, &output).map_err(value_error)?;
        Ok(GmrCore {
            predictor: Predictor::gmm(r),
            n_in: input.len(),
        })
    }

    /// Number of output dims.
    #[getter]
    fn n_out(&self) -> usize {
        self.predictor.n_out()
    }

    /// Number of input dims.
    #[getter]
    fn n_in(&self) -> usize {
        self.n_in
    }

    /// `(mean (T, O), covariance (T, O, O) or None, weights (T, K))` for input
    /// frames `(T, I)` (NaN: a missing input value).
    #[pyo3(signature = (x, with_covariance=true))]
    #[allow(clippy::type_complexity)]
    fn predict<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArray2<'py, f64>,
        with_covariance: bool,
    ) -> PyResult<(
        Bound<'py, PyArray2<f64>>,
        Option<Bound<'py, PyAny>>,
        Bound<'py, PyArray2<f64>>,
    )> {
        let (data, t, d) = matrix(&x, "X")?;
        if d != self.n_in {
            return Err(PyValueError::new_err(format!(
                "X has {d} columns, the regression {} input dims",
                self.n_in
            )));
        }
        let p = py
            .allow_threads(|| -> Result<_, String> {
                let frames = Frames::new(data, d).map_err(|e| e.to_string())?;
                self.predictor
                    .predict(frames, with_covariance)
                    .map_err(|e| e.to_string())
            })
            .map_err(value_error)?;
        let o = p.n_out;
        let k = p.weights.len().checked_div(t).unwrap_or(0);
        let cov = match p.covariance {
            Some(c) => Some(array3(py, c, (t, o, o))?.into_any()),
            None => None,
        };
        Ok((array2(py, p.mean, t, o)?, cov, array2(py, p.weights, t, k)?))
    }

    /// A frame-by-frame predictor (for a control loop).
    fn online(&self) -> OnlineGmr {
        OnlineGmr {
            online: self.predictor.online(),
            n_in: self.n_in,
            n_out: self.predictor.n_out(),
            buf: Vec::with_capacity(self.n_in),
        }
    }
}

/// One input frame in, the predicted output out (HMM-GMR: the belief carries
/// over from frame to frame; static GMR: every frame on its own).
#[pyclass(module = "phasekit._core")]
pub struct OnlineGmr {
    online: OnlinePredictor,
    n_in: usize,
    n_out: usize,
    buf: Vec<f64>,
}

#[pymethods]
impl OnlineGmr {
    /// The predicted output mean `(O,)` after input frame `frame` `(I,)`.
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        frame: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        read_frame(frame, self.n_in, &mut self.buf)?;
        let mean = self.online.step(&self.buf, false).map_err(value_error)?;
        Ok(array1(py, mean.to_vec()))
    }

    /// `(mean (O,), covariance (O, O))` after input frame `frame`.
    fn step_with_covariance<'py>(
        &mut self,
        py: Python<'py>,
        frame: &Bound<'py, PyAny>,
    ) -> PyResult<MeanAndCovariance<'py>> {
        read_frame(frame, self.n_in, &mut self.buf)?;
        let mean = self
            .online
            .step(&self.buf, true)
            .map_err(value_error)?
            .to_vec();
        let cov = self.online.covariance().to_vec();
        let o = self.n_out;
        Ok((
            array1(py, mean),
            array2(py, cov, o, o).map_err(runtime_error)?,
        ))
    }

    /// Starts a new sequence (HMM-GMR forgets its belief).
    fn reset(&mut self) {
        self.online.reset();
    }
}
