//! `[mesh]`: a gmsh geometry (structured `n` or size `h`) or a mesh file,
//! the Dirichlet parts and values, the memory limit, gmsh parameters.

use super::{Expression, Scene};
use crate::error::Result;
use serde::Deserialize;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    /// gmsh geometry, relative to the scene file's folder (e.g. "../../meshes/disk.geo").
    pub geo: Option<String>,
    /// Structured subdivisions (disk: points per quarter circle; diamond: per side).
    pub n: Option<i64>,
    /// Unstructured target size (used when `n` is absent).
    pub h: Option<f64>,
    /// An existing MSH 2.2 file (relative to the scene file's folder) instead of meshing.
    pub file: Option<String>,
    /// Uniform refinements of the mesh (`geo` or `file`): each splits every
    /// triangle in four, new boundary vertices placed on the circles the
    /// boundary parts lie on (src/mesh/refine.rs). The run's mesh is the
    /// last; `method = "multigrid"` solves on all of them. Default 0.
    #[serde(default)]
    pub refine: i64,
    /// Physical names of the boundary parts where the Dirichlet condition holds
    /// (default: the whole boundary).
    pub dirichlet: Option<Vec<String>>,
    /// The membrane's boundary values u = g_D on the Dirichlet parts (default 0).
    pub dirichlet_value: Option<Expression>,
    /// The memory a run may use, in GB (default: half of MemAvailable);
    /// a scene whose estimate is above it is refused (src/guards.rs).
    pub memory_limit_gb: Option<f64>,
    /// Numbers passed to gmsh as `-setnumber NAME VALUE` (e.g. the corners
    /// x0, x1, y0, y1 of meshes/rectangle.geo).
    #[serde(default)]
    pub parameters: std::collections::BTreeMap<String, f64>,
}

impl Scene {
    /// One mesh source, and the ranges of `n`, `h`, the memory limit and the gmsh parameters.
    pub(super) fn validate_mesh(&self) -> Result<()> {
        let m = &self.mesh;
        match (&m.file, &m.geo) {
            (Some(_), Some(_)) => {
                return Err(self.error("mesh", "give either `file` or `geo`, not both"))
            }
            (None, None) => {
                return Err(self.error(
                    "mesh",
                    "give `geo` (a gmsh .geo to mesh) or `file` (an MSH 2.2 mesh)",
                ))
            }
            (None, Some(_)) => {
                if m.n.is_none() && m.h.is_none() {
                    return Err(self.error(
                        "mesh",
                        "meshing a .geo needs `n` (structured) or `h` (target size)",
                    ));
                }
            }
            (Some(_), None) => {}
        }
        if let Some(n) = m.n {
            if !(1..=100_000).contains(&n) {
                return Err(self.error("mesh.n", format!("must be between 1 and 100000, got {n}")));
            }
        }
        if !(0..=12).contains(&m.refine) {
            return Err(self.error(
                "mesh.refine",
                format!(
                    "must be between 0 and 12 (each refinement quadruples the triangles), got {}",
                    m.refine
                ),
            ));
        }
        if let Some(h) = m.h {
            self.check_positive("mesh.h", h)?;
        }
        if let Some(gb) = m.memory_limit_gb {
            self.check_positive("mesh.memory_limit_gb", gb)?;
        }
        for (name, value) in &m.parameters {
            let field = format!("mesh.parameters.{name}");
            self.check_finite(&field, *value)?;
            let ident = name.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
                && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
            if !ident || name == "n" || name == "h" {
                return Err(self.error(
                    &field,
                    "a gmsh parameter is a name of letters, digits and _ (not `n` or `h`: those are mesh.n, mesh.h)",
                ));
            }
        }
        Ok(())
    }
}
