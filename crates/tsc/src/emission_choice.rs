//! The emission chosen at run time: by the presets, the model files and the
//! command (`--emission NAME`, `emission=NAME`).
//!
//! * [`EmissionKind`] names the choice (`full`, `diag`, `spherical`, `tied`,
//!   `student-t`, `gmm-K`) and makes the template a fit starts from;
//! * [`AnyEmission`] is one of those emissions, fitted: an enum that
//!   implements [`Emission`], [`Marginal`], [`ConcatStates`] and
//!   [`Conditional`] by dispatching each call — a whole block of frames at a
//!   time, so the dispatch costs one `match` per block, not per frame — to the
//!   emission it holds. The numbers are that emission's, bit for bit.
//!
//! The library's generic code (`Hmm<E>`, `TscHmm<E>`, `HmmRegression<E>`)
//! takes any emission with the capabilities it uses; `AnyEmission` is what
//! the command and the model files need, where the emission is a word in a
//! file rather than a type in the code.
//!
//! # Adding an emission
//!
//! One variant in [`EmissionKind`] (its name in `Display`/`FromStr` and its
//! template in [`EmissionKind::template`]), one in [`AnyEmission`], one in
//! [`AnyStats`] and [`AnySplit`] if it has a conditional, and one arm in each
//! `dispatch!` below; the compiler lists every `match` left to extend.
//!
//! # Files
//!
//! A Gaussian is written exactly as [`Gaussian`] writes itself (model files
//! written before this type existed hold Gaussians and read back unchanged);
//! any other emission as `{"emission": NAME, "model": ...}`.

use phasekit_emission::nalgebra::DMatrix;
use phasekit_emission::{
    ConcatStates, Conditional, ConditionalSplit, CovarianceType, Emission, EmissionError, Frames,
    Gaussian, GaussianSplit, GaussianStats, MStepReport, Marginal, MixtureEmission,
    MixtureEmissionStats, MixtureSplit, PerState, PerStateSplit, PerStateStats, Regularisation,
    ScaleFeatures, Shape, StudentT, StudentTDof, StudentTSplit, SufficientStatistics,
};
use rand::Rng;
use serde::de::{self, IntoDeserializer, MapAccess, Visitor};
use serde::ser::SerializeMap;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::borrow::Cow;
use std::fmt;
use std::str::FromStr;

/// The degrees of freedom a `student-t` fit starts from (then estimated).
pub const STUDENT_T_START_DOF: f64 = 5.0;

/// Largest number of Gaussians per state `gmm-K` accepts.
pub const MAX_MIXTURE_COMPONENTS: usize = 64;

/// Which emission a model uses, as the command and the model files name it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum EmissionKind {
    /// One Gaussian per state with this covariance structure (`full`, the
    /// default; `diag`, `spherical`, `tied`).
    Gaussian(CovarianceType),
    /// One multivariate Student-t per state (full scale matrix; `ν` estimated
    /// by ECME from [`STUDENT_T_START_DOF`]): robust to outlying frames.
    StudentT,
    /// A mixture of this many full-covariance Gaussians per state (`gmm-K`,
    /// hmmlearn's GMMHMM).
    GaussianMixture(usize),
}

impl Default for EmissionKind {
    /// One full-covariance Gaussian per state.
    fn default() -> Self {
        EmissionKind::Gaussian(CovarianceType::Full)
    }
}

impl EmissionKind {
    /// The names accepted, for messages.
    pub const NAMES: &'static str = "full, diag, spherical, tied, student-t, gmm-K (K ≥ 1)";

    /// One full-covariance Gaussian per state.
    pub fn is_default(&self) -> bool {
        *self == EmissionKind::default()
    }

    /// The Gaussian covariance structure, for a Gaussian choice.
    pub fn covariance(&self) -> Option<CovarianceType> {
        match *self {
            EmissionKind::Gaussian(c) => Some(c),
            _ => None,
        }
    }

    /// The template a fit of `n_states` states of dimension `dim` starts from
    /// (its values mean nothing yet; [`Emission::initialise`] sets them).
    pub fn template(&self, n_states: usize, dim: usize) -> phasekit_emission::Result<AnyEmission> {
        let shape = Shape { n_states, dim };
        Ok(match *self {
            EmissionKind::Gaussian(c) => AnyEmission::Gaussian(Gaussian::standard(c, shape)?),
            EmissionKind::StudentT => AnyEmission::StudentT(PerState::repeat(
                StudentT::standard(dim, STUDENT_T_START_DOF, StudentTDof::Estimated)?,
                n_states,
            )?),
            EmissionKind::GaussianMixture(k) => {
                let inner = Gaussian::standard(CovarianceType::Full, Shape { n_states: k, dim })?;
                AnyEmission::Mixture(MixtureEmission::new(
                    vec![1.0 / k as f64; n_states * k],
                    vec![inner; n_states],
                )?)
            }
        })
    }
}

impl fmt::Display for EmissionKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            EmissionKind::Gaussian(CovarianceType::Full) => f.write_str("full"),
            EmissionKind::Gaussian(CovarianceType::Diagonal) => f.write_str("diag"),
            EmissionKind::Gaussian(CovarianceType::Spherical) => f.write_str("spherical"),
            EmissionKind::Gaussian(CovarianceType::Tied) => f.write_str("tied"),
            EmissionKind::StudentT => f.write_str("student-t"),
            EmissionKind::GaussianMixture(k) => write!(f, "gmm-{k}"),
        }
    }
}

impl FromStr for EmissionKind {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let bad = || {
            format!(
                "unknown emission `{s}`: expected one of {}",
                EmissionKind::NAMES
            )
        };
        Ok(match s {
            "full" => EmissionKind::Gaussian(CovarianceType::Full),
            "diag" | "diagonal" => EmissionKind::Gaussian(CovarianceType::Diagonal),
            "spherical" => EmissionKind::Gaussian(CovarianceType::Spherical),
            "tied" => EmissionKind::Gaussian(CovarianceType::Tied),
            "student-t" => EmissionKind::StudentT,
            _ => {
                let k = s.strip_prefix("gmm-").ok_or_else(bad)?;
                let k: usize = k.parse().map_err(|_| bad())?;
                if !(1..=MAX_MIXTURE_COMPONENTS).contains(&k) {
                    return Err(format!(
                        "emission `{s}`: the number of Gaussians per state must be in 1..={MAX_MIXTURE_COMPONENTS}"
                    ));
                }
                EmissionKind::GaussianMixture(k)
            }
        })
    }
}

impl Serialize for EmissionKind {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for EmissionKind {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(de::Error::custom)
    }
}

/// One of the emissions [`EmissionKind`] names, fitted (see the module
/// documentation).
#[derive(Debug, Clone)]
#[non_exhaustive]
pub enum AnyEmission {
    /// Gaussian states (any covariance structure).
    Gaussian(Gaussian),
    /// Student-t states.
    StudentT(PerState<StudentT>),
    /// A mixture of full Gaussians per state.
    Mixture(MixtureEmission<Gaussian>),
}

/// Sufficient statistics of an [`AnyEmission`] (of the same variant).
#[derive(Debug, Clone)]
#[non_exhaustive]
pub enum AnyStats {
    /// Of Gaussian states.
    Gaussian(GaussianStats),
    /// Of Student-t states.
    StudentT(PerStateStats),
    /// Of a mixture per state.
    Mixture(MixtureEmissionStats<GaussianStats>),
}

/// The conditionals of an [`AnyEmission`] for one `(input, output)` split.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub enum AnySplit {
    /// Of Gaussian states.
    Gaussian(GaussianSplit),
    /// Of Student-t states.
    StudentT(PerStateSplit<StudentTSplit>),
    /// Of a mixture per state.
    Mixture(MixtureSplit<GaussianSplit>),
}

/// `match $e { V(x) => $body, ... }` over every variant of an `Any*` enum.
macro_rules! dispatch {
    ($ty:ident, $e:expr, $x:ident => $body:expr) => {
        match $e {
            $ty::Gaussian($x) => $body,
            $ty::StudentT($x) => $body,
            $ty::Mixture($x) => $body,
        }
    };
}

impl ScaleFeatures for AnyEmission {
    /// The held emission's [`ScaleFeatures::scale_features`] (Gaussian of any
    /// covariance structure — spherical only with equal factors —, Student-t,
    /// mixture), in the same variant.
    fn scale_features(&self, s: &[f64]) -> phasekit_emission::Result<Self> {
        Ok(match self {
            AnyEmission::Gaussian(g) => AnyEmission::Gaussian(g.scale_features(s)?),
            AnyEmission::StudentT(t) => AnyEmission::StudentT(t.scale_features(s)?),
            AnyEmission::Mixture(m) => AnyEmission::Mixture(m.scale_features(s)?),
        })
    }
}

fn mismatch(what: &str) -> EmissionError {
    EmissionError::StatsMismatch(format!("{what} of another emission kind"))
}

impl SufficientStatistics for AnyStats {
    fn merge(&mut self, other: &Self) -> phasekit_emission::Result<()> {
        match (self, other) {
            (AnyStats::Gaussian(a), AnyStats::Gaussian(b)) => a.merge(b),
            (AnyStats::StudentT(a), AnyStats::StudentT(b)) => a.merge(b),
            (AnyStats::Mixture(a), AnyStats::Mixture(b)) => a.merge(b),
            _ => Err(mismatch("statistics")),
        }
    }

    fn total_weight(&self) -> f64 {
        dispatch!(AnyStats, self, s => s.total_weight())
    }
}

impl AnyEmission {
    /// Which emission this is.
    pub fn kind(&self) -> EmissionKind {
        match self {
            AnyEmission::Gaussian(g) => EmissionKind::Gaussian(g.covariance_type()),
            AnyEmission::StudentT(_) => EmissionKind::StudentT,
            AnyEmission::Mixture(m) => EmissionKind::GaussianMixture(m.n_components()),
        }
    }

    /// The Gaussian states, when this is one Gaussian per state.
    pub fn as_gaussian(&self) -> Option<&Gaussian> {
        match self {
            AnyEmission::Gaussian(g) => Some(g),
            _ => None,
        }
    }

    /// The mean `E[x | state]` of state `i` (length `D`): a Gaussian's or a
    /// Student-t's location, a mixture's weighted mean of its components.
    ///
    /// # Panics
    /// If `i ≥ S`.
    pub fn mean(&self, i: usize) -> Cow<'_, [f64]> {
        match self {
            AnyEmission::Gaussian(g) => Cow::Borrowed(g.mean(i)),
            AnyEmission::StudentT(t) => Cow::Borrowed(t.states()[i].mean()),
            AnyEmission::Mixture(m) => Cow::Owned(self.mixture_moments(m, i).0),
        }
    }

    /// Every state's mean, `S × D` row-major.
    pub fn means(&self) -> Cow<'_, [f64]> {
        match self {
            AnyEmission::Gaussian(g) => Cow::Borrowed(g.means()),
            _ => Cow::Owned(
                (0..self.n_states())
                    .flat_map(|i| self.mean(i).into_owned())
                    .collect(),
            ),
        }
    }

    /// The covariance `Cov[x | state]` of state `i` (`D × D`): a Gaussian's;
    /// a Student-t's `ν/(ν − 2) Σ` (its scale `Σ` when `ν ≤ 2`, where the
    /// covariance is infinite); a mixture's moment-matched
    /// `Σ_m w_m (Σ_m + μ_m μ_mᵀ) − μ μᵀ`. What plots draw and the model
    /// files check.
    ///
    /// # Panics
    /// If `i ≥ S`.
    pub fn covariance(&self, i: usize) -> DMatrix<f64> {
        match self {
            AnyEmission::Gaussian(g) => g.covariance(i),
            AnyEmission::StudentT(t) => {
                let s = &t.states()[i];
                let d = s.mean().len();
                let nu = s.dof();
                let f = if nu > 2.0 { nu / (nu - 2.0) } else { 1.0 };
                DMatrix::from_row_slice(d, d, s.scale()) * f
            }
            AnyEmission::Mixture(m) => self.mixture_moments(m, i).1,
        }
    }

    fn mixture_moments(&self, m: &MixtureEmission<Gaussian>, i: usize) -> (Vec<f64>, DMatrix<f64>) {
        let comps = m.components(i);
        let (k, d) = (m.n_components(), comps.dim());
        let w = &m.weights()[i * k..(i + 1) * k];
        let mut mean = vec![0.0; d];
        for (c, wc) in w.iter().enumerate() {
            for (a, v) in mean.iter_mut().zip(comps.mean(c)) {
                *a += wc * v;
            }
        }
        let mut cov = DMatrix::zeros(d, d);
        for (c, wc) in w.iter().enumerate() {
            let mu = comps.mean(c);
            let sc = comps.covariance(c);
            for r in 0..d {
                for q in 0..d {
                    cov[(r, q)] += wc * (sc[(r, q)] + (mu[r] - mean[r]) * (mu[q] - mean[q]));
                }
            }
        }
        (mean, cov)
    }
}

impl Emission for AnyEmission {
    type Stats = AnyStats;

    fn n_states(&self) -> usize {
        dispatch!(AnyEmission, self, e => e.n_states())
    }

    fn dim(&self) -> usize {
        dispatch!(AnyEmission, self, e => e.dim())
    }

    fn check_frames(&self, frames: Frames<'_>) -> phasekit_emission::Result<()> {
        dispatch!(AnyEmission, self, e => e.check_frames(frames))
    }

    fn log_density_into(
        &self,
        frames: Frames<'_>,
        out: &mut [f64],
    ) -> phasekit_emission::Result<()> {
        dispatch!(AnyEmission, self, e => e.log_density_into(frames, out))
    }

    fn new_stats(&self) -> AnyStats {
        match self {
            AnyEmission::Gaussian(e) => AnyStats::Gaussian(e.new_stats()),
            AnyEmission::StudentT(e) => AnyStats::StudentT(e.new_stats()),
            AnyEmission::Mixture(e) => AnyStats::Mixture(e.new_stats()),
        }
    }

    fn accumulate(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut AnyStats,
    ) -> phasekit_emission::Result<()> {
        match (self, stats) {
            (AnyEmission::Gaussian(e), AnyStats::Gaussian(s)) => e.accumulate(frames, weights, s),
            (AnyEmission::StudentT(e), AnyStats::StudentT(s)) => e.accumulate(frames, weights, s),
            (AnyEmission::Mixture(e), AnyStats::Mixture(s)) => e.accumulate(frames, weights, s),
            _ => Err(mismatch("statistics")),
        }
    }

    fn m_step(
        &mut self,
        stats: &AnyStats,
        reg: &Regularisation,
    ) -> phasekit_emission::Result<MStepReport> {
        match (self, stats) {
            (AnyEmission::Gaussian(e), AnyStats::Gaussian(s)) => e.m_step(s, reg),
            (AnyEmission::StudentT(e), AnyStats::StudentT(s)) => e.m_step(s, reg),
            (AnyEmission::Mixture(e), AnyStats::Mixture(s)) => e.m_step(s, reg),
            _ => Err(mismatch("statistics")),
        }
    }

    fn log_prior(&self, reg: &Regularisation) -> f64 {
        dispatch!(AnyEmission, self, e => e.log_prior(reg))
    }

    fn sample_into<R: Rng + ?Sized>(
        &self,
        state: usize,
        rng: &mut R,
        out: &mut [f64],
    ) -> phasekit_emission::Result<()> {
        dispatch!(AnyEmission, self, e => e.sample_into(state, rng, out))
    }

    fn n_parameters(&self) -> usize {
        dispatch!(AnyEmission, self, e => e.n_parameters())
    }

    fn initialise<R: Rng + ?Sized>(
        &self,
        parts: &[(Frames<'_>, &[f64])],
        reg: &Regularisation,
        rng: &mut R,
    ) -> phasekit_emission::Result<(Self, MStepReport)> {
        Ok(match self {
            AnyEmission::Gaussian(e) => {
                let (m, r) = e.initialise(parts, reg, rng)?;
                (AnyEmission::Gaussian(m), r)
            }
            AnyEmission::StudentT(e) => {
                let (m, r) = e.initialise(parts, reg, rng)?;
                (AnyEmission::StudentT(m), r)
            }
            AnyEmission::Mixture(e) => {
                let (m, r) = e.initialise(parts, reg, rng)?;
                (AnyEmission::Mixture(m), r)
            }
        })
    }
}

impl Marginal for AnyEmission {
    fn marginal(&self, dims: &[usize]) -> phasekit_emission::Result<Self> {
        Ok(match self {
            AnyEmission::Gaussian(e) => AnyEmission::Gaussian(e.marginal(dims)?),
            AnyEmission::StudentT(e) => AnyEmission::StudentT(e.marginal(dims)?),
            AnyEmission::Mixture(e) => AnyEmission::Mixture(e.marginal(dims)?),
        })
    }
}

impl ConcatStates for AnyEmission {
    fn concat_states(&self, other: &Self) -> phasekit_emission::Result<Self> {
        Ok(match (self, other) {
            (AnyEmission::Gaussian(a), AnyEmission::Gaussian(b)) => {
                let tied = CovarianceType::Tied;
                if a.covariance_type() == tied
                    && b.covariance_type() == tied
                    && a.covariances_raw() != b.covariances_raw()
                {
                    // Two tied models share no covariance: the union has one
                    // full covariance per state (each part's own, unchanged).
                    AnyEmission::Gaussian(a.to_full()?.concat_states(&b.to_full()?)?)
                } else {
                    AnyEmission::Gaussian(a.concat_states(b)?)
                }
            }
            (AnyEmission::StudentT(a), AnyEmission::StudentT(b)) => {
                AnyEmission::StudentT(a.concat_states(b)?)
            }
            (AnyEmission::Mixture(a), AnyEmission::Mixture(b)) => {
                AnyEmission::Mixture(a.concat_states(b)?)
            }
            (a, b) => {
                return Err(EmissionError::InvalidParameter {
                    name: "emission",
                    reason: format!(
                        "cannot join {} states and {} states in one emission",
                        a.kind(),
                        b.kind()
                    ),
                })
            }
        })
    }
}

impl Conditional for AnyEmission {
    type Split = AnySplit;

    fn conditional(
        &self,
        input: &[usize],
        output: &[usize],
    ) -> phasekit_emission::Result<AnySplit> {
        Ok(match self {
            AnyEmission::Gaussian(e) => AnySplit::Gaussian(e.conditional(input, output)?),
            AnyEmission::StudentT(e) => AnySplit::StudentT(e.conditional(input, output)?),
            AnyEmission::Mixture(e) => AnySplit::Mixture(e.conditional(input, output)?),
        })
    }
}

impl ConditionalSplit for AnySplit {
    fn n_states(&self) -> usize {
        dispatch!(AnySplit, self, s => s.n_states())
    }

    fn input_dims(&self) -> &[usize] {
        dispatch!(AnySplit, self, s => s.input_dims())
    }

    fn output_dims(&self) -> &[usize] {
        dispatch!(AnySplit, self, s => s.output_dims())
    }

    fn input_log_density(&mut self, state: usize, input: &[f64]) -> phasekit_emission::Result<f64> {
        dispatch!(AnySplit, self, s => s.input_log_density(state, input))
    }

    fn predict(
        &mut self,
        state: usize,
        input: &[f64],
        mean: &mut [f64],
        covariance: &mut [f64],
    ) -> phasekit_emission::Result<()> {
        dispatch!(AnySplit, self, s => s.predict(state, input, mean, covariance))
    }
}

impl From<Gaussian> for AnyEmission {
    fn from(g: Gaussian) -> Self {
        AnyEmission::Gaussian(g)
    }
}

impl From<PerState<StudentT>> for AnyEmission {
    fn from(t: PerState<StudentT>) -> Self {
        AnyEmission::StudentT(t)
    }
}

impl From<MixtureEmission<Gaussian>> for AnyEmission {
    fn from(m: MixtureEmission<Gaussian>) -> Self {
        AnyEmission::Mixture(m)
    }
}

/// The key naming a non-Gaussian emission in a file, and the key of its parameters.
const TAG: &str = "emission";
const BODY: &str = "model";

impl Serialize for AnyEmission {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        match self {
            AnyEmission::Gaussian(g) => g.serialize(s),
            AnyEmission::StudentT(t) => {
                let mut m = s.serialize_map(Some(2))?;
                m.serialize_entry(TAG, &self.kind())?;
                m.serialize_entry(BODY, t)?;
                m.end()
            }
            AnyEmission::Mixture(x) => {
                let mut m = s.serialize_map(Some(2))?;
                m.serialize_entry(TAG, &self.kind())?;
                m.serialize_entry(BODY, x)?;
                m.end()
            }
        }
    }
}

impl<'de> Deserialize<'de> for AnyEmission {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        d.deserialize_map(AnyVisitor)
    }
}

struct AnyVisitor;

impl<'de> Visitor<'de> for AnyVisitor {
    type Value = AnyEmission;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("an emission: Gaussian parameters, or {\"emission\": NAME, \"model\": ...}")
    }

    fn visit_map<A: MapAccess<'de>>(
        self,
        mut map: A,
    ) -> std::result::Result<AnyEmission, A::Error> {
        let Some(first) = map.next_key::<String>()? else {
            return Err(de::Error::custom("an emission cannot be an empty object"));
        };
        if first != TAG {
            // A Gaussian, as `Gaussian` writes itself: hand it the whole map.
            return Gaussian::deserialize(de::value::MapAccessDeserializer::new(Prepended {
                key: Some(first),
                map,
            }))
            .map(AnyEmission::Gaussian);
        }
        let kind: EmissionKind = map.next_value()?;
        match map.next_key::<String>()? {
            Some(k) if k == BODY => {}
            _ => return Err(de::Error::missing_field(BODY)),
        }
        let e = match kind {
            EmissionKind::StudentT => AnyEmission::StudentT(map.next_value()?),
            EmissionKind::GaussianMixture(k) => {
                let m: MixtureEmission<Gaussian> = map.next_value()?;
                if m.n_components() != k {
                    return Err(de::Error::custom(format!(
                        "the emission is {kind} but its mixtures have {} components",
                        m.n_components()
                    )));
                }
                AnyEmission::Mixture(m)
            }
            EmissionKind::Gaussian(c) => {
                let g: Gaussian = map.next_value()?;
                if g.covariance_type() != c {
                    return Err(de::Error::custom(format!(
                        "the emission is {kind} but its covariances are {:?}",
                        g.covariance_type()
                    )));
                }
                AnyEmission::Gaussian(g)
            }
        };
        if let Some(k) = map.next_key::<String>()? {
            return Err(de::Error::custom(format!(
                "unknown field `{k}` after the emission"
            )));
        }
        Ok(e)
    }
}

/// A map whose first key was already read.
struct Prepended<A> {
    key: Option<String>,
    map: A,
}

impl<'de, A: MapAccess<'de>> MapAccess<'de> for Prepended<A> {
    type Error = A::Error;

    fn next_key_seed<K: de::DeserializeSeed<'de>>(
        &mut self,
        seed: K,
    ) -> std::result::Result<Option<K::Value>, A::Error> {
        match self.key.take() {
            Some(k) => seed.deserialize(k.into_deserializer()).map(Some),
            None => self.map.next_key_seed(seed),
        }
    }

    fn next_value_seed<V: de::DeserializeSeed<'de>>(
        &mut self,
        seed: V,
    ) -> std::result::Result<V::Value, A::Error> {
        self.map.next_value_seed(seed)
    }
}

/// The first two moments of every state: what the command draws (state
/// ellipses) and checks (that a state is resolvable in floating point), for
/// any emission it reads from a model file.
pub trait StateMoments {
    /// Number of states.
    fn moment_states(&self) -> usize;
    /// `E[x | state i]`.
    fn state_mean(&self, i: usize) -> Cow<'_, [f64]>;
    /// `Cov[x | state i]` (see [`AnyEmission::covariance`]).
    fn state_covariance(&self, i: usize) -> DMatrix<f64>;
}

impl StateMoments for Gaussian {
    fn moment_states(&self) -> usize {
        self.n_states()
    }
    fn state_mean(&self, i: usize) -> Cow<'_, [f64]> {
        Cow::Borrowed(self.mean(i))
    }
    fn state_covariance(&self, i: usize) -> DMatrix<f64> {
        self.covariance(i)
    }
}

impl StateMoments for AnyEmission {
    fn moment_states(&self) -> usize {
        self.n_states()
    }
    fn state_mean(&self, i: usize) -> Cow<'_, [f64]> {
        self.mean(i)
    }
    fn state_covariance(&self, i: usize) -> DMatrix<f64> {
        self.covariance(i)
    }
}

/// The same HMM with its emission held as an [`AnyEmission`] (to build a
/// `Predictor` from an HMM of a concrete emission type).
pub fn any_hmm<E: Emission + Into<AnyEmission>>(
    hmm: phasekit_hmm::Hmm<E>,
) -> phasekit_hmm::Result<phasekit_hmm::Hmm<AnyEmission>> {
    phasekit_hmm::Hmm::new(
        hmm.start().to_vec(),
        hmm.transition().to_vec(),
        hmm.emission().clone().into(),
    )
}
