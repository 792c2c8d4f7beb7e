//! The geometry of the states plot: Gaussians as ellipses in a plane, and the
//! linear projections (a plane of two features, an oblique view of three) that
//! map a Gaussian `N(μ, Σ)` to `N(Pμ, PΣPᵀ)`.

/// A Gaussian in a plane: mean and 2×2 covariance, in data units.
#[derive(Debug, Clone, PartialEq)]
pub struct Ellipse {
    /// Centre.
    pub mean: [f64; 2],
    /// Covariance `[[a, b], [b, c]]` as `[a, b, c]`.
    pub cov: [f64; 3],
    /// Legend label.
    pub label: String,
    /// Whether it is a transition state (TSC-HMM) or transition cluster (gmm-tsc).
    pub transition: bool,
    /// Index within its kind.
    pub index: usize,
}

impl Ellipse {
    /// Points of the `k`σ contour.
    pub fn contour(&self, k: f64, n: usize) -> Vec<(f64, f64)> {
        let [a, b, c] = self.cov;
        let half = 0.5 * (a + c);
        let r = (0.25 * (a - c).powi(2) + b * b).sqrt();
        let (l1, l2) = ((half + r).max(0.0), (half - r).max(0.0));
        let theta = 0.5 * (2.0 * b).atan2(a - c);
        let (s1, s2) = (k * l1.sqrt(), k * l2.sqrt());
        (0..=n)
            .map(|i| {
                let phi = 2.0 * std::f64::consts::PI * i as f64 / n as f64;
                let (u, v) = (s1 * phi.cos(), s2 * phi.sin());
                (
                    self.mean[0] + u * theta.cos() - v * theta.sin(),
                    self.mean[1] + u * theta.sin() + v * theta.cos(),
                )
            })
            .collect()
    }
}

/// A linear map from features to the picture's plane: `(u, v) = P x` over the
/// features `dims`, `P` a 2 × `dims.len()` matrix.
///
/// A Gaussian `N(μ, Σ)` maps to `N(Pμ, PΣPᵀ)`, and the outline of the projected
/// `k`σ ellipsoid `{x : (x − μ)ᵀ Σ⁻¹ (x − μ) ≤ k²}` is exactly the `k`σ ellipse of
/// that projected Gaussian, so ellipsoids are drawn by their projected outlines.
#[derive(Debug, Clone, PartialEq)]
pub struct Projection {
    /// Feature indices.
    pub dims: Vec<usize>,
    /// Rows of `P`, one weight per entry of `dims`.
    pub rows: [Vec<f64>; 2],
}

/// Cabinet projection: depth drawn at half scale, 30° from the horizontal.
const OBLIQUE_DEPTH: f64 = 0.5;
const OBLIQUE_ANGLE_DEG: f64 = 30.0;

impl Projection {
    /// The plane of features `x` (horizontal) and `y` (vertical).
    pub fn plane(x: usize, y: usize) -> Self {
        Projection {
            dims: vec![x, y],
            rows: [vec![1.0, 0.0], vec![0.0, 1.0]],
        }
    }

    /// An oblique (cabinet) view of features `x`, `y` (depth) and `z` (up):
    /// `u = x + ½ cos 30° · y`, `v = z + ½ sin 30° · y`.
    pub fn oblique(x: usize, y: usize, z: usize) -> Self {
        let a = OBLIQUE_ANGLE_DEG.to_radians();
        Projection {
            dims: vec![x, y, z],
            rows: [
                vec![1.0, OBLIQUE_DEPTH * a.cos(), 0.0],
                vec![0.0, OBLIQUE_DEPTH * a.sin(), 1.0],
            ],
        }
    }

    /// Whether this is a 3-D view.
    pub fn is_3d(&self) -> bool {
        self.dims.len() == 3
    }

    /// The picture point of a full feature vector.
    pub fn point(&self, x: &[f64]) -> (f64, f64) {
        let at = |r: &[f64]| r.iter().zip(&self.dims).map(|(w, &k)| w * x[k]).sum();
        (at(&self.rows[0]), at(&self.rows[1]))
    }

    /// The picture point of the coordinates `c` along `dims`.
    pub(crate) fn point_of(&self, c: &[f64]) -> (f64, f64) {
        let at = |r: &[f64]| r.iter().zip(c).map(|(w, v)| w * v).sum();
        (at(&self.rows[0]), at(&self.rows[1]))
    }

    /// `P μ` and `P Σ Pᵀ` of a Gaussian given on `dims` (mean and covariance in data units).
    pub(crate) fn gaussian(&self, mean: &[f64], cov: &[f64]) -> ([f64; 2], [f64; 3]) {
        let n = self.dims.len();
        let (u, v) = self.point_of(mean);
        let quad = |a: &[f64], b: &[f64]| {
            (0..n)
                .flat_map(|i| (0..n).map(move |j| a[i] * cov[i * n + j] * b[j]))
                .sum::<f64>()
        };
        let (r0, r1) = (&self.rows[0], &self.rows[1]);
        ([u, v], [quad(r0, r0), quad(r0, r1), quad(r1, r1)])
    }
}

#[cfg(test)]
mod tests {
    use super::Ellipse;

    #[test]
    fn projected_gaussian_outline_is_the_shadow_of_the_ellipsoid() {
        use super::Projection;
        // An ellipsoid's k-σ outline under a linear map P is the k-σ ellipse of N(Pμ, PΣPᵀ):
        // every point of the outline is the image of a point on the ellipsoid, and the image
        // of every ellipsoid point lies inside it.
        let p = Projection::oblique(0, 1, 2);
        let mean = [0.3, -0.2, 1.0];
        let cov = [2.0, 0.4, 0.1, 0.4, 1.0, -0.3, 0.1, -0.3, 0.5];
        let (m, c) = p.gaussian(&mean, &cov);
        assert_eq!(
            m,
            [
                0.3 + 0.5 * 30f64.to_radians().cos() * -0.2,
                1.0 + 0.5 * 30f64.to_radians().sin() * -0.2
            ]
        );
        let l = nalgebra_free_cholesky(&cov);
        let inv_det = 1.0 / (c[0] * c[2] - c[1] * c[1]);
        let mut max_m: f64 = 0.0;
        for i in 0..40 {
            for j in 0..20 {
                let (th, ph) = (
                    i as f64 / 40.0 * std::f64::consts::TAU,
                    j as f64 / 19.0 * std::f64::consts::PI,
                );
                let z = [ph.sin() * th.cos(), ph.sin() * th.sin(), ph.cos()];
                let x: Vec<f64> = (0..3)
                    .map(|r| mean[r] + 2.0 * (0..3).map(|k| l[r * 3 + k] * z[k]).sum::<f64>())
                    .collect();
                let (u, v) = p.point(&x);
                let (du, dv) = (u - m[0], v - m[1]);
                let maha = inv_det * (c[2] * du * du - 2.0 * c[1] * du * dv + c[0] * dv * dv);
                assert!(maha <= 4.0 + 1e-9, "{maha}");
                max_m = max_m.max(maha);
            }
        }
        assert!(max_m > 3.9, "the outline is reached: {max_m}");
    }

    /// Lower Cholesky factor of a 3×3 SPD matrix.
    fn nalgebra_free_cholesky(a: &[f64]) -> Vec<f64> {
        let mut l = vec![0.0; 9];
        for i in 0..3 {
            for j in 0..=i {
                let s: f64 = (0..j).map(|k| l[i * 3 + k] * l[j * 3 + k]).sum();
                l[i * 3 + j] = if i == j {
                    (a[i * 3 + i] - s).sqrt()
                } else {
                    (a[i * 3 + j] - s) / l[j * 3 + j]
                };
            }
        }
        l
    }

    #[test]
    fn two_sigma_contour_of_a_rotated_gaussian() {
        // Variances 4 and 1 along axes rotated by 30°.
        let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        let cov = [4.0 * c * c + s * s, 3.0 * c * s, 4.0 * s * s + c * c];
        let e = Ellipse {
            mean: [1.0, -1.0],
            cov,
            label: String::new(),
            transition: false,
            index: 0,
        };
        let inv_det = 1.0 / (cov[0] * cov[2] - cov[1] * cov[1]);
        for (x, y) in e.contour(2.0, 64) {
            let (dx, dy) = (x - 1.0, y + 1.0);
            let m = inv_det * (cov[2] * dx * dx - 2.0 * cov[1] * dx * dy + cov[0] * dy * dy);
            assert!((m - 4.0).abs() < 1e-9, "Mahalanobis² {m}");
        }
    }
}
