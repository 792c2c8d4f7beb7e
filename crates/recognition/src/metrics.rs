//! How recognition is scored: decisions after observing a fraction of a
//! demonstration, the frame from which the decision is right for good, and
//! confusion matrices.

use crate::recogniser::Decision;

/// Frames observed after a fraction `k/10` of a demonstration of `t` frames:
/// `⌈k t / 10⌉` (at least one frame, at most `t`), in integer arithmetic.
pub fn frames_observed(t: usize, tenths: usize) -> usize {
    (tenths * t).div_ceil(10).clamp(1, t.max(1))
}

/// The first frame from which every decision is `truth` (the decision
/// "becomes and stays correct"), or `None` when the last one is not.
pub fn settled_frame(decisions: &[Decision], truth: usize) -> Option<usize> {
    let mut first = None;
    for (t, d) in decisions.iter().enumerate().rev() {
        if *d != Decision::Action(truth) {
            break;
        }
        first = Some(t);
    }
    first
}

/// The first frame from which the decision is `truth` for `hold` frames in a
/// row, or up to the end of `decisions` (a right run that the end cuts short
/// counts), or `None`. In a stream an interaction ends in rest, where the
/// decision may rightly move on, so "right to the end" would be the wrong test.
pub fn held_frame(decisions: &[Decision], truth: usize, hold: usize) -> Option<usize> {
    let mut run = 0;
    for (t, d) in decisions.iter().enumerate() {
        if *d == Decision::Action(truth) {
            run += 1;
            if run >= hold.max(1) {
                return Some(t + 1 - run);
            }
        } else {
            run = 0;
        }
    }
    (run > 0).then(|| decisions.len() - run)
}

/// Whether the decision is right from the first third of the demonstration on:
/// settled at or before frame `⌈T/3⌉ − 1` (the last frame of the first third).
pub fn correct_from_first_third(decisions: &[Decision], truth: usize) -> bool {
    let third = decisions.len().div_ceil(3).max(1) - 1;
    settled_frame(decisions, truth).is_some_and(|s| s <= third)
}

/// The median of `v` with `None` ordered after every number ("never");
/// `None` if the middle element is. The mean of the two middle elements for
/// an even count (`None` if either is).
pub fn median_or_never(v: &[Option<f64>]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mut s: Vec<f64> = v.iter().map(|x| x.unwrap_or(f64::INFINITY)).collect();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    let m = if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    };
    m.is_finite().then_some(m)
}

/// A confusion matrix: rows are the true actions, columns the decided ones,
/// then a column for *unknown* and one for *rest*.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Confusion {
    /// `A × (A + 2)` counts.
    pub counts: Vec<Vec<usize>>,
}

impl Confusion {
    /// An empty matrix for `a` actions.
    pub fn new(a: usize) -> Self {
        Confusion {
            counts: vec![vec![0; a + 2]; a],
        }
    }

    /// Counts one decision for a demonstration of `truth`.
    pub fn add(&mut self, truth: usize, d: Decision) {
        let a = self.counts.len();
        let column = match d {
            Decision::Action(x) => x,
            Decision::Unknown => a,
            Decision::Rest => a + 1,
        };
        self.counts[truth][column] += 1;
    }

    /// Adds another matrix.
    pub fn merge(&mut self, other: &Confusion) {
        for (r, o) in self.counts.iter_mut().zip(&other.counts) {
            r.iter_mut().zip(o).for_each(|(x, y)| *x += y);
        }
    }
}
