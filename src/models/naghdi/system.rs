//! The Naghdi shell as a model of the pipeline (docs/formulation.md §2, thesis Problem 9),
//! with either shell element (`p1b-p0`, `p2b-psri`: forms.rs):
//! [`NaghdiSystem::setup`] checks the chart and the obstacle on the mesh,
//! resolves the boundary conditions per part and component and numbers the
//! fixed dofs; `assemble` builds exactly the effects the scene
//! declares (body force, edge loads, tangency, contact); `results` turns the
//! solver's answer into the fields of docs/formulation.md §5.
//!
//! Two reductions keep the algebra to what the scene needs:
//! * no obstacle: no λ block at all, the pipeline does one linear solve;
//! * a flat chart (`plate`) with the thesis element: a3 = e3 everywhere, so the tangency r·a3 = 0 is
//!   r3 = 0 and is imposed by eliminating r3; ψ and the ρ term (which vanishes
//!   on r3 = 0) disappear and K is symmetric positive definite (Cholesky).

use super::estimator::{shell_indicators, ShellContact, ShellState};
use super::forms::{
    add_edge_load, add_point_load, assemble_shell_layout, balanced_tangency_scale,
    constraint_factor, edge_quadrature_points, fix_fields, nodal_plane_constraint,
    obstacle_at_vertices, plane_constraint, restrict_shell, scale_tangency_multiplier, FieldRole,
    ShellElementKind, ShellLayout, SurfaceLoad,
};
use super::geometry::{obstacle_function, Chart, Material};
use crate::assembly::{quad_points, quadrature_points, DofNumbering, LinearTies};
use crate::error::{Error, Result};
use crate::linalg::{InteriorGroups, MatrixKind};
use crate::mesh::{Mesh, PointLocator};
use crate::models::{
    check_obstacle_against_boundary_values, contact_fields, named_boundary_tags, named_dofs,
    plot_result_field, vertex_field, BoundaryValues, FigureData, ModelSystem,
};
use crate::output::{AttrValue, Field, Location, ResultData};
use crate::plot;
use crate::quadrature::TriangleRule;
use crate::scene::{
    BoundaryCondition, BoundarySpec, ContactMultiplier, ElementPair, Expression, PlaneNormal,
    PlotKind, Scene, ShellSpec,
};
use crate::solvers::Probe;
use crate::solvers::{ContactProblem, SolveReport};
use crate::space::{Element, Space, TriangleGeometry};
use nalgebra::Vector3;
use std::cell::Cell;
use std::path::Path;

pub struct NaghdiSystem<'m> {
    pub mesh: &'m Mesh,
    pub chart: Chart,
    pub material: Material,
    /// The penalty ρ of a_ρ (thesis element; 0 for tangent rotations).
    pub rho: f64,
    pub layout: ShellLayout,
    pub numbering: DofNumbering,
    /// Flat chart with the thesis element: r3 eliminated, no ψ (see the
    /// module documentation).
    pub plate_reduction: bool,
    /// The body force f and pressure p, the edge loads (tag, N, M) and the
    /// point loads (triangle, barycentric coordinates, F), resolved once.
    surface_load: SurfaceLoad,
    edge_loads: Vec<(i32, [Expression; 3], [Expression; 3])>,
    point_loads: Vec<(usize, [f64; 3], [f64; 3])>,
    /// The rigid body's height h(x, y): z < h is the obstacle (a number for the plane).
    pub height: Option<Expression>,
    /// Φ at the vertices, with the plane's level added (obstacle scenes).
    pub phi: Option<Vec<f64>>,
    /// Vertices where Φ > 0 (the unloaded shell is below the plane).
    pub phi_positive_vertices: usize,
    /// The scale σ of ψ' = ψ/σ in the algebraic problem (1 without ψ);
    /// set by `assemble`.
    tangency_scale: Cell<f64>,
    /// Which effects the scene asked for (recorded in the result file).
    pub simulated: Vec<String>,
    /// The scene's element (recorded in the result file).
    element: ElementPair,
    /// The point where u is recorded (`output.probe`).
    probe: Option<[f64; 2]>,
    /// The ties of oblique symmetry planes: the solvers' unknowns are the
    /// independent ones (x_free = T y).
    ties: Option<LinearTies>,
}

/// The boundary conditions of a scene, resolved to tags: `shell.clamped`
/// (default: all of ∂ω when no `[[shell.boundary]]` is given) and each
/// `[[shell.boundary]]`.
fn resolved_conditions(
    mesh: &Mesh,
    scene: &Scene,
    shell: &ShellSpec,
) -> Result<Vec<(Option<Vec<i32>>, BoundarySpec)>> {
    let mut out = Vec::new();
    let clamped = |part: &str| BoundarySpec {
        part: part.into(),
        condition: BoundaryCondition::Clamped,
        normal: None,
        fix: None,
    };
    match &shell.clamped {
        None if shell.boundary.is_empty() => out.push((None, clamped("(all of the boundary)"))),
        None => {}
        Some(names) => {
            let tags = named_boundary_tags(mesh, scene, "shell.clamped", Some(names))?;
            for (tag, name) in tags.into_iter().flatten().zip(names) {
                out.push((Some(vec![tag]), clamped(name)));
            }
        }
    }
    for (i, b) in shell.boundary.iter().enumerate() {
        let tags = named_boundary_tags(
            mesh,
            scene,
            &format!("shell.boundary[{i}].part"),
            Some(std::slice::from_ref(&b.part)),
        )?;
        out.push((tags, b.clone()));
    }
    Ok(out)
}

/// The vertices where the fixed dofs pin the constraint value
/// w = (u − ε/2 r)·e3 to 0: u3 is fixed there and so is the rotation's
/// contribution: every rotation field entering w is fixed at the vertex, or
/// its factor vanishes (a tangent rotation with a3 = ±e3 has r·e3 = 0; with
/// tangent rotations the factor of θ^β is a_β·e3).
fn constraint_pinned_vertices(
    mesh: &Mesh,
    layout: &ShellLayout,
    chart: &Chart,
    fixed: &[bool],
) -> Vec<bool> {
    let fixed_at = |role: FieldRole, v: usize| {
        layout
            .field_of(role)
            .is_none_or(|f| fixed[layout.fields[f].offset + v])
    };
    (0..mesh.n_vertices())
        .map(|v| {
            if !fixed_at(FieldRole::Displacement(2), v) {
                return false;
            }
            let p = chart.at(mesh.vertices[v]);
            let tol = 1e-12;
            let cartesian_pinned = (0..3).all(|c| fixed_at(FieldRole::CartesianRotation(c), v))
                || p.a3.cross(&Vector3::z()).norm() <= tol;
            let tangent_pinned = (0..2).all(|be| {
                fixed_at(FieldRole::TangentRotation(be), v)
                    || p.a(be).z.abs() <= tol * p.a(be).norm()
            });
            match layout.kind {
                ShellElementKind::P1bP0 => cartesian_pinned,
                ShellElementKind::P2bPsri | ShellElementKind::P2bMitc => tangent_pinned,
            }
        })
        .collect()
}

/// The problem over the independent unknowns of `ties` (Tᵀ A T, Tᵀ F; the
/// tied unknowns are primal, so n_primal drops by their number; every
/// interior group's unknowns are independent: bubbles vanish on the boundary).
fn tie_unknowns(problem: &mut ContactProblem, ties: &LinearTies) {
    let tied_primal = (0..problem.n_primal)
        .filter(|&i| ties.independent_index(i).is_none())
        .count();
    problem.matrix = ties.congruence(&problem.matrix);
    problem.rhs = ties.transpose_times(&problem.rhs);
    problem.n_primal -= tied_primal;
    problem.kind = match problem.kind {
        MatrixKind::SymmetricSaddle { .. } => MatrixKind::SymmetricSaddle {
            n_primal: problem.n_primal,
        },
        kind => kind,
    };
    problem.interior = problem.interior.as_ref().map(|groups| {
        InteriorGroups::from_groups((0..groups.len()).map(|g| {
            groups
                .group(g)
                .iter()
                .filter_map(|&i| ties.independent_index(i))
                .collect()
        }))
    });
}

/// The ties of the symmetry planes with an oblique unit normal n, node by
/// node on their parts: u·n = 0, and r·n = 0 (Cartesian r: Σ n_c r_c;
/// tangent rotations: Σ θ^β a_β·n at the node's point). Of each relation the
/// free component with the largest coefficient is tied to the others. Two
/// relations at one node (oblique planes meeting) are refused.
fn oblique_symmetry_ties(
    mesh: &Mesh,
    scene: &Scene,
    layout: &ShellLayout,
    chart: &Chart,
    conditions: &[(Option<Vec<i32>>, BoundarySpec)],
    numbering: &DofNumbering,
) -> Result<Option<LinearTies>> {
    let mut ties: Vec<(usize, Vec<(usize, f64)>)> = Vec::new();
    let mut tied = vec![false; numbering.n_free()];
    for (tags, b) in conditions {
        let Some(normal) = b.normal.filter(|n| n.axis().is_none()) else {
            continue;
        };
        if b.condition != BoundaryCondition::Symmetry {
            continue;
        }
        let n = Vector3::from(normal.unit());
        let groups: Vec<Vec<(usize, FieldRole)>> = [
            (0..3).map(FieldRole::Displacement).collect::<Vec<_>>(),
            (0..3).map(FieldRole::CartesianRotation).collect(),
            (0..2).map(FieldRole::TangentRotation).collect(),
        ]
        .into_iter()
        .map(|roles| {
            roles
                .into_iter()
                .filter_map(|r| layout.field_of(r).map(|f| (f, r)))
                .collect::<Vec<_>>()
        })
        .filter(|g| !g.is_empty())
        .collect();
        for group in groups {
            let element = layout.fields[group[0].0].element;
            let mask = Space::new(mesh, element).boundary_dof_mask(tags.as_deref());
            for d in (0..mask.len()).filter(|&d| mask[d]) {
                let x = dof_point(mesh, element, d);
                let p = chart.at(x);
                let terms: Vec<(usize, f64)> = group
                    .iter()
                    .filter_map(|&(f, role)| {
                        let c = match role {
                            FieldRole::TangentRotation(be) => p.a(be).dot(&n),
                            FieldRole::Displacement(c) | FieldRole::CartesianRotation(c) => n[c],
                            FieldRole::TangencyMultiplier => 0.0,
                        };
                        numbering
                            .free_index(layout.fields[f].offset + d)
                            .map(|i| (i, c))
                    })
                    .collect();
                let scale = terms.iter().fold(0.0f64, |m, t| m.max(t.1.abs()));
                if scale <= 1e-12 {
                    continue; // nothing free moves across the plane here
                }
                let &(slave, c_slave) = terms
                    .iter()
                    .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                    .expect("a term");
                let masters: Vec<(usize, f64)> = terms
                    .iter()
                    .filter(|t| t.0 != slave && t.1.abs() > 1e-14 * scale)
                    .map(|&(i, c)| (i, -c / c_slave))
                    .collect();
                if std::iter::once(slave)
                    .chain(masters.iter().map(|m| m.0))
                    .any(|i| tied[i])
                {
                    return Err(scene.error("shell.boundary.normal", format!(
                            "part `{}`: at ({:.6}, {:.6}) two symmetry planes of oblique normal meet; a node takes one oblique plane",
                            b.part, x[0], x[1]
                        )));
                }
                for i in std::iter::once(slave).chain(masters.iter().map(|m| m.0)) {
                    tied[i] = true;
                }
                ties.push((slave, masters));
            }
        }
    }
    Ok((!ties.is_empty()).then(|| LinearTies::new(numbering.n_free(), ties)))
}

/// The fixed-dof mask of the boundary conditions (docs/shell-benchmarks.md):
/// clamped: u = r = 0 (and ψ = 0 with the thesis element); simply
/// supported: u = 0; diaphragm with normal e_n: u_c = 0 for c ≠ n; symmetry
/// with normal e_n: u_n = 0 and r·e_n = 0 (r_n = 0, or with tangent rotations
/// the θ^β whose a_β leaves the plane, node by node); fixed: the named fields.
fn fixed_mask(
    mesh: &Mesh,
    scene: &Scene,
    layout: &ShellLayout,
    chart: &Chart,
    conditions: &[(Option<Vec<i32>>, BoundarySpec)],
) -> Result<Vec<bool>> {
    let mut fixed = vec![false; layout.n_total()];
    let field_of = |role| layout.field_of(role);
    for (tags, b) in conditions {
        let tags = tags.as_deref();
        let oblique = b.normal.is_some_and(|n| n.axis().is_none());
        let n = b.normal.and_then(PlaneNormal::axis).map(|a| a.index());
        let fields: Vec<usize> = match b.condition {
            BoundaryCondition::Clamped => (0..layout.fields.len()).collect(),
            BoundaryCondition::SimplySupported => (0..3)
                .filter_map(|c| field_of(FieldRole::Displacement(c)))
                .collect(),
            BoundaryCondition::Diaphragm => (0..3)
                .filter(|&c| Some(c) != n)
                .filter_map(|c| field_of(FieldRole::Displacement(c)))
                .collect(),
            // An oblique plane ties components instead (`oblique_symmetry_ties`).
            BoundaryCondition::Symmetry if oblique => Vec::new(),
            BoundaryCondition::Symmetry => {
                let n = n.expect("validated: symmetry has a normal");
                let mut f = vec![field_of(FieldRole::Displacement(n)).expect("u fields")];
                if let Some(r) = field_of(FieldRole::CartesianRotation(n)) {
                    f.push(r);
                } else {
                    fix_tangent_symmetry(mesh, scene, layout, chart, tags, n, &b.part, &mut fixed)?;
                }
                f
            }
            BoundaryCondition::Free => Vec::new(),
            BoundaryCondition::Fixed => {
                let names = b.fix.as_deref().unwrap_or_default();
                let context = format!("part `{}`", b.part);
                names
                    .iter()
                    .map(|name| field_named(scene, layout, "shell.boundary.fix", &context, name))
                    .collect::<Result<_>>()?
            }
        };
        // Clamping fixes ψ too (the thesis' ψ ∈ H¹₀(γ0)); no other condition does.
        fix_fields(mesh, layout, tags, fields, &mut fixed);
    }
    let supports = scene.shell.as_ref().map_or(&[][..], |s| &s.support[..]);
    let scale = mesh.h_max();
    for (k, support) in supports.iter().enumerate() {
        let v = (0..mesh.n_vertices())
            .find(|&v| {
                let x = mesh.vertices[v];
                (x[0] - support.at[0]).hypot(x[1] - support.at[1]) <= 1e-9 * scale
            })
            .ok_or_else(|| {
                scene.error(
                    &format!("shell.support[{k}].at"),
                    format!(
                        "({}, {}) is no vertex of the mesh: a support fixes the dofs of one vertex",
                        support.at[0], support.at[1]
                    ),
                )
            })?;
        let key = format!("shell.support[{k}].fix");
        for name in &support.fix {
            let f = field_named(scene, layout, &key, "support", name)?;
            fixed[layout.fields[f].offset + v] = true;
        }
    }
    // ψ is determined up to a constant where no clamped part fixes it
    // (b(U, 1) = 0): pin one boundary value (docs/shell-benchmarks.md).
    if let Some(psi) = layout.psi() {
        let f = &layout.fields[psi];
        if !fixed[f.offset..f.offset + f.len].iter().any(|x| *x) {
            let v = mesh
                .boundary_vertex_mask(None)
                .iter()
                .position(|b| *b)
                .unwrap_or(0);
            fixed[f.offset + v] = true;
        }
    }
    Ok(fixed)
}

/// r·e_n = θ^1 a_1·e_n + θ^2 a_2·e_n = 0 on a symmetry plane, at every
/// boundary node of the part: where a_β' lies in the plane (a_β'·e_n = 0) it
/// is θ^β = 0 for the other β; a chart whose two tangents both leave the
/// plane there cannot state it by elimination, and is refused.
#[allow(clippy::too_many_arguments)]
fn fix_tangent_symmetry(
    mesh: &Mesh,
    scene: &Scene,
    layout: &ShellLayout,
    chart: &Chart,
    tags: Option<&[i32]>,
    n: usize,
    part: &str,
    fixed: &mut [bool],
) -> Result<()> {
    for be in 0..2 {
        let Some(f) = layout.field_of(FieldRole::TangentRotation(be)) else {
            continue;
        };
        let field = layout.fields[f];
        let mask = Space::new(mesh, field.element).boundary_dof_mask(tags);
        for (d, on) in mask.into_iter().enumerate() {
            if !on {
                continue;
            }
            let x = dof_point(mesh, field.element, d);
            let p = chart.at(x);
            let along = |b: usize| p.a(b)[n].abs() <= 1e-12 * p.a(b).norm();
            let other = 1 - be;
            if along(be) {
                continue; // a_β in the plane: θ^β is free.
            }
            if !along(other) {
                return Err(scene.error("shell.boundary.normal", format!(
                        "part `{part}`: at ({:.6}, {:.6}) neither tangent a_1 nor a_2 of the {} chart lies in the symmetry plane (normal e{}), so r·e{} = 0 is no condition on one rotation component",
                        x[0], x[1], chart.kind(), n + 1, n + 1
                    )));
            }
            fixed[field.offset + d] = true;
        }
    }
    Ok(())
}

/// The point of a vertex or edge-midpoint dof (boundary dofs of P1, P2).
fn dof_point(mesh: &Mesh, element: Element, d: usize) -> [f64; 2] {
    let nv = mesh.n_vertices();
    if d < nv || !matches!(element, Element::P2 | Element::P2Bubble) {
        mesh.vertices[d.min(nv - 1)]
    } else {
        let [a, b] = mesh.edges[d - nv];
        let (p, q) = (mesh.vertices[a], mesh.vertices[b]);
        [0.5 * (p[0] + q[0]), 0.5 * (p[1] + q[1])]
    }
}

impl<'m> NaghdiSystem<'m> {
    /// Checks the chart on the mesh, numbers the fixed dofs, and checks
    /// the obstacle: the clamped boundary must not lie below the plane.
    pub fn setup(mesh: &'m Mesh, scene: &Scene) -> Result<Self> {
        let shell: &ShellSpec = scene.shell.as_ref().expect("validated: naghdi has [shell]");
        let chart = shell.chart.clone();
        check_chart_regular(mesh, scene, &chart)?;
        let material = Material::of(shell);
        let kind = match scene.element {
            ElementPair::P2bPsri => ShellElementKind::P2bPsri,
            ElementPair::P2bMitc => ShellElementKind::P2bMitc,
            _ => ShellElementKind::P1bP0,
        };
        let mut layout = ShellLayout::for_element(mesh, kind);
        match scene.obstacle.as_ref().and_then(|o| o.multiplier) {
            Some(ContactMultiplier::P0) => layout = layout.with_multiplier(Element::P0),
            Some(ContactMultiplier::P1) => layout = layout.with_multiplier(Element::P1),
            None => {}
        }
        let conditions = resolved_conditions(mesh, scene, shell)?;
        if let Some(x) = scene.output.probe {
            if PointLocator::new(mesh).locate(x).is_none() {
                return Err(scene.error(
                    "output.probe",
                    format!("the point ({}, {}) lies outside the mesh", x[0], x[1]),
                ));
            }
        }
        let mut fixed = fixed_mask(mesh, scene, &layout, &chart, &conditions)?;
        check_translations_fixed(scene, &layout, &fixed)?;
        let plate_reduction =
            kind == ShellElementKind::P1bP0 && matches!(chart, Chart::Plate { .. });
        if plate_reduction {
            for f in [
                FieldRole::CartesianRotation(2),
                FieldRole::TangencyMultiplier,
            ] {
                let field = layout.fields[layout.field_of(f).expect("thesis layout")];
                fixed[field.offset..field.offset + field.len].fill(true);
            }
        }
        let numbering = DofNumbering::from_fixed_mask(&fixed);
        let ties = oblique_symmetry_ties(mesh, scene, &layout, &chart, &conditions, &numbering)?;
        let clamped_tags: Vec<Option<Vec<i32>>> = conditions
            .iter()
            .filter(|(_, b)| b.condition == BoundaryCondition::Clamped)
            .map(|(t, _)| t.clone())
            .collect();
        let load = scene.load.as_ref();
        let surface_load = SurfaceLoad {
            force: load
                .and_then(|l| l.f.clone())
                .unwrap_or_else(|| std::array::from_fn(|_| Expression::constant(0.0))),
            pressure: load.and_then(|l| l.pressure.clone()),
        };
        // Where assembly evaluates the body force and the P1 constraint the
        // obstacle: Radon's 7 points (the PSRI passes' lower-degree rules
        // evaluate no data); the estimator's rule; the origin, where the
        // `gap_origin` probe evaluates the obstacle.
        let estimator_rule = TriangleRule::exact_for(crate::models::estimator::ESTIMATOR_RULE);
        let locator = PointLocator::new(mesh);
        let mut rule_points: Vec<[f64; 2]> =
            quadrature_points(mesh, &TriangleRule::exact_for(5)).collect();
        rule_points.extend(quadrature_points(mesh, &estimator_rule));
        if locator.locate([0.0, 0.0]).is_some() {
            rule_points.push([0.0, 0.0]);
        }
        let keyed = surface_load
            .force
            .iter()
            .enumerate()
            .map(|(c, f)| (format!("load.f[{c}]"), f))
            .chain(
                surface_load
                    .pressure
                    .iter()
                    .map(|p| ("load.pressure".to_string(), p)),
            );
        for (key, f) in keyed {
            f.check_finite_at(&key, rule_points.iter().copied())
                .map_err(|reason| Error::Scene {
                    file: scene.source.clone(),
                    field: key.clone(),
                    reason,
                })?;
        }
        let mut point_loads = Vec::new();
        for (k, point) in load.map_or(&[][..], |l| &l.point[..]).iter().enumerate() {
            let (t, l) = locator.locate(point.at).ok_or_else(|| {
                scene.error(
                    &format!("load.point[{k}].at"),
                    format!(
                        "({}, {}) lies outside the meshed domain ω",
                        point.at[0], point.at[1]
                    ),
                )
            })?;
            point_loads.push((t, l, point.force));
        }
        let mut edge_loads = Vec::new();
        for (e, edge) in load.map_or(&[][..], |l| &l.edge[..]).iter().enumerate() {
            let tags = named_boundary_tags(
                mesh,
                scene,
                "load.edge.part",
                Some(std::slice::from_ref(&edge.part)),
            )?
            .expect("one name given");
            let edge_points: Vec<[f64; 2]> = edge_quadrature_points(mesh, tags[0]);
            for (i, v) in edge.traction.iter().chain(&edge.moment).enumerate() {
                let name = if i < 3 { "traction" } else { "moment" };
                let key = format!("load.edge[{e}].{name}[{}]", i % 3);
                v.check_finite_at(&key, edge_points.iter().copied())
                    .map_err(|reason| Error::Scene {
                        file: scene.source.clone(),
                        field: key.clone(),
                        reason,
                    })?;
            }
            edge_loads.push((tags[0], edge.traction.clone(), edge.moment.clone()));
        }
        let mut simulated = Vec::new();
        if !clamped_tags.is_empty() {
            simulated.push("clamping".to_string());
        }
        if conditions
            .iter()
            .any(|(_, b)| b.condition != BoundaryCondition::Clamped)
        {
            simulated.push("boundary-conditions".into());
        }
        if surface_load
            .force
            .iter()
            .any(|v| v.as_constant() != Some(0.0))
        {
            simulated.push("body-force".into());
        }
        if surface_load.pressure.is_some() {
            simulated.push("pressure".into());
        }
        if !point_loads.is_empty() {
            simulated.push("point-loads".into());
        }
        if !edge_loads.is_empty() {
            simulated.push("edge-loads".into());
        }
        simulated.push(match (kind, plate_reduction) {
            (ShellElementKind::P2bPsri, _) => "tangent-rotations,reduced-integration".into(),
            (ShellElementKind::P2bMitc, _) => "tangent-rotations,tied-strains".into(),
            (_, true) => "tangency-eliminated".into(),
            (_, false) => "tangency-multiplier".into(),
        });
        let (height, phi, phi_positive_vertices) = match &scene.obstacle {
            None => (None, None, 0),
            Some(obstacle) => {
                simulated.push("contact".into());
                let height = obstacle
                    .height
                    .clone()
                    .unwrap_or_else(|| Expression::constant(0.0));
                // h is read below the midsurface point φ(x) (docs/formulation.md §2.1).
                let below = |x: [f64; 2]| {
                    let p = chart.at(x).phi;
                    [p.x, p.y]
                };
                height
                    .check_finite_at(
                        "obstacle.height",
                        mesh.vertices.iter().chain(&rule_points).map(|&x| below(x)),
                    )
                    .map_err(|reason| Error::Scene {
                        file: scene.source.clone(),
                        field: "obstacle.height".into(),
                        reason,
                    })?;
                let phi: Vec<f64> = obstacle_at_vertices(mesh, &chart, &material)
                    .into_iter()
                    .zip(&mesh.vertices)
                    .map(|(p, &x)| p + height.eval(below(x)))
                    .collect();
                // Where a part's fixed dofs pin the constraint value to 0, the
                // obstacle must admit 0 there: checked on every part, whatever
                // its condition, before anything is solved.
                // Φ where pinned; elsewhere min(Φ, 0), which any value ≥ 0 admits.
                let pinned = constraint_pinned_vertices(mesh, &layout, &chart, &fixed);
                let lower: Vec<f64> = phi
                    .iter()
                    .zip(&pinned)
                    .map(|(&p, &pin)| if pin { p } else { p.min(0.0) })
                    .collect();
                for (tags, b) in &conditions {
                    check_obstacle_against_boundary_values(
                        mesh,
                        scene,
                        (&lower, None),
                        &BoundaryValues::Zero,
                        tags.as_deref(),
                        &format!("{} part `{}`", b.condition.name(), b.part),
                    )?;
                }
                let positive = phi.iter().filter(|p| **p > 0.0).count();
                (Some(height), Some(phi), positive)
            }
        };
        Ok(NaghdiSystem {
            mesh,
            chart,
            material,
            rho: match kind {
                ShellElementKind::P1bP0 => shell.rho.expect("validated: p1b-p0 has rho"),
                ShellElementKind::P2bPsri | ShellElementKind::P2bMitc => 0.0,
            },
            layout,
            numbering,
            plate_reduction,
            surface_load,
            edge_loads,
            point_loads,
            height,
            phi,
            phi_positive_vertices,
            tangency_scale: Cell::new(1.0),
            simulated,
            element: scene.element,
            probe: scene.output.probe,
            ties,
        })
    }

    /// The full coefficient vector (all blocks, fixed dofs = 0, ψ unscaled).
    pub fn full_coefficients(&self, x: &[f64]) -> Vec<f64> {
        let free = self.ties.as_ref().map(|t| t.expand(x));
        let x = free.as_deref().unwrap_or(x);
        let mut full = self.numbering.extend(x, &vec![0.0; self.layout.n_total()]);
        if let Some(psi) = self.layout.psi() {
            let sigma = self.tangency_scale.get();
            let f = &self.layout.fields[psi];
            full[f.offset..f.offset + f.len]
                .iter_mut()
                .for_each(|v| *v *= sigma);
        }
        full
    }

    /// The `/dofs` vectors of a result: u and the rotation unknowns (r or θ)
    /// as component blocks in a row, ψ; each names the layout's fields it holds.
    fn dof_groups(&self) -> Vec<(&'static str, Vec<usize>)> {
        match self.layout.kind {
            ShellElementKind::P1bP0 => {
                vec![("u", vec![0, 1, 2]), ("r", vec![3, 4, 5]), ("psi", vec![6])]
            }
            ShellElementKind::P2bPsri | ShellElementKind::P2bMitc => {
                vec![("u", vec![0, 1, 2]), ("theta", vec![3, 4])]
            }
        }
    }

    /// The weights of the fields in (u − ε/2 r)·e3 at a point of the chart.
    fn constraint_weights(&self, x: [f64; 2]) -> Vec<(usize, f64)> {
        let half_eps = 0.5 * self.material.thickness;
        let p = self.chart.at(x);
        self.layout
            .fields
            .iter()
            .enumerate()
            .filter_map(|(f, field)| {
                constraint_factor(field.role, Some(&p), half_eps).map(|w| (f, w))
            })
            .collect()
    }

    /// The vertex values of the constraint function (u − ε/2 r)·e3.
    fn constraint_at_vertices(&self, full: &[f64]) -> Vec<f64> {
        (0..self.layout.n_vertices)
            .map(|v| {
                self.constraint_weights(self.mesh.vertices[v])
                    .into_iter()
                    .map(|(f, w)| w * self.layout.component(full, f)[v])
                    .sum()
            })
            .collect()
    }

    /// The Cartesian rotation r at the vertices, [Nv, 3].
    fn rotation_at_vertices(&self, full: &[f64]) -> Vec<f64> {
        let mut out = Vec::with_capacity(3 * self.layout.n_vertices);
        for v in 0..self.layout.n_vertices {
            let p = self.chart.at(self.mesh.vertices[v]);
            let mut r = Vector3::zeros();
            for (f, field) in self.layout.fields.iter().enumerate() {
                let value = self.layout.component(full, f)[v];
                match field.role {
                    FieldRole::CartesianRotation(c) => r[c] += value,
                    FieldRole::TangentRotation(be) => r += p.a(be) * value,
                    _ => {}
                }
            }
            out.extend(r.iter());
        }
        out
    }
}

impl ModelSystem for NaghdiSystem<'_> {
    fn assemble(&self) -> Result<ContactProblem> {
        let (a, mut f_full) = assemble_shell_layout(
            self.mesh,
            &self.layout,
            &self.chart,
            &self.material,
            self.rho,
            &self.surface_load,
            &self.numbering,
        );
        for (tag, traction, moment) in &self.edge_loads {
            add_edge_load(
                self.mesh,
                &self.layout,
                &self.chart,
                *tag,
                traction,
                moment,
                &mut f_full,
            );
        }
        for &(t, l, force) in &self.point_loads {
            add_point_load(self.mesh, &self.layout, t, l, force, &mut f_full);
        }
        let mut problem = restrict_shell(&self.layout, a, &f_full, &self.numbering);
        if let Some(ties) = &self.ties {
            tie_unknowns(&mut problem, ties);
        }
        if problem.n_primal < problem.n() {
            // ψ present: balance its rows with K's (needed for large ρ).
            let sigma = balanced_tangency_scale(&problem);
            scale_tangency_multiplier(&mut problem, sigma);
            self.tangency_scale.set(sigma);
        }
        if let (Some(phi), Some(height)) = (&self.phi, &self.height) {
            // P0 exists for the thesis' layout only (scene validation).
            problem.constraint = Some(match self.layout.multiplier {
                Element::P0 => plane_constraint(self.mesh, &self.material, phi, &self.numbering),
                _ => nodal_plane_constraint(
                    self.mesh,
                    &self.layout,
                    &self.chart,
                    &self.material,
                    height,
                    &self.numbering,
                ),
            });
            if let (Some(ties), Some(c)) = (&self.ties, problem.constraint.as_mut()) {
                c.matrix = ties.columns(&c.matrix);
            }
        }
        Ok(problem)
    }

    /// The gap at the origin |((u − ε/2 r)·e3)(0,0) − Φ_h(0,0)| (thesis
    /// Table 5.5), when the origin lies in ω and the scene has an obstacle
    /// (Φ_h: the P1 interpolant with P0 multipliers, Φ itself with P1).
    fn probes(&self) -> Vec<Probe> {
        let (Some(phi), Some(height)) = (&self.phi, &self.height) else {
            return Vec::new();
        };
        let Some((t, l)) = PointLocator::new(self.mesh).locate([0.0, 0.0]) else {
            return Vec::new();
        };
        let mut terms: Vec<(usize, f64)> = Vec::new();
        for (f, weight) in self.constraint_weights([0.0, 0.0]) {
            let field = self.layout.fields[f];
            let basis = field.element.basis(l);
            let (dofs, n) = Space::new(self.mesh, field.element).element_dofs(t);
            for k in 0..n {
                if let Some(i) = self.numbering.free_index(field.offset + dofs[k]) {
                    match &self.ties {
                        Some(ties) => terms.extend(
                            ties.row(i)
                                .into_iter()
                                .map(|(j, t)| (j, t * weight * basis.values[k])),
                        ),
                        None => terms.push((i, weight * basis.values[k])),
                    }
                }
            }
        }
        let tri = self.mesh.triangles[t];
        let phi0: f64 = match self.layout.multiplier {
            Element::P0 => (0..3).map(|k| l[k] * phi[tri[k]]).sum(),
            _ => {
                let origin = self.chart.at([0.0, 0.0]);
                obstacle_function(&origin, self.material.thickness)
                    + height.eval([origin.phi.x, origin.phi.y])
            }
        };
        vec![Probe {
            name: "gap_origin".into(),
            evaluate: Box::new(move |x: &[f64], _| {
                let value: f64 = terms.iter().map(|(i, w)| w * x[*i]).sum();
                (value - phi0).abs()
            }),
        }]
    }

    fn results(
        &self,
        problem: &ContactProblem,
        report: &SolveReport,
        threads: usize,
    ) -> ResultData {
        let full = self.full_coefficients(&report.x);
        let layout = &self.layout;
        let nv = layout.n_vertices;
        let mut data = ResultData {
            // The midsurface at the vertices: the result shows the shell in 3D.
            surface: Some(
                self.mesh
                    .vertices
                    .iter()
                    .map(|&x| {
                        let phi = self.chart.at(x).phi;
                        [phi.x, phi.y, phi.z]
                    })
                    .collect(),
            ),
            write_edges: layout
                .fields
                .iter()
                .any(|f| matches!(f.element, Element::P2 | Element::P2Bubble)),
            ..Default::default()
        };
        let displacement: Vec<usize> = (0..3)
            .filter_map(|c| layout.field_of(FieldRole::Displacement(c)))
            .collect();
        let mut u = Vec::with_capacity(3 * nv);
        for v in 0..nv {
            u.extend(displacement.iter().map(|&f| layout.component(&full, f)[v]));
        }
        data.fields.push(Field {
            name: "u".into(),
            values: u,
            components: 3,
            location: Location::Vertex,
        });
        data.fields.push(Field {
            name: "r".into(),
            values: self.rotation_at_vertices(&full),
            components: 3,
            location: Location::Vertex,
        });
        for (name, fields) in self.dof_groups() {
            let dofs: Vec<f64> = fields
                .iter()
                .flat_map(|&f| layout.component(&full, f).iter().copied())
                .collect();
            data.dofs.push((name.into(), dofs));
            let element = layout.fields[fields[0]].element;
            data.dof_spaces
                .push((name.into(), crate::output::space_tag(element, fields.len())));
        }
        if let Some(psi) = layout.psi() {
            let psi = layout.component(&full, psi);
            data.fields.push(vertex_field("psi", psi[..nv].to_vec()));
        }
        let constraint = self.constraint_at_vertices(&full);
        let u3 = &layout.component(&full, displacement[2])[..nv];
        let (u3_min, u3_max) = min_max(u3);
        let mut attrs: Vec<(&str, AttrValue)> = vec![
            ("model", AttrValue::Str("naghdi".into())),
            ("element", AttrValue::Str(self.element.name().into())),
            ("chart", AttrValue::Str(self.chart.kind().into())),
            ("simulated", AttrValue::Str(self.simulated.join(","))),
            ("n_dofs", AttrValue::I64(self.n_dofs() as i64)),
            ("n_free_dofs", AttrValue::I64(problem.n() as i64)),
            ("h", AttrValue::F64(self.mesh.h_max())),
        ];
        if layout.kind == ShellElementKind::P1bP0 {
            attrs.push(("rho", AttrValue::F64(self.rho)));
            attrs.push(("tangency_scale", AttrValue::F64(self.tangency_scale.get())));
        }
        let (strain_energy, external_work) = problem.energies(&report.x, threads);
        attrs.push(("strain_energy", AttrValue::F64(strain_energy)));
        attrs.push(("external_work", AttrValue::F64(external_work)));
        attrs.push(("u3_min", AttrValue::F64(u3_min)));
        attrs.push(("u3_max", AttrValue::F64(u3_max)));
        for (c, (lo_name, hi_name)) in [("u1_min", "u1_max"), ("u2_min", "u2_max")]
            .into_iter()
            .enumerate()
        {
            let (lo, hi) = min_max(&layout.component(&full, displacement[c])[..nv]);
            attrs.push((lo_name, AttrValue::F64(lo)));
            attrs.push((hi_name, AttrValue::F64(hi)));
        }
        if let Some(x) = self.probe {
            if let Some((t, l)) = PointLocator::new(self.mesh).locate(x) {
                for (c, name) in ["probe_u1", "probe_u2", "probe_u3"].into_iter().enumerate() {
                    let field = layout.fields[displacement[c]];
                    let space = Space::new(self.mesh, field.element);
                    let value = space.evaluate(layout.component(&full, displacement[c]), t, l);
                    attrs.push((name, AttrValue::F64(value)));
                }
            }
        }
        if let (Some(phi), Some(c)) = (&self.phi, &problem.constraint) {
            data.fields.push(vertex_field("phi", phi.clone()));
            data.fields
                .push(vertex_field("constraint", constraint.clone()));
            let contact = report.contact();
            let active = || {
                report
                    .lambda
                    .iter()
                    .zip(&c.weights)
                    .zip(&contact)
                    .filter_map(|(lw, &in_contact)| in_contact.then_some(lw))
            };
            // Rust's empty f64 sum is −0.0; adding +0.0 records no contact as 0.
            let area: f64 = active().map(|(_, w)| w).sum::<f64>() + 0.0;
            // ∫λ: the total force the plane exerts (C's row for u3 ≡ 1 is w).
            let force: f64 = active().map(|(l, w)| l * w).sum::<f64>() + 0.0;
            contact_fields(
                &mut data,
                report.lambda.clone(),
                c.mean_gaps(&report.x),
                &contact,
                layout.multiplier,
            );
            attrs.push(("contact_area", AttrValue::F64(area)));
            attrs.push(("contact_force", AttrValue::F64(force)));
            attrs.push((
                "phi_positive_vertices",
                AttrValue::I64(self.phi_positive_vertices as i64),
            ));
            if let Some(g) = self.probes().first() {
                attrs.push((
                    "gap_origin",
                    AttrValue::F64((g.evaluate)(&report.x, &report.lambda)),
                ));
            }
        } else {
            data.fields
                .push(vertex_field("constraint", constraint.clone()));
        }
        data.root_attrs = attrs.into_iter().map(|(k, v)| (k.to_string(), v)).collect();
        data
    }

    fn primal_from_dofs(&self, dofs: &[(String, Vec<f64>)]) -> Result<Vec<f64>> {
        let layout = &self.layout;
        let mut full = vec![0.0; layout.n_total()];
        for (name, fields) in self.dof_groups() {
            let len: usize = fields.iter().map(|&f| layout.fields[f].len).sum();
            let mut values = named_dofs(dofs, name, len)?;
            for &f in &fields {
                let field = layout.fields[f];
                let (block, rest) = values.split_at(field.len);
                full[field.offset..field.offset + field.len].copy_from_slice(block);
                values = rest;
            }
        }
        // ψ' = ψ/σ in the algebraic problem (set by `assemble`).
        if let Some(psi) = layout.psi() {
            let sigma = self.tangency_scale.get();
            let f = &layout.fields[psi];
            full[f.offset..f.offset + f.len]
                .iter_mut()
                .for_each(|v| *v /= sigma);
        }
        let free = self.numbering.restrict(&full);
        Ok(match &self.ties {
            Some(ties) => ties.independent_values(&free),
            None => free,
        })
    }

    /// The residual estimator of docs/formulation.md §8 (`naghdi::estimator`).
    fn estimator(&self, _problem: &ContactProblem, report: &SolveReport) -> Option<Vec<f64>> {
        let full = self.full_coefficients(&report.x);
        let obstacle = self.height.as_ref().map(|height| {
            let eps = self.material.thickness;
            move |x: [f64; 2]| {
                let p = self.chart.at(x);
                obstacle_function(&p, eps) + height.eval([p.phi.x, p.phi.y])
            }
        });
        let contact = obstacle.as_ref().map(|obstacle| ShellContact {
            multiplier: (
                Space::new(self.mesh, self.layout.multiplier),
                &report.lambda[..],
            ),
            obstacle,
        });
        let state = ShellState {
            mesh: self.mesh,
            layout: &self.layout,
            full: &full,
            chart: &self.chart,
            material: &self.material,
            rho: self.rho,
            load: &self.surface_load,
            tangent_tests: self.layout.psi().is_none() || self.plate_reduction,
            contact,
        };
        Some(shell_indicators(&state).eta())
    }

    /// The constraint plot (thesis Fig. 5.6) is the shell's own.
    fn plot(&self, kind: PlotKind, path: &Path, title: &str, figure: &FigureData) -> Result<()> {
        match (kind, figure.field("constraint"), figure.field("phi")) {
            (PlotKind::Constraint, Some(w), Some(phi)) => {
                plot_constraint(path, self.mesh, &w.values, &phi.values, title)
            }
            _ => plot_result_field(self.mesh, kind, path, title, figure),
        }
    }

    fn mesh(&self) -> &Mesh {
        self.mesh
    }

    /// The dof count: U (and ψ) with boundary dofs, plus λ with contact.
    fn n_dofs(&self) -> usize {
        let contact = if self.phi.is_some() {
            self.layout.n_multipliers()
        } else {
            0
        };
        self.layout.n_total() + contact
    }
}

fn min_max(v: &[f64]) -> (f64, f64) {
    v.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
            (lo.min(*x), hi.max(*x))
        })
}

/// The layout's field called `name` (`u3`, `theta1`, …); the error names
/// `key`, the `context` and the fields there are.
fn field_named(
    scene: &Scene,
    layout: &ShellLayout,
    key: &str,
    context: &str,
    name: &str,
) -> Result<usize> {
    layout.field_named(name).ok_or_else(|| {
        scene.error(
            key,
            format!(
                "{context}: `{name}` is no field of element {}: {}",
                scene.element.name(),
                layout
                    .fields
                    .iter()
                    .map(|f| f.name)
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )
    })
}

/// A rigid translation along e_c is a zero-energy motion unless some dof of
/// u_c is fixed: then K is singular whatever the loads (the plane's contact
/// acts along e3 only and one-sidedly). Refused before assembling, naming
/// the free directions. (Rigid rotations are not detected here; a
/// factorisation that fails on them reports the singular pivot.)
fn check_translations_fixed(scene: &Scene, layout: &ShellLayout, fixed: &[bool]) -> Result<()> {
    let free: Vec<&str> = (0..3)
        .filter(|&c| {
            let f = layout.fields[layout.field_of(FieldRole::Displacement(c)).expect("u")];
            !fixed[f.offset..f.offset + f.len].iter().any(|&b| b)
        })
        .map(|c| ["u1 (e1)", "u2 (e2)", "u3 (e3)"][c])
        .collect();
    if free.is_empty() {
        return Ok(());
    }
    Err(scene.error("shell.clamped", format!(
            "the boundary conditions fix no dof of {}: the shell can move rigidly along those directions (a floating shell has no unique equilibrium); clamp a part (shell.clamped) or give [[shell.boundary]] conditions that hold each direction somewhere",
            free.join(", ")
        )))
}

/// The chart must be regular (|a1×a2| > 0) at every vertex and quadrature
/// point of the mesh.
fn check_chart_regular(mesh: &Mesh, scene: &Scene, chart: &Chart) -> Result<()> {
    let rule = TriangleRule::exact_for(5);
    let points = mesh
        .vertices
        .iter()
        .copied()
        .chain((0..mesh.n_triangles()).flat_map(|t| {
            let g = TriangleGeometry::new(mesh, t);
            quad_points(&g, t, &rule).map(|q| q.x).collect::<Vec<_>>()
        }));
    chart.check_regular(points).map_err(|(x, sqrt_a)| {
        scene.error(
            "shell.chart",
            format!(
                "the {} chart is singular on the mesh at ({:.6}, {:.6}): |a1×a2| = {sqrt_a:e}",
                chart.kind(),
                x[0],
                x[1]
            ),
        )
    })
}

/// The shell's constraint w = (u − ε/2 r)·e3 against Φ_h (thesis Fig. 5.6):
/// a colour map of w − Φ_h (zero on the contact zone) at `path`, and the
/// profiles of w and Φ_h along the axes y = 0 and x = 0 (through the
/// vertices that lie on them) at `<stem>-profiles.<ext>`.
fn plot_constraint(path: &Path, mesh: &Mesh, w: &[f64], phi: &[f64], title: &str) -> Result<()> {
    let gap: Vec<f64> = w.iter().zip(phi).map(|(a, b)| a - b).collect();
    plot::plot_vertex_field(path, mesh, &gap, &format!("{title}: (u − ε/2 r)·e3 − Φ_h"))?;
    let diameter = mesh.h_max().max(
        mesh.vertices
            .iter()
            .fold(0.0f64, |m, v| m.max(v[0].abs()).max(v[1].abs())),
    );
    let mut series = Vec::new();
    for (axis, along, across) in [("y = 0", 0, 1), ("x = 0", 1, 0)] {
        let on_axis: Vec<usize> = (0..mesh.n_vertices())
            .filter(|&v| mesh.vertices[v][across].abs() <= 1e-9 * diameter)
            .collect();
        if on_axis.len() < 3 {
            continue;
        }
        let line = |f: &[f64]| -> Vec<(f64, f64)> {
            on_axis
                .iter()
                .map(|&v| (mesh.vertices[v][along], f[v]))
                .collect()
        };
        series.push((format!("(u − ε/2 r)·e3 on {axis}"), line(w)));
        series.push((format!("Φ_h on {axis}"), line(phi)));
    }
    if series.is_empty() {
        return Ok(());
    }
    let stem = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("constraint");
    let ext = path.extension().and_then(|s| s.to_str()).unwrap_or("png");
    let profiles = path.with_file_name(format!("{stem}-profiles.{ext}"));
    plot::plot_lines(
        &profiles,
        &series,
        "x or y",
        "z",
        &format!("{title}: profiles"),
    )
}

/// The P2 prolongations between shell systems set up on the levels of
/// `hierarchy` (coarsest first): each system's fields by their offsets and
/// free-dof numbering (`multigrid::P2FieldLevels`).
pub fn field_prolongations(
    hierarchy: &crate::mesh::Hierarchy,
    systems: &[&NaghdiSystem],
) -> Result<crate::multigrid::P2FieldLevels> {
    let offsets: Vec<Vec<usize>> = systems
        .iter()
        .map(|s| s.layout.fields.iter().map(|f| f.offset).collect())
        .collect();
    let levels: Vec<crate::multigrid::FieldLevel> = systems
        .iter()
        .zip(&offsets)
        .map(|(s, offsets)| crate::multigrid::FieldLevel {
            offsets,
            numbering: &s.numbering,
        })
        .collect();
    crate::multigrid::P2FieldLevels::new(hierarchy, &levels)
}
