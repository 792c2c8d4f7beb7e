//! Shared machinery for missing values (NaN = "not observed"), public so
//! that every emission, built in or plug-in, follows one rule:
//!
//! * [`crate::Emission::log_density_into`] evaluates a frame with NaN on the
//!   marginal of its observed values, `b_i(x_o) = ∫ b_i(x) dx_m` (1, i.e.
//!   `log b_i = 0`, when nothing is observed), and
//!   [`crate::Emission::check_frames`] does not refuse NaN (an emission that
//!   cannot marginalise says so with an error, never a guess);
//! * [`crate::Emission::accumulate`] adds the expected sufficient statistics
//!   `E[φ(x) | x_o, state i]` under the current parameters, and nothing for a
//!   frame with nothing observed (its density does not depend on them).
//!
//! Frames are walked as maximal runs of complete frames, which go through the
//! plain (vectorised) kernels unchanged, and single incomplete frames, which
//! are handled on the marginal of their observed dimensions. Quantities that
//! depend only on which dimensions are missing (a marginal model, a
//! conditional) are cached per missing pattern, so a dropped marker that stays
//! dropped for many frames costs one factorisation, not one per frame.

use std::collections::HashMap;
use std::ops::Range;

use crate::Frames;

/// Calls `f(range, complete)` for the maximal runs of complete frames
/// (`complete = true`) and for every incomplete frame (`complete = false`,
/// a range of length 1), in frame order.
pub fn for_each_run<E>(
    frames: Frames<'_>,
    mut f: impl FnMut(Range<usize>, bool) -> Result<(), E>,
) -> Result<(), E> {
    let n = frames.len();
    let mut t = 0;
    while t < n {
        let start = t;
        while t < n && !has_nan(frames.frame(t)) {
            t += 1;
        }
        if t > start {
            f(start..t, true)?;
        }
        if t < n {
            f(t..t + 1, false)?;
            t += 1;
        }
    }
    Ok(())
}

/// True when some value of `x` is NaN (not observed).
#[inline]
pub fn has_nan(x: &[f64]) -> bool {
    x.iter().any(|v| v.is_nan())
}

/// Writes the indices of the observed (non-NaN) values of `x` into `obs`.
#[inline]
pub fn observed_dims(x: &[f64], obs: &mut Vec<usize>) {
    obs.clear();
    obs.extend(
        x.iter()
            .enumerate()
            .filter(|(_, v)| !v.is_nan())
            .map(|(k, _)| k),
    );
}

/// Values cached by missing pattern (the set of NaN positions of a frame):
/// a marginal model or a conditional, built once per pattern.
///
/// Bounded: when `CAPACITY` patterns are held, the cache is emptied, so that
/// data whose every frame misses a different set of values cannot grow it
/// without limit.
#[derive(Debug)]
pub struct PatternCache<V> {
    map: HashMap<Vec<u64>, V>,
    key: Vec<u64>,
}

const CAPACITY: usize = 4096;

impl<V> Default for PatternCache<V> {
    fn default() -> Self {
        Self::new()
    }
}

impl<V> PatternCache<V> {
    /// An empty cache.
    pub fn new() -> Self {
        PatternCache {
            map: HashMap::new(),
            key: Vec::new(),
        }
    }

    /// The value for the missing pattern of `x`, built by `make` on first use.
    pub fn get_or_try_insert<E>(
        &mut self,
        x: &[f64],
        make: impl FnOnce() -> Result<V, E>,
    ) -> Result<&V, E> {
        self.key.clear();
        self.key.resize(x.len().div_ceil(64), 0);
        for (k, v) in x.iter().enumerate() {
            if v.is_nan() {
                self.key[k / 64] |= 1 << (k % 64);
            }
        }
        if !self.map.contains_key(self.key.as_slice()) {
            if self.map.len() >= CAPACITY {
                self.map.clear();
            }
            let v = make()?;
            self.map.insert(self.key.clone(), v);
        }
        Ok(&self.map[self.key.as_slice()])
    }
}
