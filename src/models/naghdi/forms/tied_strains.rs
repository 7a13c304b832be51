//! The interpolated membrane and shear strains of the element `p2b-mitc`
//! (docs/formulation.md §7, docs/shell-benchmarks.md).
//!
//! On each triangle the covariant membrane strain γ = (γ11, γ22, γ12) and
//! the covariant transverse shear strain δ = (δ13, δ23) of every local shape
//! function are replaced by fields of two small spaces on T, given by their
//! degrees of freedom ("mixed interpolation of tensorial components"):
//!
//! * **membrane, Regge of degree 1** (Neunteufel and Schöberl, *Avoiding
//!   membrane locking with Regge interpolation*, Comput. Methods Appl. Mech.
//!   Engrg. 373 (2021) 113524, arXiv:1907.06232): linear symmetric tensors;
//!   on each edge E with tangent t the moments ∫_E tᵀγt q, q ∈ P1(E), and the
//!   means ∫_T γ. The interpolant reproduces linear strains (a flat plate's
//!   P2 membrane energy is exact) and its edge moments are shared by the two
//!   triangles of an edge, which relaxes the membrane constraint enough for
//!   inextensional bending;
//! * **shear, Nédélec of the first kind and degree 2** (the tying of MITC7:
//!   Brezzi, Bathe and Fortin, *Mixed-interpolated elements for
//!   Reissner–Mindlin plates*, Int. J. Numer. Methods Eng. 28 (1989)):
//!   P1 vectors plus x^⊥ P1; the moments ∫_E δ·t q, q ∈ P1(E), and the means
//!   ∫_T δ. Gradients of P2 functions are reproduced, so the Kirchhoff
//!   constraint δ = 0 is met by rich enough pairs (u3, θ) and the shear does
//!   not lock.
//!
//! The bubbles of the displacement fields have no moments on a flat chart
//! (b_T vanishes on ∂T and ∫_T ∇b_T = 0), so interpolating their strains
//! would leave them with no energy on a plate. Their membrane and shear
//! strains are projected in L²(T) onto linear tensors and vectors instead,
//! which keeps their energy and ties them no more than that. The rotation
//! bubbles are interpolated like every other shape function, as in MITC7.
//!
//! Every map is linear in the strain; the element matrix integrates the
//! interpolated strains with Radon's rule and no reduced-integration weight.

use super::super::geometry::Chart;
use super::{for_each_shape_strain, FieldRole, ShellField, StrainVector, DELTA, GAMMA, N_STRAINS};
use crate::quadrature::{SegmentRule, TriangleRule};
use crate::space::{Element, TriangleGeometry};
use nalgebra::{DMatrix, DVector};

/// A linear functional on one strain group over T: Σ w·(strain components)
/// over points given by barycentric coordinates.
type Functional = Vec<([f64; 3], [f64; 3])>;

/// One of the two strain groups and the space its strains are tied to.
#[derive(Clone, Copy)]
enum TiedGroup {
    /// γ (three components) in Regge of degree 1.
    Membrane,
    /// δ (two components) in Nédélec of the first kind, degree 2.
    Shear,
}

impl TiedGroup {
    /// First index of the group in the strain vector and its components.
    fn range(self) -> (usize, usize) {
        match self {
            TiedGroup::Membrane => (GAMMA, 3),
            TiedGroup::Shear => (DELTA, 2),
        }
    }

    /// The tangential (membrane: tangential–tangential) component of a
    /// strain along the edge tangent t, as weights on the components.
    fn along(self, t: [f64; 2]) -> [f64; 3] {
        match self {
            // tᵀγt for γ written as (γ11, γ22, γ12).
            TiedGroup::Membrane => [t[0] * t[0], t[1] * t[1], 2.0 * t[0] * t[1]],
            TiedGroup::Shear => [t[0], t[1], 0.0],
        }
    }

    /// The space's degrees of freedom: per edge (opposite vertex k, from
    /// vertex k+1 to k+2, t = x_{k+2} − x_{k+1} in the chart's parameters)
    /// the moments against the hats of its two end points (Gauss, exact for
    /// degree 5), then the means of the components (Radon's rule). The
    /// lengths of t and of the edge only scale rows, which leaves the
    /// interpolant unchanged.
    fn functionals(self, g: &TriangleGeometry) -> Vec<Functional> {
        let edge_rule = SegmentRule::exact_for(5);
        let mut functionals = Vec::new();
        for k in 0..3 {
            let (a, b) = ((k + 1) % 3, (k + 2) % 3);
            let t = [
                g.vertices[b][0] - g.vertices[a][0],
                g.vertices[b][1] - g.vertices[a][1],
            ];
            let along = self.along(t);
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
                            (lambda, along.map(|x| x * w * lambda[end]))
                        })
                        .collect(),
                );
            }
        }
        functionals.extend(self.moments(|_| 1.0));
        functionals
    }

    /// The L²(T) projection onto linear fields: the moments ∫_T λ_v s_c.
    fn projection_functionals(self) -> Vec<Functional> {
        (0..3).flat_map(|v| self.moments(move |l| l[v])).collect()
    }

    /// The moments ∫_T q s_c of each component c, with Radon's rule (the
    /// area scales every row alike and is left out).
    fn moments(self, q: impl Fn([f64; 3]) -> f64) -> Vec<Functional> {
        let rule = TriangleRule::exact_for(5);
        (0..self.range().1)
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

    /// The space's basis at λ, each function as its components: first the
    /// linear fields λ_v e_c (index n_c·v + c; the projection's space), then
    /// for the shear x^⊥ x_1 and x^⊥ x_2, x = (point − centroid)/h.
    fn basis(self, g: &TriangleGeometry, lambda: [f64; 3]) -> Vec<[f64; 3]> {
        let n_c = self.range().1;
        let mut basis: Vec<[f64; 3]> = (0..3 * n_c)
            .map(|i| {
                let mut value = [0.0; 3];
                value[i % n_c] = lambda[i / n_c];
                value
            })
            .collect();
        if let TiedGroup::Shear = self {
            let (p, c) = (g.point(lambda), g.point([1.0 / 3.0; 3]));
            let h =
                (g.vertices[1][0] - g.vertices[0][0]).hypot(g.vertices[1][1] - g.vertices[0][1]);
            let x = [(p[0] - c[0]) / h, (p[1] - c[1]) / h];
            basis.extend(x.map(|xk| [-x[1] * xk, x[0] * xk, 0.0]));
        }
        basis
    }
}

/// The tied strains of one group for the local shape functions of one
/// triangle: coefficients in the group's basis.
struct TiedStrain {
    group: TiedGroup,
    coefficients: Vec<DVector<f64>>,
}

impl TiedStrain {
    fn new(
        group: TiedGroup,
        g: &TriangleGeometry,
        interpolation: &[Functional],
        strains: &PointStrains,
        projected: &[bool],
    ) -> Self {
        let projection = group.projection_functionals();
        let interpolated = strains.moments(group, interpolation);
        let projected_moments = strains.moments(group, &projection);
        let interpolation_lu = moment_matrix(group, g, interpolation).lu();
        let projection_lu = moment_matrix(group, g, &projection).lu();
        let coefficients = projected
            .iter()
            .enumerate()
            .map(|(i, &p)| {
                if p {
                    // The projection's space is the basis' linear part.
                    projection_lu
                        .solve(&projected_moments[i])
                        .expect("the mass matrix of a triangle is regular")
                        .resize_vertically(interpolation.len(), 0.0)
                } else {
                    interpolation_lu
                        .solve(&interpolated[i])
                        .expect("the moment matrix of a triangle is regular")
                }
            })
            .collect();
        TiedStrain {
            group,
            coefficients,
        }
    }
}

/// The interpolated membrane and shear strains of the local shape functions
/// of one triangle, in the local order of `element_matrices` (the fields of
/// U in block order, each with its element's local basis).
pub struct TiedStrains {
    geometry: TriangleGeometry,
    groups: [TiedStrain; 2],
}

impl TiedStrains {
    pub fn new(g: &TriangleGeometry, fields: &[&ShellField], chart: &Chart) -> Self {
        // The bubble is the last local shape function of P2⊕B3 (space.rs).
        let displacement_bubble: Vec<bool> = fields
            .iter()
            .flat_map(|f| {
                let n = f.element.n_local();
                let bubble_field =
                    f.element == Element::P2Bubble && matches!(f.role, FieldRole::Displacement(_));
                (0..n).map(move |k| bubble_field && k == n - 1)
            })
            .collect();
        let groups = [TiedGroup::Membrane, TiedGroup::Shear];
        let functionals = groups.map(|group| group.functionals(g));
        let strains = PointStrains::new(g, fields, chart, functionals.iter().flatten());
        let tie = |k: usize| {
            TiedStrain::new(
                groups[k],
                g,
                &functionals[k],
                &strains,
                &displacement_bubble,
            )
        };
        TiedStrains {
            geometry: *g,
            groups: [tie(0), tie(1)],
        }
    }

    /// Overwrites the membrane and shear strains of `strains`, the strain
    /// vectors of the local shape functions at the point λ, by their tied
    /// values.
    pub fn tie(&self, lambda: [f64; 3], strains: &mut [StrainVector]) {
        for tied in &self.groups {
            let (start, n_c) = tied.group.range();
            let basis = tied.group.basis(&self.geometry, lambda);
            for (e, c) in strains.iter_mut().zip(&tied.coefficients) {
                for (k, s) in e[start..start + n_c].iter_mut().enumerate() {
                    *s = basis.iter().zip(c.iter()).map(|(b, c)| b[k] * c).sum();
                }
            }
        }
    }
}

/// The strains of every local shape function at every point the
/// interpolation functionals of both groups use (three Gauss points per
/// edge, Radon's seven, which the projections use too), each point's chart
/// geometry evaluated once.
struct PointStrains {
    points: Vec<[f64; 3]>,
    /// strains[p][i]: local shape function i at point p.
    strains: Vec<Vec<StrainVector>>,
}

impl PointStrains {
    fn new<'a>(
        g: &TriangleGeometry,
        fields: &[&ShellField],
        chart: &Chart,
        functionals: impl Iterator<Item = &'a Functional>,
    ) -> Self {
        let mut points: Vec<[f64; 3]> = Vec::new();
        for (lambda, _) in functionals.flatten() {
            if !points.contains(lambda) {
                points.push(*lambda);
            }
        }
        let n: usize = fields.iter().map(|f| f.element.n_local()).sum();
        let strains = points
            .iter()
            .map(|&lambda| {
                let mut row = vec![[0.0; N_STRAINS]; n];
                let p = chart.at(g.point(lambda));
                for_each_shape_strain(g, fields, &p, lambda, |i, _, _, strains| row[i] = strains);
                row
            })
            .collect();
        PointStrains { points, strains }
    }

    /// The functionals applied to the group's strains of every local shape
    /// function: one vector of moments per function. The projection's points
    /// are Radon's, which the means use too.
    fn moments(&self, group: TiedGroup, functionals: &[Functional]) -> Vec<DVector<f64>> {
        let (start, n_c) = group.range();
        let n = self.strains[0].len();
        let mut m = vec![DVector::zeros(functionals.len()); n];
        for (row, functional) in functionals.iter().enumerate() {
            for (lambda, w) in functional {
                let p = self
                    .points
                    .iter()
                    .position(|q| q == lambda)
                    .expect("every functional's points are in the table");
                for (mi, e) in m.iter_mut().zip(&self.strains[p]) {
                    mi[row] += (0..n_c).map(|c| w[c] * e[start + c]).sum::<f64>();
                }
            }
        }
        m
    }
}

/// The functionals applied to the group's basis (row: functional, column:
/// basis function; the projection uses the first, linear, columns).
fn moment_matrix(
    group: TiedGroup,
    g: &TriangleGeometry,
    functionals: &[Functional],
) -> DMatrix<f64> {
    let n_c = group.range().1;
    let mut m = DMatrix::zeros(functionals.len(), functionals.len());
    for (row, functional) in functionals.iter().enumerate() {
        for (lambda, w) in functional {
            let basis = group.basis(g, *lambda);
            for (col, b) in basis.iter().take(functionals.len()).enumerate() {
                m[(row, col)] += (0..n_c).map(|c| w[c] * b[c]).sum::<f64>();
            }
        }
    }
    m
}
