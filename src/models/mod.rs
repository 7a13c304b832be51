//! Models: each turns a scene and a mesh into an algebraic
//! [`ContactProblem`] using the shared FE machinery, and turns the solver's
//! answer back into fields. The pipeline sees a model only through
//! [`ModelSystem`].

pub mod estimator;
pub mod exact;
pub mod membrane;
pub mod naghdi;

use crate::error::{Error, Result};
use crate::mesh::{Hierarchy, Mesh};
use crate::output::{AttrValue, Field, Location, ResultData};
use crate::plot;
use crate::scene::{ColdStartSpec, ElementPair, Model, PlotKind, Scene};
use crate::solvers::multigrid_newton::SkeletonObstacles;
use crate::solvers::Probe;
use crate::solvers::{ContactProblem, SolveReport};
use crate::space::Element;
use faer::sparse::SparseColMat;
use std::path::Path;

/// What the stages around a model know of it before and beside its
/// [`ModelSystem`]: how it is set up, its size per triangle, the scene keys
/// that build its matrix and load, its result's layout, its cold start and
/// its FreeFEM twin. A model implements it once; [`kind`] is the one match
/// on [`Model`].
pub trait ModelKind {
    /// The model set up on the mesh for the scene (its `setup`).
    fn setup<'m>(&self, mesh: &'m Mesh, scene: &Scene) -> Result<Box<dyn ModelSystem + 'm>>;
    /// Unknowns per triangle of `element`, counting V ≈ T/2 vertices and
    /// E ≈ 3T/2 edges: primal fields plus the contact multipliers
    /// (the memory guard's estimate).
    fn unknowns_per_triangle(&self, element: ElementPair) -> f64;
    /// Bytes per unknown of a whole run (assembly, factorisation, iteration,
    /// output), `condensed` or not (`solver.condense`).
    fn bytes_per_unknown(&self, condensed: bool) -> f64;
    /// Bytes per unknown of a whole run by the multigrid method
    /// (`solver.method = "multigrid"`), the levels included.
    fn multigrid_bytes_per_unknown(&self) -> f64 {
        self.bytes_per_unknown(true)
    }
    /// The scene key named for a non-finite or singular matrix, and the keys
    /// (in prose) that build it.
    fn matrix_inputs(&self) -> (&'static str, &'static str);
    /// The scene key named for a non-finite load vector, and the keys that build it.
    fn load_inputs(&self) -> (&'static str, &'static str);
    /// The result has a 3D surface and a parameter-domain XDMF.
    fn has_surface(&self) -> bool;
    /// What `solver.cold_start = "auto"` means for the model: the start with
    /// fewer Newton solves measured on its scenes (docs/work-precision.md,
    /// "The interior-point start").
    fn auto_cold_start(&self) -> ColdStartSpec;
    /// The FreeFEM script that solves the model's scene with `element`
    /// too (`obstacle freefem`); None: the model has no twin.
    fn freefem_twin(&self, element: ElementPair) -> Option<FreefemTwin>;
    /// The prolongations between consecutive levels of `hierarchy` on the
    /// unknowns a multigrid smooths (the skeleton: the problem's unknowns
    /// outside its interior groups), coarsest first, with what the boundary
    /// values add to each and each level's obstacles there; an error naming
    /// the scene key where the model has none.
    fn skeleton_transfers(
        &self,
        _hierarchy: &Hierarchy,
        scene: &Scene,
    ) -> Result<SkeletonTransfers> {
        Err(scene.error(
            "solver.method",
            format!(
                "the model \"{}\" has no multigrid prolongations",
                scene.model.name()
            ),
        ))
    }
}

/// Prolongations between the skeletons of consecutive levels, coarsest
/// first: level l + 1's interpolant of level l's u is
/// `prolongations[l] u + lifts[l]` (the lift: the boundary values' part).
pub struct SkeletonTransfers {
    pub prolongations: Vec<SparseColMat<usize, f64>>,
    pub lifts: Vec<Vec<f64>>,
    /// `obstacles[l]`: the obstacles at level l's skeleton unknowns, every
    /// level (the finest last); none without an obstacle.
    pub obstacles: Option<Vec<SkeletonObstacles>>,
}

/// The FreeFEM twins of the models (freefem/*.edp; src/freefem.rs runs them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FreefemTwin {
    /// `membrane-obstacle.edp`: P1⊕B3–P0 and P2–P1.
    Membrane,
    /// `naghdi-contact.edp`: the shell's thesis element `p1b-p0`.
    ShellThesis,
    /// `naghdi-psri.edp`: the shell's element `p2b-psri`.
    ShellPsri,
}

/// The model a scene names: the one match on [`Model`].
pub fn kind(model: Model) -> &'static dyn ModelKind {
    match model {
        Model::Membrane => &membrane::Membrane,
        Model::Naghdi => &naghdi::Naghdi,
    }
}

/// The solver's cold start for a model: the scene's, with "auto" made
/// concrete by [`ModelKind::auto_cold_start`].
pub fn cold_start(spec: ColdStartSpec, model: Model) -> ColdStartSpec {
    match spec {
        ColdStartSpec::Auto => kind(model).auto_cold_start(),
        spec => spec,
    }
}

/// A model set up on a mesh for a scene: the steps of a run after meshing.
/// `setup` (each model's constructor) reads the scene once and resolves
/// everything the later steps need, so none of them sees the scene.
pub trait ModelSystem {
    /// The algebraic problem; the constraint only when the scene has an obstacle.
    fn assemble(&self) -> Result<ContactProblem>;
    /// Model quantities recorded in the solver history every iteration.
    fn probes(&self) -> Vec<Probe> {
        Vec::new()
    }
    /// Fields, coefficient vectors and model attributes for the result
    /// file; products with A on `threads` (`solver.threads`).
    fn results(&self, problem: &ContactProblem, report: &SolveReport, threads: usize)
        -> ResultData;
    /// The inverse of `results`' `/dofs`: the primal unknowns x of the
    /// algebraic problem from coefficient vectors named and laid out as the
    /// result file stores them (values at fixed dofs are dropped). How a
    /// solution computed elsewhere (the FreeFEM twin) becomes a result.
    fn primal_from_dofs(&self, dofs: &[(String, Vec<f64>)]) -> Result<Vec<f64>>;
    /// Errors against an exact solution, when the scene has one and asks
    /// for it, integrated on `threads` (`solver.threads`); an error when the
    /// exact solution is refused where it is evaluated (a scene's
    /// expression not finite there).
    fn exact_errors(
        &self,
        _problem: &ContactProblem,
        _report: &SolveReport,
        _threads: usize,
    ) -> Result<Option<ExactErrors>> {
        Ok(None)
    }
    /// The a posteriori error indicator η_T of every triangle
    /// (docs/formulation.md §8), when the model has one.
    fn estimator(&self, _problem: &ContactProblem, _report: &SolveReport) -> Option<Vec<f64>> {
        None
    }
    /// Draws one figure the scene asks for (all but the solver history) from
    /// the result's fields; a model adds or refines the figures it knows.
    fn plot(&self, kind: PlotKind, path: &Path, title: &str, figure: &FigureData) -> Result<()> {
        plot_result_field(self.mesh(), kind, path, title, figure)
    }
    /// The mesh the model is set up on.
    fn mesh(&self) -> &Mesh;
    /// Number of discrete unknowns as the thesis counts them (boundary dofs included).
    fn n_dofs(&self) -> usize;
}

/// What a figure of a result is drawn from: the result's fields and, when
/// known, the errors against the exact solution.
pub struct FigureData<'a> {
    pub data: &'a ResultData,
    pub errors: Option<&'a ExactErrors>,
}

impl FigureData<'_> {
    pub fn field(&self, name: &str) -> Option<&Field> {
        self.data.fields.iter().find(|f| f.name == name)
    }
}

/// Errors of u_h (and λ_h) against an exact solution, and the discrete
/// contact radius against the exact one (docs/formulation.md §1).
#[derive(Debug, Clone, Copy)]
pub struct ExactErrors {
    pub l2: f64,
    pub h1: f64,
    pub lambda_l2: f64,
    /// √(contact area / π), the contact set (`SolveReport::contact`) weighted
    /// by the Riesz weights.
    pub contact_radius: f64,
    pub exact_contact_radius: f64,
}

impl ExactErrors {
    /// The root attributes of a result file that record these errors.
    pub fn attrs(&self) -> Vec<(String, AttrValue)> {
        [
            ("error_l2_u", self.l2),
            ("error_h1_u", self.h1),
            ("error_l2_lambda", self.lambda_l2),
            ("contact_radius", self.contact_radius),
            ("exact_contact_radius", self.exact_contact_radius),
        ]
        .into_iter()
        .map(|(name, v)| (name.to_string(), AttrValue::F64(v)))
        .collect()
    }
}

/// The figures every model draws the same way: a field at the vertices or
/// per triangle (u, its components, λ, the mean gap) and the contact zone
/// (with the exact contact circle when known). Kinds without the field they
/// need (e.g. λ without an obstacle) draw nothing.
pub fn plot_result_field(
    mesh: &Mesh,
    kind: PlotKind,
    path: &Path,
    title: &str,
    figure: &FigureData,
) -> Result<()> {
    match kind {
        PlotKind::Contact => {
            if let Some(f) = figure.field("contact") {
                let active: Vec<bool> = f.values.iter().map(|&v| v > 0.0).collect();
                let circle = figure.errors.map(|e| e.exact_contact_radius);
                plot::plot_contact_zone(path, mesh, &active, title, circle)?;
            }
        }
        PlotKind::U1 | PlotKind::U2 | PlotKind::U3 => {
            let c = match kind {
                PlotKind::U1 => 0,
                PlotKind::U2 => 1,
                _ => 2,
            };
            if let Some(f) = figure.field("u") {
                let values: Vec<f64> = f.values.iter().skip(c).step_by(3).copied().collect();
                plot::plot_vertex_field(path, mesh, &values, title)?;
            }
        }
        PlotKind::U | PlotKind::Lambda | PlotKind::Gap | PlotKind::Estimator => {
            let name = match kind {
                PlotKind::U => "u",
                PlotKind::Lambda => "lambda",
                PlotKind::Estimator => "estimator",
                _ => "gap_mean",
            };
            if let Some(f) = figure.field(name) {
                match f.location {
                    Location::Vertex => plot::plot_vertex_field(path, mesh, &f.values, title)?,
                    Location::Cell => plot::plot_cell_field(path, mesh, &f.values, title)?,
                }
            }
        }
        // The solver's history is drawn by the pipeline; the constraint by
        // the shell model.
        PlotKind::History | PlotKind::Constraint => {}
    }
    Ok(())
}

/// The vector named `name` among `dofs`, checked to have `len` entries.
pub fn named_dofs<'a>(dofs: &'a [(String, Vec<f64>)], name: &str, len: usize) -> Result<&'a [f64]> {
    let (_, v) = dofs.iter().find(|(n, _)| n == name).ok_or_else(|| {
        Error::output("(coefficient vectors)", format!("no vector named `{name}`"))
    })?;
    if v.len() != len {
        return Err(Error::output(
            "(coefficient vectors)",
            format!("`{name}` has {} values, the model has {len}", v.len()),
        ));
    }
    Ok(v)
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
    let error = |reason: String| Error::Scene {
        file: scene.source.clone(),
        field: field.into(),
        reason,
    };
    // The parts a boundary condition can name: physical lines of the boundary.
    let boundary_parts = || {
        let tags: std::collections::BTreeSet<i32> =
            mesh.boundary_edges.iter().map(|e| e.tag).collect();
        let names: Vec<String> = tags
            .iter()
            .filter_map(|t| mesh.physical_names.get(t).cloned())
            .collect();
        names.join(", ")
    };
    names
        .iter()
        .map(|name| {
            let tag = mesh.tag_by_name(name).ok_or_else(|| {
                error(format!(
                    "the mesh {} has no boundary part named `{name}` (its boundary parts: {})",
                    mesh.source.display(),
                    boundary_parts()
                ))
            })?;
            if !mesh.boundary_edges.iter().any(|e| e.tag == tag) {
                return Err(error(format!(
                    "`{name}` of the mesh {} is not a part of the boundary (no boundary line carries its tag {tag}; its boundary parts: {})",
                    mesh.source.display(),
                    boundary_parts()
                )));
            }
            Ok(tag)
        })
        .collect::<Result<Vec<_>>>()
        .map(Some)
}

/// The values a solution takes on its fixed boundary parts.
pub enum BoundaryValues {
    /// u = 0 (the shell's clamped parts, the membrane without `mesh.dirichlet_value`).
    Zero,
    /// u = g_D, its values at the vertices.
    AtVertices(Vec<f64>),
}

/// Feasibility before assembling: where the boundary parts `tags` (all of
/// the boundary if None) fix the solution to g_D, the obstacles must admit
/// it, ψ₁,h ≤ g_D (≤ ψ₂,h) at each of their vertices; else no admissible u
/// exists. The error names `where_fixed`, the worst vertex and the values.
pub fn check_obstacle_against_boundary_values(
    mesh: &Mesh,
    scene: &Scene,
    (lower, upper): (&[f64], Option<&[f64]>),
    values: &BoundaryValues,
    tags: Option<&[i32]>,
    where_fixed: &str,
) -> Result<()> {
    let mask = mesh.boundary_vertex_mask(tags);
    let value = |v: usize| match values {
        BoundaryValues::Zero => 0.0,
        BoundaryValues::AtVertices(g) => g[v],
    };
    let scale = lower
        .iter()
        .chain(upper.unwrap_or(&[]))
        .fold(0.0f64, |m, p| m.max(p.abs()))
        .max(1.0);
    let fixed = || (0..mesh.n_vertices()).filter(|&v| mask[v]);
    let infeasible = |v: usize, what: String| {
        Err(scene.error("obstacle", format!(
                "infeasible: the {where_fixed} at ({:.6}, {:.6}) {what}, so no admissible displacement exists (the obstacle must admit the boundary values)",
                mesh.vertices[v][0], mesh.vertices[v][1]
            )))
    };
    let worst_below =
        fixed().max_by(|&a, &b| (lower[a] - value(a)).total_cmp(&(lower[b] - value(b))));
    if let Some(v) = worst_below.filter(|&v| lower[v] - value(v) > 1e-12 * scale) {
        return infeasible(
            v,
            format!(
                "lies {:.6e} below the obstacle (Φ_h = {:.6e} > {} there)",
                lower[v] - value(v),
                lower[v],
                value(v)
            ),
        );
    }
    if let Some(upper) = upper {
        let worst_above =
            fixed().max_by(|&a, &b| (value(a) - upper[a]).total_cmp(&(value(b) - upper[b])));
        if let Some(v) = worst_above.filter(|&v| value(v) - upper[v] > 1e-12 * scale) {
            return infeasible(
                v,
                format!(
                    "lies {:.6e} above the upper obstacle ({} > ψ₂,h = {:.6e} there)",
                    value(v) - upper[v],
                    value(v),
                    upper[v]
                ),
            );
        }
    }
    Ok(())
}

/// A scalar field where the multipliers live: per triangle (P0) or per vertex (P1).
pub fn multiplier_field(name: &str, values: Vec<f64>, multipliers: Element) -> Field {
    let location = if multipliers == Element::P0 {
        Location::Cell
    } else {
        Location::Vertex
    };
    Field {
        name: name.into(),
        values,
        components: 1,
        location,
    }
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
/// indicator (`SolveReport::contact`), per triangle (P0 multipliers) or per
/// vertex (P1), and λ's coefficient vector with its `space` attribute.
pub fn contact_fields(
    data: &mut ResultData,
    lambda: Vec<f64>,
    gap: Vec<f64>,
    contact: &[bool],
    multipliers: Element,
) {
    let contact = contact.iter().map(|&c| f64::from(c)).collect();
    for (name, values) in [
        ("lambda", lambda.clone()),
        ("gap_mean", gap),
        ("contact", contact),
    ] {
        data.fields
            .push(multiplier_field(name, values, multipliers));
    }
    data.dofs.push(("lambda".into(), lambda));
    data.dof_spaces
        .push(("lambda".into(), crate::output::space_tag(multipliers, 1)));
}
