//! Uniform refinement and nested mesh hierarchies (issue 45, multigrid).
//!
//! [`Mesh::refine_uniform`] splits every triangle in four by its edge
//! midpoints. The numbering makes the nesting explicit, and the
//! prolongations rely on it:
//!
//! - the coarse vertices keep their indices `0..n` and coordinates;
//! - fine vertex `n + e` is the midpoint of coarse edge `e` (`mesh.edges[e]`),
//!   snapped onto the boundary curve when `e` is a boundary edge of a known
//!   curve ([`BoundaryGeometry`]);
//! - coarse triangle `t` = [a, b, c] becomes fine triangles `4t..4t+4`:
//!   [a, m_ab, m_ca], [m_ab, b, m_bc], [m_ca, m_bc, c], [m_ab, m_bc, m_ca]
//!   (each counter-clockwise when its parent is);
//! - coarse boundary edge `k` = [a, b] with tag τ becomes fine boundary
//!   edges `2k` = [a, m] and `2k + 1` = [m, b], both tagged τ, so physical
//!   groups (Dirichlet parts, loads on parts) carry over.
//!
//! The `.msh` file does not say which curve a boundary line discretises, so
//! the geometry is given ([`BoundaryGeometry::circle`]) or recognised from
//! the coarse vertices ([`BoundaryGeometry::detect`]: the circles of
//! `meshes/disk.geo`). Where it is not known, a new boundary vertex stays at
//! the chord's midpoint: the refined domain is the coarse polygon, and a
//! curved boundary stays as coarse as the coarse mesh drew it.

use super::*;

/// A boundary part that is an arc of a circle: new vertices on the edges
/// tagged `tag` are projected radially onto it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle {
    pub tag: i32,
    pub center: [f64; 2],
    pub radius: f64,
}

/// What is known of the curves behind the boundary parts; parts not listed
/// are straight (their new vertices stay at the midpoints).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BoundaryGeometry {
    pub circles: Vec<Circle>,
}

/// Fewest distinct vertices of a part that [`BoundaryGeometry::detect`]
/// takes for a circle: four or five points of a polygon can be concyclic by
/// construction (a square's corners), eight on a common circle are an arc.
pub const DETECT_MIN_VERTICES: usize = 8;

/// Relative distance to the circle (of its radius) within which every
/// vertex of a part must lie for [`BoundaryGeometry::detect`].
pub const DETECT_RTOL: f64 = 1e-9;

impl BoundaryGeometry {
    /// Every boundary part straight: midpoints stay.
    pub fn straight() -> Self {
        Self::default()
    }

    /// The part `tag` lies on the circle of `center` and `radius`.
    pub fn circle(tag: i32, center: [f64; 2], radius: f64) -> Self {
        BoundaryGeometry {
            circles: vec![Circle {
                tag,
                center,
                radius,
            }],
        }
    }

    /// The circles of the mesh's boundary parts: a part (tag) with at least
    /// [`DETECT_MIN_VERTICES`] distinct vertices, all within
    /// [`DETECT_RTOL`]·r of the circle through three of them spread along
    /// it, is taken for an arc of that circle (`meshes/disk.geo`: the part
    /// "boundary" on the unit circle). Parts on a line or off any circle are
    /// straight. A polygon of eight or more concyclic vertices (a regular
    /// octagon meant as one) is taken for its circle: give such a geometry
    /// explicitly instead.
    pub fn detect(mesh: &Mesh) -> Self {
        let mut by_tag: BTreeMap<i32, Vec<usize>> = BTreeMap::new();
        for be in &mesh.boundary_edges {
            by_tag.entry(be.tag).or_default().extend(be.vertices);
        }
        let circles = by_tag
            .into_iter()
            .filter_map(|(tag, mut vs)| {
                vs.sort_unstable();
                vs.dedup();
                let points: Vec<[f64; 2]> = vs.iter().map(|&v| mesh.vertices[v]).collect();
                fitted_circle(&points).map(|(center, radius)| Circle {
                    tag,
                    center,
                    radius,
                })
            })
            .collect();
        BoundaryGeometry { circles }
    }

    /// Where the new vertex of a boundary edge of part `tag` with chord
    /// midpoint `m` goes.
    pub fn place(&self, tag: i32, m: [f64; 2]) -> [f64; 2] {
        match self.circles.iter().find(|c| c.tag == tag) {
            Some(c) => {
                let (dx, dy) = (m[0] - c.center[0], m[1] - c.center[1]);
                let d = dx.hypot(dy);
                if d == 0.0 {
                    return m;
                }
                let s = c.radius / d;
                [c.center[0] + s * dx, c.center[1] + s * dy]
            }
            None => m,
        }
    }
}

/// The circle through all `points` (see [`BoundaryGeometry::detect`]).
fn fitted_circle(points: &[[f64; 2]]) -> Option<([f64; 2], f64)> {
    if points.len() < DETECT_MIN_VERTICES {
        return None;
    }
    // Three points spread along the part: the first, the farthest from it,
    // and the one farthest from the line through those two.
    let p = points[0];
    let far = |from: [f64; 2]| {
        points
            .iter()
            .copied()
            .max_by(|a, b| dist(from, *a).total_cmp(&dist(from, *b)))
    };
    let q = far(p)?;
    let r = points.iter().copied().max_by(|a, b| {
        signed_area(p, q, *a)
            .abs()
            .total_cmp(&signed_area(p, q, *b).abs())
    })?;
    let det = 2.0 * signed_area(p, q, r) * 2.0;
    let scale = dist(p, q);
    if det.abs() <= 1e-12 * scale * scale {
        return None; // collinear: a straight part
    }
    // Circumcentre of p, q, r.
    let (b, c) = ([q[0] - p[0], q[1] - p[1]], [r[0] - p[0], r[1] - p[1]]);
    let (b2, c2) = (b[0] * b[0] + b[1] * b[1], c[0] * c[0] + c[1] * c[1]);
    let ux = (c[1] * b2 - b[1] * c2) / det;
    let uy = (b[0] * c2 - c[0] * b2) / det;
    let center = [p[0] + ux, p[1] + uy];
    let radius = ux.hypot(uy);
    let on_circle = points
        .iter()
        .all(|&x| (dist(center, x) - radius).abs() <= DETECT_RTOL * radius);
    on_circle.then_some((center, radius))
}

impl Mesh {
    /// The uniform refinement: every triangle split in four by its edge
    /// midpoints, new boundary vertices placed by `geometry`; numbering as
    /// in the [module docs](self). The result is validated like any mesh
    /// (a snapped vertex that inverts a triangle is an error naming it).
    pub fn refine_uniform(&self, geometry: &BoundaryGeometry) -> Result<Mesh> {
        let n = self.n_vertices();
        let mut vertices = Vec::with_capacity(n + self.n_edges());
        vertices.extend_from_slice(&self.vertices);
        vertices.extend(self.edges.iter().map(|&[a, b]| {
            let (p, q) = (self.vertices[a], self.vertices[b]);
            [0.5 * (p[0] + q[0]), 0.5 * (p[1] + q[1])]
        }));
        // The boundary edges' indices among all edges (a map of the few
        // boundary edges, not of all of them).
        let wanted: super::VertexMap<[usize; 2], usize> = self
            .boundary_edges
            .iter()
            .enumerate()
            .map(|(l, be)| {
                let [a, b] = be.vertices;
                ([a.min(b), a.max(b)], l)
            })
            .collect();
        let mut edge_of_boundary = vec![0usize; self.boundary_edges.len()];
        for (e, key) in self.edges.iter().enumerate() {
            if let Some(&l) = wanted.get(key) {
                edge_of_boundary[l] = e;
            }
        }
        let mut boundary_edges = Vec::with_capacity(2 * self.boundary_edges.len());
        for (be, &e) in self.boundary_edges.iter().zip(&edge_of_boundary) {
            let [a, b] = be.vertices;
            let m = n + e;
            vertices[m] = geometry.place(be.tag, vertices[m]);
            boundary_edges.push(BoundaryEdge {
                vertices: [a, m],
                tag: be.tag,
            });
            boundary_edges.push(BoundaryEdge {
                vertices: [m, b],
                tag: be.tag,
            });
        }
        let mut triangles = Vec::with_capacity(4 * self.n_triangles());
        for (tri, edges) in self.triangles.iter().zip(&self.triangle_edges) {
            let [a, b, c] = *tri;
            // Local edge i is opposite local vertex i.
            let (m_bc, m_ca, m_ab) = (n + edges[0], n + edges[1], n + edges[2]);
            triangles.push([a, m_ab, m_ca]);
            triangles.push([m_ab, b, m_bc]);
            triangles.push([m_ca, m_bc, c]);
            triangles.push([m_ab, m_bc, m_ca]);
        }
        Mesh::from_parts(
            vertices,
            triangles,
            boundary_edges,
            self.physical_names.clone(),
            self.source.clone(),
        )
    }
}

/// Nested meshes: `levels[0]` the coarse mesh, `levels[l + 1]` the uniform
/// refinement of `levels[l]` ([`Mesh::refine_uniform`], so the numbering of
/// the module docs links consecutive levels).
#[derive(Debug, Clone)]
pub struct Hierarchy {
    pub levels: Vec<Mesh>,
    pub geometry: BoundaryGeometry,
}

impl Hierarchy {
    /// The coarse mesh and `refinements` uniform refinements of it
    /// (`refinements + 1` levels).
    pub fn new(coarse: Mesh, refinements: usize, geometry: BoundaryGeometry) -> Result<Self> {
        let mut levels = Vec::with_capacity(refinements + 1);
        levels.push(coarse);
        for _ in 0..refinements {
            let next = levels[levels.len() - 1].refine_uniform(&geometry)?;
            levels.push(next);
        }
        Ok(Hierarchy { levels, geometry })
    }

    /// [`Hierarchy::new`] with the circles [`BoundaryGeometry::detect`]
    /// finds on the coarse mesh.
    pub fn detected(coarse: Mesh, refinements: usize) -> Result<Self> {
        let geometry = BoundaryGeometry::detect(&coarse);
        Self::new(coarse, refinements, geometry)
    }

    pub fn n_levels(&self) -> usize {
        self.levels.len()
    }

    pub fn finest(&self) -> &Mesh {
        &self.levels[self.levels.len() - 1]
    }
}
