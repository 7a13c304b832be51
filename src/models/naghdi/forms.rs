//! The forms of the Cartesian Naghdi shell (SPEC §2, thesis (1.12), (2.14)) and
//! the algebraic problem of the discrete Problem 9 without and with contact.
//!
//! Unknowns: seven scalar P1⊕B3 fields in blocks, u1, u2, u3, r1, r2, r3 (the
//! Cartesian displacement u and rotation r, U = (u, r)) and the tangency
//! multiplier ψ; the global index of scalar dof d of component c is
//! `c * n_scalar + d` with n_scalar = Nv + Nt ([`ShellLayout`]). The contact
//! multiplier λ is P0, one per triangle.
//!
//! At each quadrature point the exact chart geometry ([`SurfacePoint`]) is
//! evaluated and every local basis function (one scalar shape function placed
//! in one component of U) is mapped to its vector of generalised strains
//! ([`generalized_strains`]); the element matrix is K_T = Σ_q w_q Eᵀ D E with
//! the block-diagonal weight D of [`strain_weights`]. The rule is Radon's
//! 7-point rule (FreeFEM's default `qf5pT`), as a FreeFEM script would use.
//!
//! [`assemble_shell`] gives the saddle problem without contact,
//! [`rigid_plane_constraint`] the P0 contact with the plane z = 0, and
//! [`scale_tangency_multiplier`] rebalances the ψ block for large ρ.

use super::geometry::{obstacle_function, Chart, Material, SurfacePoint};
use crate::assembly::{eliminate, quad_points, DofNumbering, Triplets};
use crate::linalg::MatrixKind;
use crate::mesh::Mesh;
use crate::quadrature::{SegmentRule, TriangleRule};
use crate::solvers::{Constraint, ContactProblem};
use crate::space::{Element, Space, TriangleGeometry};
use nalgebra::{Matrix2, Vector3};

/// Number of components of U = (u, r).
pub const N_U_COMPONENTS: usize = 6;
/// Number of scalar fields: U and ψ.
pub const N_COMPONENTS: usize = 7;
/// Component index of the tangency multiplier ψ.
pub const PSI: usize = 6;
/// Names of the components, in block order.
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

/// Local basis functions of P1⊕B3 on one triangle.
const N_LOCAL: usize = 4;
/// Local U dofs on one triangle: local index `component * N_LOCAL + k`.
const N_LOCAL_U: usize = N_U_COMPONENTS * N_LOCAL;

/// The symmetric index pairs (α, β) of the strain components 11, 22, 12.
const PAIRS: [[usize; 2]; 3] = [[0, 0], [1, 1], [0, 1]];

/// Dof layout of the seven P1⊕B3 fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShellLayout {
    pub n_vertices: usize,
    pub n_triangles: usize,
}

impl ShellLayout {
    pub fn new(mesh: &Mesh) -> Self {
        ShellLayout {
            n_vertices: mesh.n_vertices(),
            n_triangles: mesh.n_triangles(),
        }
    }

    /// Dofs of one scalar P1⊕B3 field: Nv vertex values, then Nt bubbles.
    pub fn n_scalar(&self) -> usize {
        self.n_vertices + self.n_triangles
    }

    /// All dofs of U and ψ, boundary dofs included.
    pub fn n_total(&self) -> usize {
        N_COMPONENTS * self.n_scalar()
    }

    /// Global index of scalar dof `scalar` of `component`.
    pub fn index(&self, component: usize, scalar: usize) -> usize {
        component * self.n_scalar() + scalar
    }

    /// The coefficients of one component in a full vector.
    pub fn component<'a>(&self, full: &'a [f64], component: usize) -> &'a [f64] {
        let n = self.n_scalar();
        &full[component * n..(component + 1) * n]
    }

    /// The thesis' dof count (SPEC §2): U and ψ with boundary dofs, plus the
    /// P0 contact multipliers, 7·(Nv + Nt) + Nt.
    pub fn thesis_dof_count(&self) -> usize {
        self.n_total() + self.n_triangles
    }
}

/// The numbering of the clamped shell: u = r = ψ = 0 at the vertices of the
/// boundary parts with tags in `clamped_tags` (all of ∂ω if None); bubbles
/// vanish on the boundary and stay free. Free dofs keep the block order, so
/// the free U dofs come first and the free ψ dofs last.
pub fn clamped_numbering(mesh: &Mesh, clamped_tags: Option<&[i32]>) -> DofNumbering {
    let scalar = Space::new(mesh, Element::P1Bubble).boundary_dof_mask(clamped_tags);
    let fixed: Vec<bool> = (0..N_COMPONENTS)
        .flat_map(|_| scalar.iter().copied())
        .collect();
    DofNumbering::from_fixed_mask(&fixed)
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
/// `component` of U (0..3: u_c, 3..6: r_{c−3}).
pub fn shape_strains(
    p: &SurfacePoint,
    component: usize,
    value: f64,
    grad: [f64; 2],
) -> StrainVector {
    let zero = Vector3::zeros();
    let unit = Vector3::ith(component % 3, 1.0);
    let d = [unit * grad[0], unit * grad[1]];
    if component < 3 {
        generalized_strains(p, &d, &zero, &[zero; 2])
    } else {
        generalized_strains(p, &[zero; 2], &(unit * value), &d)
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
///   tangency   ρ I (no √a: SPEC §2 integrates ∇(r·a3)·∇(s·a3) in dx)
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

/// Element matrices and load of one triangle, local U dofs ordered
/// `component * 4 + k` (k: the three hats then the bubble).
pub struct ShellElement {
    /// a_ρ(φ_j, φ_i), 24 × 24.
    pub stiffness: [[f64; N_LOCAL_U]; N_LOCAL_U],
    /// b(φ_j, χ_k) = ∫ ∇(s_j·a3)·∇χ_k dx, 4 × 24 (rows: ψ shape functions).
    pub tangency: [[f64; N_LOCAL_U]; N_LOCAL],
    /// L(φ_i) = ∫ f·v_i √a dx, 24.
    pub load: [f64; N_LOCAL_U],
}

/// The element matrices of a_ρ, b and L on triangle t.
pub fn shell_element(
    mesh: &Mesh,
    t: usize,
    rule: &TriangleRule,
    chart: &Chart,
    material: &Material,
    rho: f64,
    load: [f64; 3],
) -> ShellElement {
    let g = TriangleGeometry::new(mesh, t);
    let mut el = ShellElement {
        stiffness: [[0.0; N_LOCAL_U]; N_LOCAL_U],
        tangency: [[0.0; N_LOCAL_U]; N_LOCAL],
        load: [0.0; N_LOCAL_U],
    };
    for q in quad_points(&g, t, rule) {
        let p = chart.at(q.x);
        let d = strain_weights(&p, material, rho);
        let basis = Element::P1Bubble.basis(q.lambda);
        let grads: [[f64; 2]; N_LOCAL] = std::array::from_fn(|k| g.gradient(basis.d_lambda[k]));
        // E: strains of every local U basis function; DE = D·E.
        let mut e = [[0.0; N_STRAINS]; N_LOCAL_U];
        for c in 0..N_U_COMPONENTS {
            for k in 0..N_LOCAL {
                e[c * N_LOCAL + k] = shape_strains(&p, c, basis.values[k], grads[k]);
            }
        }
        let de: Vec<StrainVector> = e
            .iter()
            .map(|ej| std::array::from_fn(|a| (0..N_STRAINS).map(|b| d[a][b] * ej[b]).sum()))
            .collect();
        for i in 0..N_LOCAL_U {
            for j in 0..N_LOCAL_U {
                let s: f64 = (0..N_STRAINS).map(|a| e[i][a] * de[j][a]).sum();
                el.stiffness[i][j] += q.weight * s;
            }
        }
        // b: ∇(s·a3)·∇χ, the last two strains against the ψ shape gradients.
        for k in 0..N_LOCAL {
            for j in 0..N_LOCAL_U {
                let gn = &e[j][GRAD_NORMAL_ROTATION..];
                el.tangency[k][j] += q.weight * (gn[0] * grads[k][0] + gn[1] * grads[k][1]);
            }
        }
        // L: f·v √a for the displacement components.
        for c in 0..3 {
            for k in 0..N_LOCAL {
                el.load[c * N_LOCAL + k] += q.weight * load[c] * basis.values[k] * p.sqrt_a;
            }
        }
    }
    el
}

/// The full (unclamped) saddle matrix [[K_ρ, Bᵀ], [B, 0]] over all 7·n_scalar
/// dofs, and the full load vector (zero in the ψ block).
pub fn assemble_shell_full(
    mesh: &Mesh,
    chart: &Chart,
    material: &Material,
    rho: f64,
    load: [f64; 3],
) -> (Triplets, Vec<f64>) {
    let layout = ShellLayout::new(mesh);
    let space = Space::new(mesh, Element::P1Bubble);
    let rule = TriangleRule::exact_for(5);
    let n = layout.n_total();
    let mut a = Triplets::new(n, n);
    a.entries
        .reserve(mesh.n_triangles() * (N_LOCAL_U * N_LOCAL_U + 2 * N_LOCAL * N_LOCAL_U));
    let mut f = vec![0.0; n];
    for t in 0..mesh.n_triangles() {
        let el = shell_element(mesh, t, &rule, chart, material, rho, load);
        let (scalar, _) = space.element_dofs(t);
        let global = |local: usize| layout.index(local / N_LOCAL, scalar[local % N_LOCAL]);
        for i in 0..N_LOCAL_U {
            f[global(i)] += el.load[i];
            for j in 0..N_LOCAL_U {
                a.entries.push((global(i), global(j), el.stiffness[i][j]));
            }
        }
        for k in 0..N_LOCAL {
            let row = layout.index(PSI, scalar[k]);
            for j in 0..N_LOCAL_U {
                let v = el.tangency[k][j];
                a.entries.push((row, global(j), v));
                a.entries.push((global(j), row, v));
            }
        }
    }
    (a, f)
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
    let (a_full, f_full) = assemble_shell_full(mesh, chart, material, rho, load);
    let problem = restrict_shell(mesh, a_full, &f_full, &numbering);
    (problem, numbering)
}

/// The shell problem over the free dofs of `numbering` (homogeneous clamping:
/// fixed dofs are zero, so no lifting): A restricted, F restricted,
/// n_primal = number of free U dofs (they come first in block order). With
/// ψ the matrix is a symmetric saddle-point matrix; without (the plate
/// reduction eliminated it) K is symmetric positive definite.
pub fn restrict_shell(
    mesh: &Mesh,
    a_full: Triplets,
    f_full: &[f64],
    numbering: &DofNumbering,
) -> ContactProblem {
    let layout = ShellLayout::new(mesh);
    let zeros = vec![0.0; layout.n_total()];
    let (a, _) = eliminate(a_full, numbering, numbering, &zeros);
    let psi_start = layout.index(PSI, 0);
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
    ContactProblem {
        matrix: a.into_sparse(),
        kind,
        rhs: numbering.restrict(f_full),
        n_primal,
        constraint: None,
    }
}

/// Adds the edge loads ∫_γ1 (N·v + M·s) ℓ dσ to a full load vector, on the
/// boundary edges with tag `tag`; ℓ = |a_α ς^α| is the chart's length element
/// along the edge (ς the unit tangent in ω). On an edge the bubble vanishes
/// and the hats are linear; ℓ is not polynomial, so a 5-point Gauss rule.
pub fn add_edge_load(
    mesh: &Mesh,
    chart: &Chart,
    tag: i32,
    traction: [f64; 3],
    moment: [f64; 3],
    f_full: &mut [f64],
) {
    let layout = ShellLayout::new(mesh);
    let rule = SegmentRule::exact_for(9);
    for edge in mesh.boundary_edges.iter().filter(|e| e.tag == tag) {
        let [p, q] = edge.vertices.map(|v| mesh.vertices[v]);
        let d = [q[0] - p[0], q[1] - p[1]];
        let length = d[0].hypot(d[1]);
        for (&s, &w) in rule.points.iter().zip(&rule.weights) {
            let x = [p[0] + s * d[0], p[1] + s * d[1]];
            let sp = chart.at(x);
            let ell = (sp.a1 * (d[0] / length) + sp.a2 * (d[1] / length)).norm();
            for (k, hat) in [(0, 1.0 - s), (1, s)] {
                let v = edge.vertices[k];
                for c in 0..3 {
                    let weight = w * length * ell * hat;
                    f_full[layout.index(c, v)] += weight * traction[c];
                    f_full[layout.index(3 + c, v)] += weight * moment[c];
                }
            }
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

/// The contact with the rigid plane z = 0 (SPEC §2, P0 multiplier, one row per
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
    let mut c_full = Triplets::new(mesh.n_triangles(), layout.n_total());
    let mut obstacle = Vec::with_capacity(mesh.n_triangles());
    let mut weights = Vec::with_capacity(mesh.n_triangles());
    for t in 0..mesh.n_triangles() {
        let g = TriangleGeometry::new(mesh, t);
        let (scalar, _) = space.element_dofs(t);
        // ∫_T φ_k dx for the four shape functions (|T|/3 and 9|T|/20).
        let mut integrals = [0.0; N_LOCAL];
        for q in quad_points(&g, t, &rule) {
            let b = Element::P1Bubble.basis(q.lambda);
            for k in 0..N_LOCAL {
                integrals[k] += q.weight * b.values[k];
            }
        }
        for k in 0..N_LOCAL {
            c_full
                .entries
                .push((t, layout.index(2, scalar[k]), integrals[k]));
            c_full
                .entries
                .push((t, layout.index(5, scalar[k]), -half_eps * integrals[k]));
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
    fn element_matrices() {
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
        let rule = TriangleRule::exact_for(5);
        let el = shell_element(
            &mesh,
            0,
            &rule,
            &hypar(),
            &material(),
            1e3,
            [0.0, 0.0, -0.25],
        );
        let scale = el
            .stiffness
            .iter()
            .flatten()
            .fold(0.0f64, |m, v| m.max(v.abs()));
        for i in 0..N_LOCAL_U {
            for j in 0..N_LOCAL_U {
                assert!((el.stiffness[i][j] - el.stiffness[j][i]).abs() < 1e-13 * scale);
            }
            assert!(el.stiffness[i][i] >= 0.0);
        }
        let total: f64 = el.load.iter().sum();
        // √a ≈ 1 for this flat hypar: ∫ f3 ≈ −0.25 (|T| + 9|T|/20).
        let area = mesh.area(0);
        assert!((total / (-0.25 * area * 1.45) - 1.0).abs() < 1e-3);
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
                plate,
                field(&|p| {
                    let u = omega.cross(&plate.at(p).phi);
                    let r = omega.cross(&Vector3::z());
                    [u.x, u.y, u.z, r.x, r.y, r.z]
                }),
            ),
        ];
        for (chart, x) in cases {
            let (a, _) = assemble_shell_full(&mesh, &chart, &material(), 1e3, [0.0; 3]);
            let scale = a.entries.iter().fold(0.0f64, |m, e| m.max(e.2.abs()));
            let ax = crate::assembly::mat_vec(&a.into_sparse(), &x);
            let worst = ax.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(worst < 1e-12 * scale, "{chart:?}: |K U_rigid| = {worst:e}");
        }
    }
}
