//! Labellers and transition detectors.
//!
//! A labeller assigns a state to every frame (a GMM's most responsible
//! component, an HMM's Viterbi path, or the argmax of the HMM's forward
//! variable on all dims or on a marginal). A detector turns one labelling
//! (label changes) or two labellings (their disagreement) into per-frame
//! transition flags, dilated by ±w frames; runs of flagged frames are the
//! transition segments.

use crate::error::{Result, TscError};
use phasekit_emission::{Emission, Frames, Marginal};
use phasekit_gmm::Gmm;
use phasekit_hmm::Hmm;
use std::borrow::Cow;
use std::ops::Range;

/// Anything that assigns a state to each frame of a sequence.
pub trait Labeller {
    /// One label per frame.
    fn label(&self, seq: Frames<'_>) -> Result<Vec<usize>>;
}

/// Index of the largest value (ties to the lower index).
pub fn argmax(v: &[f64]) -> usize {
    v.iter()
        .enumerate()
        .fold(
            (0, f64::NEG_INFINITY),
            |b, (j, x)| if *x > b.1 { (j, *x) } else { b },
        )
        .0
}

/// Selects the columns `dims` of every frame, `T × |dims|` row-major.
///
/// # Panics
///
/// When a dim is not below the frames' dimension; check the dims first (as
/// [`crate::Roles::check`] does), or use [`crate::human_frames`], which checks.
pub fn select(seq: Frames<'_>, dims: &[usize]) -> Vec<f64> {
    seq.iter()
        .flat_map(|x| dims.iter().map(move |&d| x[d]))
        .collect()
}

/// Labels by the most responsible mixture component.
pub struct MixtureLabeller<'a, E: Emission>(pub &'a Gmm<E>);

impl<E: Emission> Labeller for MixtureLabeller<'_, E> {
    fn label(&self, seq: Frames<'_>) -> Result<Vec<usize>> {
        Ok(self.0.predict(seq)?)
    }
}

/// Labels by the Viterbi path.
pub struct ViterbiLabeller<'a, E: Emission>(pub &'a Hmm<E>);

impl<E: Emission> Labeller for ViterbiLabeller<'_, E> {
    fn label(&self, seq: Frames<'_>) -> Result<Vec<usize>> {
        Ok(self.0.viterbi(seq)?.states)
    }
}

/// Labels by `argmax_i h_t(i)`, the causal (filtered) belief
/// `h_t(i) = p(z_t = i | o_{1:t})` (the normalised forward variable α_t, which
/// includes the current frame), computed on the dims `dims` of the frames (all
/// dims when `None`) with the model's marginal on those dims.
///
/// The joint labeller borrows the model; the marginal one owns its marginal HMM.
pub struct FilterLabeller<'a, E: Emission> {
    hmm: Cow<'a, Hmm<E>>,
    dims: Option<Vec<usize>>,
}

impl<'a, E: Emission> FilterLabeller<'a, E> {
    /// Filtered argmax on all dims of `hmm`.
    pub fn joint(hmm: &'a Hmm<E>) -> Self {
        FilterLabeller {
            hmm: Cow::Borrowed(hmm),
            dims: None,
        }
    }
}

impl<E: Marginal> FilterLabeller<'_, E> {
    /// Filtered argmax on the marginal of `hmm` on `dims` (e.g. the human's).
    pub fn marginal(hmm: &Hmm<E>, dims: &[usize]) -> Result<Self> {
        Ok(FilterLabeller {
            hmm: Cow::Owned(hmm.marginal(dims)?),
            dims: Some(dims.to_vec()),
        })
    }
}

impl<E: Emission> Labeller for FilterLabeller<'_, E> {
    fn label(&self, seq: Frames<'_>) -> Result<Vec<usize>> {
        let s = self.hmm.n_states();
        let forward = match &self.dims {
            None => self.hmm.forward(seq)?,
            Some(d) => {
                let sub = select(seq, d);
                self.hmm.forward(Frames::new(&sub, d.len())?)?
            }
        };
        Ok(forward.filtered().chunks_exact(s).map(argmax).collect())
    }
}

/// A detector made of two labellers: frame `t` is flagged when their labels differ,
/// `f_t = [a(o)_t ≠ b(o)_t]`.
///
/// The seed paper's transition states are
/// `Disagreement::new(FilterLabeller::joint(λ), FilterLabeller::marginal(λ, human)?)`:
/// the state believed from both partners and the one believed from the human alone.
pub struct Disagreement<A: Labeller, B: Labeller> {
    a: A,
    b: B,
}

impl<A: Labeller, B: Labeller> Disagreement<A, B> {
    /// The detector of frames where `a` and `b` disagree.
    pub fn new(a: A, b: B) -> Self {
        Disagreement { a, b }
    }

    /// The first labeller.
    pub fn a(&self) -> &A {
        &self.a
    }

    /// The second labeller.
    pub fn b(&self) -> &B {
        &self.b
    }

    /// One flag per frame of `seq`.
    pub fn flags(&self, seq: Frames<'_>) -> Result<Vec<bool>> {
        disagreement(&self.a.label(seq)?, &self.b.label(seq)?)
    }
}

/// Flags frame `t` when the label changes at `t` (from `t − 1`) and the new
/// label then lasts at least `min_run` frames (`min_run = 2` ignores one-frame flips;
/// a flip that returns to the previous label is ignored entirely).
pub fn label_changes(labels: &[usize], min_run: usize) -> Vec<bool> {
    let n = labels.len();
    let mut flags = vec![false; n];
    // Smooth away runs shorter than `min_run` by carrying the previous stable label.
    let mut stable = Vec::with_capacity(n);
    let mut t = 0;
    while t < n {
        let mut end = t + 1;
        while end < n && labels[end] == labels[t] {
            end += 1;
        }
        let keep = end - t >= min_run.max(1) || stable.is_empty();
        let label = if keep {
            labels[t]
        } else {
            *stable.last().unwrap_or(&labels[t])
        };
        stable.extend(std::iter::repeat_n(label, end - t));
        t = end;
    }
    for t in 1..n {
        flags[t] = stable[t] != stable[t - 1];
    }
    flags
}

/// Flags frames where two labellings of the same frames disagree,
/// `f_t = [a_t ≠ b_t]`; errors when they label different numbers of frames.
pub fn disagreement(a: &[usize], b: &[usize]) -> Result<Vec<bool>> {
    if a.len() != b.len() {
        return Err(TscError::InvalidSetting {
            name: "labels",
            reason: format!(
                "two labellings of the same frames are needed, got {} and {} labels",
                a.len(),
                b.len()
            ),
        });
    }
    Ok(a.iter().zip(b).map(|(x, y)| x != y).collect())
}

/// Widens every flagged frame to `±w` frames: `out_t = ∃ s: flags_s ∧ |t − s| ≤ w`.
///
/// Any `w` is accepted (saturating arithmetic: `w ≥ T` flags the whole sequence
/// when any frame is flagged); callers bound `w` by the sequence length.
pub fn dilate(flags: &[bool], w: usize) -> Vec<bool> {
    let n = flags.len();
    let mut out = vec![false; n];
    for (t, f) in flags.iter().enumerate() {
        if *f {
            out[t.saturating_sub(w)..t.saturating_add(w).saturating_add(1).min(n)].fill(true);
        }
    }
    out
}

/// Maximal runs of flagged frames of at least `min_len` frames.
pub fn runs(flags: &[bool], min_len: usize) -> Vec<Range<usize>> {
    let mut out = Vec::new();
    let mut t = 0;
    while t < flags.len() {
        if flags[t] {
            let start = t;
            while t < flags.len() && flags[t] {
                t += 1;
            }
            if t - start >= min_len {
                out.push(start..t);
            }
        } else {
            t += 1;
        }
    }
    out
}

/// Flags the frames whose value in `errors` is among the largest `fraction`
/// of all values across `errors` (ties broken by position, deterministic).
pub fn worst_fraction(errors: &[Vec<f64>], fraction: f64) -> Vec<Vec<bool>> {
    let mut all: Vec<(f64, usize, usize)> = errors
        .iter()
        .enumerate()
        .flat_map(|(k, e)| e.iter().enumerate().map(move |(t, v)| (*v, k, t)))
        .collect();
    all.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let n = ((all.len() as f64) * fraction.clamp(0.0, 1.0)).round() as usize;
    let mut flags: Vec<Vec<bool>> = errors.iter().map(|e| vec![false; e.len()]).collect();
    for &(_, k, t) in &all[..n] {
        flags[k][t] = true;
    }
    flags
}
