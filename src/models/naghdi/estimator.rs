//! The residual a posteriori estimator of the Naghdi shell in contact
//! (docs/formulation.md §8), per triangle, for both shell elements. With
//! V = (v, s) ∈ R⁶ the Cartesian test field, the model's own form is
//! a_ρ(U, V) + b(V, ψ) = ∫ σ·e(V) dx = ∫ F_α·∂_α V + G·V dx, with the
//! generalised stress σ = D e(U_h) (+ ∇ψ_h in the tangency slots: thesis
//! element), the fluxes F_α = B_αᵀσ and G = B_0ᵀσ (e(V) = B_α ∂_α V + B_0 V,
//! [`generalized_strains`]). Integrating by parts on each triangle gives
//!
//! ```text
//! R = (f √a, 0) + λ_h (e3, −ε/2 e3) + ∂_α F_α − G     element residual (equilibrium with λ_h)
//! t = n_α F_α                                          membrane, bending and shear tractions
//!
//! η_T² = (h_T² ‖R‖²_T + ½ Σ_{E ⊂ ∂T interior} h_E ‖[t]‖²_E) / (E ε)
//!      + ∫_T λ_h⁺ (w_h − Φ)⁺                       complementarity defect
//!      + E ε ‖∇(Φ − w_h)⁺‖²_T                      penetration
//!      + ρ ‖∇(r_h·a3)‖²_T                          tangency defect (thesis element)
//! ```
//!
//! w_h = (u_h − ε/2 r_h)·e3 the constraint function, Φ the obstacle function
//! itself (data). For the tangent-rotation element the rotation tests are
//! s = θ^β a_β, so only the components s·a_β of R's and t's rotation parts
//! enter. ∂_α F_α is taken by central differences of F_α on the triangle's
//! polynomial (the chart is smooth inside T).

use super::forms::{
    generalized_strains, strain_weights, FieldRole, ShellLayout, StrainVector, SurfaceLoad,
    GRAD_NORMAL_ROTATION, N_STRAINS,
};
use super::geometry::{Chart, Material, SurfacePoint};
use crate::assembly::quad_points;
use crate::mesh::Mesh;
use crate::models::estimator::{add_edge_jumps, central_gradient, diameter, Indicators};
use crate::quadrature::{SegmentRule, TriangleRule};
use crate::space::{Space, TriangleGeometry};
use nalgebra::{Matrix6x2, Vector3, Vector6};

/// What the shell estimator reads: the discrete solution and the problem's data.
pub struct ShellState<'a> {
    pub mesh: &'a Mesh,
    pub layout: &'a ShellLayout,
    /// Full coefficients of every field (fixed dofs included, ψ unscaled).
    pub full: &'a [f64],
    pub chart: &'a Chart,
    pub material: &'a Material,
    pub rho: f64,
    /// The body force f.
    pub load: &'a SurfaceLoad,
    /// The rotation test functions are tangent: θ^β a_β (p2b-psri), or the
    /// plate reduction's r3 = 0; else all of s is tested (thesis element with ψ).
    pub tangent_tests: bool,
    pub contact: Option<ShellContact<'a>>,
}

/// The contact: λ_h's space and coefficients, and the obstacle function Φ.
pub struct ShellContact<'a> {
    pub multiplier: (Space<'a>, &'a [f64]),
    pub obstacle: &'a dyn Fn([f64; 2]) -> f64,
}

/// The discrete solution at one point of one triangle.
struct PointState {
    p: SurfacePoint,
    /// σ = D e(U_h), ∇ψ_h added to the tangency slots.
    sigma: StrainVector,
    /// e(U_h).
    strains: StrainVector,
    /// The constraint function w_h = (u_h − ε/2 r_h)·e3.
    w: f64,
}

/// Central-difference step for the fluxes, relative to h_T.
const FLUX_STEP: f64 = 1e-4;

impl ShellState<'_> {
    /// U_h and its stress at the physical point x, from triangle t's
    /// polynomials (x may lie just outside t: the polynomials continue).
    fn at(&self, g: &TriangleGeometry, t: usize, x: [f64; 2]) -> PointState {
        let l = barycentric(g, x);
        let p = self.chart.at(x);
        let zero = Vector3::zeros();
        let (mut du, mut r, mut dr) = ([zero; 2], zero, [zero; 2]);
        let (mut grad_psi, mut u3) = ([0.0; 2], 0.0);
        for (f, field) in self.layout.fields.iter().enumerate() {
            let c = self.layout.component(self.full, f);
            let (dofs, n) = Space::new(self.mesh, field.element).element_dofs(t);
            let basis = field.element.basis(l);
            let (mut value, mut grad) = (0.0, [0.0; 2]);
            for k in 0..n {
                let gk = g.gradient(basis.d_lambda[k]);
                value += c[dofs[k]] * basis.values[k];
                grad[0] += c[dofs[k]] * gk[0];
                grad[1] += c[dofs[k]] * gk[1];
            }
            match field.role {
                FieldRole::Displacement(i) => {
                    if i == 2 {
                        u3 = value;
                    }
                    du[0][i] += grad[0];
                    du[1][i] += grad[1];
                }
                FieldRole::CartesianRotation(i) => {
                    r[i] += value;
                    dr[0][i] += grad[0];
                    dr[1][i] += grad[1];
                }
                FieldRole::TangentRotation(be) => {
                    // r = θ a_β: ∂_α r = ∂_α θ a_β + θ ∂_α a_β.
                    let a_be = *p.a(be);
                    r += a_be * value;
                    for al in 0..2 {
                        dr[al] += a_be * grad[al] + p.d_a[be][al] * value;
                    }
                }
                FieldRole::TangencyMultiplier => grad_psi = grad,
            }
        }
        let strains = generalized_strains(&p, &du, &r, &dr);
        let d = strain_weights(&p, self.material, self.rho);
        let mut sigma: StrainVector =
            std::array::from_fn(|a| (0..N_STRAINS).map(|b| d[a][b] * strains[b]).sum());
        sigma[GRAD_NORMAL_ROTATION] += grad_psi[0];
        sigma[GRAD_NORMAL_ROTATION + 1] += grad_psi[1];
        let w = u3 - 0.5 * self.material.thickness * r.z;
        PointState {
            p,
            sigma,
            strains,
            w,
        }
    }

    /// The rotation part of a residual or traction as the test space sees
    /// it: all of s (thesis element), or its components s·a_β (tangent rotations).
    fn tested(&self, p: &SurfacePoint, v: &Vector6<f64>) -> Vector6<f64> {
        if !self.tangent_tests {
            return *v;
        }
        let s = Vector3::new(v[3], v[4], v[5]);
        Vector6::new(v[0], v[1], v[2], s.dot(&p.a1), s.dot(&p.a2), 0.0)
    }
}

/// The barycentric coordinates of x in the triangle of `g` (outside it: < 0).
fn barycentric(g: &TriangleGeometry, x: [f64; 2]) -> [f64; 3] {
    let gl = &g.grad_lambda;
    let l = |i: usize| {
        // λ_i is affine with gradient ∇λ_i and λ_i(v_i) = 1.
        let vi = g.vertices[i];
        1.0 + gl[i][0] * (x[0] - vi[0]) + gl[i][1] * (x[1] - vi[1])
    };
    let (l1, l2) = (l(1), l(2));
    [1.0 - l1 - l2, l1, l2]
}

/// The fluxes of σ at p: column α of F is F_α = B_αᵀσ (the coefficient of
/// ∂_α V in σ·e(V)), and G = B_0ᵀσ (of V itself; only s enters).
fn fluxes(p: &SurfacePoint, sigma: &StrainVector) -> (Matrix6x2<f64>, Vector6<f64>) {
    let zero = Vector3::zeros();
    let dot = |e: StrainVector| (0..N_STRAINS).map(|a| e[a] * sigma[a]).sum::<f64>();
    let mut flux = Matrix6x2::zeros();
    let mut g = Vector6::zeros();
    for c in 0..3 {
        let unit = Vector3::ith(c, 1.0);
        for al in 0..2 {
            let mut d = [zero; 2];
            d[al] = unit;
            flux[(c, al)] = dot(generalized_strains(p, &d, &zero, &[zero; 2]));
            flux[(3 + c, al)] = dot(generalized_strains(p, &[zero; 2], &zero, &d));
        }
        g[3 + c] = dot(generalized_strains(p, &[zero; 2], &unit, &[zero; 2]));
    }
    (flux, g)
}

/// The indicators of every triangle (docs/formulation.md §8).
pub fn shell_indicators(state: &ShellState) -> Indicators {
    let mesh = state.mesh;
    let nt = mesh.n_triangles();
    let material = state.material;
    // The one stiffness scale: residuals are divided by it, the penetration
    // (a displacement gradient) multiplied, so every term is an energy.
    let stiffness = material.young * material.thickness;
    let half_eps = 0.5 * material.thickness;
    let rule = TriangleRule::exact_for(crate::models::estimator::ESTIMATOR_RULE);
    let mut ind = Indicators::zeros(nt);
    for t in 0..nt {
        let g = TriangleGeometry::new(mesh, t);
        let h = diameter(mesh, t);
        let flux_at = |x: [f64; 2]| {
            let s = state.at(&g, t, x);
            fluxes(&s.p, &s.sigma).0
        };
        for q in quad_points(&g, t, &rule) {
            let s = state.at(&g, t, q.x);
            let (_, g0) = fluxes(&s.p, &s.sigma);
            let d_flux = central_gradient(flux_at, q.x, FLUX_STEP * h);
            let mut r: Vector6<f64> = d_flux[0].column(0) + d_flux[1].column(1) - g0;
            let force = state.load.at(&s.p);
            for c in 0..3 {
                r[c] += force[c] * s.p.sqrt_a;
            }
            if let Some(contact) = &state.contact {
                let (space, coefficients) = contact.multiplier;
                let lambda = space.evaluate(coefficients, t, q.lambda);
                r[2] += lambda;
                r[5] -= half_eps * lambda;
                let phi = (contact.obstacle)(q.x);
                let gap = s.w - phi;
                ind.complementarity[t] += q.weight * lambda.max(0.0) * gap.max(0.0);
                if gap < 0.0 {
                    let d = central_gradient(
                        |x| (contact.obstacle)(x) - state.at(&g, t, x).w,
                        q.x,
                        FLUX_STEP * h,
                    );
                    ind.penetration[t] += q.weight * stiffness * (d[0] * d[0] + d[1] * d[1]);
                }
            }
            let r = state.tested(&s.p, &r);
            ind.residual[t] += q.weight * h * h * r.norm_squared() / stiffness;
            if !state.tangent_tests {
                let n = &s.strains[GRAD_NORMAL_ROTATION..];
                ind.tangency[t] += q.weight * state.rho * (n[0] * n[0] + n[1] * n[1]);
            }
        }
    }
    // The tractions are not polynomial (the chart's coefficients): degree 6
    // resolves them on an edge to well below the estimator's accuracy.
    let mut jumps = vec![0.0; nt];
    add_edge_jumps(
        mesh,
        &SegmentRule::exact_for(6),
        &mut jumps,
        |(t1, l1), (t2, l2), normal| {
            let traction = |t: usize, l: [f64; 3]| {
                let g = TriangleGeometry::new(mesh, t);
                let s = state.at(&g, t, g.point(l));
                let (flux, _) = fluxes(&s.p, &s.sigma);
                (flux * nalgebra::Vector2::new(normal[0], normal[1]), s.p)
            };
            let ((t_1, p), (t_2, _)) = (traction(t1, l1), traction(t2, l2));
            state.tested(&p, &(t_1 - t_2)).data.0[0]
        },
    );
    for t in 0..nt {
        ind.jump[t] = jumps[t] / stiffness;
    }
    ind
}
