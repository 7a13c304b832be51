//! `[adapt]`: the adaptive loop (docs/formulation.md §8).

use super::Scene;
use crate::error::Result;
use serde::Deserialize;

/// `[adapt]`: solve → estimate → mark → remesh, until the estimator reaches
/// `target_error`, the next mesh would pass `max_dofs`, or `max_steps` solves.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AdaptSpec {
    pub marking: Marking,
    /// Dörfler's bulk parameter: the marked triangles carry ≥ θ of Σ η_T².
    pub theta: f64,
    /// Stop once η = (Σ η_T²)^½ ≤ target_error.
    pub target_error: Option<f64>,
    /// Stop before solving on a mesh with more than max_dofs unknowns.
    pub max_dofs: Option<i64>,
    /// At most this many solves (the first mesh included).
    pub max_steps: i64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Marking {
    /// Dörfler (bulk) marking with `theta`.
    Dorfler,
}

impl Scene {
    /// `[adapt]`: ranges, and what the loop needs (the membrane, a gmsh mesh, contact).
    pub(super) fn validate_adapt(&self) -> Result<()> {
        let Some(a) = &self.adapt else {
            return Ok(());
        };
        if !(a.theta.is_finite() && a.theta > 0.0 && a.theta <= 1.0) {
            return Err(self.error(
                "adapt.theta",
                format!("Dörfler's θ must lie in (0, 1], got {}", a.theta),
            ));
        }
        if let Some(t) = a.target_error {
            if !(t.is_finite() && t > 0.0) {
                return Err(self.error(
                    "adapt.target_error",
                    format!("must be a finite number > 0, got {t}"),
                ));
            }
        }
        if let Some(n) = a.max_dofs {
            if n < 1 {
                return Err(self.error("adapt.max_dofs", format!("must be ≥ 1, got {n}")));
            }
        }
        if !(1..=100).contains(&a.max_steps) {
            return Err(self.error(
                "adapt.max_steps",
                format!("must be between 1 and 100, got {}", a.max_steps),
            ));
        }
        if self.mesh.geo.is_none() {
            return Err(self.error(
                "adapt",
                "the adaptive loop remeshes with gmsh: give `mesh.geo` (taking `n` and `h`), not `mesh.file`",
            ));
        }
        if self.solver.nested {
            return Err(self.error(
                "adapt",
                "the adaptive loop warm-starts each step from the previous one; drop `solver.nested`",
            ));
        }
        if self.solver.method == super::Method::Multigrid {
            return Err(self.error(
                "adapt",
                "the adaptive loop's meshes are no uniform refinements of one another: the multigrid method needs mesh.refine's hierarchy (choose another method)",
            ));
        }
        Ok(())
    }
}
