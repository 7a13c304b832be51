//! The residual a posteriori estimator of the membrane obstacle problem
//! (docs/formulation.md §8), per triangle, for both pairs (P1⊕B3–P0, P2–P1):
//!
//! ```text
//! η_T² = h_T² ‖g + λ_h + Δu_h‖²_T                 element residual (λ_h's consistency on the contact zone)
//!      + ½ Σ_{E ⊂ ∂T interior} h_E ‖[∂_n u_h]‖²_E  flux jumps
//!      + ∫_T λ_h⁺ (u_h − φ)⁺                       complementarity defect
//!      + ‖∇(φ − u_h)⁺‖²_T                          penetration
//! ```
//!
//! Δu_h is taken elementwise (the bubble and P2 have second derivatives).
//! The shell's estimator (`naghdi::estimator`) shares [`Indicators`] and the edge loop.

use crate::assembly::quad_points;
use crate::mesh::Mesh;
use crate::quadrature::{SegmentRule, TriangleRule};
use crate::space::{Element, Space, TriangleGeometry, MAX_LOCAL};

/// What the estimator reads: the discrete solution and the problem's data.
pub struct MembraneState<'a> {
    pub u_space: Space<'a>,
    /// Full coefficients of u_h (Dirichlet values included).
    pub u: &'a [f64],
    /// The source term g of −Δu = g + λ.
    pub load: &'a dyn Fn([f64; 2]) -> f64,
    /// The obstacles (none, the lower one, or lower and upper).
    pub bounds: Vec<Bound<'a>>,
}

/// One obstacle with its multiplier: u ≥ ψ (`sign` = +1, lower) or u ≤ ψ
/// (`sign` = −1, upper); it enters −Δu = g + Σ sign·λ.
pub struct Bound<'a> {
    pub obstacle: &'a dyn Fn([f64; 2]) -> f64,
    /// λ_h's space and coefficients (λ ≥ 0).
    pub multiplier: (Space<'a>, &'a [f64]),
    pub sign: f64,
}

/// The squared contributions of every triangle (each ≥ 0); `tangency` is
/// the shell's (thesis element, docs/formulation.md §8), zero for the membrane.
#[derive(Debug, Clone, Default)]
pub struct Indicators {
    pub residual: Vec<f64>,
    pub jump: Vec<f64>,
    pub complementarity: Vec<f64>,
    pub penetration: Vec<f64>,
    pub tangency: Vec<f64>,
}

impl Indicators {
    /// Every contribution zero on `nt` triangles.
    pub fn zeros(nt: usize) -> Self {
        Indicators {
            residual: vec![0.0; nt],
            jump: vec![0.0; nt],
            complementarity: vec![0.0; nt],
            penetration: vec![0.0; nt],
            tangency: vec![0.0; nt],
        }
    }

    /// η_T per triangle.
    pub fn eta(&self) -> Vec<f64> {
        (0..self.residual.len())
            .map(|t| {
                (self.residual[t]
                    + self.jump[t]
                    + self.complementarity[t]
                    + self.penetration[t]
                    + self.tangency[t])
                    .sqrt()
            })
            .collect()
    }

    /// η = (Σ_T η_T²)^½.
    pub fn total(&self) -> f64 {
        self.eta().iter().map(|e| e * e).sum::<f64>().sqrt()
    }
}

/// Second barycentric derivatives ∂²φ_i/∂λ_a∂λ_b of the local basis at `l`
/// (zero for P0 and P1).
fn basis_hessians(element: Element, l: [f64; 3]) -> [[[f64; 3]; 3]; MAX_LOCAL] {
    let mut h = [[[0.0; 3]; 3]; MAX_LOCAL];
    let bubble = |h: &mut [[f64; 3]; 3]| {
        for a in 0..3 {
            for b in 0..3 {
                if a != b {
                    h[a][b] = 27.0 * l[3 - a - b];
                }
            }
        }
    };
    match element {
        Element::P0 | Element::P1 => {}
        Element::P1Bubble => bubble(&mut h[3]),
        Element::P2 | Element::P2Bubble => {
            for i in 0..3 {
                h[i][i][i] = 4.0;
                let (j, k) = ((i + 1) % 3, (i + 2) % 3);
                h[3 + i][j][k] = 4.0;
                h[3 + i][k][j] = 4.0;
            }
            if element == Element::P2Bubble {
                bubble(&mut h[6]);
            }
        }
    }
    h
}

/// Δu_h on triangle t at barycentric point `l`.
fn laplacian(space: &Space, c: &[f64], g: &TriangleGeometry, t: usize, l: [f64; 3]) -> f64 {
    let (dofs, n) = space.element_dofs(t);
    let h = basis_hessians(space.element, l);
    let gl = &g.grad_lambda;
    let mut sum = 0.0;
    for i in 0..n {
        for a in 0..3 {
            for b in 0..3 {
                if h[i][a][b] != 0.0 {
                    let metric = gl[a][0] * gl[b][0] + gl[a][1] * gl[b][1];
                    sum += c[dofs[i]] * h[i][a][b] * metric;
                }
            }
        }
    }
    sum
}

/// ∇u_h on triangle t at barycentric point `l`.
pub(crate) fn gradient(
    space: &Space,
    c: &[f64],
    g: &TriangleGeometry,
    t: usize,
    l: [f64; 3],
) -> [f64; 2] {
    let (dofs, n) = space.element_dofs(t);
    let b = space.element.basis(l);
    let mut grad = [0.0; 2];
    for i in 0..n {
        let gi = g.gradient(b.d_lambda[i]);
        grad[0] += c[dofs[i]] * gi[0];
        grad[1] += c[dofs[i]] * gi[1];
    }
    grad
}

/// Longest edge of triangle t (h_T).
pub(crate) fn diameter(mesh: &Mesh, t: usize) -> f64 {
    mesh.triangle_edges[t]
        .iter()
        .map(|&e| mesh.edge_length(e))
        .fold(0.0, f64::max)
}

/// The barycentric coordinates in triangle t of the point (1 − s) a + s b of its edge [a, b].
fn on_edge(mesh: &Mesh, t: usize, [a, b]: [usize; 2], s: f64) -> [f64; 3] {
    let mut l = [0.0; 3];
    for (k, &v) in mesh.triangles[t].iter().enumerate() {
        if v == a {
            l[k] = 1.0 - s;
        } else if v == b {
            l[k] = s;
        }
    }
    l
}

/// The degree of the estimators' area rule (membrane and shell): 6 covers
/// (g + λ_h + Δu_h)² for both membrane pairs exactly. Scene data evaluated
/// there is checked there too, before solving.
pub const ESTIMATOR_RULE: usize = 6;

/// The indicators of every triangle (docs/formulation.md §8).
pub fn membrane_indicators(state: &MembraneState) -> Indicators {
    let space = &state.u_space;
    let mesh = space.mesh;
    let nt = mesh.n_triangles();
    // The positive parts in the contact terms are resolved to quadrature
    // accuracy only.
    let rule = TriangleRule::exact_for(ESTIMATOR_RULE);
    let mut ind = Indicators::zeros(nt);
    for t in 0..nt {
        let g = TriangleGeometry::new(mesh, t);
        let h = diameter(mesh, t);
        for p in quad_points(&g, t, &rule) {
            let lambdas: Vec<f64> = state
                .bounds
                .iter()
                .map(|b| b.multiplier.0.evaluate(b.multiplier.1, t, p.lambda))
                .collect();
            let net: f64 = state
                .bounds
                .iter()
                .zip(&lambdas)
                .map(|(b, l)| b.sign * l)
                .sum();
            let r = (state.load)(p.x) + net + laplacian(space, state.u, &g, t, p.lambda);
            ind.residual[t] += p.weight * h * h * r * r;
            let u = space.evaluate(state.u, t, p.lambda);
            for (bound, lambda) in state.bounds.iter().zip(&lambdas) {
                let psi = bound.obstacle;
                // The gap in the direction the bound allows: u − ψ (lower), ψ − u (upper).
                let gap = bound.sign * (u - psi(p.x));
                ind.complementarity[t] += p.weight * lambda.max(0.0) * gap.max(0.0);
                if gap < 0.0 {
                    // ∇ψ by central differences: ψ is data, not an FE function.
                    let dpsi = central_gradient(psi, p.x, 1e-6);
                    let du = gradient(space, state.u, &g, t, p.lambda);
                    ind.penetration[t] +=
                        p.weight * ((dpsi[0] - du[0]).powi(2) + (dpsi[1] - du[1]).powi(2));
                }
            }
        }
    }
    // ∇u_h is quadratic (P1⊕B3) or linear (P2) along an edge: degree 4 is exact for the jump².
    add_edge_jumps(
        mesh,
        &SegmentRule::exact_for(4),
        &mut ind.jump,
        |(t1, l1), (t2, l2), normal| {
            let d1 = gradient(space, state.u, &TriangleGeometry::new(mesh, t1), t1, l1);
            let d2 = gradient(space, state.u, &TriangleGeometry::new(mesh, t2), t2, l2);
            [(d1[0] - d2[0]) * normal[0] + (d1[1] - d2[1]) * normal[1]]
        },
    );
    ind
}

/// ∇f at x by central differences with step d (data, or an FE function's
/// polynomial on one triangle continued past its edges).
pub(crate) fn central_gradient<T, F: Fn([f64; 2]) -> T>(f: F, x: [f64; 2], d: f64) -> [T; 2]
where
    T: std::ops::Sub<Output = T> + std::ops::Div<f64, Output = T>,
{
    [
        (f([x[0] + d, x[1]]) - f([x[0] - d, x[1]])) / (2.0 * d),
        (f([x[0], x[1] + d]) - f([x[0], x[1] - d])) / (2.0 * d),
    ]
}

/// The edge terms ½ Σ_{E ⊂ ∂T interior} h_E ‖[·]‖²_E of every triangle, added
/// to `out`: `jump((t1, l1), (t2, l2), n)` is the jump (its components) at one point
/// of an interior edge, given as barycentric coordinates in both triangles
/// beside it, with n the unit normal out of t1. Each edge's share is split
/// half and half between its triangles.
pub(crate) fn add_edge_jumps<J: IntoIterator<Item = f64>>(
    mesh: &Mesh,
    segment: &SegmentRule,
    out: &mut [f64],
    mut jump: impl FnMut((usize, [f64; 3]), (usize, [f64; 3]), [f64; 2]) -> J,
) {
    for (e, sides) in mesh.edge_triangles().iter().enumerate() {
        let [Some(t1), Some(t2)] = *sides else {
            continue;
        };
        let [a, b] = mesh.edges[e];
        let (pa, pb) = (mesh.vertices[a], mesh.vertices[b]);
        let len = mesh.edge_length(e);
        let normal = [(pb[1] - pa[1]) / len, (pa[0] - pb[0]) / len];
        let mut sum = 0.0;
        for (&s, &w) in segment.points.iter().zip(&segment.weights) {
            let sides = (
                (t1, on_edge(mesh, t1, [a, b], s)),
                (t2, on_edge(mesh, t2, [a, b], s)),
            );
            for j in jump(sides.0, sides.1, normal) {
                sum += w * len * j * j;
            }
        }
        // h_E ‖[·]‖²_E, half to each side.
        out[t1] += 0.5 * len * sum;
        out[t2] += 0.5 * len * sum;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transfer::tests::square;

    /// Δ of interpolated quadratics is exact for P2 and P2⊕B3 (Δ(x² + 3xy − 2y²) = −2),
    /// and the interpolant of a global quadratic has no flux jumps; with g = 2 the
    /// residual vanishes too.
    #[test]
    fn quadratics_have_zero_residual_and_jumps() {
        let mesh = square(3);
        let f = |x: [f64; 2]| x[0] * x[0] + 3.0 * x[0] * x[1] - 2.0 * x[1] * x[1];
        for element in [Element::P2, Element::P2Bubble] {
            let space = Space::new(&mesh, element);
            let u = space.interpolate(f);
            let ind = membrane_indicators(&MembraneState {
                u_space: space,
                u: &u,
                load: &|_| 2.0,
                bounds: Vec::new(),
            });
            let total = ind.total();
            assert!(total < 1e-12, "{element:?}: η = {total:e}");
        }
    }

    /// The bubble's Laplacian: Δ(27 λ1λ2λ3) integrates to ∮∂_n b = 0 over T,
    /// and equals −27·2·(∇λ1·∇λ2 + …) pointwise; checked against finite differences.
    #[test]
    fn bubble_laplacian_matches_finite_differences() {
        let mesh = Mesh::from_triangles(
            vec![[0.0, 0.0], [1.0, 0.2], [0.3, 0.9]],
            vec![[0, 1, 2]],
            "one".into(),
        )
        .unwrap();
        let space = Space::new(&mesh, Element::P1Bubble);
        let c = [0.0, 0.0, 0.0, 1.0];
        let g = TriangleGeometry::new(&mesh, 0);
        let l = [0.2, 0.5, 0.3];
        let x = g.point(l);
        // b at a physical point through its barycentric coordinates.
        let bary = |p: [f64; 2]| {
            let gl = &g.grad_lambda;
            let v = g.vertices;
            let l1 = 1.0 + gl[0][0] * (p[0] - v[0][0]) + gl[0][1] * (p[1] - v[0][1]);
            let l2 = gl[1][0] * (p[0] - v[0][0]) + gl[1][1] * (p[1] - v[0][1]);
            [l1, l2, 1.0 - l1 - l2]
        };
        let b = |p: [f64; 2]| space.evaluate(&c, 0, bary(p));
        let d = 1e-4;
        let fd =
            (b([x[0] + d, x[1]]) + b([x[0] - d, x[1]]) + b([x[0], x[1] + d]) + b([x[0], x[1] - d])
                - 4.0 * b(x))
                / (d * d);
        let exact = laplacian(&space, &c, &g, 0, l);
        assert!((fd - exact).abs() < 1e-5 * exact.abs(), "{fd} vs {exact}");
    }
}
