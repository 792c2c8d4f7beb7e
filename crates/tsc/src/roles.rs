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
///
/// The *velocities* ([`Roles::velocities`], none unless
/// [`Roles::with_velocities`] names them) are the dims that are first
/// differences of other dims, each with its position's dim: the command names
/// them for `--velocity`. A regularisation relative to the positions
/// ([`crate::RegUnits::Positions`]) reads them.
///
/// The *error units* ([`Roles::error_units`], none unless
/// [`Roles::with_error_units`] sets them) say in which unit a cross-validated
/// choice judges the robot's prediction error when the data given are not in
/// the user's units: the command, when it z-scores (`--standardise`), sets
/// them to the standard deviations, so that `auto` chooses by the error in
/// the file's units, the same choice as without `--standardise`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RolesRaw")]
pub struct Roles {
    human: Vec<usize>,
    robot: Vec<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    scored: Option<Vec<usize>>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    velocities: Vec<(usize, usize)>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    error_units: Option<Vec<f64>>,
}

/// The serialised form of [`Roles`], before validation.
#[derive(Deserialize)]
struct RolesRaw {
    human: Vec<usize>,
    robot: Vec<usize>,
    #[serde(default)]
    scored: Option<Vec<usize>>,
    #[serde(default)]
    velocities: Vec<(usize, usize)>,
    #[serde(default)]
    error_units: Option<Vec<f64>>,
}

impl TryFrom<RolesRaw> for Roles {
    type Error = TscError;
    fn try_from(r: RolesRaw) -> Result<Self> {
        let roles = Roles::new(r.human, r.robot)?;
        let roles = match r.scored {
            Some(s) => roles.with_scored(s)?,
            None => roles,
        };
        let roles = roles.with_velocities(r.velocities)?;
        match r.error_units {
            Some(u) => roles.with_error_units(u),
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
            velocities: Vec::new(),
            error_units: None,
        })
    }

    /// Names the velocities: `(velocity, position)` pairs of frame dims, the
    /// velocity being the first difference of the position
    /// (`v_t = x_t − x_{t−1}`, in the same or another unit). Both of one side
    /// (the human's or the robot's), no velocity in two pairs (a position
    /// may have several velocities, e.g. in two units), no velocity a
    /// position of another pair.
    pub fn with_velocities(mut self, velocities: Vec<(usize, usize)>) -> Result<Roles> {
        let bad = |reason: String| {
            Err(TscError::InvalidSetting {
                name: "roles",
                reason,
            })
        };
        let side = |d: usize| {
            if self.human.contains(&d) {
                Some(0)
            } else if self.robot.contains(&d) {
                Some(1)
            } else {
                None
            }
        };
        let mut seen: Vec<usize> = Vec::new();
        for &(v, x) in &velocities {
            match (side(v), side(x)) {
                (Some(a), Some(b)) if a == b && v != x => {}
                _ => {
                    return bad(format!(
                    "velocity {v} of position {x}: both must be dims of the same side, and differ"
                ))
                }
            }
            if seen.contains(&v) {
                return bad(format!("dimension {v} is in two velocity pairs"));
            }
            seen.push(v);
        }
        if let Some(&(_, x)) = velocities.iter().find(|(_, x)| seen.contains(x)) {
            return bad(format!("position {x} is itself a velocity"));
        }
        self.velocities = velocities;
        Ok(self)
    }

    /// The `(velocity, position)` pairs of frame dims (see [`Roles::with_velocities`]).
    pub fn velocities(&self) -> &[(usize, usize)] {
        &self.velocities
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

    /// Sets the unit in which a cross-validated choice judges the error of
    /// each of the robot's dims: `units[j]` (finite, positive) for
    /// [`Roles::robot`]`[j]`, the factor that takes a value of the data given
    /// to the user's unit (the standard deviation, for z-scored data). The
    /// squared error of a held-out frame is then `Σ_a (u_a (y_a − μ_a))²`
    /// over the scored dims `a`, its log density gains `−Σ_a ln u_a`: both in
    /// the user's units. Calibration (Mahalanobis distances) does not depend
    /// on them.
    pub fn with_error_units(mut self, units: Vec<f64>) -> Result<Roles> {
        if units.len() != self.robot.len() {
            return Err(TscError::InvalidSetting {
                name: "roles",
                reason: format!(
                    "{} error units for the robot's {} dimensions",
                    units.len(),
                    self.robot.len()
                ),
            });
        }
        if let Some((j, u)) = units
            .iter()
            .enumerate()
            .find(|(_, u)| !(u.is_finite() && **u > 0.0))
        {
            return Err(TscError::InvalidSetting {
                name: "roles",
                reason: format!(
                    "the error unit of the robot's dimension {} is {u}, not a finite positive number",
                    self.robot[j]
                ),
            });
        }
        self.error_units = Some(units);
        Ok(self)
    }

    /// The error units of the robot's dims, if set ([`Roles::with_error_units`]).
    pub fn error_units(&self) -> Option<&[f64]> {
        self.error_units.as_deref()
    }

    /// The error unit of each scored dim, in [`Roles::scored`]'s order (1
    /// when none are set).
    pub fn scored_error_units(&self) -> Vec<f64> {
        match &self.error_units {
            Some(u) => self.scored_outputs().iter().map(|&j| u[j]).collect(),
            None => vec![1.0; self.scored().len()],
        }
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
