//! NumPy arrays in and out, sequences, errors and thread pools.

use numpy::ndarray::{Array1, Array2, Array3, ArrayD, IxDyn};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayDyn, PyReadonlyArray2, PyUntypedArrayMethods,
};
use phasekit::emission::{Frames, SequenceSet};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use rayon::ThreadPool;
use std::collections::HashMap;
use std::fmt::Display;
use std::sync::{Arc, Mutex, OnceLock};

/// phasekit's error (it names the sequence, frame, column or state) as a `ValueError`.
pub fn value_error(e: impl Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// A failure that is not the caller's input (a thread pool, an internal shape).
pub fn runtime_error(e: impl Display) -> PyErr {
    PyRuntimeError::new_err(e.to_string())
}

/// The row-major values of a C-contiguous float64 array, borrowed, with its shape.
pub fn matrix<'a>(
    x: &'a PyReadonlyArray2<'_, f64>,
    name: &str,
) -> PyResult<(&'a [f64], usize, usize)> {
    let shape = x.shape();
    let (t, d) = (shape[0], shape[1]);
    let data = x.as_slice().map_err(|_| {
        PyValueError::new_err(format!(
            "{name}: the array must be C-contiguous float64 (the Python layer converts it)"
        ))
    })?;
    Ok((data, t, d))
}

/// Checks `lengths` against `n_frames` (all positive, summing to `n_frames`);
/// `None` is one sequence of every frame.
pub fn sequence_lengths(lengths: Option<Vec<usize>>, n_frames: usize) -> PyResult<Vec<usize>> {
    let lengths = lengths.unwrap_or_else(|| vec![n_frames]);
    if lengths.is_empty() {
        return Err(PyValueError::new_err("lengths is empty: no sequence given"));
    }
    if let Some(k) = lengths.iter().position(|&l| l == 0) {
        return Err(PyValueError::new_err(format!(
            "lengths[{k}] is 0: sequence {k} is empty"
        )));
    }
    let total: usize = lengths.iter().sum();
    if total != n_frames {
        return Err(PyValueError::new_err(format!(
            "lengths sum to {total}, but X has {n_frames} frames"
        )));
    }
    Ok(lengths)
}

/// The sequences of `data` (`T × d` row-major) split by `lengths`, borrowed.
pub fn split<'a>(data: &'a [f64], d: usize, lengths: &[usize]) -> Vec<&'a [f64]> {
    let mut out = Vec::with_capacity(lengths.len());
    let mut offset = 0;
    for &len in lengths {
        out.push(&data[offset * d..(offset + len) * d]);
        offset += len;
    }
    out
}

/// Validated frames of one sequence, naming it in errors.
pub fn frames_of(seq: &[f64], d: usize, k: usize) -> PyResult<Frames<'_>> {
    Frames::new(seq, d).map_err(|e| PyValueError::new_err(format!("sequence {k}: {e}")))
}

/// A `T × S` row-major vector as a NumPy array.
pub fn array2<'py>(
    py: Python<'py>,
    v: Vec<f64>,
    rows: usize,
    cols: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    Ok(Array2::from_shape_vec((rows, cols), v)
        .map_err(runtime_error)?
        .into_pyarray(py))
}

/// A row-major vector as a 3-D NumPy array.
pub fn array3<'py>(
    py: Python<'py>,
    v: Vec<f64>,
    shape: (usize, usize, usize),
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    Ok(Array3::from_shape_vec(shape, v)
        .map_err(runtime_error)?
        .into_pyarray(py))
}

/// A row-major vector as an N-D NumPy array.
pub fn array_dyn<'py>(
    py: Python<'py>,
    v: Vec<f64>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    Ok(ArrayD::from_shape_vec(IxDyn(shape), v)
        .map_err(runtime_error)?
        .into_pyarray(py))
}

/// A vector as a 1-D NumPy array.
pub fn array1<'py, T: numpy::Element>(py: Python<'py>, v: Vec<T>) -> Bound<'py, PyArray1<T>> {
    Array1::from_vec(v).into_pyarray(py)
}

/// A shared rayon pool of `n` threads (built once per count and reused), so
/// that `n_jobs` is honoured without building a pool per call. phasekit's
/// E-steps give bit-identical results for any thread count.
pub fn pool(n: usize) -> PyResult<Arc<ThreadPool>> {
    static POOLS: OnceLock<Mutex<HashMap<usize, Arc<ThreadPool>>>> = OnceLock::new();
    if n == 0 {
        return Err(PyValueError::new_err(
            "n_jobs: at least one thread is needed",
        ));
    }
    let mut pools = POOLS
        .get_or_init(|| Mutex::new(HashMap::new()))
        .lock()
        .map_err(runtime_error)?;
    if let Some(p) = pools.get(&n) {
        return Ok(p.clone());
    }
    let p = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .thread_name(|i| format!("phasekit-{i}"))
            .build()
            .map_err(|e| runtime_error(format!("cannot start {n} threads: {e}")))?,
    );
    pools.insert(n, p.clone());
    Ok(p)
}

/// Sequences of frames copied once into phasekit's contiguous set, for the
/// repeated E-steps of a fit (each iteration reads them in place).
#[pyclass(module = "phasekit._core", frozen)]
pub struct Sequences {
    pub set: SequenceSet,
}

#[pymethods]
impl Sequences {
    /// `x` is `(n_frames, n_features)` C-contiguous float64; `lengths` splits it
    /// into sequences (one sequence when `None`). NaN means "not observed";
    /// infinity is refused with the sequence, frame and column.
    #[new]
    #[pyo3(signature = (x, lengths=None))]
    fn new(
        py: Python<'_>,
        x: PyReadonlyArray2<'_, f64>,
        lengths: Option<Vec<usize>>,
    ) -> PyResult<Self> {
        let (data, t, d) = matrix(&x, "X")?;
        let lengths = sequence_lengths(lengths, t)?;
        let parts = split(data, d, &lengths);
        let set = py
            .allow_threads(|| SequenceSet::new(&parts, d))
            .map_err(value_error)?;
        Ok(Sequences { set })
    }

    /// Number of sequences.
    #[getter]
    fn n_sequences(&self) -> usize {
        self.set.len()
    }

    /// Total number of frames.
    #[getter]
    fn n_frames(&self) -> usize {
        self.set.total_frames()
    }

    /// Dimension of a frame.
    #[getter]
    fn n_features(&self) -> usize {
        self.set.dim()
    }

    /// Length of every sequence.
    fn lengths(&self) -> Vec<usize> {
        self.set.lengths().collect()
    }

    fn __repr__(&self) -> String {
        format!(
            "Sequences({} sequences, {} frames of {} features)",
            self.set.len(),
            self.set.total_frames(),
            self.set.dim()
        )
    }
}
