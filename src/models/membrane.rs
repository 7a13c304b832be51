//! The membrane obstacle problem (docs/formulation.md §1): find u ∈ H¹₀, u ≥ φ, minimising
//! ½∫|∇u|² − ∫g u; in mixed form (∇u, ∇v) − ⟨λ, v⟩ = (g, v), λ ≥ 0.
//!
//! Steps, as in deal.II's step-41: [`MembraneSystem::setup`] (spaces, Dirichlet
//! dofs) → [`MembraneSystem::assemble`] (K, F, C, g, Riesz weights) → a solver
//! from `solvers` → [`MembraneSystem::results`] (fields, errors).

use super::exact::RadialObstacle;
use super::{
    check_obstacle_below_fixed_boundary, contact_fields, named_boundary_tags, named_dofs,
    vertex_field, ExactErrors, ModelSystem,
};
use crate::assembly::{
    assemble_bilinear, assemble_linear, eliminate, integrate_per_triangle, laplace, lumped_mass,
    mass, DofNumbering,
};
use crate::error::{Error, Result};
use crate::linalg::MatrixKind;
use crate::mesh::Mesh;
use crate::output::{AttrValue, ResultData};
use crate::quadrature::TriangleRule;
use crate::scene::{ElementPair, ObstacleSpec, Scene};
use crate::solvers::{Constraint, ContactProblem, SolveReport};
use crate::space::{Element, Space};

pub struct MembraneSystem<'m> {
    pub mesh: &'m Mesh,
    pub pair: ElementPair,
    pub u_space: Space<'m>,
    pub lambda_space: Space<'m>,
    pub numbering: DofNumbering,
    /// The source term g of −Δu = g (`load.g`, default 0).
    pub load: f64,
    /// The obstacle u ≥ φ, when the scene has one.
    pub obstacle: Option<ObstacleSpec>,
    /// φ_h: the obstacle's P1 interpolant at the vertices (with an obstacle).
    pub phi: Option<Vec<f64>>,
    /// Which effects the scene asked for (recorded in the result file).
    pub simulated: Vec<String>,
}

impl<'m> MembraneSystem<'m> {
    /// Spaces and the Dirichlet dofs named by the scene.
    pub fn setup(mesh: &'m Mesh, scene: &Scene) -> Result<Self> {
        let (u_element, lambda_element) = match scene.element {
            ElementPair::P1bP0 => (Element::P1Bubble, Element::P0),
            ElementPair::P2P1 => (Element::P2, Element::P1),
            ElementPair::P2bPsri => unreachable!("validated: a shell element"),
        };
        let u_space = Space::new(mesh, u_element);
        let tags = named_boundary_tags(
            mesh,
            scene,
            "mesh.dirichlet",
            scene.mesh.dirichlet.as_deref(),
        )?;
        let fixed = u_space.boundary_dof_mask(tags.as_deref());
        if !fixed.iter().any(|&f| f) {
            return Err(Error::Scene {
                file: scene.source.clone(),
                field: "mesh.dirichlet".into(),
                reason: format!(
                    "no dof is fixed (the mesh {} has no boundary line there): with natural boundary conditions alone −Δu = g determines u only up to a constant, and the problem is singular",
                    mesh.source.display()
                ),
            });
        }
        let numbering = DofNumbering::from_fixed_mask(&fixed);
        // φ_h, the P1 interpolant of the obstacle at the vertices.
        let phi = scene
            .obstacle
            .as_ref()
            .map(|obstacle| Space::new(mesh, Element::P1).interpolate(|x| obstacle.value(x)));
        if let Some(phi) = &phi {
            // u = 0 on the Dirichlet parts: the obstacle must lie below 0 there.
            check_obstacle_below_fixed_boundary(
                mesh,
                scene,
                phi,
                tags.as_deref(),
                "Dirichlet boundary (u = 0)",
            )?;
        }
        if scene.output.errors {
            check_exact_solution_applies(mesh, scene, tags.is_none())?;
        }
        let mut simulated = vec!["load".to_string(), "dirichlet".to_string()];
        if scene.obstacle.is_some() {
            simulated.push("obstacle".into());
        }
        Ok(MembraneSystem {
            mesh,
            pair: scene.element,
            u_space,
            lambda_space: Space::new(mesh, lambda_element),
            numbering,
            load: scene.load.as_ref().and_then(|l| l.g).unwrap_or(0.0),
            obstacle: scene.obstacle.clone(),
            phi,
            simulated,
        })
    }

    /// Full coefficient vector of u (Dirichlet values included).
    pub fn u_coefficients(&self, report: &SolveReport) -> Vec<f64> {
        self.numbering
            .extend(&report.x, &vec![0.0; self.u_space.n_dofs()])
    }
}

/// `output.errors` measures against the exact radial solution: it applies
/// only to the unit disk (every boundary vertex at |x| = 1), u = 0 on all of
/// the boundary, a paraboloid obstacle and data for which the radial solution
/// exists. Anything else is refused, naming what differs.
fn check_exact_solution_applies(
    mesh: &Mesh,
    scene: &Scene,
    dirichlet_everywhere: bool,
) -> Result<()> {
    let refuse = |reason: String| {
        Err(Error::Scene {
            file: scene.source.clone(),
            field: "output.errors".into(),
            reason: format!("errors are measured against the exact solution on the unit disk (docs/formulation.md §1), but {reason}"),
        })
    };
    if !dirichlet_everywhere {
        return refuse("mesh.dirichlet names only some boundary parts".into());
    }
    let boundary = mesh.boundary_vertex_mask(None);
    let off_circle = (0..mesh.n_vertices())
        .filter(|&v| boundary[v])
        .map(|v| (v, mesh.vertices[v][0].hypot(mesh.vertices[v][1])))
        .find(|(_, r)| (r - 1.0).abs() > 1e-9);
    if let Some((v, r)) = off_circle {
        let [x, y] = mesh.vertices[v];
        return refuse(format!(
            "the mesh {} is not the unit disk: its boundary vertex ({x:.6}, {y:.6}) lies at radius {r:.6}",
            mesh.source.display()
        ));
    }
    let Some(obstacle) = &scene.obstacle else {
        return refuse("the scene has no obstacle".into());
    };
    let g = scene.load.as_ref().and_then(|l| l.g).unwrap_or(0.0);
    let curvature = obstacle.curvature.unwrap_or(0.0);
    if RadialObstacle::new(g, obstacle.level(), curvature).is_none() {
        return refuse(format!(
            "no radial solution exists for load.g = {g}, obstacle height {} and curvature {curvature} (it needs 4·curvature ≥ g)",
            obstacle.level()
        ));
    }
    Ok(())
}

impl ModelSystem for MembraneSystem<'_> {
    /// The algebraic problem: stiffness K, load F, and (only when the scene has
    /// an obstacle) the constraint C u ≥ g with its Riesz weights.
    fn assemble(&self) -> Result<ContactProblem> {
        // Degree 5 (Radon, 7 points) is exact for every integrand below:
        // ∇(P1⊕B3)·∇(P1⊕B3) has degree 4, P2·P1 and φ·P1 degree 3.
        let rule = TriangleRule::exact_for(5);
        let g = self.load;
        let u = &self.u_space;
        let k_full = assemble_bilinear(u, u, &rule, laplace);
        let fixed_values = vec![0.0; u.n_dofs()];
        let (k, shift) = eliminate(k_full, &self.numbering, &self.numbering, &fixed_values);
        let f_full = assemble_linear(u, &rule, |v, _| g * v.value);
        let rhs: Vec<f64> = self
            .numbering
            .restrict(&f_full)
            .iter()
            .zip(&shift)
            .map(|(a, b)| a + b)
            .collect();
        let constraint = match &self.obstacle {
            None => None,
            Some(obstacle) => {
                let lam = &self.lambda_space;
                let c_full = assemble_bilinear(lam, u, &rule, mass);
                let all_rows = DofNumbering::all_free(lam.n_dofs());
                let (c, c_shift) = eliminate(c_full, &all_rows, &self.numbering, &fixed_values);
                let (mut g_vec, weights) = match self.pair {
                    ElementPair::P1bP0 => {
                        // g_T = ∫_T φ_h with φ_h the P1 interpolant; w_T = |T|.
                        let phi = self.phi.as_ref().expect("set up with the obstacle");
                        let areas: Vec<f64> = (0..self.mesh.n_triangles())
                            .map(|t| self.mesh.area(t))
                            .collect();
                        let g_vec = self
                            .mesh
                            .triangles
                            .iter()
                            .zip(&areas)
                            .map(|(tri, a)| a * (phi[tri[0]] + phi[tri[1]] + phi[tri[2]]) / 3.0)
                            .collect();
                        (g_vec, areas)
                    }
                    ElementPair::P2P1 | ElementPair::P2bPsri => {
                        // g_i = ∫ φ μ_i; w_i = lumped P1 mass (docs/formulation.md §1: the Riesz map
                        // whose projection is a nodal max).
                        let g_vec =
                            assemble_linear(lam, &rule, |v, p| obstacle.value(p.x) * v.value);
                        (g_vec, lumped_mass(lam, &rule))
                    }
                };
                // C_free x + C_fixed u_fixed ≥ g.
                g_vec.iter_mut().zip(&c_shift).for_each(|(gi, s)| *gi += s);
                Some(Constraint {
                    matrix: c.into_sparse(),
                    obstacle: g_vec,
                    weights,
                })
            }
        };
        let bubbles: Vec<usize> = u.bubble_start().into_iter().collect();
        Ok(ContactProblem {
            matrix: k.into_sparse(),
            kind: MatrixKind::SymmetricPositiveDefinite,
            n_primal: rhs.len(),
            rhs,
            constraint,
            interior: Some(
                self.numbering
                    .interior_groups(&bubbles, self.mesh.n_triangles()),
            ),
        })
    }

    /// Errors against the exact radial solution, when the scene is that case.
    fn exact_errors(&self, problem: &ContactProblem, report: &SolveReport) -> Option<ExactErrors> {
        let (obstacle, constraint) = (self.obstacle.as_ref()?, problem.constraint.as_ref()?);
        let exact = RadialObstacle::new(
            self.load,
            obstacle.level(),
            obstacle.curvature.unwrap_or(0.0),
        )?;
        let u = self.u_coefficients(report);
        // The exact solution is not polynomial (ln r, and a kink of u'' at r = a):
        // a degree-10 collapsed Gauss rule keeps quadrature error far below the FE error.
        let rule = TriangleRule::exact_for(10);
        let l2 = integrate_per_triangle(&self.u_space, &u, &rule, |uh, p| {
            (uh.value - exact.u(p.x)).powi(2)
        });
        let h1 = integrate_per_triangle(&self.u_space, &u, &rule, |uh, p| {
            let e = exact.grad_u(p.x);
            (uh.grad[0] - e[0]).powi(2) + (uh.grad[1] - e[1]).powi(2)
        });
        let lam = integrate_per_triangle(&self.lambda_space, &report.lambda, &rule, |lh, p| {
            (lh.value - exact.lambda(p.x)).powi(2)
        });
        let area: f64 = report
            .lambda
            .iter()
            .zip(&constraint.weights)
            .filter(|(l, _)| **l > 0.0)
            .map(|(_, w)| w)
            .sum();
        Some(ExactErrors {
            l2: l2.iter().sum::<f64>().sqrt(),
            h1: h1.iter().sum::<f64>().sqrt(),
            lambda_l2: lam.iter().sum::<f64>().sqrt(),
            contact_radius: (area / std::f64::consts::PI).sqrt(),
            exact_contact_radius: exact.a,
        })
    }

    /// Fields and coefficient vectors for the result file (docs/formulation.md §5).
    fn results(&self, problem: &ContactProblem, report: &SolveReport) -> ResultData {
        let u = self.u_coefficients(report);
        let mut data = ResultData {
            write_edges: self.u_space.element == Element::P2,
            ..Default::default()
        };
        data.fields
            .push(vertex_field("u", self.u_space.vertex_values(&u)));
        data.dofs.push(("u".into(), u));
        data.dof_spaces.push((
            "u".into(),
            crate::output::space_tag(self.u_space.element, 1),
        ));
        if let (Some(phi), Some(c)) = (&self.phi, &problem.constraint) {
            data.fields.push(vertex_field("phi", phi.clone()));
            contact_fields(
                &mut data,
                report.lambda.clone(),
                c.mean_gaps(&report.x),
                self.lambda_space.element,
            );
        }
        data.root_attrs
            .push(("model".into(), AttrValue::Str("membrane".into())));
        data.root_attrs
            .push(("element".into(), AttrValue::Str(self.pair.name().into())));
        data.root_attrs
            .push(("simulated".into(), AttrValue::Str(self.simulated.join(","))));
        data.root_attrs.push((
            "n_dofs".into(),
            AttrValue::I64(self.u_space.n_dofs() as i64),
        ));
        data.root_attrs.push((
            "n_free_dofs".into(),
            AttrValue::I64(self.numbering.n_free() as i64),
        ));
        data.root_attrs
            .push(("h".into(), AttrValue::F64(self.mesh.h_max())));
        data
    }

    fn primal_from_dofs(&self, dofs: &[(String, Vec<f64>)]) -> Result<Vec<f64>> {
        let u = named_dofs(dofs, "u", self.u_space.n_dofs())?;
        Ok(self.numbering.restrict(u))
    }

    fn mesh(&self) -> &Mesh {
        self.mesh
    }

    fn n_dofs(&self) -> usize {
        self.u_space.n_dofs()
    }
}
