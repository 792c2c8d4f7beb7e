//! Packed lower triangles and the factorisations that produce them.
//!
//! A lower-triangular `D × D` matrix is packed row by row: row `r` holds
//! `r + 1` entries starting at `r (r + 1) / 2`, so a row is contiguous and a
//! triangular matrix–vector product is a sequence of contiguous dot products.

use nalgebra::DMatrix;

/// Number of entries of a packed `d × d` lower triangle.
#[inline]
pub fn packed_len(d: usize) -> usize {
    d * (d + 1) / 2
}

/// Row `r` of a packed lower triangle.
#[inline]
pub fn packed_row(packed: &[f64], r: usize) -> &[f64] {
    let start = r * (r + 1) / 2;
    &packed[start..start + r + 1]
}

/// Packs the lower triangle of `m` row by row.
pub fn pack_lower(m: &DMatrix<f64>, out: &mut Vec<f64>) {
    for r in 0..m.nrows() {
        for c in 0..=r {
            out.push(m[(r, c)]);
        }
    }
}

/// Unpacks a packed lower triangle into a dense matrix (upper part zero).
pub fn unpack_lower(packed: &[f64], d: usize) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(d, d);
    for r in 0..d {
        for (c, v) in packed_row(packed, r).iter().enumerate() {
            m[(r, c)] = *v;
        }
    }
    m
}

/// `out = L z` for a packed lower-triangular `L`.
#[inline]
pub fn packed_lower_mul(packed: &[f64], z: &[f64], out: &mut [f64]) {
    for (r, o) in out.iter_mut().enumerate() {
        *o = packed_row(packed, r)
            .iter()
            .zip(&z[..=r])
            .map(|(a, b)| a * b)
            .sum();
    }
}

/// Cholesky factor of a symmetric matrix, or `None` when it is not positive
/// definite (or not finite).
pub fn cholesky(m: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let l = nalgebra::Cholesky::new(m.clone())?.unpack();
    if l.diagonal().iter().all(|v| *v > 0.0 && v.is_finite()) {
        Some(l)
    } else {
        None
    }
}

/// Inverse of a lower-triangular matrix by forward substitution against `I`.
///
/// For `L = chol(Σ)` this is the Cholesky factor of the precision (`Σ⁻¹ = Wᵀ W`),
/// the form scikit-learn stores; the covariance itself is never inverted.
pub fn lower_triangular_inverse(l: &DMatrix<f64>) -> DMatrix<f64> {
    let d = l.nrows();
    l.solve_lower_triangular(&DMatrix::identity(d, d))
        .expect("a Cholesky factor has a positive diagonal")
}
