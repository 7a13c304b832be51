//! The forms of the Cartesian Naghdi shell (docs/formulation.md §2, thesis (1.12), (2.14)) and
//! the algebraic problem of the discrete Problem 9 without and with contact,
//! for both shell elements ([`ShellElementKind`]):
//!
//! * `p1b-p0`, the thesis' element: seven scalar P1⊕B3 fields u1, u2, u3,
//!   r1, r2, r3 (the Cartesian displacement u and rotation r) and the
//!   tangency multiplier ψ for r·a3 = 0; P0 contact multipliers; every form
//!   with Radon's 7-point rule (FreeFEM's `qf5pT`);
//! * `p2b-psri`, the locking-free element (docs/shell-benchmarks.md):
//!   u1, u2, u3 and the rotation r = θ^1 a_1 + θ^2 a_2, all five in P2⊕B3;
//!   r is tangent by construction (no ψ, no ρ: K is symmetric positive
//!   definite); the membrane and shear energies by partial selective reduced
//!   integration (Arnold–Brezzi, as FEniCS-Shells): a weight
//!   α_T = min(1, ε²/h_T²) on the full rule and 1 − α_T on the 3-point
//!   interior rule of degree 2; P1 contact multipliers;
//! * `p2b-mitc`, the recommended element: the spaces and contact of
//!   `p2b-psri`, with the membrane strain tied to Regge and the shear strain
//!   to Nédélec elements ([`TiedStrains`]) and every energy fully
//!   integrated: no reduced rule, no weight, no zero-energy mode.
//!
//! The unknowns are scalar fields in blocks ([`ShellLayout`]): the global index
//! of scalar dof d of field f is `fields[f].offset + d`.
//!
//! At each quadrature point the exact chart geometry ([`SurfacePoint`]) is
//! evaluated and every local basis function (one scalar shape function in one
//! field) is mapped to its vector of generalised strains
//! ([`generalized_strains`]); the element matrix is K_T = Σ_q w_q Eᵀ D E with
//! the block-diagonal weight D of [`strain_weights`].
//!
//! [`assemble_shell`] gives the saddle problem without contact,
//! [`rigid_plane_constraint`] the contact with the plane z = 0, and
//! [`scale_tangency_multiplier`] rebalances the ψ block for large ρ.

pub mod tied_strains;

use super::geometry::{obstacle_function, Chart, Material, SurfacePoint};
use crate::assembly::{eliminate, quad_points, DofNumbering, ElementMatrix, Triplets};
use crate::linalg::MatrixKind;
use crate::mesh::Mesh;
use crate::quadrature::{SegmentRule, TriangleRule};
use crate::scene::Expression;
use crate::solvers::{Constraint, ContactProblem};
use crate::space::{Element, Space, TriangleGeometry};
use faer::sparse::SparseColMat;
use nalgebra::{Matrix2, Vector3};
use tied_strains::TiedStrains;

/// Number of components of U = (u, r) in the thesis' layout.
pub const N_U_COMPONENTS: usize = 6;
/// Number of scalar fields of the thesis' layout: U and ψ.
pub const N_COMPONENTS: usize = 7;
/// Field index of the tangency multiplier ψ in the thesis' layout.
pub const PSI: usize = 6;
/// Names of the thesis' fields, in block order.
pub const COMPONENT_NAMES: [&str; N_COMPONENTS] = ["u1", "u2", "u3", "r1", "r2", "r3", "psi"];

/// Length of the generalised strain vector, ordered
/// [γ11, γ22, γ12, χ11, χ22, χ12, δ13, δ23, ∂1(r·a3), ∂2(r·a3)].
pub const N_STRAINS: usize = 10;
/// Offsets of the strain groups in a [`StrainVector`].
pub const GAMMA: usize = 0;
pub const CHI: usize = 3;
pub const DELTA: usize = 6;
pub const GRAD_NORMAL_ROTATION: usize = 8;

/// Generalised strains at one point (order: see [`N_STRAINS`]).
pub type StrainVector = [f64; N_STRAINS];

/// The symmetric index pairs (α, β) of the strain components 11, 22, 12.
const PAIRS: [[usize; 2]; 3] = [[0, 0], [1, 1], [0, 1]];

/// The shell discretisations (scene `element`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShellElementKind {
    /// The thesis' element: (P1⊕B3)⁶ × P1⊕B3 (ψ), P0 contact multipliers.
    P1bP0,
    /// The locking-free element: (P2⊕B3)⁵ (u and two tangent rotation
    /// components), PSRI, P1 contact multipliers.
    P2bPsri,
    /// The spaces of `P2bPsri`, the membrane strain tied to Regge and the
    /// shear strain to Nédélec elements (L² projections for the displacement
    /// bubbles), every energy fully integrated.
    P2bMitc,
}

impl ShellElementKind {
    /// The element's own space of the contact multiplier λ (a scene may
    /// choose P1 for `p1b-p0`: [`ShellLayout::with_multiplier`]).
    pub fn multiplier_element(self) -> Element {
        match self {
            ShellElementKind::P1bP0 => Element::P0,
            ShellElementKind::P2bPsri | ShellElementKind::P2bMitc => Element::P1,
        }
    }
}

/// How one scalar field enters the shell's unknowns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FieldRole {
    /// The Cartesian displacement component u_c (c = 0, 1, 2).
    Displacement(usize),
    /// The Cartesian rotation component r_c (thesis; tangency through ψ).
    CartesianRotation(usize),
    /// The tangent rotation component θ^β: r = θ^1 a_1 + θ^2 a_2.
    TangentRotation(usize),
    /// The tangency multiplier ψ of r·a3 = 0.
    TangencyMultiplier,
}

/// One scalar field of the layout: its name, role, space and block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShellField {
    pub name: &'static str,
    pub role: FieldRole,
    pub element: Element,
    /// First global index of the block.
    pub offset: usize,
    /// Number of dofs of the block.
    pub len: usize,
}

/// Dof layout: one scalar field per block, U's fields first, ψ (if any) last.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShellLayout {
    pub kind: ShellElementKind,
    pub fields: Vec<ShellField>,
    /// The space of the contact multiplier λ: P0 (one per triangle) or P1
    /// (one per vertex).
    pub multiplier: Element,
    pub n_vertices: usize,
    pub n_triangles: usize,
}

impl ShellLayout {
    /// The thesis' layout (seven P1⊕B3 fields).
    pub fn new(mesh: &Mesh) -> Self {
        Self::for_element(mesh, ShellElementKind::P1bP0)
    }

    pub fn for_element(mesh: &Mesh, kind: ShellElementKind) -> Self {
        use FieldRole::*;
        let spec: Vec<(&'static str, FieldRole, Element)> = match kind {
            ShellElementKind::P1bP0 => COMPONENT_NAMES
                .iter()
                .enumerate()
                .map(|(c, &name)| {
                    let role = match c {
                        0..=2 => Displacement(c),
                        3..=5 => CartesianRotation(c - 3),
                        _ => TangencyMultiplier,
                    };
                    (name, role, Element::P1Bubble)
                })
                .collect(),
            ShellElementKind::P2bPsri | ShellElementKind::P2bMitc => vec![
                ("u1", Displacement(0), Element::P2Bubble),
                ("u2", Displacement(1), Element::P2Bubble),
                ("u3", Displacement(2), Element::P2Bubble),
                ("theta1", TangentRotation(0), Element::P2Bubble),
                ("theta2", TangentRotation(1), Element::P2Bubble),
            ],
        };
        let mut offset = 0;
        let fields = spec
            .into_iter()
            .map(|(name, role, element)| {
                let len = Space::new(mesh, element).n_dofs();
                let field = ShellField {
                    name,
                    role,
                    element,
                    offset,
                    len,
                };
                offset += len;
                field
            })
            .collect();
        ShellLayout {
            kind,
            fields,
            multiplier: kind.multiplier_element(),
            n_vertices: mesh.n_vertices(),
            n_triangles: mesh.n_triangles(),
        }
    }

    /// The layout with contact multipliers in `multiplier` (P0 or P1).
    pub fn with_multiplier(self, multiplier: Element) -> Self {
        ShellLayout { multiplier, ..self }
    }

    /// Dofs of one scalar P1⊕B3 field of the thesis' layout: Nv + Nt.
    pub fn n_scalar(&self) -> usize {
        self.fields[0].len
    }

    /// All dofs of U and ψ, boundary dofs included.
    pub fn n_total(&self) -> usize {
        self.fields.last().map_or(0, |f| f.offset + f.len)
    }

    /// Global index of scalar dof `scalar` of field `component`.
    pub fn index(&self, component: usize, scalar: usize) -> usize {
        self.fields[component].offset + scalar
    }

    /// The coefficients of one field in a full vector.
    pub fn component<'a>(&self, full: &'a [f64], component: usize) -> &'a [f64] {
        let f = &self.fields[component];
        &full[f.offset..f.offset + f.len]
    }

    /// The field of ψ, if the layout has one.
    pub fn psi(&self) -> Option<usize> {
        self.fields
            .iter()
            .position(|f| f.role == FieldRole::TangencyMultiplier)
    }

    /// The field of a role.
    pub fn field_of(&self, role: FieldRole) -> Option<usize> {
        self.fields.iter().position(|f| f.role == role)
    }

    /// The field named `name` (u1, …, r3, psi, theta1, theta2).
    pub fn field_named(&self, name: &str) -> Option<usize> {
        self.fields.iter().position(|f| f.name == name)
    }

    /// The fields of U (all but ψ), in block order.
    pub fn u_fields(&self) -> impl Iterator<Item = &ShellField> {
        self.fields
            .iter()
            .filter(|f| f.role != FieldRole::TangencyMultiplier)
    }

    /// Number of contact multipliers (one per triangle or per vertex).
    pub fn n_multipliers(&self) -> usize {
        match self.multiplier {
            Element::P0 => self.n_triangles,
            _ => self.n_vertices,
        }
    }

    /// The dof count with boundary dofs and the contact multipliers; for
    /// the thesis' layout 7·(Nv + Nt) + Nt (docs/formulation.md §2).
    pub fn thesis_dof_count(&self) -> usize {
        self.n_total() + self.n_multipliers()
    }
}

/// The numbering of the clamped shell (thesis' layout): u = r = ψ = 0 at the
/// vertices of the boundary parts with tags in `clamped_tags` (all of ∂ω if
/// None); bubbles vanish on the boundary and stay free. Free dofs keep the
/// block order, so the free U dofs come first and the free ψ dofs last.
pub fn clamped_numbering(mesh: &Mesh, clamped_tags: Option<&[i32]>) -> DofNumbering {
    let layout = ShellLayout::new(mesh);
    let mut fixed = vec![false; layout.n_total()];
    fix_fields(
        mesh,
        &layout,
        clamped_tags,
        0..layout.fields.len(),
        &mut fixed,
    );
    DofNumbering::from_fixed_mask(&fixed)
}

/// Marks as fixed the boundary dofs (on the parts `tags`, all of ∂ω if None)
/// of the given fields.
pub fn fix_fields(
    mesh: &Mesh,
    layout: &ShellLayout,
    tags: Option<&[i32]>,
    fields: impl IntoIterator<Item = usize>,
    fixed: &mut [bool],
) {
    for f in fields {
        let field = &layout.fields[f];
        let mask = Space::new(mesh, field.element).boundary_dof_mask(tags);
        for (d, on) in mask.into_iter().enumerate() {
            if on {
                fixed[field.offset + d] = true;
            }
        }
    }
}

/// Generalised strains of a field U = (u, r) from its values and first
/// derivatives at a point (`du[α]` = ∂_α u, `dr[α]` = ∂_α r):
///
/// ```text
///   γ_αβ(u)    = ½(∂_α u·a_β + ∂_β u·a_α)                       membrane
///   χ_αβ(U)    = ½(∂_α u·∂_β a3 + ∂_β u·∂_α a3 + ∂_α r·a_β + ∂_β r·a_α)   bending
///   δ_α3(U)    = ½(∂_α u·a3 + r·a_α)                            transverse shear
///   ∂_α(r·a3)  = ∂_α r·a3 + r·∂_α a3                            tangency (a3 varies)
/// ```
pub fn generalized_strains(
    p: &SurfacePoint,
    du: &[Vector3<f64>; 2],
    r: &Vector3<f64>,
    dr: &[Vector3<f64>; 2],
) -> StrainVector {
    let a = [p.a1, p.a2];
    let mut e = [0.0; N_STRAINS];
    for (i, &[al, be]) in PAIRS.iter().enumerate() {
        e[GAMMA + i] = 0.5 * (du[al].dot(&a[be]) + du[be].dot(&a[al]));
        e[CHI + i] = 0.5
            * (du[al].dot(&p.d_a3[be])
                + du[be].dot(&p.d_a3[al])
                + dr[al].dot(&a[be])
                + dr[be].dot(&a[al]));
    }
    for al in 0..2 {
        e[DELTA + al] = 0.5 * (du[al].dot(&p.a3) + r.dot(&a[al]));
        e[GRAD_NORMAL_ROTATION + al] = dr[al].dot(&p.a3) + r.dot(&p.d_a3[al]);
    }
    e
}

/// Strains of one scalar shape function (value, physical gradient) placed in
/// a field of U with `role`.
pub fn field_strains(
    p: &SurfacePoint,
    role: FieldRole,
    value: f64,
    grad: [f64; 2],
) -> StrainVector {
    let zero = Vector3::zeros();
    match role {
        FieldRole::Displacement(c) => {
            let unit = Vector3::ith(c, 1.0);
            generalized_strains(p, &[unit * grad[0], unit * grad[1]], &zero, &[zero; 2])
        }
        FieldRole::CartesianRotation(c) => {
            let unit = Vector3::ith(c, 1.0);
            let d = [unit * grad[0], unit * grad[1]];
            generalized_strains(p, &[zero; 2], &(unit * value), &d)
        }
        FieldRole::TangentRotation(be) => {
            // r = θ a_β: ∂_α r = ∂_α θ a_β + θ ∂_α a_β, ∂_α a_β = ∂_α∂_β φ.
            let a_be = *p.a(be);
            let dr = [
                a_be * grad[0] + p.d_a[be][0] * value,
                a_be * grad[1] + p.d_a[be][1] * value,
            ];
            generalized_strains(p, &[zero; 2], &(a_be * value), &dr)
        }
        FieldRole::TangencyMultiplier => [0.0; N_STRAINS],
    }
}

/// The matrix M with eᵀ M e = Σ_{αβρσ} a^αβρσ e_αβ e_ρσ for the symmetric
/// strain written as the vector (e11, e22, e12).
pub fn elasticity_matrix(material: &Material, a_contra: &Matrix2<f64>) -> [[f64; 3]; 3] {
    let c = material.elasticity(a_contra);
    let mut m = [[0.0; 3]; 3];
    // Each off-diagonal strain e12 = e21 appears twice in the full sum.
    let members = |i: usize| -> Vec<[usize; 2]> {
        let [al, be] = PAIRS[i];
        if al == be {
            vec![[al, be]]
        } else {
            vec![[al, be], [be, al]]
        }
    };
    for i in 0..3 {
        for j in 0..3 {
            for [al, be] in members(i) {
                for [rh, si] in members(j) {
                    m[i][j] += c[al][be][rh][si];
                }
            }
        }
    }
    m
}

/// The pointwise weight D of a_ρ: a_ρ(U, V) = ∫ e(U)ᵀ D e(V) dx with
///
/// ```text
///   membrane   ε √a a^αβρσ
///   bending    ε³/12 √a a^αβρσ
///   shear      2εE/(1+ν) √a a^αβ
///   tangency   ρ I (no √a: docs/formulation.md §2 integrates ∇(r·a3)·∇(s·a3) in dx)
/// ```
pub fn strain_weights(
    p: &SurfacePoint,
    material: &Material,
    rho: f64,
) -> [[f64; N_STRAINS]; N_STRAINS] {
    let eps = material.thickness;
    let m = elasticity_matrix(material, &p.a_contra);
    let mut d = [[0.0; N_STRAINS]; N_STRAINS];
    for i in 0..3 {
        for j in 0..3 {
            d[GAMMA + i][GAMMA + j] = eps * p.sqrt_a * m[i][j];
            d[CHI + i][CHI + j] = eps.powi(3) / 12.0 * p.sqrt_a * m[i][j];
        }
    }
    let shear = 2.0 * eps * material.young / (1.0 + material.poisson) * p.sqrt_a;
    for al in 0..2 {
        for be in 0..2 {
            d[DELTA + al][DELTA + be] = shear * p.a_contra[(al, be)];
        }
        d[GRAD_NORMAL_ROTATION + al][GRAD_NORMAL_ROTATION + al] = rho;
    }
    d
}

/// The factors of the strain groups of D in one integration pass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroupFactors {
    pub membrane: f64,
    pub bending: f64,
    pub shear: f64,
}

/// One quadrature pass of an element: a rule, and (PSRI) factors on D's
/// strain groups; the load and b are integrated in the pass that has `full`.
pub struct IntegrationPass {
    pub rule: TriangleRule,
    pub factors: Option<GroupFactors>,
    pub full: bool,
}

/// The partial selective reduced integration weight of triangle T
/// (Arnold–Brezzi): α_T = min(1, ε²/h_T²), h_T the longest edge of T
/// (FreeFEM's `hTriangle`), the fraction of the membrane and shear energies
/// integrated exactly. It also holds the one zero-energy mode per triangle
/// and displacement field that the reduced rule leaves in P2⊕B3
/// (docs/shell-benchmarks.md).
pub fn psri_weight(mesh: &Mesh, t: usize, thickness: f64) -> f64 {
    let v = mesh.triangles[t].map(|i| mesh.vertices[i]);
    let h = (0..3)
        .map(|i| {
            let (p, q) = (v[i], v[(i + 1) % 3]);
            (p[0] - q[0]).hypot(p[1] - q[1])
        })
        .fold(0.0, f64::max);
    (thickness * thickness / (h * h)).min(1.0)
}

/// The quadrature passes of the layout's element: one pass of Radon's rule
/// (thesis; `p2b-mitc`, whose tied strains need no reduced rule), or the PSRI
/// pair of `p2b-psri` with α = [`psri_weight`] of the triangle (full rule:
/// bending and α (membrane + shear); the interior 3-point rule of degree 2:
/// (1 − α)(membrane + shear)).
pub fn integration_passes(layout: &ShellLayout, alpha: f64) -> Vec<IntegrationPass> {
    match layout.kind {
        ShellElementKind::P1bP0 | ShellElementKind::P2bMitc => vec![IntegrationPass {
            rule: TriangleRule::exact_for(5),
            factors: None,
            full: true,
        }],
        ShellElementKind::P2bPsri => vec![
            IntegrationPass {
                rule: TriangleRule::exact_for(5),
                factors: Some(GroupFactors {
                    membrane: alpha,
                    bending: 1.0,
                    shear: alpha,
                }),
                full: true,
            },
            IntegrationPass {
                rule: TriangleRule::exact_for(2),
                factors: Some(GroupFactors {
                    membrane: 1.0 - alpha,
                    bending: 0.0,
                    shear: 1.0 - alpha,
                }),
                full: false,
            },
        ],
    }
}

/// Element matrices and load of one triangle. Local U dofs: the fields of U
/// in block order, each with its element's local basis (thesis:
/// `component * 4 + k`, k the three hats then the bubble).
pub struct ElementMatrices {
    /// Number of local U dofs.
    pub n_u: usize,
    /// a_ρ(φ_j, φ_i), n_u × n_u row-major.
    pub stiffness: Vec<f64>,
    /// b(φ_j, χ_k) = ∫ ∇(s_j·a3)·∇χ_k dx, rows: ψ shape functions (thesis only).
    pub tangency: Vec<Vec<f64>>,
    /// L(φ_i) = ∫ f·v_i √a dx.
    pub load: Vec<f64>,
}

/// The distributed loads of L(V) = ∫ (f + p a3)·v √a dx: a body force f and
/// a pressure p along the unit normal a3.
#[derive(Debug, Clone)]
pub struct SurfaceLoad {
    pub force: [Expression; 3],
    pub pressure: Option<Expression>,
}

impl SurfaceLoad {
    /// A constant body force, no pressure.
    pub fn body(force: [f64; 3]) -> SurfaceLoad {
        SurfaceLoad {
            force: force.map(Expression::constant),
            pressure: None,
        }
    }

    /// The force per unit area f + p a3 at the chart point `p`.
    pub fn at(&self, p: &SurfacePoint) -> Vector3<f64> {
        let f = Vector3::from_fn(|c, _| self.force[c].eval(p.x));
        match &self.pressure {
            Some(pressure) => f + pressure.eval(p.x) * p.a3,
            None => f,
        }
    }
}

/// The element matrices of a_ρ, b and L on triangle t.
#[allow(clippy::too_many_arguments)]
pub fn element_matrices(
    mesh: &Mesh,
    layout: &ShellLayout,
    passes: &[IntegrationPass],
    t: usize,
    chart: &Chart,
    material: &Material,
    rho: f64,
    load: &SurfaceLoad,
) -> ElementMatrices {
    let g = TriangleGeometry::new(mesh, t);
    let u_fields: Vec<&ShellField> = layout.u_fields().collect();
    let n_u: usize = u_fields.iter().map(|f| f.element.n_local()).sum();
    let psi_element = layout.psi().map(|f| layout.fields[f].element);
    let n_psi = psi_element.map_or(0, |e| e.n_local());
    let mut el = ElementMatrices {
        n_u,
        stiffness: vec![0.0; n_u * n_u],
        tangency: vec![vec![0.0; n_u]; n_psi],
        load: vec![0.0; n_u],
    };
    let mut e = vec![[0.0; N_STRAINS]; n_u];
    let tied =
        (layout.kind == ShellElementKind::P2bMitc).then(|| TiedStrains::new(&g, &u_fields, chart));
    for pass in passes {
        for q in quad_points(&g, t, &pass.rule) {
            let p = chart.at(q.x);
            let mut d = strain_weights(&p, material, rho);
            if let Some(f) = pass.factors {
                scale_strain_groups(&mut d, f);
            }
            let force = if pass.full {
                load.at(&p)
            } else {
                Vector3::zeros()
            };
            // E: strains of every local U basis function; DE = D·E.
            for_each_shape_strain(&g, &u_fields, &p, q.lambda, |i, role, value, strains| {
                e[i] = strains;
                if let (FieldRole::Displacement(c), true) = (role, pass.full) {
                    el.load[i] += q.weight * force[c] * value * p.sqrt_a;
                }
            });
            if let Some(tied) = &tied {
                tied.tie(q.lambda, &mut e);
            }
            let de: Vec<StrainVector> = e
                .iter()
                .map(|ej| std::array::from_fn(|a| (0..N_STRAINS).map(|b| d[a][b] * ej[b]).sum()))
                .collect();
            for i in 0..n_u {
                for j in 0..n_u {
                    let s: f64 = (0..N_STRAINS).map(|a| e[i][a] * de[j][a]).sum();
                    el.stiffness[i * n_u + j] += q.weight * s;
                }
            }
            // b: ∇(s·a3)·∇χ, the last two strains against the ψ shape gradients.
            if let (Some(psi), true) = (psi_element, pass.full) {
                let basis = psi.basis(q.lambda);
                for k in 0..n_psi {
                    let grad = g.gradient(basis.d_lambda[k]);
                    for j in 0..n_u {
                        let gn = &e[j][GRAD_NORMAL_ROTATION..];
                        el.tangency[k][j] += q.weight * (gn[0] * grad[0] + gn[1] * grad[1]);
                    }
                }
            }
        }
    }
    el
}

/// Calls `visit(i, role, value, strains)` for every local U shape function i
/// at the point λ of T (the fields in block order, each with its element's
/// local basis): its field's role, its value and its generalised strains at
/// the chart point `p`.
fn for_each_shape_strain(
    g: &TriangleGeometry,
    fields: &[&ShellField],
    p: &SurfacePoint,
    lambda: [f64; 3],
    mut visit: impl FnMut(usize, FieldRole, f64, StrainVector),
) {
    let mut i = 0;
    for field in fields {
        let basis = field.element.basis(lambda);
        for k in 0..basis.n {
            let grad = g.gradient(basis.d_lambda[k]);
            visit(
                i,
                field.role,
                basis.values[k],
                field_strains(p, field.role, basis.values[k], grad),
            );
            i += 1;
        }
    }
}

/// Scales the membrane, bending and shear blocks of D (PSRI passes).
fn scale_strain_groups(d: &mut [[f64; N_STRAINS]; N_STRAINS], f: GroupFactors) {
    for (start, len, factor) in [
        (GAMMA, 3, f.membrane),
        (CHI, 3, f.bending),
        (DELTA, 2, f.shear),
    ] {
        for row in d.iter_mut().skip(start).take(len) {
            for v in row.iter_mut() {
                *v *= factor;
            }
        }
    }
}

/// The global indices of the local U dofs (and of ψ's) of triangle t.
fn element_globals(mesh: &Mesh, layout: &ShellLayout, t: usize) -> (Vec<usize>, Vec<usize>) {
    let mut u = Vec::new();
    let mut psi = Vec::new();
    for field in &layout.fields {
        let (dofs, n) = Space::new(mesh, field.element).element_dofs(t);
        let target = if field.role == FieldRole::TangencyMultiplier {
            &mut psi
        } else {
            &mut u
        };
        target.extend(dofs[..n].iter().map(|d| field.offset + d));
    }
    (u, psi)
}

/// The matrix over the free dofs of `numbering` — the saddle matrix
/// [[K_ρ, Bᵀ], [B, 0]] with ψ, K alone without; homogeneous conditions, so
/// a clamped dof's rows and columns are dropped — and the full load vector
/// (zero in the ψ block). Assembled straight into compressed columns
/// ([`ElementMatrix`]): U dofs couple within a triangle, ψ's with U's only.
pub fn assemble_shell_layout(
    mesh: &Mesh,
    layout: &ShellLayout,
    chart: &Chart,
    material: &Material,
    rho: f64,
    load: &SurfaceLoad,
    numbering: &DofNumbering,
) -> (SparseColMat<usize, f64>, Vec<f64>) {
    let free = |globals: &[usize]| -> Vec<Option<usize>> {
        globals.iter().map(|&d| numbering.free_index(d)).collect()
    };
    let mut a = ElementMatrix::new(numbering.n_free(), mesh.n_triangles(), |t, dofs| {
        let (u, psi) = element_globals(mesh, layout, t);
        dofs.coupled.extend(free(&u).into_iter().flatten());
        dofs.multipliers.extend(free(&psi).into_iter().flatten());
    });
    let mut f = vec![0.0; layout.n_total()];
    for t in 0..mesh.n_triangles() {
        let passes = integration_passes(layout, psri_weight(mesh, t, material.thickness));
        let el = element_matrices(mesh, layout, &passes, t, chart, material, rho, load);
        let (u, psi) = element_globals(mesh, layout, t);
        for i in 0..el.n_u {
            f[u[i]] += el.load[i];
        }
        let n_u = el.n_u;
        let mut dofs = free(&u);
        dofs.extend(free(&psi));
        a.add(&dofs, |i, j| match (i < n_u, j < n_u) {
            (true, true) => el.stiffness[i * n_u + j],
            (false, true) => el.tangency[i - n_u][j],
            (true, false) => el.tangency[j - n_u][i],
            (false, false) => 0.0,
        });
    }
    (a.into_sparse(), f)
}

/// The thesis' saddle matrix over every dof (nothing clamped) and its load
/// (see [`assemble_shell_layout`]).
pub fn assemble_shell_full(
    mesh: &Mesh,
    chart: &Chart,
    material: &Material,
    rho: f64,
    load: [f64; 3],
) -> (SparseColMat<usize, f64>, Vec<f64>) {
    let load = SurfaceLoad::body(load);
    let layout = ShellLayout::new(mesh);
    let numbering = DofNumbering::all_free(layout.n_total());
    assemble_shell_layout(mesh, &layout, chart, material, rho, &load, &numbering)
}

/// The shell without contact: the saddle matrix [[K_ρ, Bᵀ], [B, 0]] over the
/// free dofs (U block, then ψ block), F = L over the free U dofs and 0 for ψ,
/// n_primal = number of free U dofs, and the numbering of the clamped dofs.
pub fn assemble_shell(
    mesh: &Mesh,
    chart: &Chart,
    material: &Material,
    rho: f64,
    load: [f64; 3],
    clamped_tags: Option<&[i32]>,
) -> (ContactProblem, DofNumbering) {
    let numbering = clamped_numbering(mesh, clamped_tags);
    let layout = ShellLayout::new(mesh);
    let load = SurfaceLoad::body(load);
    let (a, f_full) = assemble_shell_layout(mesh, &layout, chart, material, rho, &load, &numbering);
    let problem = restrict_shell(&layout, a, &f_full, &numbering);
    (problem, numbering)
}

/// The shell problem over the free dofs of `numbering` from its matrix
/// `a` over them ([`assemble_shell_layout`]) and the full load: F
/// restricted, n_primal = number of free U dofs (they come first in block
/// order). With ψ the matrix is a symmetric saddle-point matrix; without
/// (the tangent-rotation element, or the plate reduction that eliminated it)
/// K is symmetric positive definite.
pub fn restrict_shell(
    layout: &ShellLayout,
    a: SparseColMat<usize, f64>,
    f_full: &[f64],
    numbering: &DofNumbering,
) -> ContactProblem {
    let psi_start = layout
        .psi()
        .map_or(layout.n_total(), |f| layout.fields[f].offset);
    let n_primal = numbering
        .free_dofs
        .iter()
        .filter(|&&d| d < psi_start)
        .count();
    let kind = if n_primal < numbering.free_dofs.len() {
        MatrixKind::SymmetricSaddle { n_primal }
    } else {
        MatrixKind::SymmetricPositiveDefinite
    };
    // Every field's bubbles (ψ's too: a triangle's ψ bubble couples only
    // with its own U bubbles and vertices).
    let bubbles: Vec<usize> = layout
        .fields
        .iter()
        .filter(|f| f.element.has_bubble())
        .map(|f| f.offset + f.len - layout.n_triangles)
        .collect();
    ContactProblem {
        matrix: a,
        kind,
        rhs: numbering.restrict(f_full),
        n_primal,
        constraint: None,
        interior: Some(numbering.interior_groups(&bubbles, layout.n_triangles)),
    }
}

/// The dofs of a field on one boundary edge and their basis functions at
/// the edge parameter s ∈ [0, 1]: the two vertex hats (P1⊕B3: the bubble
/// vanishes on the edge), or the quadratic Lagrange functions at the two
/// vertices and the midpoint (P2, P2⊕B3).
fn edge_basis(
    element: Element,
    vertices: [usize; 2],
    midpoint: Option<usize>,
    s: f64,
) -> Vec<(usize, f64)> {
    match (element, midpoint) {
        (Element::P2 | Element::P2Bubble, Some(m)) => vec![
            (vertices[0], (1.0 - s) * (1.0 - 2.0 * s)),
            (vertices[1], s * (2.0 * s - 1.0)),
            (m, 4.0 * s * (1.0 - s)),
        ],
        _ => vec![(vertices[0], 1.0 - s), (vertices[1], s)],
    }
}

/// The degree of the Gauss rule of the edge loads (5 points).
const EDGE_RULE_DEGREE: usize = 9;

/// The points where [`add_edge_load`] evaluates the loads on the boundary
/// edges with tag `tag`.
pub fn edge_quadrature_points(mesh: &Mesh, tag: i32) -> Vec<[f64; 2]> {
    let rule = SegmentRule::exact_for(EDGE_RULE_DEGREE);
    mesh.boundary_edges
        .iter()
        .filter(|e| e.tag == tag)
        .flat_map(|edge| {
            let [p, q] = edge.vertices.map(|v| mesh.vertices[v]);
            rule.points
                .iter()
                .map(move |&s| [p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1])])
        })
        .collect()
}

/// Adds the edge loads ∫_γ1 (N·v + M·s) ℓ dσ to a full load vector, on the
/// boundary edges with tag `tag`; ℓ = |a_α ς^α| is the chart's length element
/// along the edge (ς the unit tangent in ω). With tangent rotations s =
/// θ^β a_β, the moment acts on θ^β through M·a_β. ℓ is not polynomial, so a
/// 5-point Gauss rule.
pub fn add_edge_load(
    mesh: &Mesh,
    layout: &ShellLayout,
    chart: &Chart,
    tag: i32,
    traction: &[Expression; 3],
    moment: &[Expression; 3],
    f_full: &mut [f64],
) {
    let rule = SegmentRule::exact_for(EDGE_RULE_DEGREE);
    let edges = mesh.edge_lookup();
    for edge in mesh.boundary_edges.iter().filter(|e| e.tag == tag) {
        let [a, b] = edge.vertices;
        let midpoint = edges
            .get(&[a.min(b), a.max(b)])
            .map(|e| mesh.n_vertices() + e);
        let [p, q] = edge.vertices.map(|v| mesh.vertices[v]);
        let d = [q[0] - p[0], q[1] - p[1]];
        let length = d[0].hypot(d[1]);
        for (&s, &w) in rule.points.iter().zip(&rule.weights) {
            let x = [p[0] + s * d[0], p[1] + s * d[1]];
            let sp = chart.at(x);
            let ell = (sp.a1 * (d[0] / length) + sp.a2 * (d[1] / length)).norm();
            let traction = traction.each_ref().map(|t| t.eval(x));
            let moment = Vector3::from(moment.each_ref().map(|m| m.eval(x)));
            for element in [Element::P1Bubble, Element::P2, Element::P2Bubble] {
                for (dof, value) in edge_basis(element, edge.vertices, midpoint, s) {
                    let weight = w * length * ell * value;
                    for field in layout.u_fields().filter(|f| f.element == element) {
                        let density = match field.role {
                            FieldRole::Displacement(c) => traction[c],
                            FieldRole::CartesianRotation(c) => moment[c],
                            FieldRole::TangentRotation(be) => moment.dot(sp.a(be)),
                            FieldRole::TangencyMultiplier => 0.0,
                        };
                        f_full[field.offset + dof] += weight * density;
                    }
                }
            }
        }
    }
}

/// Adds a concentrated force F·v(x₀) to a full load vector: x₀ has the
/// barycentric coordinates `l` in triangle `t`, and each displacement field's
/// basis functions are evaluated there (at a vertex: 1 on that vertex's dof,
/// 0 elsewhere, so the load is exact).
pub fn add_point_load(
    mesh: &Mesh,
    layout: &ShellLayout,
    t: usize,
    l: [f64; 3],
    force: [f64; 3],
    f_full: &mut [f64],
) {
    for field in layout.u_fields() {
        let FieldRole::Displacement(c) = field.role else {
            continue;
        };
        let basis = field.element.basis(l);
        let (dofs, n) = Space::new(mesh, field.element).element_dofs(t);
        for k in 0..n {
            f_full[field.offset + dofs[k]] += force[c] * basis.values[k];
        }
    }
}

/// Rescales the tangency multiplier: the matrix becomes [[K_ρ, σBᵀ], [σB, 0]],
/// the unknown ψ' = ψ/σ, and the residual of the ψ rows σ·BU. U is unchanged.
///
/// Why: K_ρ has entries up to ~max(Eε, ρ) while B's are O(1). For large ρ
/// (the thesis goes to 1e9) the unscaled saddle matrix defeats LU with
/// partial pivoting (on the thesis mesh, ρ = 1e9 fails `factorize_checked`
/// with a test residual 4e-5), and even at ρ = 1e3 the plain solve leaves
/// ‖BU‖ ~ 1e-10 where the scaled one gives 1e-16. [`balanced_tangency_scale`]
/// is a σ that works for ρ from 1 to 1e9.
pub fn scale_tangency_multiplier(problem: &mut ContactProblem, sigma: f64) {
    let np = problem.n_primal;
    let (symbolic, values) = problem.matrix.parts_mut();
    let (col_ptr, row_idx) = (symbolic.col_ptr(), symbolic.row_idx());
    for j in 0..symbolic.ncols() {
        for k in col_ptr[j]..col_ptr[j + 1] {
            let (row_multiplier, col_multiplier) = (row_idx[k] >= np, j >= np);
            if row_multiplier != col_multiplier {
                values[k] *= sigma;
            } else if row_multiplier {
                // The zero block stays zero; kept general for safety.
                values[k] *= sigma * sigma;
            }
        }
    }
    // F is zero in the ψ rows, so the right-hand side needs no change.
}

/// σ = max|K_ρ| / max|B|: the ψ rows get the magnitude of the U rows.
pub fn balanced_tangency_scale(problem: &ContactProblem) -> f64 {
    let np = problem.n_primal;
    let symbolic = problem.matrix.symbolic();
    let (col_ptr, row_idx, values) = (symbolic.col_ptr(), symbolic.row_idx(), problem.matrix.val());
    let (mut k_max, mut b_max) = (0.0f64, 0.0f64);
    for j in 0..symbolic.ncols() {
        for k in col_ptr[j]..col_ptr[j + 1] {
            let v = values[k].abs();
            if j < np && row_idx[k] < np {
                k_max = k_max.max(v);
            } else {
                b_max = b_max.max(v);
            }
        }
    }
    if k_max > 0.0 && b_max > 0.0 {
        k_max / b_max
    } else {
        1.0
    }
}

/// The P1 interpolant of the obstacle function Φ = (ε/2 a3 − φ)·e3 at the
/// vertices, for the rigid plane z = 0.
pub fn obstacle_at_vertices(mesh: &Mesh, chart: &Chart, material: &Material) -> Vec<f64> {
    mesh.vertices
        .iter()
        .map(|&x| obstacle_function(&chart.at(x), material.thickness))
        .collect()
}

/// The contact with the rigid plane z = 0 (docs/formulation.md §2, P0 multiplier, one row per
/// triangle): C row T = ∫_T (v − ε/2 s)·e3 dx (no √a) over the free dofs of
/// `numbering` (ψ columns are empty), g_T = ∫_T Φ_h with Φ_h the P1
/// interpolant of Φ, weights |T|. The mean gap is ḡ_T = (CU − g)_T / |T|.
pub fn rigid_plane_constraint(
    mesh: &Mesh,
    chart: &Chart,
    material: &Material,
    numbering: &DofNumbering,
) -> Constraint {
    let phi = obstacle_at_vertices(mesh, chart, material);
    plane_constraint(mesh, material, &phi, numbering)
}

/// The P0 contact constraint (u − ε/2 r)·e3 ≥ Φ_h on triangle means, given
/// the obstacle's vertex values Φ_h (for the plane z = z0: Φ + z0).
pub fn plane_constraint(
    mesh: &Mesh,
    material: &Material,
    phi: &[f64],
    numbering: &DofNumbering,
) -> Constraint {
    let layout = ShellLayout::new(mesh);
    let space = Space::new(mesh, Element::P1Bubble);
    let rule = TriangleRule::exact_for(5);
    let half_eps = 0.5 * material.thickness;
    // u3 and r3 with their constant weights (a3 plays no part: r3 = r·e3).
    let terms: Vec<(usize, f64)> = (0..layout.fields.len())
        .filter_map(|f| constraint_factor(layout.fields[f].role, None, half_eps).map(|w| (f, w)))
        .collect();
    let mut c_full = Triplets::new(mesh.n_triangles(), layout.n_total());
    let mut obstacle = Vec::with_capacity(mesh.n_triangles());
    let mut weights = Vec::with_capacity(mesh.n_triangles());
    for t in 0..mesh.n_triangles() {
        let g = TriangleGeometry::new(mesh, t);
        let (scalar, _) = space.element_dofs(t);
        // ∫_T φ_k dx for the four shape functions (|T|/3 and 9|T|/20).
        const N_LOCAL: usize = 4;
        let mut integrals = [0.0; N_LOCAL];
        for q in quad_points(&g, t, &rule) {
            let b = Element::P1Bubble.basis(q.lambda);
            for k in 0..N_LOCAL {
                integrals[k] += q.weight * b.values[k];
            }
        }
        for k in 0..N_LOCAL {
            for (f, factor) in &terms {
                c_full.push(t, layout.index(*f, scalar[k]), factor * integrals[k]);
            }
        }
        let tri = mesh.triangles[t];
        obstacle.push(g.area * (phi[tri[0]] + phi[tri[1]] + phi[tri[2]]) / 3.0);
        weights.push(g.area);
    }
    let rows = DofNumbering::all_free(mesh.n_triangles());
    let zeros = vec![0.0; layout.n_total()];
    let (c, _) = eliminate(c_full, &rows, numbering, &zeros);
    Constraint {
        matrix: c.into_sparse(),
        obstacle,
        weights,
    }
}

/// The weight of a field in the constraint function (u − ε/2 r)·e3 at a
/// point of the chart: 1 for u3, −ε/2 for r3, −ε/2 a_β·e3 for θ^β (the point
/// is needed for that one; None asks only whether the field enters, with a
/// placeholder weight), None for the fields that do not enter.
pub fn constraint_factor(role: FieldRole, p: Option<&SurfacePoint>, half_eps: f64) -> Option<f64> {
    match role {
        FieldRole::Displacement(2) => Some(1.0),
        FieldRole::CartesianRotation(2) => Some(-half_eps),
        FieldRole::TangentRotation(be) => Some(-half_eps * p.map_or(1.0, |p| p.a(be).z)),
        _ => None,
    }
}

/// The contact with the plane z = level with P1 multipliers (one per vertex,
/// as the membrane's P2–P1 pair), for either element's layout:
/// C row i = ∫ (v − ε/2 s)·e3 μ_i dx over the free dofs of `numbering`, with
/// s·e3 = θ^β a_β·e3; g_i = ∫ Φ μ_i dx with Φ = (ε/2 a3 − φ)·e3 + level at
/// the quadrature points; weights w_i = ∫ μ_i dx (the lumped P1 mass, whose
/// Riesz map makes the dual projection a nodal max). The mean gap is
/// ḡ_i = (CU − g)_i / w_i. Radon's 7-point rule (no √a, as the thesis' C).
pub fn nodal_plane_constraint(
    mesh: &Mesh,
    layout: &ShellLayout,
    chart: &Chart,
    material: &Material,
    height: &Expression,
    numbering: &DofNumbering,
) -> Constraint {
    let rule = TriangleRule::exact_for(5);
    let half_eps = 0.5 * material.thickness;
    let nv = mesh.n_vertices();
    let mut c_full = Triplets::new(nv, layout.n_total());
    let mut obstacle = vec![0.0; nv];
    let mut weights = vec![0.0; nv];
    // The fields that enter (u − ε/2 r)·e3.
    let terms: Vec<&ShellField> = layout
        .u_fields()
        .filter(|f| constraint_factor(f.role, None, half_eps).is_some())
        .collect();
    for t in 0..mesh.n_triangles() {
        let g = TriangleGeometry::new(mesh, t);
        let tri = mesh.triangles[t];
        // ∫_T factor · φ_k μ_i per field, vertex i and local dof k.
        let mut local = vec![[[0.0; crate::space::MAX_LOCAL]; 3]; terms.len()];
        for q in quad_points(&g, t, &rule) {
            let p = chart.at(q.x);
            for (field, rows) in terms.iter().zip(local.iter_mut()) {
                let factor =
                    constraint_factor(field.role, Some(&p), half_eps).expect("a constraint term");
                let b = field.element.basis(q.lambda);
                for (i, row) in rows.iter_mut().enumerate() {
                    for k in 0..b.n {
                        row[k] += q.weight * q.lambda[i] * factor * b.values[k];
                    }
                }
            }
            let phi = obstacle_function(&p, material.thickness) + height.eval([p.phi.x, p.phi.y]);
            for i in 0..3 {
                obstacle[tri[i]] += q.weight * phi * q.lambda[i];
                weights[tri[i]] += q.weight * q.lambda[i];
            }
        }
        for (field, rows) in terms.iter().zip(&local) {
            let (dofs, n) = Space::new(mesh, field.element).element_dofs(t);
            for (i, row) in rows.iter().enumerate() {
                for k in 0..n {
                    c_full.push(tri[i], field.offset + dofs[k], row[k]);
                }
            }
        }
    }
    let rows = DofNumbering::all_free(nv);
    let zeros = vec![0.0; layout.n_total()];
    let (c, _) = eliminate(c_full, &rows, numbering, &zeros);
    Constraint {
        matrix: c.into_sparse(),
        obstacle,
        weights,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hypar() -> Chart {
        Chart::HyperbolicParaboloid {
            r: 50.0 * std::f64::consts::SQRT_2,
            offset: 1.4,
        }
    }

    fn material() -> Material {
        Material {
            young: 2.85e4,
            poisson: 0.4,
            thickness: 0.8,
        }
    }

    #[test]
    fn elasticity_matrix_reproduces_the_full_sum() {
        let mat = material();
        let p = Chart::HyperbolicParaboloid {
            r: 1.7,
            offset: 0.0,
        }
        .at([0.4, -0.9]);
        let c = mat.elasticity(&p.a_contra);
        let m = elasticity_matrix(&mat, &p.a_contra);
        let (x, y) = ([0.3, -1.2, 0.7], [-0.5, 0.8, 1.1]);
        let full = |v: [f64; 3]| [[v[0], v[2]], [v[2], v[1]]];
        let (fx, fy) = (full(x), full(y));
        let mut sum = 0.0;
        for al in 0..2 {
            for be in 0..2 {
                for rh in 0..2 {
                    for si in 0..2 {
                        sum += c[al][be][rh][si] * fx[al][be] * fy[rh][si];
                    }
                }
            }
        }
        let vec: f64 = (0..3)
            .map(|i| (0..3).map(|j| x[i] * m[i][j] * y[j]).sum::<f64>())
            .sum();
        assert!(
            (sum - vec).abs() < 1e-12 * sum.abs().max(1.0),
            "{sum} vs {vec}"
        );
    }

    /// An infinitesimal rigid motion moves φ + x3 a3 by a + ω×(φ + x3 a3):
    /// U = (a + ω×φ, ω×a3). It has no strain at all (and r·a3 = 0).
    #[test]
    fn rigid_motions_are_strain_free() {
        let charts = [
            hypar(),
            Chart::HyperbolicParaboloid {
                r: 1.7,
                offset: 0.3,
            },
            Chart::Cylinder {
                radius: 2.0,
                height: 1.0,
            },
            Chart::Plate { height: 0.5 },
        ];
        let omega = Vector3::new(0.3, -0.7, 0.2);
        for chart in charts {
            for x in [[0.1, 0.2], [-0.6, 0.9], [1.1, -0.4]] {
                let p = chart.at(x);
                let du = [omega.cross(&p.a1), omega.cross(&p.a2)];
                let r = omega.cross(&p.a3);
                let dr = [omega.cross(&p.d_a3[0]), omega.cross(&p.d_a3[1])];
                let e = generalized_strains(&p, &du, &r, &dr);
                for (i, v) in e.iter().enumerate() {
                    assert!(v.abs() < 1e-14, "{chart:?} at {x:?}: strain {i} = {v}");
                }
                // A non-rigid field is not strain-free (the test has teeth).
                let e = generalized_strains(&p, &du, &omega, &dr);
                assert!(e[DELTA].abs() + e[DELTA + 1].abs() > 1e-3);
            }
        }
    }

    /// The element stiffness is symmetric and positive semi-definite, and
    /// the assembled load is ∫ f √a dx per displacement component.
    #[test]
    fn element_matrices_symmetric_with_load() {
        let mesh = Mesh::from_parts(
            vec![[0.0, 0.0], [3.0, 0.5], [1.0, 2.0]],
            vec![[0, 1, 2]],
            [[0, 1], [1, 2], [2, 0]]
                .map(|vertices| crate::mesh::BoundaryEdge { vertices, tag: 1 })
                .to_vec(),
            Default::default(),
            Default::default(),
        )
        .unwrap();
        // Both elements: the u3 basis integrates to |T| + 9|T|/20 (the bubble).
        for (kind, mass) in [
            (ShellElementKind::P1bP0, 1.45),
            (ShellElementKind::P2bPsri, 1.45),
            (ShellElementKind::P2bMitc, 1.45),
        ] {
            let layout = ShellLayout::for_element(&mesh, kind);
            let passes = integration_passes(&layout, psri_weight(&mesh, 0, 0.8));
            let el = element_matrices(
                &mesh,
                &layout,
                &passes,
                0,
                &hypar(),
                &material(),
                1e3,
                &SurfaceLoad::body([0.0, 0.0, -0.25]),
            );
            let n = el.n_u;
            let scale = el.stiffness.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for i in 0..n {
                for j in 0..n {
                    let (a, b) = (el.stiffness[i * n + j], el.stiffness[j * n + i]);
                    assert!((a - b).abs() < 1e-13 * scale, "{kind:?}");
                }
                assert!(el.stiffness[i * n + i] >= 0.0);
            }
            let total: f64 = el.load.iter().sum();
            // √a ≈ 1 for this flat hypar.
            let area = mesh.area(0);
            assert!(
                (total / (-0.25 * area * mass) - 1.0).abs() < 1e-3,
                "{kind:?}: {total} vs {}",
                -0.25 * area * mass
            );
        }
    }

    /// The assembled (unclamped) K_ρ annihilates rigid motions that P1⊕B3
    /// represents exactly: translations on any chart, and on a plate also the
    /// rotations (u = ω×φ is affine, r = ω×e3 constant).
    #[test]
    fn assembled_stiffness_kernel() {
        let mesh = Mesh::from_parts(
            vec![[0.0, 0.0], [2.0, 0.3], [1.6, 1.9], [-0.4, 1.2]],
            vec![[0, 1, 2], [0, 2, 3]],
            [[0, 1], [1, 2], [2, 3], [3, 0]]
                .map(|vertices| crate::mesh::BoundaryEdge { vertices, tag: 1 })
                .to_vec(),
            Default::default(),
            Default::default(),
        )
        .unwrap();
        let layout = ShellLayout::new(&mesh);
        let space = Space::new(&mesh, Element::P1Bubble);
        let field = |f: &dyn Fn([f64; 2]) -> [f64; 6]| {
            let mut x = vec![0.0; layout.n_total()];
            for c in 0..N_U_COMPONENTS {
                let values = space.interpolate(|p| f(p)[c]);
                x[layout.index(c, 0)..layout.index(c + 1, 0)].copy_from_slice(&values);
            }
            x
        };
        let omega = Vector3::new(0.3, -0.7, 0.2);
        let plate = Chart::Plate { height: 0.5 };
        let cases: Vec<(Chart, Vec<f64>)> = vec![
            (hypar(), field(&|_| [0.2, -0.4, 1.0, 0.0, 0.0, 0.0])),
            (
                Chart::HyperbolicParaboloid {
                    r: 1.7,
                    offset: 0.3,
                },
                field(&|_| [0.2, -0.4, 1.0, 0.0, 0.0, 0.0]),
            ),
            (
                plate.clone(),
                field(&|p| {
                    let u = omega.cross(&plate.at(p).phi);
                    let r = omega.cross(&Vector3::z());
                    [u.x, u.y, u.z, r.x, r.y, r.z]
                }),
            ),
        ];
        for (chart, x) in cases {
            let (a, _) = assemble_shell_full(&mesh, &chart, &material(), 1e3, [0.0; 3]);
            let scale = crate::assembly::norm_inf(a.val());
            let ax = crate::assembly::mat_vec(&a, &x);
            let worst = ax.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(worst < 1e-12 * scale, "{chart:?}: |K U_rigid| = {worst:e}");
        }
    }
}
