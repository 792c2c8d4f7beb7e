//! A plug-in emission written outside phasekit, on the per-state route:
//! independent Laplace dimensions, `b(x) = Π_k exp(−|x_k − m_k| / s_k) / (2 s_k)`.
//!
//! It uses only phasekit's public API and its re-exports
//! (`phasekit_emission::rand`), while depending on another `rand` itself.
//! `PerState<Laplace>` is then an `Emission`: Baum-Welch, mixture EM, the
//! online filter, missing values (the dims are independent, so the marginal
//! is the product of the observed ones) and regression (the conditional of
//! independent dims is the output's marginal) all work. The count of lines
//! of the `impl StateDistribution` block is quoted in the emission crate's
//! guide ("Writing an emission").

use phasekit_emission::rand::Rng;
use phasekit_emission::{
    EmissionError, Frames, MStepReport, Regularisation, Result, StateConditional,
    StateDistribution, StateSplit,
};

/// Independent Laplace dimensions: locations `m` and scales `s > 0`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Laplace {
    location: Vec<f64>,
    scale: Vec<f64>,
}

impl Laplace {
    /// Checked: equal lengths `≥ 1`, finite locations, finite positive scales.
    pub fn new(location: Vec<f64>, scale: Vec<f64>) -> Result<Self> {
        if location.is_empty() || location.len() != scale.len() {
            return Err(EmissionError::plugin(
                "Laplace",
                "locations and scales must have one equal, non-zero length",
            ));
        }
        if location.iter().any(|v| !v.is_finite())
            || scale.iter().any(|v| !(v.is_finite() && *v > 0.0))
        {
            return Err(EmissionError::plugin(
                "Laplace",
                "locations must be finite and scales finite and positive",
            ));
        }
        Ok(Laplace { location, scale })
    }

    /// Location 0, scale 1 in `dim` dimensions (a template).
    pub fn standard(dim: usize) -> Result<Self> {
        Self::new(vec![0.0; dim], vec![1.0; dim])
    }

    /// Locations `m`.
    pub fn location(&self) -> &[f64] {
        &self.location
    }

    /// Scales `s`.
    pub fn scale(&self) -> &[f64] {
        &self.scale
    }
}

/// The weighted median of `(value, weight)` pairs (weights > 0): the smallest
/// value whose cumulative weight reaches half the total.
fn weighted_median(pairs: &mut [(f64, f64)]) -> f64 {
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let half = 0.5 * pairs.iter().map(|p| p.1).sum::<f64>();
    let mut acc = 0.0;
    for &(v, w) in pairs.iter() {
        acc += w;
        if acc >= half {
            return v;
        }
    }
    pairs.last().map_or(0.0, |p| p.0)
}

impl StateDistribution for Laplace {
    const NAME: &'static str = "Laplace";
    // Independent dims: the marginal keeps the observed ones, and the fit of
    // each dim uses its observed values only (exact for the observed data).
    const MISSING_VALUES: bool = true;

    fn dim(&self) -> usize {
        self.location.len()
    }

    fn log_density(&self, x: &[f64]) -> f64 {
        x.iter()
            .zip(&self.location)
            .zip(&self.scale)
            .map(|((x, m), s)| -(x - m).abs() / s - (2.0 * s).ln())
            .sum()
    }

    fn sample<R: Rng + ?Sized>(&self, rng: &mut R, out: &mut [f64]) {
        for ((o, m), s) in out.iter_mut().zip(&self.location).zip(&self.scale) {
            // Inverse CDF of the Laplace: u uniform on (−½, ½).
            let u: f64 = rng.random::<f64>() - 0.5;
            *o = m - s * u.signum() * (1.0 - 2.0 * u.abs()).ln();
        }
    }

    /// Exact weighted maximum likelihood per dim: the weighted median and
    /// the weighted mean absolute deviation about it.
    fn fit(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        _reg: &Regularisation,
        _report: &mut MStepReport,
    ) -> Result<Self> {
        let mut location = Vec::with_capacity(self.dim());
        let mut scale = Vec::with_capacity(self.dim());
        for k in 0..self.dim() {
            let mut pairs: Vec<(f64, f64)> = frames
                .iter()
                .zip(weights)
                .filter(|(x, w)| **w > 0.0 && !x[k].is_nan())
                .map(|(x, w)| (x[k], *w))
                .collect();
            if pairs.is_empty() {
                // Never observed: keep the current parameters of this dim.
                location.push(self.location[k]);
                scale.push(self.scale[k]);
                continue;
            }
            let m = weighted_median(&mut pairs);
            let total: f64 = pairs.iter().map(|p| p.1).sum();
            let s = pairs.iter().map(|(v, w)| w * (v - m).abs()).sum::<f64>() / total;
            if s.is_nan() || s <= 0.0 {
                return Err(EmissionError::plugin(
                    "Laplace",
                    format!("dimension {k} is constant over the state's frames"),
                ));
            }
            location.push(m);
            scale.push(s);
        }
        Laplace::new(location, scale)
    }

    fn n_parameters(&self) -> usize {
        2 * self.dim()
    }

    fn marginal(&self, dims: &[usize]) -> Result<Self> {
        Laplace::new(
            dims.iter().map(|&k| self.location[k]).collect(),
            dims.iter().map(|&k| self.scale[k]).collect(),
        )
    }
}

/// The conditional of independent dims: the output's own marginal (mean
/// `m_O`, covariance `diag(2 s_O²)`), whatever the input.
#[derive(Debug, Clone)]
pub struct LaplaceSplit {
    input: Laplace,
    output: Laplace,
}

impl StateSplit for LaplaceSplit {
    fn input_log_density(&mut self, input: &[f64]) -> f64 {
        self.input.log_density(input)
    }

    fn predict(&mut self, _input: &[f64], mean: &mut [f64], covariance: &mut [f64]) -> Result<()> {
        let o = mean.len();
        mean.copy_from_slice(&self.output.location);
        covariance.fill(0.0);
        for (k, s) in self.output.scale.iter().enumerate() {
            covariance[k * o + k] = 2.0 * s * s;
        }
        Ok(())
    }
}

impl StateConditional for Laplace {
    type Split = LaplaceSplit;

    fn conditional(&self, input: &[usize], output: &[usize]) -> Result<LaplaceSplit> {
        Ok(LaplaceSplit {
            input: self.marginal(input)?,
            output: self.marginal(output)?,
        })
    }
}

/// A draw with the plug-in's own `rand` (0.10), to show that the two
/// versions live side by side: the emission trait never sees this one.
pub fn own_rand_seed() -> u64 {
    use rand::RngExt as _;
    rand::rng().random()
}
