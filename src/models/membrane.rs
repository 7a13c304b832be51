//! The membrane obstacle problem (docs/formulation.md §1): find u ∈ H¹₀, u ≥ φ, minimising
//! ½∫|∇u|² − ∫g u; in mixed form (∇u, ∇v) − ⟨λ, v⟩ = (g, v), λ ≥ 0.
//!
//! Steps, as in deal.II's step-41: [`MembraneSystem::setup`] (spaces, Dirichlet
//! dofs) → [`MembraneSystem::assemble`] (K, F, C, g, Riesz weights) → a solver
//! from `solvers` → [`MembraneSystem::results`] (fields, errors).

use super::estimator::{membrane_indicators, Bound, MembraneState};
use super::exact::RadialObstacle;
use super::{
    check_obstacle_against_boundary_values, contact_fields, multiplier_field, named_boundary_tags,
    named_dofs, vertex_field, BoundaryValues, ExactErrors, FreefemTwin, ModelKind, ModelSystem,
    SkeletonTransfers,
};
use crate::assembly::{
    assemble_bilinear_eliminated, assemble_constant_linear, assemble_linear, assemble_p0_mass,
    element_diagonal, integrate_fields, laplace, lumped_mass, mass, quadrature_points,
    DofNumbering, QuadPoint, ShapeValue,
};
use crate::error::{Error, Result};
use crate::expression::{ExpressionSet, SetEvaluator};
use crate::linalg::{beside, MatrixKind};
use crate::mesh::{Hierarchy, Mesh};
use crate::multigrid::P1Levels;
use crate::output::{AttrValue, ResultData};
use crate::quadrature::TriangleRule;
use crate::scene::{ColdStartSpec, ElementPair, Expression, ObstacleSpec, Scene};
use crate::solvers::multigrid_newton::SkeletonObstacles;
use crate::solvers::{Constraint, ContactProblem, SolveReport};
use crate::space::{Element, Space, TriangleGeometry};
use faer::sparse::{SparseColMat, SymbolicSparseColMat};
use std::path::PathBuf;

/// The membrane model as the stages around it see it ([`ModelKind`]).
pub struct Membrane;

/// Bytes per unknown of a membrane run (one field, at most one bubble per
/// triangle), condensed or not: the disk P1⊕B3–P0 at n = 512, 1,158,566
/// unknowns, active set 2606 MB (2.2 KB each).
const BYTES_PER_UNKNOWN: f64 = 3.0e3;

impl ModelKind for Membrane {
    fn setup<'m>(&self, mesh: &'m Mesh, scene: &Scene) -> Result<Box<dyn ModelSystem + 'm>> {
        Ok(Box::new(MembraneSystem::setup(mesh, scene)?))
    }

    fn unknowns_per_triangle(&self, _element: ElementPair) -> f64 {
        // P1⊕B3 (V + T) and P0 (T); P2 (V + E) and P1 (V).
        2.5
    }

    fn bytes_per_unknown(&self, _condensed: bool) -> f64 {
        BYTES_PER_UNKNOWN
    }

    /// No factorisation: the ball at 513², 1025², 2049² and 4097² (1.3M,
    /// 5.2M, 21M and 84M unknowns; `make peers-bench`) peaks at 263, 250,
    /// 252 and 248 bytes per unknown (329, 1252, 5045 and 19874 MiB); 280
    /// keeps the estimate above the peak, within 1.13× of it.
    fn multigrid_bytes_per_unknown(&self) -> f64 {
        280.0
    }

    fn matrix_inputs(&self) -> (&'static str, &'static str) {
        ("mesh", "the mesh coordinates")
    }

    fn load_inputs(&self) -> (&'static str, &'static str) {
        ("load.g", "load.g")
    }

    fn has_surface(&self) -> bool {
        false
    }

    /// The depth bisection: the disk takes 3–7 Newton solves with it,
    /// 11–12 from the interior point.
    fn auto_cold_start(&self) -> ColdStartSpec {
        ColdStartSpec::DepthBisection
    }

    fn freefem_twin(&self, _element: ElementPair) -> Option<FreefemTwin> {
        Some(FreefemTwin::Membrane)
    }

    /// P1 interpolation on the free vertices: the skeleton of P1⊕B3 (its
    /// bubbles are the interior groups), numbered as `DofNumbering` numbers
    /// the free vertices.
    fn skeleton_transfers(
        &self,
        hierarchy: &Hierarchy,
        scene: &Scene,
    ) -> Result<SkeletonTransfers> {
        if scene.element != ElementPair::P1bP0 {
            return Err(scene.error(
                "solver.method",
                format!(
                    "multigrid prolongs the P1 skeleton of p1b-p0, not element = \"{}\"",
                    scene.element.name()
                ),
            ));
        }
        let tags = named_boundary_tags(
            hierarchy.finest(),
            scene,
            "mesh.dirichlet",
            scene.mesh.dirichlet.as_deref(),
        )?;
        let levels = P1Levels::new(hierarchy, tags.as_deref())?;
        let lifts = match &scene.mesh.dirichlet_value {
            Some(g_d) => levels.lifts(hierarchy, |x| g_d.eval(x)),
            None => levels.lifts(hierarchy, |_| 0.0),
        };
        // The obstacles at the finest level's vertices, each level's free
        // ones read from them: a coarse vertex keeps its index and place.
        let finest = hierarchy.finest();
        let at_free_vertices = |values: &[f64]| -> Vec<Vec<f64>> {
            (levels.numberings.iter())
                .map(|n| n.free_dofs.iter().map(|&v| values[v]).collect())
                .collect()
        };
        let obstacles = scene.obstacle.as_ref().map(|obstacle| {
            let at_vertices = |f: &dyn Fn([f64; 2]) -> f64| {
                at_free_vertices(&finest.vertices.iter().map(|&x| f(x)).collect::<Vec<_>>())
            };
            let lower = at_vertices(&|x| obstacle.value(x));
            let mut upper =
                (obstacle.upper.as_ref()).map(|e| at_vertices(&|x| e.eval(x)).into_iter());
            lower
                .into_iter()
                .map(|lower| SkeletonObstacles {
                    lower,
                    upper: upper.as_mut().and_then(Iterator::next),
                })
                .collect()
        });
        Ok(SkeletonTransfers {
            prolongations: levels.prolongations,
            lifts,
            obstacles,
        })
    }
}

pub struct MembraneSystem<'m> {
    pub mesh: &'m Mesh,
    pub pair: ElementPair,
    pub u_space: Space<'m>,
    pub lambda_space: Space<'m>,
    pub numbering: DofNumbering,
    /// The source term g of −Δu = g (`load.g`, default 0).
    pub load: Expression,
    /// The obstacle u ≥ φ, when the scene has one.
    pub obstacle: Option<ObstacleSpec>,
    /// φ_h: the obstacle's P1 interpolant at the vertices (with an obstacle).
    pub phi: Option<Vec<f64>>,
    /// ψ₂,h: the upper obstacle's P1 interpolant (two-sided scenes).
    pub upper: Option<Vec<f64>>,
    /// What the errors are measured against, when the scene asks for them
    /// (`output.errors`) and one is known.
    exact: Option<ExactSolution>,
    /// The scene file, named by the errors found after setup.
    source: PathBuf,
    /// The boundary values g_D (`mesh.dirichlet_value`) at the fixed dofs,
    /// 0 at the others (never read). All 0 without boundary values.
    pub boundary_values: Vec<f64>,
    /// Which effects the scene asked for (recorded in the result file).
    pub simulated: Vec<String>,
    /// `solver.threads`: with 2 or more the constraint rows and the
    /// bubbles' diagonal are assembled beside the stiffness.
    threads: usize,
}

impl<'m> MembraneSystem<'m> {
    /// Spaces and the Dirichlet dofs named by the scene.
    pub fn setup(mesh: &'m Mesh, scene: &Scene) -> Result<Self> {
        let (u_element, lambda_element) = match scene.element {
            ElementPair::P1bP0 => (Element::P1Bubble, Element::P0),
            ElementPair::P2P1 => (Element::P2, Element::P1),
            ElementPair::P2bPsri | ElementPair::P2bMitc => {
                unreachable!("validated: a shell element")
            }
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
            return Err(scene.error("mesh.dirichlet", format!(
                    "no dof is fixed (the mesh {} has no boundary line there): with natural boundary conditions alone −Δu = g determines u only up to a constant, and the problem is singular",
                    mesh.source.display()
                )));
        }
        let numbering = DofNumbering::from_fixed_mask(&fixed);
        let load = scene
            .load
            .as_ref()
            .and_then(|l| l.g.clone())
            .unwrap_or_else(|| Expression::constant(0.0));
        // Assembly evaluates g at the quadrature points of `MEMBRANE_RULE`.
        let rule = TriangleRule::exact_for(MEMBRANE_RULE);
        let expression_error = |field: &str, reason: String| Error::Scene {
            file: scene.source.clone(),
            field: field.into(),
            reason,
        };
        // ... and the estimator at its own rule's.
        let estimator_rule = TriangleRule::exact_for(super::estimator::ESTIMATOR_RULE);
        let load_points =
            quadrature_points(mesh, &rule).chain(quadrature_points(mesh, &estimator_rule));
        load.check_finite_at("load.g", load_points)
            .map_err(|r| expression_error("load.g", r))?;
        let p1 = Space::new(mesh, Element::P1);
        let boundary_values = match &scene.mesh.dirichlet_value {
            None => vec![0.0; u_space.n_dofs()],
            Some(g_d) => {
                // Evaluated at the fixed dofs only: the only entries read.
                let nodes = fixed_dof_points(&u_space, &fixed);
                g_d.check_finite_at("mesh.dirichlet_value", nodes.iter().map(|(_, x)| *x))
                    .map_err(|r| expression_error("mesh.dirichlet_value", r))?;
                let mut values = vec![0.0; u_space.n_dofs()];
                for (d, x) in nodes {
                    values[d] = g_d.eval(x);
                }
                values
            }
        };
        // φ_h (and ψ₂,h), the P1 interpolants of the obstacles at the vertices.
        let interpolant = |field: &str, e: &Expression| -> Result<Vec<f64>> {
            e.check_finite_at(field, mesh.vertices.iter().copied())
                .map_err(|r| expression_error(field, r))?;
            if pair_uses_quadrature(scene.element) {
                e.check_finite_at(field, quadrature_points(mesh, &rule))
                    .map_err(|r| expression_error(field, r))?;
            }
            Ok(p1.interpolate(|x| e.eval(x)))
        };
        let (phi, upper) = match &scene.obstacle {
            None => (None, None),
            Some(obstacle) => {
                let phi = match &obstacle.lower {
                    Some(lower) => interpolant("obstacle.lower", lower)?,
                    None => p1.interpolate(|x| obstacle.value(x)),
                };
                let upper = match &obstacle.upper {
                    Some(upper) => Some(interpolant("obstacle.upper", upper)?),
                    None => None,
                };
                if let Some(upper) = &upper {
                    check_obstacles_ordered(mesh, scene, &phi, upper)?;
                }
                // Before solving: ψ₁ ≤ g_D ≤ ψ₂ on the Dirichlet parts.
                let values = match &scene.mesh.dirichlet_value {
                    None => BoundaryValues::Zero,
                    Some(_) => BoundaryValues::AtVertices(u_space.vertex_values(&boundary_values)),
                };
                check_obstacle_against_boundary_values(
                    mesh,
                    scene,
                    (&phi, upper.as_deref()),
                    &values,
                    tags.as_deref(),
                    "Dirichlet boundary",
                )?;
                (Some(phi), upper)
            }
        };
        let exact = match scene.output.errors {
            false => None,
            true => {
                check_exact_solution_applies(mesh, scene, tags.is_none())?;
                ExactSolution::of(scene, &load)
                    .map_err(|reason| expression_error("output.exact.u", reason))?
            }
        };
        if let Some(ExactSolution::Given { set, .. }) = &exact {
            // Checked only where the errors evaluate it (∇u may be singular
            // at a vertex: a re-entrant corner): before anything is solved
            // at the error rule's first point in each triangle, then at
            // every point as the errors integrate it (`exact_errors`).
            let first = TriangleRule::exact_for(EXACT_ERROR_RULE).points[0];
            let points =
                (0..mesh.n_triangles()).map(|t| TriangleGeometry::new(mesh, t).point(first));
            set.check_finite_at(points)
                .map_err(|(key, reason)| expression_error(key, reason))?;
        }
        let mut simulated = vec!["load".to_string(), "dirichlet".to_string()];
        if scene.obstacle.is_some() {
            simulated.push("obstacle".into());
        }
        let system = MembraneSystem {
            threads: scene.solver.threads as usize,
            mesh,
            pair: scene.element,
            u_space,
            lambda_space: Space::new(mesh, lambda_element),
            numbering,
            load,
            obstacle: scene.obstacle.clone(),
            phi,
            upper,
            boundary_values,
            exact,
            source: scene.source.clone(),
            simulated,
        };
        system.check_rows_ordered(scene)?;
        Ok(system)
    }

    /// g₁,i ≤ g₂,i for every multiplier i of a two-sided scene, else the
    /// discrete problem is infeasible: rows i of C x ≥ g₁ and −C x ≥ −g₂
    /// hold the same (C x)_i between them. Ordered vertex values
    /// ([`check_obstacles_ordered`]) give ordered rows for P1⊕B3–P0,
    /// whose rows integrate the interpolants; P2–P1 integrates the
    /// expressions themselves against each hat μ_i, so bounds that touch at
    /// the vertices and cross between them can order the moments the
    /// other way.
    fn check_rows_ordered(&self, scene: &Scene) -> Result<()> {
        let (Some(obstacle), Some(phi), Some(upper_values)) =
            (&self.obstacle, &self.phi, &self.upper)
        else {
            return Ok(());
        };
        let Some(upper) = &obstacle.upper else {
            return Ok(());
        };
        let rule = TriangleRule::exact_for(MEMBRANE_RULE);
        let (lower_rows, _) = self.obstacle_rows(phi, |x| obstacle.value(x), &rule);
        let (upper_rows, _) = self.obstacle_rows(upper_values, |x| upper.eval(x), &rule);
        let Some(i) = (0..lower_rows.len()).find(|&i| lower_rows[i] > upper_rows[i]) else {
            return Ok(());
        };
        let [x, y] = dof_points(&self.lambda_space)[i];
        let (node, moment) = match self.lambda_space.element {
            Element::P0 => ("in the triangle with centroid", "∫_T ψ"),
            _ => ("at the vertex", "∫ψ μ_i (μ_i its hat function)"),
        };
        Err(scene.error("obstacle.upper", format!(
                "the bounds' integrated moments cross: infeasible: {node} ({x:.6}, {y:.6}) obstacle.lower's moment {moment} is {:.6e}, above obstacle.upper's {:.6e}; the constraint holds u between these moments (element {}), so no u is admissible although the bounds are ordered at every vertex",
                lower_rows[i],
                upper_rows[i],
                scene.element.name()
            )))
    }

    /// Full coefficient vector of u (Dirichlet values included).
    pub fn u_coefficients(&self, report: &SolveReport) -> Vec<f64> {
        self.numbering.extend(&report.x, &self.boundary_values)
    }

    /// The constraint rows of one obstacle: g (∫_T ψ_h or ∫ ψ μ_i) and the Riesz weights.
    fn obstacle_rows(
        &self,
        values: &[f64],
        exact: impl Fn([f64; 2]) -> f64,
        rule: &TriangleRule,
    ) -> (Vec<f64>, Vec<f64>) {
        match self.pair {
            ElementPair::P1bP0 => {
                // g_T = ∫_T φ_h with φ_h the P1 interpolant; w_T = |T|.
                let areas: Vec<f64> = (0..self.mesh.n_triangles())
                    .map(|t| self.mesh.area(t))
                    .collect();
                let g_vec = self
                    .mesh
                    .triangles
                    .iter()
                    .zip(&areas)
                    .map(|(tri, a)| a * (values[tri[0]] + values[tri[1]] + values[tri[2]]) / 3.0)
                    .collect();
                (g_vec, areas)
            }
            ElementPair::P2P1 | ElementPair::P2bPsri | ElementPair::P2bMitc => {
                // g_i = ∫ φ μ_i; w_i = lumped P1 mass (docs/formulation.md §1: the Riesz map
                // whose projection is a nodal max).
                let lam = &self.lambda_space;
                let g_vec = assemble_linear(lam, rule, |v, p| exact(p.x) * v.value);
                (g_vec, lumped_mass(lam, rule))
            }
        }
    }

    /// The P1⊕B3 stiffness as the blocks it is: ∫_T ∇φ·∇b = ∇φ·∮_∂T b n = 0
    /// for a P1 function φ and the cubic bubble b of a straight triangle, so
    /// A = diag(K, D) with K the P1 stiffness (one-point rule: constant
    /// gradients: `assembly::p1_stiffness`) and D_t = ∫_T |∇b_t|²
    /// ([`MembraneSystem::bubble_diagonal`]).
    /// Quadrature would give the coupling as round-off; left out, A has less
    /// than half the entries. Bubbles are numbered after the vertices and
    /// never fixed, so the free unknowns are the free vertices, then every
    /// bubble. This is K on the free vertices, and its shift.
    fn p1_stiffness(&self) -> (SparseColMat<usize, f64>, Vec<f64>) {
        let n_vertices = self.mesh.n_vertices();
        let vertices = self.numbering.leading(n_vertices);
        // Room for the bubbles' diagonal ([`MembraneSystem::with_bubbles`]).
        let bubbles = self.mesh.n_triangles();
        crate::assembly::p1_stiffness(
            self.mesh,
            &vertices,
            &self.boundary_values[..n_vertices],
            bubbles,
        )
    }

    /// D_t = ∫_T |∇b_t|² of every triangle's bubble.
    fn bubble_diagonal(&self, rule: &TriangleRule) -> Vec<f64> {
        let bubble = self.u_space.element.n_local() - 1;
        element_diagonal(&self.u_space, rule, laplace, bubble)
    }

    /// A = diag(K, D) from the P1 stiffness on the free vertices and its
    /// shift ([`MembraneSystem::p1_stiffness`]) and the bubbles' diagonal.
    fn with_bubbles(
        &self,
        (k, mut shift): (SparseColMat<usize, f64>, Vec<f64>),
        d: &[f64],
    ) -> (SparseColMat<usize, f64>, Vec<f64>) {
        let n_free_vertices = k.nrows();
        let n = n_free_vertices + d.len();
        debug_assert_eq!(n, self.numbering.n_free(), "free vertices, then bubbles");
        let (symbolic, mut values) = k.into_parts();
        let (_, _, mut col_ptr, _, mut rows) = symbolic.into_parts();
        rows.reserve_exact(d.len());
        values.reserve_exact(d.len());
        col_ptr.reserve_exact(d.len());
        for (t, &dt) in d.iter().enumerate() {
            rows.push(n_free_vertices + t);
            values.push(dt);
            col_ptr.push(rows.len());
        }
        shift.resize(n, 0.0);
        let symbolic = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, rows);
        (SparseColMat::new(symbolic, values), shift)
    }

    /// Rows of the lower obstacle: λ has this many entries per bound.
    fn n_rows(&self) -> usize {
        self.lambda_space.n_dofs()
    }
}

/// What errors are measured against: the disk's radial solution or a
/// scene's `[output.exact]`, whose u, λ and exact ∇u (u's expression
/// differentiated) are evaluated together at each point.
enum ExactSolution {
    Radial(RadialObstacle),
    Given {
        /// u, λ, ∂u/∂x, ∂u/∂y, under the keys that name them in errors.
        set: ExpressionSet,
        contact_radius: f64,
    },
}

/// An exact solution at one point.
struct ExactValues {
    u: f64,
    grad_u: [f64; 2],
    lambda: f64,
}

/// Evaluates an exact solution point by point.
enum ExactEvaluator<'a> {
    Radial(&'a RadialObstacle),
    Given(SetEvaluator<'a>),
}

/// The exact solution is not polynomial (ln r, and a kink of u'' at r = a):
/// a degree-10 collapsed Gauss rule keeps quadrature error far below the FE error.
const EXACT_ERROR_RULE: usize = 10;

impl ExactSolution {
    /// The scene's `[output.exact]`, else the radial solution of the disk
    /// case (a paraboloid obstacle, a constant load); None when neither
    /// applies. The error is why u's expression has no derivative.
    fn of(scene: &Scene, load: &Expression) -> std::result::Result<Option<Self>, String> {
        use crate::expression::Variable::{X, Y};
        if let Some(given) = &scene.output.exact {
            let members = [
                ("output.exact.u", given.u.clone()),
                ("output.exact.lambda", given.lambda.clone()),
                ("output.exact.u (∂u/∂x)", given.u.derivative(X)?),
                ("output.exact.u (∂u/∂y)", given.u.derivative(Y)?),
            ];
            let set = ExpressionSet::new(members.map(|(key, e)| (key.to_string(), e)).into());
            return Ok(Some(ExactSolution::Given {
                set,
                contact_radius: given.contact_radius,
            }));
        }
        let radial = match (&scene.obstacle, load.as_constant()) {
            (Some(obstacle), Some(g))
                if obstacle.shape == crate::scene::ObstacleShape::Paraboloid =>
            {
                RadialObstacle::new(g, obstacle.level(), obstacle.curvature.unwrap_or(0.0))
            }
            _ => None,
        };
        Ok(radial.map(ExactSolution::Radial))
    }

    fn evaluator(&self) -> ExactEvaluator<'_> {
        match self {
            ExactSolution::Radial(e) => ExactEvaluator::Radial(e),
            ExactSolution::Given { set, .. } => ExactEvaluator::Given(set.evaluator()),
        }
    }

    fn contact_radius(&self) -> f64 {
        match self {
            ExactSolution::Radial(e) => e.a,
            ExactSolution::Given { contact_radius, .. } => *contact_radius,
        }
    }
}

impl<'a> ExactEvaluator<'a> {
    /// The values at x; a scene's values are checked finite
    /// ([`SetEvaluator::finite_at`]: the key of a refused one and why).
    fn at(&mut self, x: [f64; 2]) -> std::result::Result<ExactValues, (&'a str, String)> {
        match self {
            ExactEvaluator::Radial(e) => Ok(ExactValues {
                u: e.u(x),
                grad_u: e.grad_u(x),
                lambda: e.lambda(x),
            }),
            ExactEvaluator::Given(evaluator) => match *evaluator.finite_at(x)? {
                [u, lambda, dx, dy] => Ok(ExactValues {
                    u,
                    grad_u: [dx, dy],
                    lambda,
                }),
                _ => unreachable!("the four members of `ExactSolution::of`"),
            },
        }
    }
}

/// The rule of the membrane's assembly: degree 5 (Radon, 7 points) is exact
/// for every integrand: ∇(P1⊕B3)·∇(P1⊕B3) has degree 4, P2·P1 and φ·P1 degree 3.
const MEMBRANE_RULE: usize = 5;

/// The P2–P1 pair integrates the obstacle itself at quadrature points
/// (P1⊕B3–P0 its P1 interpolant).
fn pair_uses_quadrature(pair: ElementPair) -> bool {
    pair != ElementPair::P1bP0
}

/// The point of every dof of a Lagrange space (its node), bubbles at the centroid.
fn dof_points(space: &Space) -> Vec<[f64; 2]> {
    let mut points = vec![[0.0; 2]; space.n_dofs()];
    let nodes = space.element.nodes();
    for t in 0..space.mesh.n_triangles() {
        let g = TriangleGeometry::new(space.mesh, t);
        let (dofs, n) = space.element_dofs(t);
        for i in 0..n {
            points[dofs[i]] = g.point(nodes[i]);
        }
    }
    points
}

/// The fixed dofs of `space` (`fixed`) with their nodes, each once.
fn fixed_dof_points(space: &Space, fixed: &[bool]) -> Vec<(usize, [f64; 2])> {
    let nodes = space.element.nodes();
    let mut seen = vec![false; space.n_dofs()];
    let mut points = Vec::new();
    for t in 0..space.mesh.n_triangles() {
        let (dofs, n) = space.element_dofs(t);
        if !dofs[..n].iter().any(|&d| fixed[d] && !seen[d]) {
            continue;
        }
        let g = TriangleGeometry::new(space.mesh, t);
        for (&d, &node) in dofs[..n].iter().zip(&nodes) {
            if fixed[d] && !seen[d] {
                seen[d] = true;
                points.push((d, g.point(node)));
            }
        }
    }
    points
}

/// ψ₁,h ≤ ψ₂,h at every vertex, else no admissible u exists.
fn check_obstacles_ordered(mesh: &Mesh, scene: &Scene, lower: &[f64], upper: &[f64]) -> Result<()> {
    let crossing = (0..mesh.n_vertices()).find(|&v| lower[v] > upper[v]);
    match crossing {
        Some(v) => Err(scene.error("obstacle.upper", format!(
                "infeasible: at the vertex ({:.6}, {:.6}) the lower obstacle {:.6e} lies above the upper one {:.6e} (the two-sided problem needs lower ≤ upper)",
                mesh.vertices[v][0], mesh.vertices[v][1], lower[v], upper[v]
            ))),
        None => Ok(()),
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
        Err(scene.error("output.errors", format!("errors are measured against the exact solution on the unit disk (docs/formulation.md §1), but {reason}")))
    };
    if scene.output.exact.is_some() {
        // The scene states its exact solution (checked finite where the
        // errors evaluate it: in `setup` and `exact_errors`).
        return Ok(());
    }
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
    if obstacle.shape != crate::scene::ObstacleShape::Paraboloid {
        return refuse("the obstacle is not the paraboloid".into());
    }
    if scene
        .mesh
        .dirichlet_value
        .as_ref()
        .and_then(Expression::as_constant)
        .is_some_and(|v| v != 0.0)
        || scene
            .mesh
            .dirichlet_value
            .as_ref()
            .is_some_and(|v| v.as_constant().is_none())
    {
        return refuse("mesh.dirichlet_value is not 0".into());
    }
    let Some(g) = scene
        .load
        .as_ref()
        .and_then(|l| l.g.as_ref())
        .map_or(Some(0.0), Expression::as_constant)
    else {
        return refuse("load.g is an expression, not a number".into());
    };
    let curvature = obstacle.curvature.unwrap_or(0.0);
    if RadialObstacle::new(g, obstacle.level(), curvature).is_none() {
        return refuse(format!(
            "no radial solution exists for load.g = {g}, obstacle height {} and curvature {curvature} (it needs 4·curvature ≥ g)",
            obstacle.level()
        ));
    }
    Ok(())
}

/// [C; −C]: the rows of both bounds of a two-sided obstacle.
fn stacked_with_negation(c: &SparseColMat<usize, f64>) -> SparseColMat<usize, f64> {
    let (m, n) = (c.nrows(), c.ncols());
    let (mut col_ptr, mut rows, mut values) = (vec![0usize], Vec::new(), Vec::new());
    for j in 0..n {
        let (col_rows, col_values) = (c.symbolic().row_idx_of_col_raw(j), c.val_of_col(j));
        rows.extend_from_slice(col_rows);
        rows.extend(col_rows.iter().map(|&i| m + i));
        values.extend_from_slice(col_values);
        values.extend(col_values.iter().map(|&v| -v));
        col_ptr.push(rows.len());
    }
    let symbolic = SymbolicSparseColMat::new_checked(2 * m, n, col_ptr, None, rows);
    SparseColMat::new(symbolic, values)
}

impl ModelSystem for MembraneSystem<'_> {
    /// The algebraic problem: stiffness K, load F, and (only when the scene has
    /// an obstacle) the constraint C u ≥ g with its Riesz weights.
    fn assemble(&self) -> Result<ContactProblem> {
        let rule = TriangleRule::exact_for(MEMBRANE_RULE);
        let g = &self.load;
        let u = &self.u_space;
        // Nonzero boundary values are lifted: −K_free,fixed g_D on the right.
        let fixed_values = &self.boundary_values;
        let numbering = &self.numbering;
        // P1⊕B3: K on one thread, the bubbles' D (and C) on the other.
        let stiffness = || match self.pair {
            ElementPair::P1bP0 => self.p1_stiffness(),
            _ => assemble_bilinear_eliminated(
                u,
                u,
                &rule,
                laplace,
                numbering,
                numbering,
                fixed_values,
            ),
        };
        let constraint = || {
            let obstacle = self.obstacle.as_ref()?;
            let lam = &self.lambda_space;
            let (mut c, c_shift) = match lam.element {
                Element::P0 => assemble_p0_mass(u, numbering, fixed_values),
                _ => assemble_bilinear_eliminated(
                    lam,
                    u,
                    &rule,
                    mass,
                    &DofNumbering::all_free(lam.n_dofs()),
                    numbering,
                    fixed_values,
                ),
            };
            let phi = self.phi.as_ref().expect("set up with the obstacle");
            let (mut g_vec, mut weights) = self.obstacle_rows(phi, |x| obstacle.value(x), &rule);
            // C_free x + C_fixed u_fixed ≥ g.
            g_vec.iter_mut().zip(&c_shift).for_each(|(gi, s)| *gi += s);
            if let (Some(upper), Some(upper_values)) = (&obstacle.upper, &self.upper) {
                // u ≤ ψ₂ as −C x ≥ −g₂: the solvers see one stacked
                // constraint [C; −C] x ≥ [g₁; −g₂], each bound with its weights.
                let (g_upper, w_upper) = self.obstacle_rows(upper_values, |x| upper.eval(x), &rule);
                c = stacked_with_negation(&c);
                g_vec.extend(g_upper.iter().zip(&c_shift).map(|(g, s)| -(g + s)));
                weights.extend(w_upper);
            }
            Some(Constraint {
                matrix: c,
                obstacle: g_vec,
                weights,
            })
        };
        let bubble_diagonal = || match self.pair {
            ElementPair::P1bP0 => Some(self.bubble_diagonal(&rule)),
            _ => None,
        };
        let (stiffness, (bubble_diagonal, constraint)) = beside(self.threads, stiffness, || {
            (bubble_diagonal(), constraint())
        });
        let (k, shift) = match bubble_diagonal {
            Some(d) => self.with_bubbles(stiffness, &d),
            None => stiffness,
        };
        let f_full = match g.as_constant() {
            Some(g) => assemble_constant_linear(u, g),
            None => assemble_linear(u, &rule, |v, p| g.eval(p.x) * v.value),
        };
        let rhs: Vec<f64> = numbering
            .restrict(&f_full)
            .iter()
            .zip(&shift)
            .map(|(a, b)| a + b)
            .collect();
        let bubbles: Vec<usize> = u.bubble_start().into_iter().collect();
        Ok(ContactProblem {
            matrix: k,
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

    /// Errors against the exact solution: the scene's `[output.exact]`, or
    /// the radial one when the scene is the disk case. One pass over the
    /// degree-10 rule's points evaluates the exact solution once at each and
    /// checks a scene's values finite there: a refused value is an error
    /// naming its key and the point.
    fn exact_errors(
        &self,
        problem: &ContactProblem,
        report: &SolveReport,
        threads: usize,
    ) -> Result<Option<ExactErrors>> {
        let (Some(exact), Some(_), Some(constraint)) =
            (&self.exact, &self.obstacle, &problem.constraint)
        else {
            return Ok(None);
        };
        let u = self.u_coefficients(report);
        let rule = TriangleRule::exact_for(EXACT_ERROR_RULE);
        let fields = [
            (&self.u_space, &u[..]),
            (&self.lambda_space, &report.lambda[..]),
        ];
        let [l2, h1, lam] = integrate_fields(fields, &rule, threads, || {
            let mut evaluator = exact.evaluator();
            move |&[uh, lh]: &[ShapeValue; 2], p: &QuadPoint| {
                let e = evaluator.at(p.x)?;
                Ok::<_, (&str, String)>([
                    (uh.value - e.u).powi(2),
                    (uh.grad[0] - e.grad_u[0]).powi(2) + (uh.grad[1] - e.grad_u[1]).powi(2),
                    (lh.value - e.lambda).powi(2),
                ])
            }
        })
        .map_err(|(key, reason)| Error::Scene {
            file: self.source.clone(),
            field: key.into(),
            reason,
        })?;
        let area: f64 = report
            .contact()
            .iter()
            .zip(&constraint.weights)
            .filter(|(in_contact, _)| **in_contact)
            .map(|(_, w)| w)
            .sum();
        Ok(Some(ExactErrors {
            l2: l2.sqrt(),
            h1: h1.sqrt(),
            lambda_l2: lam.sqrt(),
            contact_radius: (area / std::f64::consts::PI).sqrt(),
            exact_contact_radius: exact.contact_radius(),
        }))
    }

    /// The residual estimator of docs/formulation.md §8 (`models::estimator`).
    fn estimator(&self, _problem: &ContactProblem, report: &SolveReport) -> Option<Vec<f64>> {
        let u = self.u_coefficients(report);
        let load = |x: [f64; 2]| self.load.eval(x);
        let lower = self
            .obstacle
            .as_ref()
            .map(|o| move |x: [f64; 2]| o.value(x));
        let upper = self
            .obstacle
            .as_ref()
            .and_then(|o| o.upper.as_ref())
            .map(|e| move |x: [f64; 2]| e.eval(x));
        // λ holds the lower bound's rows, then the upper bound's (two-sided).
        let m = self.n_rows();
        let mut bounds = Vec::new();
        if let Some(lower) = &lower {
            bounds.push(Bound {
                obstacle: lower,
                multiplier: (self.lambda_space, &report.lambda[..m]),
                sign: 1.0,
            });
        }
        if let Some(upper) = &upper {
            bounds.push(Bound {
                obstacle: upper,
                multiplier: (self.lambda_space, &report.lambda[m..]),
                sign: -1.0,
            });
        }
        let state = MembraneState {
            u_space: self.u_space,
            u: &u,
            load: &load,
            bounds,
        };
        Some(membrane_indicators(&state).eta())
    }

    /// Fields and coefficient vectors for the result file (docs/formulation.md §5).
    fn results(
        &self,
        problem: &ContactProblem,
        report: &SolveReport,
        _threads: usize,
    ) -> ResultData {
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
            let mut gaps = c.mean_gaps(&report.x);
            let contact = report.contact();
            match &self.upper {
                None => contact_fields(
                    &mut data,
                    report.lambda.clone(),
                    gaps,
                    &contact,
                    self.lambda_space.element,
                ),
                Some(upper) => {
                    // Two-sided: λ = λ₁ − λ₂ (net), and each bound's own
                    // multiplier, mean gap and contact indicator (§5).
                    let m = self.n_rows();
                    let (lower_lambda, upper_lambda) = report.lambda.split_at(m);
                    let net = lower_lambda
                        .iter()
                        .zip(upper_lambda)
                        .map(|(a, b)| a - b)
                        .collect();
                    let upper_gaps = gaps.split_off(m);
                    let (lower_contact, upper_contact) = contact.split_at(m);
                    contact_fields(
                        &mut data,
                        net,
                        gaps,
                        lower_contact,
                        self.lambda_space.element,
                    );
                    data.fields.push(vertex_field("phi_upper", upper.clone()));
                    for (name, values) in [
                        ("lambda_lower", lower_lambda.to_vec()),
                        ("lambda_upper", upper_lambda.to_vec()),
                        ("gap_upper_mean", upper_gaps),
                        (
                            "contact_upper",
                            upper_contact.iter().map(|&c| f64::from(c)).collect(),
                        ),
                    ] {
                        data.fields
                            .push(multiplier_field(name, values, self.lambda_space.element));
                    }
                }
            }
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
