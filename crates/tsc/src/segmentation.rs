//! The segmentation of one demonstration: a state per frame, the transition
//! frames and their clusters.

use serde::{Deserialize, Serialize};

/// Per-demonstration output of a segmentation (read-only: made by
/// `Model::segment` and `KrishnanTsc::segment`; new fields may be added).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct Segmentation {
    /// State (component) of every frame, of the model that predicts: for a
    /// TSC-HMM with a union composition the union's states (`0..S` are `λ`'s,
    /// `S..S + S_T` the transition states of `λ_T`).
    pub labels: Vec<usize>,
    /// Frames flagged as transitions, in order.
    pub transitions: Vec<usize>,
    /// Cluster of every transition frame (`None` if its cluster was pruned or there are none).
    pub clusters: Vec<Option<usize>>,
    /// For a TSC-HMM: the base HMM `λ`'s Viterbi state of every frame (`0..S`),
    /// whose human-only and joint beliefs define the transitions; `None` for
    /// the other models.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base_labels: Option<Vec<usize>>,
}
