//! Labellers and transition detectors.
//!
//! A labeller assigns a state to every frame (a GMM's most responsible
//! component, an HMM's Viterbi path, or the argmax of the HMM's forward
//! variable on all dims or on a marginal). A detector turns one labelling
//! (label changes) or two labellings (their disagreement) into per-frame
//! transition flags, dilated by ±w frames; runs of flagged frames are the
//! transition segments.

use crate::error::Result;
use phasekit_emission::{Emission, Frames};
use phasekit_gmm::MixtureModel;
use phasekit_hmm::Hmm;
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

/// Selects the columns `dims` of every frame.
pub fn select(seq: Frames<'_>, dims: &[usize]) -> Vec<f64> {
    seq.iter()
        .flat_map(|x| dims.iter().map(move |&d| x[d]))
        .collect()
}

/// Labels by the most responsible mixture component.
pub struct MixtureLabeller<'a, E: Emission>(pub &'a MixtureModel<E>);

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

/// Labels by `argmax_i h_t(i)`, the causal (filtered) belief, computed on
/// the dims `dims` of the frames (all dims when `None`).
pub struct FilterLabeller<E: Emission> {
    hmm: Hmm<E>,
    dims: Option<Vec<usize>>,
}

impl<E: Emission> FilterLabeller<E> {
    /// Filtered argmax on all dims of `hmm`.
    pub fn joint(hmm: &Hmm<E>) -> Self {
        FilterLabeller {
            hmm: hmm.clone(),
            dims: None,
        }
    }

    /// Filtered argmax on the marginal of `hmm` on `dims` (e.g. the human's).
    pub fn marginal(hmm: &Hmm<E>, dims: &[usize]) -> Result<Self> {
        Ok(FilterLabeller {
            hmm: hmm.marginal(dims)?,
            dims: Some(dims.to_vec()),
        })
    }
}

impl<E: Emission> Labeller for FilterLabeller<E> {
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

/// Flags frames where two labellings disagree.
pub fn disagreement(a: &[usize], b: &[usize]) -> Vec<bool> {
    a.iter().zip(b).map(|(x, y)| x != y).collect()
}

/// Widens every flagged frame to `±w` frames.
pub fn dilate(flags: &[bool], w: usize) -> Vec<bool> {
    let n = flags.len();
    let mut out = vec![false; n];
    for (t, f) in flags.iter().enumerate() {
        if *f {
            out[t.saturating_sub(w)..(t + w + 1).min(n)].fill(true);
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
