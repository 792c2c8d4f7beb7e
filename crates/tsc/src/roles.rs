//! Which dimensions of a joint frame belong to the human and which to the robot.

use crate::error::{Result, TscError};
use serde::{Deserialize, Serialize};

/// The human's dims of a joint frame (observed at test time, the inputs) and
/// the robot's (predicted, the outputs).
///
/// Validated at construction (and on deserialisation): both non-empty, no
/// dimension repeated, none in both. Whether they fit a frame dimension is
/// checked where the dimension is known, by [`Roles::check`].
///
/// The robot's *scored* dims ([`Roles::scored`], all of the robot's unless
/// [`Roles::with_scored`] narrows them) are those a cross-validated choice
/// (`auto`, the `-cv` presets) scores and calibrates on: the command sets them
/// to the robot's positions, which is what `evaluate` reports, so that the
/// choice optimises the reported error and not the velocities' as well.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "RolesRaw")]
pub struct Roles {
    human: Vec<usize>,
    robot: Vec<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    scored: Option<Vec<usize>>,
}

/// The serialised form of [`Roles`], before validation.
#[derive(Deserialize)]
struct RolesRaw {
    human: Vec<usize>,
    robot: Vec<usize>,
    #[serde(default)]
    scored: Option<Vec<usize>>,
}

impl TryFrom<RolesRaw> for Roles {
    type Error = TscError;
    fn try_from(r: RolesRaw) -> Result<Self> {
        let roles = Roles::new(r.human, r.robot)?;
        match r.scored {
            Some(s) => roles.with_scored(s),
            None => Ok(roles),
        }
    }
}

impl Roles {
    /// The roles `human` (inputs) and `robot` (outputs): both non-empty, no
    /// dimension repeated within one, and none in both.
    pub fn new(human: Vec<usize>, robot: Vec<usize>) -> Result<Roles> {
        let bad = |reason: String| {
            Err(TscError::InvalidSetting {
                name: "roles",
                reason,
            })
        };
        for (who, dims) in [("human", &human), ("robot", &robot)] {
            if dims.is_empty() {
                return bad(format!("the {who} has no dimension"));
            }
            let mut sorted = dims.clone();
            sorted.sort_unstable();
            if let Some(w) = sorted.windows(2).find(|w| w[0] == w[1]) {
                return bad(format!("the {who}'s dimension {} is repeated", w[0]));
            }
        }
        if let Some(d) = human.iter().find(|d| robot.contains(d)) {
            return bad(format!(
                "dimension {d} is both input and output (the human's and the robot's)"
            ));
        }
        Ok(Roles {
            human,
            robot,
            scored: None,
        })
    }

    /// Narrows the robot's scored dims to `scored`: a non-empty subset of the
    /// robot's dims (frame dims, each once), kept in the robot's order.
    pub fn with_scored(mut self, scored: Vec<usize>) -> Result<Roles> {
        let bad = |reason: String| {
            Err(TscError::InvalidSetting {
                name: "roles",
                reason,
            })
        };
        if scored.is_empty() {
            return bad("no robot dimension is scored".into());
        }
        for (i, d) in scored.iter().enumerate() {
            if !self.robot.contains(d) {
                return bad(format!("scored dimension {d} is not one of the robot's"));
            }
            if scored[..i].contains(d) {
                return bad(format!("scored dimension {d} is repeated"));
            }
        }
        let kept: Vec<usize> = self
            .robot
            .iter()
            .copied()
            .filter(|d| scored.contains(d))
            .collect();
        self.scored = (kept != self.robot).then_some(kept);
        Ok(self)
    }

    /// The robot's dims a cross-validated choice scores, as frame dims in the
    /// robot's order (all of the robot's unless narrowed).
    pub fn scored(&self) -> &[usize] {
        self.scored.as_deref().unwrap_or(&self.robot)
    }

    /// The positions within [`Roles::robot`] (the predictor's output index) of
    /// the scored dims.
    pub fn scored_outputs(&self) -> Vec<usize> {
        self.scored()
            .iter()
            .filter_map(|d| self.robot.iter().position(|r| r == d))
            .collect()
    }

    /// The human's dims (inputs), in the order the predictor reads them.
    pub fn human(&self) -> &[usize] {
        &self.human
    }

    /// The robot's dims (outputs), in the order the predictor writes them.
    pub fn robot(&self) -> &[usize] {
        &self.robot
    }

    /// Checks that every dim lies below the frame dimension `dim`.
    pub fn check(&self, dim: usize) -> Result<()> {
        phasekit_gmr::check_io(&self.human, &self.robot, dim)?;
        Ok(())
    }
}
