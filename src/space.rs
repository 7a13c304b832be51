//! Finite element spaces on a triangle mesh: the elements P0, P1, P1⊕B3, P2
//! and P2⊕B3, their basis functions in barycentric coordinates, and DOF maps.
//!
//! Global numbering (also the `/dofs/<name>` layout of the result file):
//! - P0: one dof per triangle, in triangle order;
//! - P1: one per vertex;
//! - P1⊕B3: Nv vertex values, then Nt bubble amplitudes (b_T = 27 λ1λ2λ3,
//!   value 1 at the centroid; the vertex functions are the plain hats, as in
//!   FreeFEM's `P1b`);
//! - P2: Nv vertex values, then one value per edge midpoint in `mesh.edges` order;
//! - P2⊕B3: the P2 dofs, then Nt bubble amplitudes (the Lagrange P2 basis
//!   plus b_T = 27 λ1λ2λ3, as FreeFEM's `P2b` spans; b_T's coefficient is not
//!   the centroid value, which also has the P2 part).

use crate::mesh::Mesh;

/// The largest number of local basis functions of any element here.
pub const MAX_LOCAL: usize = 7;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Element {
    P0,
    P1,
    P1Bubble,
    P2,
    P2Bubble,
}

/// Basis values and barycentric derivatives at one point of one element.
#[derive(Debug, Clone, Copy)]
pub struct LocalBasis {
    pub n: usize,
    pub values: [f64; MAX_LOCAL],
    /// ∂φ_i/∂λ_k: chain with ∇λ_k to get physical gradients.
    pub d_lambda: [[f64; 3]; MAX_LOCAL],
}

impl Element {
    pub fn n_local(self) -> usize {
        match self {
            Element::P0 => 1,
            Element::P1 => 3,
            Element::P1Bubble => 4,
            Element::P2 => 6,
            Element::P2Bubble => 7,
        }
    }

    /// Polynomial degree of the basis functions.
    pub fn degree(self) -> usize {
        match self {
            Element::P0 => 0,
            Element::P1 => 1,
            Element::P1Bubble | Element::P2Bubble => 3,
            Element::P2 => 2,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Element::P0 => "P0",
            Element::P1 => "P1",
            Element::P1Bubble => "P1+B3",
            Element::P2 => "P2",
            Element::P2Bubble => "P2+B3",
        }
    }

    /// The short name stored with a coefficient vector (`space` attribute of
    /// `/dofs/<name>`, FreeFEM's names): P0, P1, P1b, P2, P2b.
    pub fn tag(self) -> &'static str {
        match self {
            Element::P0 => "P0",
            Element::P1 => "P1",
            Element::P1Bubble => "P1b",
            Element::P2 => "P2",
            Element::P2Bubble => "P2b",
        }
    }

    /// The element of a [`Element::tag`].
    pub fn from_tag(tag: &str) -> Option<Element> {
        [
            Element::P0,
            Element::P1,
            Element::P1Bubble,
            Element::P2,
            Element::P2Bubble,
        ]
        .into_iter()
        .find(|e| e.tag() == tag)
    }

    /// Whether the element has one interior (bubble) dof per triangle, last.
    pub fn has_bubble(self) -> bool {
        matches!(self, Element::P1Bubble | Element::P2Bubble)
    }

    /// Basis at barycentric point `l`.
    pub fn basis(self, l: [f64; 3]) -> LocalBasis {
        let mut b = LocalBasis {
            n: self.n_local(),
            values: [0.0; MAX_LOCAL],
            d_lambda: [[0.0; 3]; MAX_LOCAL],
        };
        match self {
            Element::P0 => b.values[0] = 1.0,
            Element::P1 | Element::P1Bubble => {
                for i in 0..3 {
                    b.values[i] = l[i];
                    b.d_lambda[i][i] = 1.0;
                }
                if self == Element::P1Bubble {
                    b.values[3] = 27.0 * l[0] * l[1] * l[2];
                    b.d_lambda[3] = [27.0 * l[1] * l[2], 27.0 * l[0] * l[2], 27.0 * l[0] * l[1]];
                }
            }
            Element::P2 | Element::P2Bubble => {
                for i in 0..3 {
                    b.values[i] = l[i] * (2.0 * l[i] - 1.0);
                    b.d_lambda[i][i] = 4.0 * l[i] - 1.0;
                    // Edge i is opposite vertex i: it joins vertices i+1 and i+2.
                    let (j, k) = ((i + 1) % 3, (i + 2) % 3);
                    b.values[3 + i] = 4.0 * l[j] * l[k];
                    b.d_lambda[3 + i][j] = 4.0 * l[k];
                    b.d_lambda[3 + i][k] = 4.0 * l[j];
                }
                if self == Element::P2Bubble {
                    b.values[6] = 27.0 * l[0] * l[1] * l[2];
                    b.d_lambda[6] = [27.0 * l[1] * l[2], 27.0 * l[0] * l[2], 27.0 * l[0] * l[1]];
                }
            }
        }
        b
    }

    /// Barycentric coordinates of the local interpolation nodes.
    pub fn nodes(self) -> Vec<[f64; 3]> {
        let v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        match self {
            Element::P0 => vec![[1.0 / 3.0; 3]],
            Element::P1 => v.to_vec(),
            Element::P1Bubble => {
                let mut n = v.to_vec();
                n.push([1.0 / 3.0; 3]);
                n
            }
            Element::P2 | Element::P2Bubble => {
                let mut n = v.to_vec();
                n.extend([[0.0, 0.5, 0.5], [0.5, 0.0, 0.5], [0.5, 0.5, 0.0]]);
                if self == Element::P2Bubble {
                    n.push([1.0 / 3.0; 3]);
                }
                n
            }
        }
    }
}

/// Affine geometry of one triangle.
#[derive(Debug, Clone, Copy)]
pub struct TriangleGeometry {
    pub vertices: [[f64; 2]; 3],
    pub area: f64,
    /// Constant gradients of the barycentric coordinates.
    pub grad_lambda: [[f64; 2]; 3],
}

impl TriangleGeometry {
    pub fn new(mesh: &Mesh, t: usize) -> Self {
        let tri = mesh.triangles[t];
        let p = [
            mesh.vertices[tri[0]],
            mesh.vertices[tri[1]],
            mesh.vertices[tri[2]],
        ];
        let two_area =
            (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
        let mut grad_lambda = [[0.0; 2]; 3];
        for i in 0..3 {
            let (j, k) = ((i + 1) % 3, (i + 2) % 3);
            grad_lambda[i] = [
                (p[j][1] - p[k][1]) / two_area,
                (p[k][0] - p[j][0]) / two_area,
            ];
        }
        TriangleGeometry {
            vertices: p,
            area: 0.5 * two_area,
            grad_lambda,
        }
    }

    /// Physical point of barycentric coordinates `l`.
    pub fn point(&self, l: [f64; 3]) -> [f64; 2] {
        let p = &self.vertices;
        [
            l[0] * p[0][0] + l[1] * p[1][0] + l[2] * p[2][0],
            l[0] * p[0][1] + l[1] * p[1][1] + l[2] * p[2][1],
        ]
    }

    /// Physical gradient from barycentric derivatives.
    pub fn gradient(&self, d_lambda: [f64; 3]) -> [f64; 2] {
        let g = &self.grad_lambda;
        [
            d_lambda[0] * g[0][0] + d_lambda[1] * g[1][0] + d_lambda[2] * g[2][0],
            d_lambda[0] * g[0][1] + d_lambda[1] * g[1][1] + d_lambda[2] * g[2][1],
        ]
    }
}

/// A scalar FE space: an element on a mesh, with its global DOF map.
#[derive(Debug, Clone, Copy)]
pub struct Space<'m> {
    pub mesh: &'m Mesh,
    pub element: Element,
}

impl<'m> Space<'m> {
    pub fn new(mesh: &'m Mesh, element: Element) -> Self {
        Space { mesh, element }
    }

    /// The first bubble dof (that of triangle 0; triangle t's is this + t),
    /// for an element with bubbles.
    pub fn bubble_start(&self) -> Option<usize> {
        self.element
            .has_bubble()
            .then(|| self.n_dofs() - self.mesh.n_triangles())
    }

    pub fn n_dofs(&self) -> usize {
        let m = self.mesh;
        match self.element {
            Element::P0 => m.n_triangles(),
            Element::P1 => m.n_vertices(),
            Element::P1Bubble => m.n_vertices() + m.n_triangles(),
            Element::P2 => m.n_vertices() + m.n_edges(),
            Element::P2Bubble => m.n_vertices() + m.n_edges() + m.n_triangles(),
        }
    }

    /// Global dofs of triangle t, in local basis order.
    pub fn element_dofs(&self, t: usize) -> ([usize; MAX_LOCAL], usize) {
        let m = self.mesh;
        let v = m.triangles[t];
        let mut d = [0; MAX_LOCAL];
        match self.element {
            Element::P0 => d[0] = t,
            Element::P1 => d[..3].copy_from_slice(&v),
            Element::P1Bubble => {
                d[..3].copy_from_slice(&v);
                d[3] = m.n_vertices() + t;
            }
            Element::P2 | Element::P2Bubble => {
                d[..3].copy_from_slice(&v);
                for i in 0..3 {
                    d[3 + i] = m.n_vertices() + m.triangle_edges[t][i];
                }
                if self.element == Element::P2Bubble {
                    d[6] = m.n_vertices() + m.n_edges() + t;
                }
            }
        }
        (d, self.element.n_local())
    }

    /// Dofs lying on boundary edges with a tag in `tags` (all boundary tags if None).
    pub fn boundary_dof_mask(&self, tags: Option<&[i32]>) -> Vec<bool> {
        let m = self.mesh;
        let mut mask = vec![false; self.n_dofs()];
        match self.element {
            Element::P0 => {}
            Element::P1 | Element::P1Bubble | Element::P2 | Element::P2Bubble => {
                let vm = m.boundary_vertex_mask(tags);
                mask[..m.n_vertices()].copy_from_slice(&vm);
                if matches!(self.element, Element::P2 | Element::P2Bubble) {
                    for (e, on) in m.boundary_edge_mask(tags).into_iter().enumerate() {
                        mask[m.n_vertices() + e] = on;
                    }
                }
            }
        }
        mask
    }

    /// Nodal interpolant of f. For P1⊕B3 and P2⊕B3 the bubble amplitude makes
    /// the centroid value exact (as FreeFEM's P1b interpolation does).
    pub fn interpolate(&self, f: impl Fn([f64; 2]) -> f64) -> Vec<f64> {
        let mut c = vec![0.0; self.n_dofs()];
        let nodes = self.element.nodes();
        // A vertex dof (dof v is vertex v, local nodes 0..3) is evaluated
        // once, at the vertex itself, not once per triangle around it.
        let first_in_triangle = match self.element {
            Element::P0 => 0,
            _ => {
                for (v, &x) in self.mesh.vertices.iter().enumerate() {
                    c[v] = f(x);
                }
                3
            }
        };
        for t in 0..self.mesh.n_triangles() {
            let g = TriangleGeometry::new(self.mesh, t);
            let (dofs, n) = self.element_dofs(t);
            for i in first_in_triangle..n {
                c[dofs[i]] = f(g.point(nodes[i]));
            }
            match self.element {
                Element::P1Bubble => {
                    let mean = (c[dofs[0]] + c[dofs[1]] + c[dofs[2]]) / 3.0;
                    c[dofs[3]] -= mean;
                }
                Element::P2Bubble => {
                    // The P2 basis at the centroid: −1/9 per vertex, 4/9 per edge.
                    let rest = (4.0 * (c[dofs[3]] + c[dofs[4]] + c[dofs[5]])
                        - (c[dofs[0]] + c[dofs[1]] + c[dofs[2]]))
                        / 9.0;
                    c[dofs[6]] -= rest;
                }
                _ => {}
            }
        }
        c
    }

    /// Value of the FE function with coefficients `c` at barycentric point `l` of triangle t.
    pub fn evaluate(&self, c: &[f64], t: usize, l: [f64; 3]) -> f64 {
        let (dofs, n) = self.element_dofs(t);
        let b = self.element.basis(l);
        (0..n).map(|i| c[dofs[i]] * b.values[i]).sum()
    }

    /// Values at the mesh vertices (exact for P1, P1⊕B3, P2, P2⊕B3: their vertex dofs;
    /// for P0 the area-weighted mean of the surrounding triangles).
    pub fn vertex_values(&self, c: &[f64]) -> Vec<f64> {
        let m = self.mesh;
        match self.element {
            Element::P0 => {
                let mut sum = vec![0.0; m.n_vertices()];
                let mut weight = vec![0.0; m.n_vertices()];
                for (t, tri) in m.triangles.iter().enumerate() {
                    let a = m.area(t);
                    for &v in tri {
                        sum[v] += a * c[t];
                        weight[v] += a;
                    }
                }
                sum.iter().zip(&weight).map(|(s, w)| s / w).collect()
            }
            _ => c[..m.n_vertices()].to_vec(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bases_are_nodal_and_sum_to_one() {
        for e in [Element::P1, Element::P2] {
            let nodes = e.nodes();
            for (i, node) in nodes.iter().enumerate() {
                let b = e.basis(*node);
                for j in 0..e.n_local() {
                    let expected = if i == j { 1.0 } else { 0.0 };
                    assert!(
                        (b.values[j] - expected).abs() < 1e-15,
                        "{e:?} φ_{j}(node {i})"
                    );
                }
            }
            let b = e.basis([0.2, 0.3, 0.5]);
            let s: f64 = b.values[..e.n_local()].iter().sum();
            assert!((s - 1.0).abs() < 1e-15);
        }
        let b = Element::P1Bubble.basis([1.0 / 3.0; 3]);
        assert!(
            (b.values[3] - 1.0).abs() < 1e-15,
            "bubble is 1 at the centroid"
        );
    }

    #[test]
    fn barycentric_derivatives_match_finite_differences() {
        for e in [Element::P1Bubble, Element::P2, Element::P2Bubble] {
            let l = [0.2, 0.3, 0.5];
            let b = e.basis(l);
            let h = 1e-6;
            for k in 0..3 {
                let mut lp = l;
                lp[k] += h;
                let mut lm = l;
                lm[k] -= h;
                let (bp, bm) = (e.basis(lp), e.basis(lm));
                for i in 0..e.n_local() {
                    let fd = (bp.values[i] - bm.values[i]) / (2.0 * h);
                    assert!((fd - b.d_lambda[i][k]).abs() < 1e-8);
                }
            }
        }
    }
}
