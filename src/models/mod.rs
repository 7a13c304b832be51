//! Models: each turns a scene and a mesh into an algebraic
//! [`ContactProblem`] using the shared FE machinery, and turns the solver's
//! answer back into fields. The pipeline sees a model only through
//! [`ModelSystem`].

pub mod exact;
pub mod membrane;
pub mod naghdi;

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use crate::output::{Field, Location, ResultData};
use crate::scene::Scene;
use crate::solvers::Probe;
use crate::solvers::{ContactProblem, SolveReport};
use crate::space::Element;
use membrane::ExactErrors;

/// A model set up on a mesh for a scene: the steps of a run after meshing.
pub trait ModelSystem {
    /// The algebraic problem; the constraint only when the scene has an obstacle.
    fn assemble(&self, scene: &Scene) -> Result<ContactProblem>;
    /// Model quantities recorded in the solver history every iteration.
    fn probes(&self) -> Vec<Probe> {
        Vec::new()
    }
    /// Fields, coefficient vectors and model attributes for the result file.
    fn results(&self, scene: &Scene, problem: &ContactProblem, report: &SolveReport) -> ResultData;
    /// Errors against an exact solution, when the scene has one and asks for it.
    fn exact_errors(
        &self,
        _scene: &Scene,
        _problem: &ContactProblem,
        _report: &SolveReport,
    ) -> Option<ExactErrors> {
        None
    }
    /// Number of discrete unknowns as the thesis counts them (boundary dofs included).
    fn n_dofs(&self) -> usize;
}

/// The physical tags of the boundary parts `names` (scene field `field`);
/// None (no names given) means all of the boundary.
pub fn named_boundary_tags(
    mesh: &Mesh,
    scene: &Scene,
    field: &str,
    names: Option<&[String]>,
) -> Result<Option<Vec<i32>>> {
    let Some(names) = names else {
        return Ok(None);
    };
    names
        .iter()
        .map(|name| {
            mesh.tag_by_name(name).ok_or_else(|| Error::Scene {
                file: scene.source.clone(),
                field: field.into(),
                reason: format!(
                    "the mesh {} has no boundary part named `{name}` (it has: {})",
                    mesh.source.display(),
                    mesh.physical_names
                        .values()
                        .cloned()
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            })
        })
        .collect::<Result<Vec<_>>>()
        .map(Some)
}

/// A scalar field at the vertices.
pub fn vertex_field(name: &str, values: Vec<f64>) -> Field {
    Field {
        name: name.into(),
        values,
        components: 1,
        location: Location::Vertex,
    }
}

/// The contact fields of a result: λ, the mean gap ḡ and the contact
/// indicator (λ > 0), per triangle (P0 multipliers) or per vertex (P1), and
/// λ's coefficient vector with its `space` attribute.
pub fn contact_fields(
    data: &mut ResultData,
    lambda: Vec<f64>,
    gap: Vec<f64>,
    multipliers: Element,
) {
    let location = if multipliers == Element::P0 {
        Location::Cell
    } else {
        Location::Vertex
    };
    let contact = lambda
        .iter()
        .map(|&l| if l > 0.0 { 1.0 } else { 0.0 })
        .collect();
    for (name, values) in [
        ("lambda", lambda.clone()),
        ("gap_mean", gap),
        ("contact", contact),
    ] {
        data.fields.push(Field {
            name: name.into(),
            values,
            components: 1,
            location,
        });
    }
    data.dofs.push(("lambda".into(), lambda));
    data.dof_spaces
        .push(("lambda".into(), crate::output::space_tag(multipliers, 1)));
}
