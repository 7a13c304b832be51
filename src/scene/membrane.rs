//! The scene keys of model "membrane": what it needs and what it refuses
//! (the shell's keys).

use super::{Expression, ObstacleShape, Scene};
use crate::error::Result;

impl Scene {
    /// What the membrane model needs and cannot use.
    pub(super) fn validate_membrane(&self) -> Result<()> {
        let load = self
            .load
            .as_ref()
            .ok_or_else(|| self.error("load", "the membrane model needs `[load] g = ...`"))?;
        let g = load
            .g
            .as_ref()
            .ok_or_else(|| self.error("load.g", "the membrane model needs the source term g"))?;
        if let Some(g) = g.as_constant() {
            self.check_finite("load.g", g)?;
        }
        if let Some(v) = self
            .mesh
            .dirichlet_value
            .as_ref()
            .and_then(Expression::as_constant)
        {
            self.check_finite("mesh.dirichlet_value", v)?;
        }
        if load.f.is_some()
            || !load.edge.is_empty()
            || load.pressure.is_some()
            || !load.point.is_empty()
        {
            return Err(self.error(
                "load",
                "`f`, `pressure`, `point` and `edge` are shell loads; the membrane takes `g`",
            ));
        }
        if self.shell.is_some() {
            return Err(self.error("shell", "a [shell] table needs model = \"naghdi\""));
        }
        if self.element.is_p2b_shell() {
            return Err(self.error(
                "element",
                format!(
                    "\"{}\" is a shell element; the membrane takes \"p1b-p0\" or \"p2-p1\"",
                    self.element.name()
                ),
            ));
        }
        if let Some(o) = &self.obstacle {
            if o.multiplier.is_some() {
                return Err(self.error(
                    "obstacle.multiplier",
                    "a shell key: the membrane's multiplier space comes with `element` (\"p1b-p0\": P0, \"p2-p1\": P1)",
                ));
            }
            match o.shape {
                ObstacleShape::Paraboloid => {
                    if o.height.is_none() {
                        return Err(
                            self.error("obstacle.height", "the paraboloid needs φ(0,0) = height")
                        );
                    }
                    if o.lower.is_some() || o.upper.is_some() {
                        return Err(self.error(
                            "obstacle.lower",
                            "`lower` and `upper` go with shape = \"expression\"",
                        ));
                    }
                }
                ObstacleShape::Expression => {
                    if o.lower.is_none() {
                        return Err(self.error(
                            "obstacle.lower",
                            "shape = \"expression\" needs `lower = \"<expression in x, y, r>\"` (u ≥ lower)",
                        ));
                    }
                    if o.height.is_some() || o.curvature.is_some() {
                        return Err(self.error(
                            "obstacle.height",
                            "`height` and `curvature` belong to the paraboloid; shape = \"expression\" takes `lower` (and `upper`)",
                        ));
                    }
                }
                shape => {
                    return Err(self.error(
                        "obstacle.shape",
                        format!(
                        "the membrane takes shape = \"paraboloid\" or \"expression\", not \"{}\"",
                        shape.name()
                    ),
                    ))
                }
            }
        }
        if self.output.probe.is_some() {
            return Err(self.error("output.probe", "the probe records a shell's displacement"));
        }
        if let Some(exact) = &self.output.exact {
            self.check_finite("output.exact.contact_radius", exact.contact_radius)?;
            if !self.output.errors {
                return Err(self.error("output.exact", "an exact solution is for `errors = true`"));
            }
        }
        if let Some(k) = self.output.plots.iter().find(|k| k.shell_only()) {
            return Err(self.error(
                "output.plots",
                format!("{k:?} is a shell plot; the membrane has \"u\"").to_lowercase(),
            ));
        }
        Ok(())
    }
}
