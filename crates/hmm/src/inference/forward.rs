//! The forward recursion in scaled form: [`super::formulas::forward_variable`]
//! carried as the filtered distribution `h_t(j) = α_t(j) / Σ_k α_t(k) =
//! p(z_t = j | x_0 … x_t)` and the log normaliser
//! `log c_t = log p(x_t | x_0 … x_{t−1})`, so that
//! `log α_t(j) = log h_t(j) + Σ_{s ≤ t} log c_s` and `log p(x) = Σ_t log c_t`.
//!
//! One step takes the prediction `p_t(j) = p(z_t = j | x_0 … x_{t−1})`
//! (`p_0 = π`, `p_{t+1} = Aᵀ h_t`) to `o_j = p_t(j) e^{log b_j(x_t) − m}`
//! with `m = max_j log b_j(x_t)` (so that densities far below `e^{−745}`, as
//! 36-dimensional Gaussians give, never underflow), `c = Σ_j o_j`,
//! `h_t = o / c` and `log c_t = m + ln c`.
//!
//! Linear arithmetic is exact while every reachable state's predicted
//! probability is at least [`SAFE`]: an underflowed term then carries an
//! absolute error below ~1e-308. When some reachable state's prediction
//! drops below it (a glitch frame rules a state out by more than `e^{−745}`
//! and the chain cannot re-enter it quickly), the prediction is carried in
//! log space until the dynamic range is small again, so that a state ruled
//! out by one frame can still come back when later frames favour it. A frame
//! no reachable state can explain is impossible: `log c_t = −∞`, `h_t = 0`,
//! and the recursion is left as it was. Forbidden transitions (`a_ij = 0`)
//! give `−∞`, never NaN.
//!
//! [`ForwardCore::step`] has two forms: the general one, which follows every
//! rule above, and a fast one for the common frame (linear mode, every state
//! reachable and every `a_ij > 0`, every density positive, no re-scaling,
//! every next prediction at least [`SAFE`]) without any per-state
//! bookkeeping. They do the same arithmetic in the same order on such a
//! frame, so the result does not depend on which one ran (tested against
//! each other and against [`super::formulas::forward_variable`]).

use super::kernels::{
    all_at_least, all_positive_densities, chunks, exp_shifted, max_lanes, padded, padded_rows,
    scale_lanes, sum_lanes, vec_mat, vec_mat_dyn, vec_mat_into, Lanes, PAD_LOG_B, RESCALE, SAFE, W,
};
use crate::model::Hmm;
use phasekit_emission::linalg::{dispatch, exp_slice, ln, log_sum_exp};
use phasekit_emission::Emission;

/// The forward recursion between two frames (see the module documentation).
///
/// Per-state vectors are padded chunks ([`Lanes`]); the log-densities it
/// takes are padded with [`super::kernels::PAD_LOG_B`], the filtered rows it
/// writes have zero padding. The batch [`Hmm::forward`], the E-step and the
/// online [`crate::ForwardFilter`] all step this, so they agree to the last bit.
#[derive(Debug, Clone)]
pub(crate) struct ForwardCore {
    s: usize,
    /// `A` as padded rows, and `log A` (row-major `S × S`).
    transition: Vec<Lanes>,
    log_transition: Vec<f64>,
    /// `A` row-major (for the structural checks).
    transition_dense: Vec<f64>,
    /// `π` (padded) and `log π`.
    start: Vec<Lanes>,
    log_start: Vec<f64>,
    /// `SAFE` on the lanes of real states, 0 on the padding.
    floor: Vec<Lanes>,
    /// Every `a_ij > 0`: after any possible frame every state is reachable.
    dense: bool,
    /// Linear prediction (valid when `!log_mode`), padded with zeros.
    pred: Vec<Lanes>,
    /// Log prediction (valid when `log_mode`).
    log_pred: Vec<f64>,
    /// Where the prediction is exactly positive (structural reachability).
    reachable: Vec<bool>,
    /// Every entry of `reachable` is true.
    all_reachable: bool,
    log_mode: bool,
    /// Frames that took the fast form and the general form (diagnostics:
    /// tests check that the fast form runs, `Hmm::step_counts` reports them).
    pub(crate) fast_steps: usize,
    pub(crate) general_steps: usize,
    // Scratch.
    alive: Vec<bool>,
    reach_next: Vec<bool>,
    pred_next: Vec<Lanes>,
    odd: Vec<Lanes>,
    log_h: Vec<f64>,
    terms: Vec<f64>,
    /// `e^{log b_j − m}` of the current shift `m`.
    e: Vec<Lanes>,
    /// Padded copies of one frame's log-densities and filtered row, for
    /// [`ForwardCore::step_row_inline`].
    row_log_b: Vec<Lanes>,
    row_h: Vec<Lanes>,
}

impl ForwardCore {
    /// The recursion of `hmm` before its first frame.
    pub(crate) fn new<E: Emission>(hmm: &Hmm<E>) -> Self {
        let s = hmm.n_states();
        let c = chunks(s);
        let mut start = vec![[0.0; W]; c];
        padded(&hmm.start, 0.0, &mut start);
        let mut floor = vec![[0.0; W]; c];
        padded(&vec![SAFE; s], 0.0, &mut floor);
        let mut core = ForwardCore {
            s,
            transition: padded_rows(&hmm.transition, s),
            log_transition: hmm.log_transition.clone(),
            transition_dense: hmm.transition.clone(),
            start,
            log_start: hmm.log_start.clone(),
            floor,
            dense: hmm.transition.iter().all(|a| *a > 0.0),
            pred: vec![[0.0; W]; c],
            log_pred: vec![f64::NEG_INFINITY; s],
            reachable: vec![false; s],
            all_reachable: false,
            log_mode: false,
            fast_steps: 0,
            general_steps: 0,
            alive: vec![false; s],
            reach_next: vec![false; s],
            pred_next: vec![[0.0; W]; c],
            odd: vec![[0.0; W]; c],
            log_h: vec![f64::NEG_INFINITY; s],
            terms: vec![f64::NEG_INFINITY; s],
            e: vec![[0.0; W]; c],
            row_log_b: vec![[0.0; W]; c],
            row_h: vec![[0.0; W]; c],
        };
        core.reset();
        core
    }

    /// Whether the fast form of the step can ever apply (every `a_ij > 0`):
    /// otherwise the shifted densities of [`ForwardCore::step_shifted_inline`]
    /// would never be read.
    pub(crate) fn can_step_fast(&self) -> bool {
        self.dense
    }

    /// Back to the initial distribution (before the first frame).
    pub(crate) fn reset(&mut self) {
        self.pred.copy_from_slice(&self.start);
        self.log_pred.copy_from_slice(&self.log_start);
        let start = self.start.as_flattened();
        for (r, p) in self.reachable.iter_mut().zip(start) {
            *r = *p > 0.0;
        }
        self.all_reachable = self.reachable.iter().all(|r| *r);
        self.log_mode = start[..self.s].iter().any(|p| *p > 0.0 && *p < SAFE);
    }

    /// One frame (see [`ForwardCore::step_inline`]) on an unpadded row of `S`
    /// log-densities, writing the `S` filtered probabilities into `h`.
    pub(crate) fn step_row(&mut self, log_b: &[f64], h: &mut [f64]) -> f64 {
        dispatch(
            #[inline(always)]
            || self.step_row_inline(log_b, h),
        )
    }

    /// [`ForwardCore::step_row`] in the build of its caller.
    #[inline(always)]
    pub(crate) fn step_row_inline(&mut self, log_b: &[f64], h: &mut [f64]) -> f64 {
        let mut lb = std::mem::take(&mut self.row_log_b);
        let mut hp = std::mem::take(&mut self.row_h);
        padded(log_b, PAD_LOG_B, &mut lb);
        let lc = self.step_inline(&lb, &mut hp);
        h.copy_from_slice(&hp.as_flattened()[..self.s]);
        self.row_log_b = lb;
        self.row_h = hp;
        lc
    }

    /// Filters one frame with padded log-densities `log_b` (padding
    /// [`PAD_LOG_B`]): writes `h_t = p(z_t | x_0 … x_t)` into the padded `h`
    /// and returns `log c_t`. An impossible frame returns `−∞`, zeroes `h` and
    /// leaves the recursion unchanged. In the build of its caller: callers
    /// run it through `dispatch`.
    #[inline(always)]
    pub(crate) fn step_inline(&mut self, log_b: &[Lanes], h: &mut [Lanes]) -> f64 {
        if !self.log_mode && self.all_reachable && self.dense {
            let fast = match self.pred.len() {
                1 => self.fast_step::<1>(log_b, h),
                2 => self.fast_step::<2>(log_b, h),
                3 => self.fast_step::<3>(log_b, h),
                4 => self.fast_step::<4>(log_b, h),
                _ => self.fast_step_dyn(log_b, h),
            };
            if let Some(lc) = fast {
                self.fast_steps += 1;
                return lc;
            }
        }
        self.general_steps += 1;
        self.general_step(log_b, h)
    }

    /// [`ForwardCore::step_inline`] with the frame's shifted densities
    /// computed beforehand: `shifted = e^{log b − m}` (as [`exp_shifted`]
    /// gives them) with `m = max_j log b_j`, or `m` NaN when the frame cannot
    /// take the fast form (a zero or NaN density, `m = +∞`; see
    /// [`super::kernels::fast_shift`]). The same bits as
    /// [`ForwardCore::step_inline`]; a caller that has every frame at once
    /// takes the exponentials of all of them in one pass, where they overlap,
    /// instead of one frame's on the recursion's critical path.
    #[inline(always)]
    pub(crate) fn step_shifted_inline(
        &mut self,
        log_b: &[Lanes],
        shifted: &[Lanes],
        m: f64,
        h: &mut [Lanes],
    ) -> f64 {
        if !self.log_mode && self.all_reachable && self.dense && !m.is_nan() {
            let fast = match self.pred.len() {
                1 => self.fast_rest::<1>(shifted, m, h),
                2 => self.fast_rest::<2>(shifted, m, h),
                3 => self.fast_rest::<3>(shifted, m, h),
                4 => self.fast_rest::<4>(shifted, m, h),
                _ => self.fast_dyn_rest(shifted, m, h),
            };
            if let Some(lc) = fast {
                self.fast_steps += 1;
                return lc;
            }
        }
        self.general_steps += 1;
        self.general_step(log_b, h)
    }

    /// The common frame without bookkeeping, with `C` chunks in registers,
    /// or `None` (nothing changed but `h`) when one of its conditions fails;
    /// then the general step redoes the frame.
    #[inline(always)]
    fn fast_step<const C: usize>(&mut self, log_b: &[Lanes], h: &mut [Lanes]) -> Option<f64> {
        // Inputs are copied into locals and results stored at the end, so
        // that the compiler sees that nothing aliases and keeps the vectors
        // in registers.
        let log_b: [Lanes; C] = *<&[Lanes; C]>::try_from(log_b).expect("C chunks");
        let m = max_lanes(&log_b);
        if !all_positive_densities(&log_b) || m == f64::INFINITY {
            return None;
        }
        let mut o = [[0.0; W]; C];
        exp_shifted(&log_b, m, &mut o);
        self.fast_rest::<C>(&o, m, h)
    }

    /// The fast step from `e = e^{log b − m}` (`C` chunks).
    #[inline(always)]
    fn fast_rest<const C: usize>(&mut self, e: &[Lanes], m: f64, h: &mut [Lanes]) -> Option<f64> {
        let mut o: [Lanes; C] = *<&[Lanes; C]>::try_from(e).expect("C chunks");
        let pred: [Lanes; C] = *<&[Lanes; C]>::try_from(self.pred.as_slice()).expect("C chunks");
        for (ok, pk) in o.iter_mut().zip(&pred) {
            for l in 0..W {
                ok[l] *= pk[l];
            }
        }
        let c = sum_lanes(&o);
        if c.is_nan() || c < RESCALE {
            return None;
        }
        let inv = 1.0 / c;
        scale_lanes(&mut o, inv);
        let next = vec_mat::<C>(&o.as_flattened()[..self.s], &self.transition);
        if !all_at_least(&next, &self.floor) {
            return None;
        }
        h.copy_from_slice(&o);
        self.pred.copy_from_slice(&next);
        Some(m + ln(c))
    }

    /// [`ForwardCore::fast_step`] for more than four chunks (through memory).
    #[inline(always)]
    fn fast_step_dyn(&mut self, log_b: &[Lanes], h: &mut [Lanes]) -> Option<f64> {
        let m = max_lanes(log_b);
        if !all_positive_densities(log_b) || m == f64::INFINITY {
            return None;
        }
        let mut e = std::mem::take(&mut self.e);
        exp_shifted(log_b, m, &mut e);
        let lc = self.fast_dyn_rest(&e, m, h);
        self.e = e;
        lc
    }

    /// [`ForwardCore::fast_step_dyn`] from `e = e^{log b − m}`.
    #[inline(always)]
    fn fast_dyn_rest(&mut self, e: &[Lanes], m: f64, h: &mut [Lanes]) -> Option<f64> {
        for ((hk, pk), ek) in h.iter_mut().zip(&self.pred).zip(e) {
            for l in 0..W {
                hk[l] = pk[l] * ek[l];
            }
        }
        let c = sum_lanes(h);
        if c.is_nan() || c < RESCALE {
            return None;
        }
        let inv = 1.0 / c;
        scale_lanes(h, inv);
        vec_mat_dyn(
            &h.as_flattened()[..self.s],
            &self.transition,
            &mut self.pred_next,
            &mut self.odd,
        );
        if !all_at_least(&self.pred_next, &self.floor) {
            return None;
        }
        std::mem::swap(&mut self.pred, &mut self.pred_next);
        Some(m + ln(c))
    }

    /// `out_j = pred_j e^{log b_j − m}` over the possible states (0
    /// elsewhere and on the padding); returns their sum. The exponentials are
    /// taken in one vectorised pass over every lane (branch-free), then masked.
    #[inline(always)]
    fn scaled(&mut self, log_b: &[Lanes], m: f64, out: &mut [Lanes]) -> f64 {
        exp_shifted(log_b, m, &mut self.e);
        let (e, pred) = (self.e.as_flattened(), self.pred.as_flattened());
        for (j, o) in out.as_flattened_mut().iter_mut().enumerate() {
            *o = if j < self.s && self.alive[j] {
                pred[j] * e[j]
            } else {
                0.0
            };
        }
        sum_lanes(out)
    }

    /// Every rule of the module documentation, state by state.
    // `j` indexes several per-state arrays (densities, reachability, predictions) at once.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn general_step(&mut self, log_b_padded: &[Lanes], h_padded: &mut [Lanes]) -> f64 {
        let s = self.s;
        let log_b = &log_b_padded.as_flattened()[..s];
        let mut any = false;
        for j in 0..s {
            self.alive[j] = self.reachable[j] && log_b[j] > f64::NEG_INFINITY;
            any |= self.alive[j];
        }
        if !any {
            h_padded.fill([0.0; W]);
            return f64::NEG_INFINITY;
        }
        let was_log = self.log_mode;
        let lc = if was_log {
            for j in 0..s {
                self.log_h[j] = if self.alive[j] {
                    self.log_pred[j] + log_b[j]
                } else {
                    f64::NEG_INFINITY
                };
            }
            let lc = log_sum_exp(&self.log_h);
            h_padded.fill([0.0; W]);
            let h = &mut h_padded.as_flattened_mut()[..s];
            for (lh, o) in self.log_h.iter_mut().zip(h.iter_mut()) {
                *lh -= lc;
                *o = *lh;
            }
            exp_slice(h);
            lc
        } else {
            // Shift by the largest density among the possible states; their
            // predicted probabilities are at least SAFE, so c ≥ SAFE > 0.
            let mut m = f64::NEG_INFINITY;
            for j in 0..s {
                if self.alive[j] {
                    m = m.max(log_b[j]);
                }
            }
            let mut c = self.scaled(log_b_padded, m, h_padded);
            if c < RESCALE {
                m += c.ln();
                c = self.scaled(log_b_padded, m, h_padded);
            }
            let inv = 1.0 / c;
            for v in h_padded.as_flattened_mut() {
                *v *= inv;
            }
            m + ln(c)
        };
        let h = &h_padded.as_flattened()[..s];

        // The prediction for the next frame, linear where that is exact. A
        // column whose linear value is below SAFE may have lost precision (or
        // underflowed) although the state is reachable: only such columns are
        // recomputed in log space, and the prediction is then carried in log
        // form (exact columns as `ln p_j`).
        vec_mat_into(h, &self.transition, &mut self.pred_next, &mut self.odd);
        let a = &self.transition_dense;
        let pred_next = self.pred_next.as_flattened();
        let mut any_inexact = false;
        for j in 0..s {
            if pred_next[j] >= SAFE {
                self.reach_next[j] = true;
            } else {
                let mut r = false;
                for i in 0..s {
                    r |= self.alive[i] && a[i * s + j] > 0.0;
                }
                self.reach_next[j] = r;
                any_inexact |= r;
            }
        }
        if !any_inexact {
            std::mem::swap(&mut self.pred, &mut self.pred_next);
            self.log_mode = false;
        } else {
            if !was_log {
                // log h_t exactly: in linear mode every possible state's pred_j ≥ SAFE.
                let pred = self.pred.as_flattened();
                for j in 0..s {
                    self.log_h[j] = if self.alive[j] {
                        pred[j].ln() + log_b[j] - lc
                    } else {
                        f64::NEG_INFINITY
                    };
                }
            }
            let la = &self.log_transition;
            for j in 0..s {
                self.log_pred[j] = if !self.reach_next[j] {
                    f64::NEG_INFINITY
                } else if pred_next[j] >= SAFE {
                    pred_next[j].ln()
                } else {
                    for i in 0..s {
                        self.terms[i] = self.log_h[i] + la[i * s + j];
                    }
                    log_sum_exp(&self.terms)
                };
            }
            self.log_mode = true;
        }
        std::mem::swap(&mut self.reachable, &mut self.reach_next);
        self.all_reachable = self.reachable.iter().all(|r| *r);
        lc
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::inference::kernels::{fast_shift, shifted_arguments};
    use crate::model::Hmm;
    use phasekit_emission::Gaussian;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A random `s`-state chain (every `a_ij > 0` unless `zeros`) with a
    /// placeholder emission, and `t_len` rows of log-densities: mostly within
    /// 30 nats of each other, with frames that rule states out by thousands
    /// of nats (log mode, re-scaling) and impossible (state, frame) pairs.
    pub(crate) fn random_case(
        seed: u64,
        s: usize,
        t_len: usize,
        zeros: bool,
    ) -> (Hmm<Gaussian>, Vec<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let row = |rng: &mut ChaCha8Rng| -> Vec<f64> {
            let keep = rng.random_range(0..s);
            let r: Vec<f64> = (0..s)
                .map(|j| {
                    if zeros && j != keep && rng.random_bool(0.3) {
                        0.0
                    } else {
                        rng.random_range(0.05..1.0)
                    }
                })
                .collect();
            let total: f64 = r.iter().sum();
            r.iter().map(|v| v / total).collect()
        };
        let start = row(&mut rng);
        let a: Vec<f64> = (0..s).flat_map(|_| row(&mut rng)).collect();
        let g = Gaussian::diagonal(1, vec![0.0; s], vec![1.0; s]).unwrap();
        let hmm = Hmm::new(start, a, g).unwrap();
        let log_b = (0..t_len * s)
            .map(|_| {
                let u: f64 = rng.random();
                if u < 0.02 {
                    f64::NEG_INFINITY
                } else if u < 0.08 {
                    -rng.random_range(700.0..3000.0)
                } else {
                    -rng.random_range(0.0..30.0)
                }
            })
            .collect();
        (hmm, log_b)
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The fast form where it applies (computing its exponentials, or given
    /// them computed beforehand) and the general form everywhere give the
    /// same filtered rows, normalisers and recursion state, frame by frame.
    #[test]
    fn the_fast_step_is_the_general_step_where_it_applies() {
        let (mut fast_total, mut shifted_total) = (0, 0);
        for seed in 0..240 {
            let s = 1 + (seed as usize % 40);
            let c = chunks(s);
            let (hmm, log_b) = random_case(seed, s, 120, seed % 3 == 0);
            let mut a = ForwardCore::new(&hmm);
            let mut b = a.clone();
            let mut d = a.clone();
            let z = vec![[0.0; W]; c];
            let (mut ha, mut hb, mut hd) = (z.clone(), z.clone(), z.clone());
            let (mut row, mut e) = (z.clone(), z.clone());
            for (t, lb) in log_b.chunks_exact(s).enumerate() {
                padded(lb, PAD_LOG_B, &mut row);
                let la = a.step_inline(&row, &mut ha);
                let lb = b.general_step(&row, &mut hb);
                let m = fast_shift(&row);
                shifted_arguments(&row, m, &mut e);
                exp_slice(e.as_flattened_mut());
                let ld = d.step_shifted_inline(&row, &e, m, &mut hd);
                assert_eq!(la.to_bits(), lb.to_bits(), "seed {seed}, frame {t}");
                assert_eq!(ld.to_bits(), lb.to_bits(), "seed {seed}, frame {t}");
                if lb > f64::NEG_INFINITY {
                    assert_eq!(
                        bits(ha.as_flattened()),
                        bits(hb.as_flattened()),
                        "seed {seed}, frame {t}"
                    );
                    assert_eq!(bits(hd.as_flattened()), bits(hb.as_flattened()));
                }
                assert_eq!(bits(d.pred.as_flattened()), bits(a.pred.as_flattened()));
                assert_eq!(bits(&d.log_pred), bits(&a.log_pred));
                assert_eq!(a.log_mode, b.log_mode);
                assert_eq!(a.reachable, b.reachable);
                if a.log_mode {
                    assert_eq!(bits(&a.log_pred), bits(&b.log_pred));
                } else {
                    assert_eq!(
                        bits(a.pred.as_flattened()),
                        bits(b.pred.as_flattened()),
                        "seed {seed}, frame {t}"
                    );
                }
            }
            fast_total += a.fast_steps;
            shifted_total += d.fast_steps;
        }
        assert!(
            fast_total > 8000 && shifted_total == fast_total,
            "the fast form ran on {fast_total} frames only, given the exponentials on {shifted_total}"
        );
    }

    /// The batch forward pass (every frame's exponentials taken first) and
    /// the online filter's step on unpadded rows give the same bits, frame
    /// by frame, impossible frames included.
    #[test]
    fn the_batch_forward_pass_is_the_online_step_to_the_bit() {
        for seed in 0..120 {
            let s = 1 + (seed as usize % 40);
            let (hmm, log_b) = random_case(seed, s, 90, seed % 3 == 0);
            let batch = hmm.forward_from(&log_b);
            let mut core = ForwardCore::new(&hmm);
            let mut h = vec![0.0; s];
            for (t, lb) in log_b.chunks_exact(s).enumerate() {
                let lc = core.step_row_inline(lb, &mut h);
                assert_eq!(
                    lc.to_bits(),
                    batch.log_normalisers()[t].to_bits(),
                    "seed {seed}, frame {t}"
                );
                assert_eq!(
                    bits(&h),
                    bits(&batch.filtered()[t * s..(t + 1) * s]),
                    "seed {seed}, frame {t}"
                );
                if lc == f64::NEG_INFINITY {
                    break;
                }
            }
        }
    }
}
