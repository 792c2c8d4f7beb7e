//! The library as ONE composed HMM, for continuous streams in which
//! interactions follow one another with rest in between.
//!
//! States: every action's states (those of its action HMM,
//! [`crate::parts::action_hmm`], joint Gaussians) followed by one rest state
//! (the library's rest Gaussian). Transitions, with `A_a`, `π_a` the action
//! HMMs', `e_i` the exit probabilities and `ε` the end distribution
//! ([`crate::library`]), `p(a)` the prior and `s` the rest state's expected stay:
//!
//! * within action `a`: `(1 − e_i) A_a(i, j)`; from its state `i` into rest: `e_i`;
//! * rest to rest: `1 − 1/s`; rest into action `a`'s state `j`: `(1/s) p(a) π_a(j)`;
//! * initial: rest `1/(A + 1)`, action `a`'s state `j`: `(A/(A + 1)) p(a) π_a(j)`.
//!
//! It is a union of the actions' HMMs with structured transitions, filtered
//! on the human marginal like any HMM; the action posterior is the belief
//! summed over each action's states, `p(a | o¹_{1:t}) = Σ_{i ∈ a} h_t(i)`, the
//! rest of the mass is the belief in rest, and the robot's prediction is the
//! HMM-GMR of the composed HMM: every state's conditional weighted by the
//! belief (the rest state's predicts the rest pose). No reset is needed
//! between interactions: the filter leaves an action through its end states.

use crate::error::{check_frame, Result};
use crate::library::Library;
use crate::parts::action_hmm;
use crate::recogniser::{argmax, Decision};
use phasekit_emission::Gaussian;
use phasekit_gmr::{HmmRegression, OnlineRegression};
use phasekit_hmm::Hmm;
use std::ops::Range;

/// The composed HMM and where each action's states are in it.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct ComposedHmm {
    /// The joint HMM (every action's states, then the rest state).
    pub hmm: Hmm<Gaussian>,
    /// The states of each action, in the library's order.
    pub actions: Vec<Range<usize>>,
    /// The rest state.
    pub rest: usize,
}

impl ComposedHmm {
    /// Composes the library's actions and rest state (see the module documentation).
    pub fn new(library: &Library) -> Result<Self> {
        let d = library.dim();
        let hmms = library
            .actions()
            .iter()
            .map(|a| action_hmm(&a.model))
            .collect::<Result<Vec<_>>>()?;
        let n: usize = hmms.iter().map(|h| h.n_states()).sum::<usize>() + 1;
        let rest = n - 1;
        let n_actions = hmms.len() as f64;
        let stay = library.rest().stay;
        let (mut means, mut covs) = (Vec::with_capacity(n * d), Vec::with_capacity(n * d * d));
        let mut transition = vec![0.0; n * n];
        let mut start = vec![0.0; n];
        let mut actions = Vec::new();
        let mut offset = 0;
        for ((hmm, action), p) in hmms.iter().zip(library.actions()).zip(library.prior()) {
            let s = hmm.n_states();
            let g = hmm.emission();
            for i in 0..s {
                means.extend_from_slice(g.mean(i));
                covs.extend(g.covariance(i).transpose().iter().copied());
                let e = action.exit[i];
                let row = &mut transition[(offset + i) * n..(offset + i + 1) * n];
                for j in 0..s {
                    row[offset + j] = (1.0 - e) * hmm.transition()[i * s + j];
                }
                row[rest] = e;
                transition[rest * n + offset + i] = p * hmm.start()[i] / stay;
                start[offset + i] = n_actions / (n_actions + 1.0) * p * hmm.start()[i];
            }
            actions.push(offset..offset + s);
            offset += s;
        }
        means.extend_from_slice(&library.rest().mean);
        covs.extend_from_slice(&library.rest().covariance);
        transition[rest * n + rest] = 1.0 - 1.0 / stay;
        start[rest] = 1.0 / (n_actions + 1.0);
        let hmm = Hmm::new(start, transition, Gaussian::full(d, means, covs)?)?;
        Ok(ComposedHmm { hmm, actions, rest })
    }
}

/// Online recognition and prediction with the composed HMM. No allocation per frame.
#[derive(Debug, Clone)]
pub struct ComposedRecogniser {
    online: OnlineRegression,
    actions: Vec<Range<usize>>,
    rest: usize,
    posterior: Vec<f64>,
    rest_probability: f64,
    decision: Decision,
    with_covariance: bool,
    n_human: usize,
    frames: usize,
}

impl ComposedRecogniser {
    /// A recogniser over the library's composed HMM; with `with_covariance`
    /// every step also computes the predictive covariance.
    pub fn new(library: &Library, with_covariance: bool) -> Result<Self> {
        let c = ComposedHmm::new(library)?;
        let roles = library.roles();
        let online = HmmRegression::new(&c.hmm, roles.human(), roles.robot())?.online();
        let mut r = ComposedRecogniser {
            online,
            posterior: vec![0.0; c.actions.len()],
            actions: c.actions,
            rest: c.rest,
            rest_probability: 0.0,
            decision: Decision::Rest,
            with_covariance,
            n_human: roles.human().len(),
            frames: 0,
        };
        r.sum_belief();
        Ok(r)
    }

    /// Sums the belief over each action's states and decides: the most
    /// probable action, or rest when the belief in rest is larger.
    fn sum_belief(&mut self) {
        let h = self.online.belief();
        for (p, r) in self.posterior.iter_mut().zip(&self.actions) {
            *p = h[r.clone()].iter().sum();
        }
        self.rest_probability = h[self.rest];
        let best = argmax(&self.posterior);
        self.decision = if self.rest_probability > self.posterior[best] {
            Decision::Rest
        } else {
            Decision::Action(best)
        };
    }

    /// Takes one human frame (NaN = missing) and returns the decision. An
    /// impossible frame is an error that leaves the belief as it was.
    pub fn step(&mut self, human: &[f64]) -> Result<Decision> {
        check_frame("human frame", human, self.n_human)?;
        if self.with_covariance {
            self.online.step_with_covariance(human)?;
        } else {
            self.online.step(human)?;
        }
        self.frames += 1;
        self.sum_belief();
        Ok(self.decision)
    }

    /// Starts again from the initial distribution.
    pub fn reset(&mut self) {
        self.online.reset();
        self.frames = 0;
        self.sum_belief();
    }

    /// The decision after the last frame.
    pub fn decision(&self) -> Decision {
        self.decision
    }

    /// The belief summed over each action's states.
    pub fn posterior(&self) -> &[f64] {
        &self.posterior
    }

    /// The belief in the rest state.
    pub fn rest_probability(&self) -> f64 {
        self.rest_probability
    }

    /// The belief over every state of the composed HMM.
    pub fn belief(&self) -> &[f64] {
        self.online.belief()
    }

    /// The robot's predicted features for the last frame.
    pub fn robot(&self) -> &[f64] {
        self.online.mean()
    }

    /// Its covariance (`O × O`), when asked for.
    pub fn robot_covariance(&self) -> Option<&[f64]> {
        self.with_covariance.then(|| self.online.covariance())
    }

    /// Whether the last frame was impossible under every state (a glitch, e.g.
    /// `1e200`): the GMR took it as not observed.
    pub fn frame_rejected(&self) -> bool {
        self.online.evidence().rejected
    }

    /// `log p(o¹_{1:t})` under the composed HMM.
    pub fn log_likelihood(&self) -> f64 {
        self.online.log_likelihood()
    }

    /// Frames since the last reset.
    pub fn frames(&self) -> usize {
        self.frames
    }
}
