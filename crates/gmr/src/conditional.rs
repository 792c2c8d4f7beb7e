//! Conditioning one joint Gaussian on a subset of its dimensions.
//!
//! For input dims `i` and output dims `o` of `N(μ, Σ)`:
//! `p(x_o | x_i) = N(μ_o + R (x_i − μ_i), Σ_oo − R Σ_io)` with the regression
//! matrix `R = Σ_oi Σ_ii⁻¹`, obtained by a Cholesky solve `Σ_ii Rᵀ = Σ_io` once
//! per state; the per-frame path is a matrix–vector product.

use crate::error::{GmrError, Result};
use nalgebra::DMatrix;
use phasekit_emission::EmissionError;
use serde::{Deserialize, Serialize};

/// Validates disjoint, non-empty, in-range input and output dimensions.
pub fn check_io(input: &[usize], output: &[usize], dim: usize) -> Result<()> {
    let fail = |what: String| Err(GmrError::InvalidDims(what));
    for (name, dims) in [("input", input), ("output", output)] {
        if let Err(e) = phasekit_emission::check_dims(dims, dim) {
            return fail(format!("{name}: {e}"));
        }
    }
    if let Some(d) = input.iter().find(|d| output.contains(d)) {
        return fail(format!("dimension {d} is both input and output"));
    }
    Ok(())
}

/// The conditional `p(x_o | x_i)` of one joint Gaussian, precomputed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Conditional {
    n_in: usize,
    n_out: usize,
    mean_in: Vec<f64>,
    mean_out: Vec<f64>,
    /// `R = Σ_oi Σ_ii⁻¹`, `O × I` row-major.
    regression: Vec<f64>,
    /// `Σ_oo − R Σ_io`, `O × O` row-major.
    covariance: Vec<f64>,
}

impl Conditional {
    /// Conditions `N(mean, cov)` (`state` only names it in errors) on the `input` dims, predicting `output`.
    pub fn new(
        mean: &[f64],
        cov: &DMatrix<f64>,
        input: &[usize],
        output: &[usize],
        state: usize,
    ) -> Result<Self> {
        check_io(input, output, mean.len())?;
        let d = mean.len();
        if cov.nrows() != d || cov.ncols() != d {
            return Err(EmissionError::DimensionMismatch {
                context: "conditional: covariance rows/columns vs mean length",
                expected: d,
                found: if cov.nrows() != d {
                    cov.nrows()
                } else {
                    cov.ncols()
                },
            }
            .into());
        }
        if let Some(i) = mean.iter().chain(cov.iter()).position(|v| !v.is_finite()) {
            return Err(EmissionError::InvalidParameter {
                name: if i < d { "mean" } else { "covariance" },
                reason: format!("state {state}: a value is not finite"),
            }
            .into());
        }
        let sub = |rows: &[usize], cols: &[usize]| {
            DMatrix::from_fn(rows.len(), cols.len(), |r, c| cov[(rows[r], cols[c])])
        };
        let s_ii = sub(input, input);
        let s_io = sub(input, output);
        let s_oo = sub(output, output);
        let chol = nalgebra::Cholesky::new(s_ii).ok_or(GmrError::SingularInput { state })?;
        let rt = chol.solve(&s_io); // I × O: Σ_ii⁻¹ Σ_io
        let cond = &s_oo - rt.transpose() * &s_io;
        let cond = (&cond + cond.transpose()) * 0.5;
        let (n_in, n_out) = (input.len(), output.len());
        Ok(Conditional {
            n_in,
            n_out,
            mean_in: input.iter().map(|&d| mean[d]).collect(),
            mean_out: output.iter().map(|&d| mean[d]).collect(),
            regression: (0..n_out)
                .flat_map(|o| (0..n_in).map(move |i| (o, i)))
                .map(|(o, i)| rt[(i, o)])
                .collect(),
            covariance: (0..n_out)
                .flat_map(|r| (0..n_out).map(move |c| (r, c)))
                .map(|(r, c)| cond[(r, c)])
                .collect(),
        })
    }

    /// The outputs' marginal `N(μ_o, Σ_oo)`: the "conditional" on no input at
    /// all, for a frame whose inputs are all missing.
    pub fn unconditional(mean: &[f64], cov: &DMatrix<f64>, output: &[usize]) -> Result<Self> {
        let d = mean.len();
        if let Err(e) = phasekit_emission::check_dims(output, d) {
            return Err(GmrError::InvalidDims(format!("output: {e}")));
        }
        if cov.nrows() != d || cov.ncols() != d {
            return Err(EmissionError::DimensionMismatch {
                context: "conditional: covariance rows/columns vs mean length",
                expected: d,
                found: cov.nrows(),
            }
            .into());
        }
        let n_out = output.len();
        Ok(Conditional {
            n_in: 0,
            n_out,
            mean_in: Vec::new(),
            mean_out: output.iter().map(|&k| mean[k]).collect(),
            regression: Vec::new(),
            covariance: (0..n_out * n_out)
                .map(|k| cov[(output[k / n_out], output[k % n_out])])
                .collect(),
        })
    }

    /// Writes the conditional mean `μ_o + R (x_i − μ_i)` into `out` (length
    /// `O`); `x_in` has length `I`. A buffer of another length is an error.
    pub fn mean_into(&self, x_in: &[f64], out: &mut [f64]) -> Result<()> {
        for (context, expected, found) in [
            ("conditional: input frame", self.n_in, x_in.len()),
            ("conditional: output buffer", self.n_out, out.len()),
        ] {
            if expected != found {
                return Err(EmissionError::DimensionMismatch {
                    context,
                    expected,
                    found,
                }
                .into());
            }
        }
        self.mean_unchecked(x_in, out);
        Ok(())
    }

    /// [`Conditional::mean_into`] on buffers of the right lengths.
    #[inline]
    pub(crate) fn mean_unchecked(&self, x_in: &[f64], out: &mut [f64]) {
        if self.n_in == 0 {
            out[..self.n_out].copy_from_slice(&self.mean_out);
            return;
        }
        // Input-major: the O running sums are independent, so each step of `i`
        // is O independent multiply-adds instead of one long dependency chain
        // per output. Every output still adds its terms in increasing `i`,
        // exactly as a row-by-row dot product would.
        let n_in = self.n_in;
        for o in out.iter_mut().take(self.n_out) {
            *o = 0.0;
        }
        for (i, (x, m)) in x_in.iter().zip(&self.mean_in).enumerate() {
            let dx = x - m;
            for (o, row) in out.iter_mut().zip(self.regression.chunks_exact(n_in)) {
                *o += row[i] * dx;
            }
        }
        for (o, m) in out.iter_mut().zip(&self.mean_out) {
            *o += m;
        }
    }

    /// The conditional covariance `Σ_oo − Σ_oi Σ_ii⁻¹ Σ_io`, `O × O` row-major.
    pub fn covariance(&self) -> &[f64] {
        &self.covariance
    }

    /// The regression matrix `Σ_oi Σ_ii⁻¹`, `O × I` row-major.
    pub fn regression(&self) -> &[f64] {
        &self.regression
    }

    /// Number of input dims.
    pub fn n_in(&self) -> usize {
        self.n_in
    }

    /// Number of output dims.
    pub fn n_out(&self) -> usize {
        self.n_out
    }
}
