//! Which dimensions of a joint frame belong to the human and which to the robot.

use crate::error::{Result, TscError};
use serde::{Deserialize, Serialize};

/// The human's dims of a joint frame (observed at test time, the inputs) and
/// the robot's (predicted, the outputs).
///
/// Validated at construction (and on deserialisation): both non-empty, no
/// dimension repeated, none in both. Whether they fit a frame dimension is
/// checked where the dimension is known, by [`Roles::check`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "RolesRaw")]
pub struct Roles {
    human: Vec<usize>,
    robot: Vec<usize>,
}

/// The serialised form of [`Roles`], before validation.
#[derive(Deserialize)]
struct RolesRaw {
    human: Vec<usize>,
    robot: Vec<usize>,
}

impl TryFrom<RolesRaw> for Roles {
    type Error = TscError;
    fn try_from(r: RolesRaw) -> Result<Self> {
        Roles::new(r.human, r.robot)
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
        Ok(Roles { human, robot })
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
