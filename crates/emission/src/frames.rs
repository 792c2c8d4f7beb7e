//! Contiguous, validated views of frames.
//!
//! A sequence of `T` frames of dimension `D` is stored row-major: frame `t`
//! occupies `data[t*D .. (t+1)*D]`. The same memory is a column-major `D × T`
//! matrix, which is how the linear algebra sees it, without a copy.
//!
//! A NaN value means "not observed" (a dropped marker, an empty CSV cell).
//! Every emission evaluates such a frame on the marginal of its observed
//! dimensions and accumulates the expected statistics of the missing ones;
//! a frame with nothing observed has density 1 under every state. Infinity is
//! always an error. Whether a block has any missing value is found once, at
//! construction, so that complete data take the plain code paths unchanged.

use crate::error::{EmissionError, Result};

/// A borrowed, validated block of `len()` frames of dimension `dim()`.
///
/// Validation happens once in [`Frames::new`]; every model then reads the data
/// without further checks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frames<'a> {
    data: &'a [f64],
    dim: usize,
    /// True when some value is NaN (not observed).
    missing: bool,
}

impl<'a> Frames<'a> {
    /// Wraps `data` as frames of dimension `dim`. A NaN value means "not
    /// observed"; every other value must be finite.
    ///
    /// Errors name the frame and column of the first infinite value.
    pub fn new(data: &'a [f64], dim: usize) -> Result<Self> {
        if dim == 0 {
            return Err(EmissionError::InvalidParameter {
                name: "dim",
                reason: "frames must have at least one dimension".into(),
            });
        }
        if data.len() % dim != 0 {
            return Err(EmissionError::DimensionMismatch {
                context: "frames: data length is not a multiple of the dimension",
                expected: dim * (data.len() / dim + 1),
                found: data.len(),
            });
        }
        if let Some(i) = data.iter().position(|v| v.is_infinite()) {
            return Err(EmissionError::InvalidValue {
                frame: i / dim,
                column: i % dim,
                value: data[i],
                reason: "value is infinite (a missing value is NaN; infinity is refused)",
            });
        }
        Ok(Frames {
            data,
            dim,
            missing: any_missing(data),
        })
    }

    /// True when some value is NaN (not observed).
    #[inline]
    pub fn has_missing(&self) -> bool {
        self.missing
    }

    /// Number of missing values (NaN) in the block.
    pub fn missing_count(&self) -> usize {
        if self.missing {
            self.data.iter().filter(|v| v.is_nan()).count()
        } else {
            0
        }
    }

    /// Number of frames.
    #[inline]
    pub fn len(&self) -> usize {
        self.data.len() / self.dim
    }

    /// True when there are no frames.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Dimension of each frame.
    #[inline]
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Frame `t` as a slice of length `dim()`.
    ///
    /// # Panics
    /// If `t ≥ len()` (like slice indexing).
    #[inline]
    pub fn frame(&self, t: usize) -> &'a [f64] {
        &self.data[t * self.dim..(t + 1) * self.dim]
    }

    /// The whole row-major block.
    #[inline]
    pub fn as_slice(&self) -> &'a [f64] {
        self.data
    }

    /// Iterator over the frames.
    pub fn iter(&self) -> std::slice::ChunksExact<'a, f64> {
        self.data.chunks_exact(self.dim)
    }

    /// Frames `range.start .. range.end` (no re-validation needed; the missing
    /// flag is recomputed for the slice only when the block has missing values).
    ///
    /// # Panics
    /// If the range is decreasing or ends after `len()` (like slice indexing);
    /// [`Frames::try_slice`] is the checked form.
    pub fn slice(&self, range: std::ops::Range<usize>) -> Frames<'a> {
        let data = &self.data[range.start * self.dim..range.end * self.dim];
        Frames {
            data,
            dim: self.dim,
            missing: self.missing && any_missing(data),
        }
    }
}

impl<'a> Frames<'a> {
    /// [`Frames::slice`], or the error naming the range and the length.
    pub fn try_slice(&self, range: std::ops::Range<usize>) -> Result<Frames<'a>> {
        if range.start > range.end || range.end > self.len() {
            return Err(EmissionError::InvalidParameter {
                name: "range",
                reason: format!(
                    "frames {}..{} of a block of {} frames",
                    range.start,
                    range.end,
                    self.len()
                ),
            });
        }
        Ok(self.slice(range))
    }

    /// Frames `range` known to hold no missing value (no scan).
    #[inline]
    pub(crate) fn slice_complete(&self, range: std::ops::Range<usize>) -> Frames<'a> {
        Frames {
            data: &self.data[range.start * self.dim..range.end * self.dim],
            dim: self.dim,
            missing: false,
        }
    }
}

/// True when some value is NaN.
#[inline]
fn any_missing(data: &[f64]) -> bool {
    // A fold without early exit vectorises; the scan is one pass over data
    // that every caller reads anyway.
    data.iter().fold(false, |acc, v| acc | v.is_nan())
}

/// Many variable-length sequences of frames in one contiguous buffer.
///
/// Sequence `k` is frames `offsets[k] .. offsets[k+1]` of the buffer.
#[derive(Debug, Clone, PartialEq)]
pub struct SequenceSet {
    data: Vec<f64>,
    dim: usize,
    offsets: Vec<usize>,
    /// Per sequence: some value is NaN (not observed).
    missing: Vec<bool>,
}

impl SequenceSet {
    /// Builds a set from row-major sequences, each `len_k × dim`. NaN values
    /// mean "not observed" (see the module documentation).
    ///
    /// Errors say which sequence, frame and column is bad; empty sequences are refused.
    pub fn new<S: AsRef<[f64]>>(sequences: &[S], dim: usize) -> Result<Self> {
        let mut data = Vec::with_capacity(sequences.iter().map(|s| s.as_ref().len()).sum());
        let mut offsets = vec![0];
        let mut missing = Vec::with_capacity(sequences.len());
        for (k, s) in sequences.iter().enumerate() {
            let s = s.as_ref();
            let frames = Frames::new(s, dim).map_err(|e| match e {
                EmissionError::InvalidValue {
                    frame,
                    column,
                    value,
                    reason,
                } => EmissionError::InvalidParameter {
                    name: "sequences",
                    reason: format!(
                        "sequence {k}, frame {frame}, column {column}: {reason} (value {value})"
                    ),
                },
                EmissionError::DimensionMismatch { found, .. } => EmissionError::InvalidParameter {
                    name: "sequences",
                    reason: format!(
                        "sequence {k} has {found} values, not a multiple of the dimension {dim}"
                    ),
                },
                other => other,
            })?;
            if frames.is_empty() {
                return Err(EmissionError::InvalidParameter {
                    name: "sequences",
                    reason: format!("sequence {k} is empty"),
                });
            }
            data.extend_from_slice(s);
            offsets.push(offsets.last().unwrap() + frames.len());
            missing.push(frames.has_missing());
        }
        if dim == 0 {
            return Err(EmissionError::InvalidParameter {
                name: "dim",
                reason: "frames must have at least one dimension".into(),
            });
        }
        Ok(SequenceSet {
            data,
            dim,
            offsets,
            missing,
        })
    }

    /// One sequence stored as a single block.
    pub fn single(data: &[f64], dim: usize) -> Result<Self> {
        Self::new(&[data], dim)
    }

    /// Number of sequences.
    pub fn len(&self) -> usize {
        self.offsets.len() - 1
    }

    /// True when there is no sequence.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Dimension of every frame.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Total number of frames over all sequences.
    pub fn total_frames(&self) -> usize {
        *self.offsets.last().unwrap()
    }

    /// Length of every sequence.
    pub fn lengths(&self) -> impl Iterator<Item = usize> + '_ {
        self.offsets.windows(2).map(|w| w[1] - w[0])
    }

    /// Sequence `k`.
    ///
    /// # Panics
    /// If `k ≥ len()` (like slice indexing); [`SequenceSet::sequence`] is the
    /// checked form.
    pub fn get(&self, k: usize) -> Frames<'_> {
        Frames {
            data: &self.data[self.offsets[k] * self.dim..self.offsets[k + 1] * self.dim],
            dim: self.dim,
            missing: self.missing[k],
        }
    }

    /// Sequence `k`, or the error naming it and the number of sequences.
    pub fn sequence(&self, k: usize) -> Result<Frames<'_>> {
        if k >= self.len() {
            return Err(EmissionError::InvalidParameter {
                name: "sequence",
                reason: format!("sequence {k} out of range ({} sequences)", self.len()),
            });
        }
        Ok(self.get(k))
    }

    /// True when some value of some sequence is NaN (not observed).
    pub fn has_missing(&self) -> bool {
        self.missing.iter().any(|m| *m)
    }

    /// Iterator over the sequences.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = Frames<'_>> + '_ {
        (0..self.len()).map(move |k| self.get(k))
    }

    /// All frames of all sequences as one block.
    pub fn all_frames(&self) -> Frames<'_> {
        Frames {
            data: &self.data,
            dim: self.dim,
            missing: self.has_missing(),
        }
    }

    /// A new set holding only the given columns of every frame, in that order.
    pub fn select_columns(&self, columns: &[usize]) -> Result<Self> {
        crate::check_dims(columns, self.dim)?;
        let mut data = Vec::with_capacity(self.total_frames() * columns.len());
        for frame in self.data.chunks_exact(self.dim) {
            data.extend(columns.iter().map(|&c| frame[c]));
        }
        let missing = self
            .offsets
            .windows(2)
            .map(|w| any_missing(&data[w[0] * columns.len()..w[1] * columns.len()]))
            .collect();
        Ok(SequenceSet {
            data,
            dim: columns.len(),
            offsets: self.offsets.clone(),
            missing,
        })
    }

    /// A new set holding the sequences with the given indices, in that order.
    pub fn subset(&self, indices: &[usize]) -> Result<Self> {
        let mut seqs = Vec::with_capacity(indices.len());
        for &k in indices {
            if k >= self.len() {
                return Err(EmissionError::InvalidParameter {
                    name: "indices",
                    reason: format!("sequence index {k} out of range ({} sequences)", self.len()),
                });
            }
            seqs.push(self.get(k).as_slice());
        }
        Self::new(&seqs, self.dim)
    }
}

/// The shape of an emission: `n_states` distributions over frames of `dim` values.
///
/// Named fields, so that a call such as
/// `Gaussian::standard(CovarianceType::Full, Shape { n_states: 4, dim: 12 })`
/// says which number is which. (Its fields are public on purpose: it is a
/// pair of named arguments, with nothing to validate on its own.)
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Shape {
    /// Number of states `S`.
    pub n_states: usize,
    /// Dimension `D` of a frame.
    pub dim: usize,
}
