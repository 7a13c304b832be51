//! The interpolated membrane strain of the element `p2b-regge`
//! (docs/formulation.md §7, docs/shell-benchmarks.md).
//!
//! On each triangle the membrane strain γ(u) = (γ11, γ22, γ12) of every
//! local shape function is replaced by a symmetric tensor field that is
//! linear on T, Σ_v λ_v S_v:
//!
//! * for the six P2 shape functions, the Regge interpolant of degree 1
//!   (Neunteufel and Schöberl, *Avoiding membrane locking with
//!   Regge interpolation*, Comput. Methods Appl. Mech. Engrg. 373 (2021)
//!   113524): on each edge E with tangent t the moments ∫_E tᵀγt q for
//!   q ∈ P1(E), and ∫_T γ. The tangential–tangential moments are shared by
//!   the two triangles of an edge, which relaxes the membrane constraint
//!   enough for inextensional bending, and the interpolant reproduces every
//!   linear strain (a flat plate's P2 membrane energy is exact);
//! * for the bubble b_T, the L²(T) projection onto linear symmetric tensors.
//!   The Regge moments of a bubble's strain vanish on a flat chart (b_T is
//!   zero on ∂T and ∫_T ∇b_T ⊗ e_c = 0), so the Regge interpolant alone
//!   would leave the in-plane bubbles with no energy; the projection keeps
//!   them with their own strain's energy on P1.
//!
//! Both are linear maps of the strain; the element matrix integrates the
//! interpolated strains with Radon's rule, with no reduced-integration
//! weight on the membrane.

use super::forms::{field_strains, ShellField, GAMMA};
use super::geometry::Chart;
use crate::quadrature::{SegmentRule, TriangleRule};
use crate::space::{Element, TriangleGeometry};
use nalgebra::{SMatrix, SVector};

/// Coefficients (S_v)_c at index 3v + c: vertex v, strain component c.
const N_COEFFICIENTS: usize = 9;
type Moments = SVector<f64, N_COEFFICIENTS>;

/// A linear functional on strain fields over T: ∫ w(x)·γ(x) as a sum over
/// points (barycentric coordinates, weights per strain component).
type Functional = Vec<([f64; 3], [f64; 3])>;

/// The interpolated membrane strains of the local shape functions of one
/// triangle, in the local order of `element_matrices` (the fields of U in
/// block order, each with its element's local basis).
pub struct MembraneInterpolant {
    coefficients: Vec<Moments>,
}

impl MembraneInterpolant {
    pub fn new(g: &TriangleGeometry, fields: &[&ShellField], chart: &Chart) -> Self {
        // The bubble is the last local shape function of P2⊕B3 (space.rs).
        let bubble: Vec<bool> = fields
            .iter()
            .flat_map(|f| {
                let n = f.element.n_local();
                (0..n).map(move |k| f.element == Element::P2Bubble && k == n - 1)
            })
            .collect();
        let (regge_rows, projection_rows) = (regge_functionals(g), projection_functionals());
        let regge = moments(g, fields, chart, &regge_rows);
        let projection = moments(g, fields, chart, &projection_rows);
        let regge_lu = moment_matrix(&regge_rows).lu();
        let projection_lu = moment_matrix(&projection_rows).lu();
        let coefficients = bubble
            .iter()
            .enumerate()
            .map(|(i, &b)| {
                let (lu, m) = if b {
                    (&projection_lu, &projection[i])
                } else {
                    (&regge_lu, &regge[i])
                };
                lu.solve(m)
                    .expect("the moment matrices of a triangle are regular")
            })
            .collect();
        MembraneInterpolant { coefficients }
    }

    /// The interpolated membrane strain of local shape function `i` at the
    /// point with barycentric coordinates `lambda`.
    pub fn strain(&self, i: usize, lambda: [f64; 3]) -> [f64; 3] {
        let s = &self.coefficients[i];
        std::array::from_fn(|c| (0..3).map(|v| lambda[v] * s[3 * v + c]).sum())
    }
}

/// The functionals applied to the membrane strain of every local shape
/// function (the chart evaluated once per point).
fn moments(
    g: &TriangleGeometry,
    fields: &[&ShellField],
    chart: &Chart,
    functionals: &[Functional],
) -> Vec<Moments> {
    let n: usize = fields.iter().map(|f| f.element.n_local()).sum();
    let mut m = vec![Moments::zeros(); n];
    for (row, functional) in functionals.iter().enumerate() {
        for (lambda, w) in functional {
            let p = chart.at(g.point(*lambda));
            let mut i = 0;
            for field in fields {
                let basis = field.element.basis(*lambda);
                for k in 0..basis.n {
                    let grad = g.gradient(basis.d_lambda[k]);
                    let e = field_strains(&p, field.role, basis.values[k], grad);
                    m[i][row] += (0..3).map(|c| w[c] * e[GAMMA + c]).sum::<f64>();
                    i += 1;
                }
            }
        }
    }
    m
}

/// The Regge degrees of freedom: per edge (opposite vertex k, from vertex
/// k+1 to k+2, tangent t = x_{k+2} − x_{k+1} in the chart's parameters) the
/// moments of tᵀγt against the hats of its two end points (Gauss, exact for
/// degree 5), then the three means ∫_T γ_c (Radon's rule). The lengths of t
/// and of the edge only scale rows, which leaves the interpolant unchanged.
fn regge_functionals(g: &TriangleGeometry) -> Vec<Functional> {
    let edge_rule = SegmentRule::exact_for(5);
    let mut functionals = Vec::with_capacity(N_COEFFICIENTS);
    for k in 0..3 {
        let (a, b) = ((k + 1) % 3, (k + 2) % 3);
        let t = [
            g.vertices[b][0] - g.vertices[a][0],
            g.vertices[b][1] - g.vertices[a][1],
        ];
        // tᵀγt for γ written as (γ11, γ22, γ12).
        let tt = [t[0] * t[0], t[1] * t[1], 2.0 * t[0] * t[1]];
        for end in [a, b] {
            functionals.push(
                edge_rule
                    .points
                    .iter()
                    .zip(&edge_rule.weights)
                    .map(|(&s, &w)| {
                        let mut lambda = [0.0; 3];
                        lambda[a] = 1.0 - s;
                        lambda[b] = s;
                        (lambda, tt.map(|x| x * w * lambda[end]))
                    })
                    .collect(),
            );
        }
    }
    functionals.extend(triangle_moments(|_| 1.0));
    functionals
}

/// The L²(T) projection onto linear tensors: the moments ∫_T λ_v γ_c.
fn projection_functionals() -> Vec<Functional> {
    (0..3)
        .flat_map(|v| triangle_moments(move |lambda| lambda[v]))
        .collect()
}

/// The three moments ∫_T q γ_c, c = 11, 22, 12, with Radon's rule (the area
/// scales every row alike and is left out).
fn triangle_moments(q: impl Fn([f64; 3]) -> f64) -> Vec<Functional> {
    let rule = TriangleRule::exact_for(5);
    (0..3)
        .map(|c| {
            rule.points
                .iter()
                .zip(&rule.weights)
                .map(|(&lambda, &w)| {
                    let mut weights = [0.0; 3];
                    weights[c] = w * q(lambda);
                    (lambda, weights)
                })
                .collect()
        })
        .collect()
}

/// The functionals applied to the linear basis λ_v E_c (row: functional,
/// column 3v + c).
fn moment_matrix(functionals: &[Functional]) -> SMatrix<f64, N_COEFFICIENTS, N_COEFFICIENTS> {
    let mut m = SMatrix::zeros();
    for (row, functional) in functionals.iter().enumerate() {
        for (lambda, w) in functional {
            for v in 0..3 {
                for c in 0..3 {
                    m[(row, 3 * v + c)] += w[c] * lambda[v];
                }
            }
        }
    }
    m
}
