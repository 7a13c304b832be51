//! The Naghdi shell as a model of the pipeline (SPEC §2, thesis Problem 9):
//! [`NaghdiSystem::setup`] checks the chart and the obstacle on the mesh and
//! numbers the clamped dofs; `assemble` builds exactly the effects the scene
//! declares (body force, edge loads, tangency, contact); `results` turns the
//! solver's answer into the fields of SPEC §5.
//!
//! Two reductions keep the algebra to what the scene needs:
//! * no obstacle: no λ block at all, the pipeline does one linear solve;
//! * a flat chart (`plate`): a3 = e3 everywhere, so the tangency r·a3 = 0 is
//!   r3 = 0 and is imposed by eliminating r3; ψ and the ρ term (which vanishes
//!   on r3 = 0) disappear and K is symmetric positive definite (Cholesky).

use super::forms::{
    add_edge_load, assemble_shell_full, balanced_tangency_scale, clamped_numbering,
    obstacle_at_vertices, plane_constraint, restrict_shell, scale_tangency_multiplier, ShellLayout,
    N_COMPONENTS, PSI,
};
use super::geometry::{Chart, Material};
use crate::assembly::{quad_points, DofNumbering};
use crate::error::{Error, Result};
use crate::mesh::{Mesh, PointLocator};
use crate::models::{contact_fields, named_boundary_tags, vertex_field, ModelSystem};
use crate::output::{AttrValue, Field, Location, ResultData};
use crate::quadrature::TriangleRule;
use crate::scene::{Scene, ShellSpec};
use crate::solvers::uzawa::Probe;
use crate::solvers::{ContactProblem, SolveReport};
use crate::space::{Element, Space, TriangleGeometry};
use std::cell::Cell;

/// Components of r (rotation) in the block layout.
const R3: usize = 5;

pub struct NaghdiSystem<'m> {
    pub mesh: &'m Mesh,
    pub chart: Chart,
    pub material: Material,
    pub rho: f64,
    pub layout: ShellLayout,
    pub numbering: DofNumbering,
    /// Flat chart: r3 eliminated, no ψ (see the module documentation).
    pub plate_reduction: bool,
    /// Φ_h at the vertices, with the plane's level added (obstacle scenes).
    pub phi: Option<Vec<f64>>,
    /// Vertices where Φ_h > 0 (the unloaded shell is below the plane).
    pub phi_positive_vertices: usize,
    /// The scale σ of ψ' = ψ/σ in the algebraic problem (1 without ψ);
    /// set by `assemble`.
    tangency_scale: Cell<f64>,
    /// Which effects the scene asked for (recorded in the result file).
    pub simulated: Vec<String>,
}

impl<'m> NaghdiSystem<'m> {
    /// Checks the chart on the mesh, numbers the clamped dofs, and checks
    /// the obstacle: the clamped boundary must not lie below the plane.
    pub fn setup(mesh: &'m Mesh, scene: &Scene) -> Result<Self> {
        let shell: &ShellSpec = scene.shell.as_ref().expect("validated: naghdi has [shell]");
        let chart = shell.chart;
        check_chart_regular(mesh, scene, &chart)?;
        let material = shell.material();
        let clamped = named_boundary_tags(mesh, scene, "shell.clamped", shell.clamped.as_deref())?;
        let plate_reduction = matches!(chart, Chart::Plate { .. });
        let layout = ShellLayout::new(mesh);
        let mut numbering = clamped_numbering(mesh, clamped.as_deref());
        if plate_reduction {
            let mut fixed: Vec<bool> = numbering.free_index.iter().map(Option::is_none).collect();
            for c in [R3, PSI] {
                for d in 0..layout.n_scalar() {
                    fixed[layout.index(c, d)] = true;
                }
            }
            numbering = DofNumbering::from_fixed_mask(&fixed);
        }
        let edges = scene.load.as_ref().map_or(0, |l| l.edge.len());
        let mut simulated = vec!["clamping".to_string()];
        if scene
            .load
            .as_ref()
            .and_then(|l| l.f)
            .is_some_and(|f| f.iter().any(|v| *v != 0.0))
        {
            simulated.push("body-force".into());
        }
        if edges > 0 {
            simulated.push("edge-loads".into());
        }
        simulated.push(if plate_reduction {
            "tangency-eliminated".into()
        } else {
            "tangency-multiplier".into()
        });
        let (phi, phi_positive_vertices) = match &scene.obstacle {
            None => (None, 0),
            Some(obstacle) => {
                simulated.push("contact".into());
                let level = obstacle.level();
                let phi: Vec<f64> = obstacle_at_vertices(mesh, &chart, &material)
                    .into_iter()
                    .map(|p| p + level)
                    .collect();
                check_feasible(mesh, scene, &phi, clamped.as_deref())?;
                let positive = phi.iter().filter(|p| **p > 0.0).count();
                (Some(phi), positive)
            }
        };
        Ok(NaghdiSystem {
            mesh,
            chart,
            material,
            rho: shell.rho,
            layout,
            numbering,
            plate_reduction,
            phi,
            phi_positive_vertices,
            tangency_scale: Cell::new(1.0),
            simulated,
        })
    }

    /// The full coefficient vector (all 7 blocks, clamped dofs = 0, ψ unscaled).
    pub fn full_coefficients(&self, x: &[f64]) -> Vec<f64> {
        let mut full = self.numbering.extend(x, &vec![0.0; self.layout.n_total()]);
        let sigma = self.tangency_scale.get();
        let ns = self.layout.n_scalar();
        full[PSI * ns..].iter_mut().for_each(|v| *v *= sigma);
        full
    }

    /// The vertex values of the constraint function (u − ε/2 r)·e3.
    fn constraint_at_vertices(&self, full: &[f64]) -> Vec<f64> {
        let (u3, r3) = (
            self.layout.component(full, 2),
            self.layout.component(full, R3),
        );
        let half_eps = 0.5 * self.material.thickness;
        (0..self.layout.n_vertices)
            .map(|v| u3[v] - half_eps * r3[v])
            .collect()
    }
}

impl ModelSystem for NaghdiSystem<'_> {
    fn assemble(&self, scene: &Scene) -> Result<ContactProblem> {
        let load = scene.load.as_ref();
        let f = load.and_then(|l| l.f).unwrap_or([0.0; 3]);
        let (a_full, mut f_full) =
            assemble_shell_full(self.mesh, &self.chart, &self.material, self.rho, f);
        for edge in load.map_or(&[][..], |l| &l.edge[..]) {
            let tags = named_boundary_tags(
                self.mesh,
                scene,
                "load.edge.part",
                Some(std::slice::from_ref(&edge.part)),
            )?
            .expect("one name given");
            add_edge_load(
                self.mesh,
                &self.chart,
                tags[0],
                edge.traction,
                edge.moment,
                &mut f_full,
            );
        }
        let mut problem = restrict_shell(self.mesh, a_full, &f_full, &self.numbering);
        if problem.n_primal < problem.n() {
            // ψ present: balance its rows with K's (needed for large ρ).
            let sigma = balanced_tangency_scale(&problem);
            scale_tangency_multiplier(&mut problem, sigma);
            self.tangency_scale.set(sigma);
        }
        if let Some(phi) = &self.phi {
            problem.constraint = Some(plane_constraint(
                self.mesh,
                &self.material,
                phi,
                &self.numbering,
            ));
        }
        Ok(problem)
    }

    /// The gap at the origin |((u − ε/2 r)·e3)(0,0) − Φ_h(0,0)| (thesis
    /// Table 5.5), when the origin lies in ω and the scene has an obstacle.
    fn probes(&self) -> Vec<Probe> {
        let Some(phi) = &self.phi else {
            return Vec::new();
        };
        let Some((t, l)) = PointLocator::new(self.mesh).locate([0.0, 0.0]) else {
            return Vec::new();
        };
        // Coefficients of the P1⊕B3 basis at the origin, for u3 and r3, in the
        // free numbering; Φ_h is P1.
        let space = Space::new(self.mesh, Element::P1Bubble);
        let basis = Element::P1Bubble.basis(l);
        let (dofs, _) = space.element_dofs(t);
        let half_eps = 0.5 * self.material.thickness;
        let mut terms: Vec<(usize, f64)> = Vec::new();
        for k in 0..4 {
            for (c, factor) in [(2, 1.0), (R3, -half_eps)] {
                if let Some(i) = self.numbering.free_index[self.layout.index(c, dofs[k])] {
                    terms.push((i, factor * basis.values[k]));
                }
            }
        }
        let tri = self.mesh.triangles[t];
        let phi0: f64 = (0..3).map(|k| l[k] * phi[tri[k]]).sum();
        vec![Probe {
            name: "gap_origin".into(),
            evaluate: Box::new(move |x: &[f64], _| {
                let value: f64 = terms.iter().map(|(i, w)| w * x[*i]).sum();
                (value - phi0).abs()
            }),
        }]
    }

    fn results(&self, scene: &Scene, problem: &ContactProblem, report: &SolveReport) -> ResultData {
        let full = self.full_coefficients(&report.x);
        let nv = self.layout.n_vertices;
        let mut data = ResultData {
            scene_text: scene.text.clone(),
            ..Default::default()
        };
        // Vertex fields [Nv, 3] of u and r; /dofs/u, /dofs/r are the three
        // component blocks (Nv vertex values then Nt bubbles each) in a row.
        for (name, first) in [("u", 0), ("r", 3)] {
            let mut values = Vec::with_capacity(3 * nv);
            for v in 0..nv {
                for c in first..first + 3 {
                    values.push(self.layout.component(&full, c)[v]);
                }
            }
            data.fields.push(Field {
                name: name.into(),
                values,
                components: 3,
                location: Location::Vertex,
            });
            let dofs: Vec<f64> = (first..first + 3)
                .flat_map(|c| self.layout.component(&full, c).iter().copied())
                .collect();
            data.dofs.push((name.into(), dofs));
        }
        let psi = self.layout.component(&full, PSI);
        data.fields.push(vertex_field("psi", psi[..nv].to_vec()));
        data.dofs.push(("psi".into(), psi.to_vec()));
        let constraint = self.constraint_at_vertices(&full);
        let u3 = &self.layout.component(&full, 2)[..nv];
        let (u3_min, u3_max) = min_max(u3);
        let mut attrs: Vec<(&str, AttrValue)> = vec![
            ("model", AttrValue::Str("naghdi".into())),
            ("element", AttrValue::Str(scene.element.name().into())),
            ("chart", AttrValue::Str(self.chart.kind().into())),
            ("simulated", AttrValue::Str(self.simulated.join(","))),
            ("n_dofs", AttrValue::I64(self.n_dofs() as i64)),
            ("n_free_dofs", AttrValue::I64(problem.n() as i64)),
            ("h", AttrValue::F64(self.mesh.h_max())),
            ("rho", AttrValue::F64(self.rho)),
            ("tangency_scale", AttrValue::F64(self.tangency_scale.get())),
            ("u3_min", AttrValue::F64(u3_min)),
            ("u3_max", AttrValue::F64(u3_max)),
        ];
        for (name, c) in [("u1", 0), ("u2", 1)] {
            let (lo, hi) = min_max(&self.layout.component(&full, c)[..nv]);
            attrs.push((
                if name == "u1" { "u1_min" } else { "u2_min" },
                AttrValue::F64(lo),
            ));
            attrs.push((
                if name == "u1" { "u1_max" } else { "u2_max" },
                AttrValue::F64(hi),
            ));
        }
        if let (Some(phi), Some(c)) = (&self.phi, &problem.constraint) {
            data.fields.push(vertex_field("phi", phi.clone()));
            data.fields
                .push(vertex_field("constraint", constraint.clone()));
            let area: f64 = report
                .lambda
                .iter()
                .zip(&c.weights)
                .filter(|(l, _)| **l > 0.0)
                .map(|(_, w)| w)
                .sum();
            contact_fields(
                &mut data,
                report.lambda.clone(),
                c.mean_gaps(&report.x),
                Location::Cell,
            );
            attrs.push(("contact_area", AttrValue::F64(area)));
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

    /// The thesis count: U and ψ with boundary dofs, plus λ with contact.
    fn n_dofs(&self) -> usize {
        let contact = if self.phi.is_some() {
            self.layout.n_triangles
        } else {
            0
        };
        N_COMPONENTS * self.layout.n_scalar() + contact
    }
}

fn min_max(v: &[f64]) -> (f64, f64) {
    v.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
            (lo.min(*x), hi.max(*x))
        })
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
    chart
        .check_regular(points)
        .map_err(|(x, sqrt_a)| Error::Scene {
            file: scene.source.clone(),
            field: "shell.chart".into(),
            reason: format!(
                "the {} chart is singular on the mesh at ({:.6}, {:.6}): |a1×a2| = {sqrt_a:e}",
                chart.kind(),
                x[0],
                x[1]
            ),
        })
}

/// A clamped point has u = r = 0, so its constraint value is 0: where Φ_h > 0
/// at a clamped vertex the obstacle would need the clamped edge to
/// penetrate, and no admissible displacement exists. Detected before iterating.
fn check_feasible(mesh: &Mesh, scene: &Scene, phi: &[f64], clamped: Option<&[i32]>) -> Result<()> {
    let mask = mesh.boundary_vertex_mask(clamped);
    let scale = phi.iter().fold(0.0f64, |m, p| m.max(p.abs())).max(1.0);
    let worst = (0..mesh.n_vertices())
        .filter(|&v| mask[v])
        .max_by(|&a, &b| phi[a].total_cmp(&phi[b]));
    match worst {
        Some(v) if phi[v] > 1e-12 * scale => Err(Error::Scene {
            file: scene.source.clone(),
            field: "obstacle".into(),
            reason: format!(
                "infeasible: the clamped boundary at ({:.6}, {:.6}) lies {:.6e} below the obstacle (Φ_h > 0 there), so no admissible displacement exists (thesis (2.2) asks Φ ≤ 0)",
                mesh.vertices[v][0], mesh.vertices[v][1], phi[v]
            ),
        }),
        _ => Ok(()),
    }
}
