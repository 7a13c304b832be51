//! `[obstacle]`: the membrane's paraboloid or expression bounds, the shell's
//! rigid plane or surface, the shell's contact multiplier space.

use super::{Expression, Scene};
use crate::error::Result;
use serde::Deserialize;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    pub shape: ObstacleShape,
    /// Paraboloid: φ(0, 0). Rigid plane: the plane z = height (default 0).
    /// Rigid surface: the body fills z < height(x, y) (an expression).
    pub height: Option<Expression>,
    /// k in φ = height − k (x² + y²) (paraboloid only).
    pub curvature: Option<f64>,
    /// Shape "expression" (membrane): u ≥ lower(x, y).
    pub lower: Option<Expression>,
    /// Shape "expression" (membrane), optional: u ≤ upper(x, y), the two-sided problem.
    pub upper: Option<Expression>,
    /// Shell only: the space of the contact multiplier λ (default: the element's,
    /// P0 for "p1b-p0", P1 for "p2b-psri"); the membrane's comes with `element`.
    pub multiplier: Option<ContactMultiplier>,
}

/// The space of the shell's contact multiplier (scene `obstacle.multiplier`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ContactMultiplier {
    /// One multiplier per triangle: the constraint on triangle means.
    P0,
    /// One multiplier per vertex: the constraint tested with the P1 hat functions.
    P1,
}

impl ContactMultiplier {
    pub fn name(self) -> &'static str {
        match self {
            ContactMultiplier::P0 => "p0",
            ContactMultiplier::P1 => "p1",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ObstacleShape {
    /// Membrane: φ(x, y) = height − curvature · (x² + y²).
    Paraboloid,
    /// Membrane: lower ≤ u (≤ upper) with expressions in x, y, r.
    Expression,
    /// Shell: the rigid half-space z < height below the shell (docs/formulation.md §2).
    RigidPlane,
    /// Shell: the rigid body z < height(x, y) below the shell (docs/formulation.md §2.1).
    RigidSurface,
}

impl ObstacleShape {
    pub fn name(self) -> &'static str {
        match self {
            ObstacleShape::Paraboloid => "paraboloid",
            ObstacleShape::Expression => "expression",
            ObstacleShape::RigidPlane => "rigid-plane",
            ObstacleShape::RigidSurface => "rigid-surface",
        }
    }
}

impl ObstacleSpec {
    /// The height when a number: φ(0, 0) or the plane's level (default 0);
    /// validation requires a number for the paraboloid and the plane.
    pub fn level(&self) -> f64 {
        self.height
            .as_ref()
            .and_then(Expression::as_constant)
            .unwrap_or(0.0)
    }

    /// The membrane's lower obstacle ψ₁(x): the paraboloid or `lower`.
    pub fn value(&self, x: [f64; 2]) -> f64 {
        match &self.lower {
            Some(lower) => lower.eval(x),
            None => self.level() - self.curvature.unwrap_or(0.0) * (x[0] * x[0] + x[1] * x[1]),
        }
    }
}

impl Scene {
    /// An expression height only on a rigid surface; finite numbers.
    pub(super) fn validate_obstacle(&self) -> Result<()> {
        if let Some(o) = &self.obstacle {
            let surface = matches!(o.shape, ObstacleShape::RigidSurface);
            match o.height.as_ref().map(|h| (h.as_constant(), h.text())) {
                Some((None, text)) if !surface => {
                    return Err(self.error(
                        "obstacle.height",
                        format!("shape \"{}\" takes a number, not \"{text}\" (an expression height is shape = \"rigid-surface\")", o.shape.name()),
                    ))
                }
                Some((Some(h), _)) => self.check_finite("obstacle.height", h)?,
                _ => {}
            }
            self.check_finite("obstacle.curvature", o.curvature.unwrap_or(0.0))?;
        }
        Ok(())
    }
}
