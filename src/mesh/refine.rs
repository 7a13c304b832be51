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
    /// in the [module docs](self).
    ///
    /// The refined mesh is built from this mesh's topology (edges, triangle
    /// edges, boundary edges), with the fields [`Mesh::from_parts`] derives
    /// numbered as it numbers them, without validating it anew: the split
    /// of a valid triangulation is a valid triangulation (no duplicate
    /// triangles, stray vertices, non-manifold or overlapping edges, every
    /// boundary edge tagged). What can go wrong is geometric, and is
    /// checked: a new vertex that is not finite (a midpoint overflowing
    /// f64), and a child triangle that is degenerate or inverted (a vertex
    /// snapped onto its circle across the opposite edge); the error names
    /// the child triangle and its coarse triangle.
    pub fn refine_uniform(&self, geometry: &BoundaryGeometry) -> Result<Mesh> {
        let n = self.n_vertices();
        let mut vertices = Vec::with_capacity(n + self.n_edges());
        vertices.extend_from_slice(&self.vertices);
        vertices.extend(self.edges.iter().map(|&[a, b]| {
            let (p, q) = (self.vertices[a], self.vertices[b]);
            [0.5 * (p[0] + q[0]), 0.5 * (p[1] + q[1])]
        }));
        let mut boundary_edges = Vec::with_capacity(2 * self.boundary_edges.len());
        for (be, e) in (self.boundary_edges.iter()).zip(self.boundary_edge_global_indices()) {
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
        let refinement = || {
            format!(
                "the uniform refinement of the mesh of {n} vertices and {} triangles",
                self.n_triangles()
            )
        };
        if let Some(v) = (n..vertices.len()).find(|&v| !vertices[v].iter().all(|x| x.is_finite())) {
            let [x, y] = vertices[v];
            return Err(Error::mesh(
                self.source.clone(),
                format!(
                    "{}: vertex {v} (zero-based; the midpoint of edge {}) has non-finite \
                     coordinates ({x}, {y})",
                    refinement(),
                    v - n
                ),
            ));
        }

        // Child edges, numbered by first appearance over the child triangles
        // in order and, in each, local edges 0, 1, 2 (as `validate::build`
        // numbers them). Coarse triangle t = [a, b, c] brings, in that
        // order: the interior edge m_ab–m_ca, the halves of ca and ab at a,
        // the half of bc at b, the interior edge m_bc–m_ab, the half of ab
        // at b, the halves of bc and ca at c, the interior edge m_ca–m_bc.
        // A half is new in the first coarse triangle that holds its coarse
        // edge, both halves of which its children hold; interior edges are
        // new in theirs. Half-edge keys [v, n + e] have v < n <= n + e.
        let n_edges = 2 * self.n_edges() + 3 * self.n_triangles();
        let mut edges: Vec<[usize; 2]> = Vec::with_capacity(n_edges);
        let mut halves = vec![[usize::MAX; 2]; self.n_edges()];
        let mut half = |edges: &mut Vec<[usize; 2]>, e: usize, v: usize| {
            let slot = &mut halves[e][usize::from(self.edges[e][0] != v)];
            if *slot == usize::MAX {
                *slot = edges.len();
                edges.push([v, n + e]);
            }
            *slot
        };
        let interior = |edges: &mut Vec<[usize; 2]>, p: usize, q: usize| {
            edges.push([p.min(q), p.max(q)]);
            edges.len() - 1
        };
        let mut triangles = Vec::with_capacity(4 * self.n_triangles());
        let mut triangle_edges = Vec::with_capacity(4 * self.n_triangles());
        for (tri, te) in self.triangles.iter().zip(&self.triangle_edges) {
            let [a, b, c] = *tri;
            // Local edge i is opposite local vertex i.
            let [e_bc, e_ca, e_ab] = *te;
            let (m_bc, m_ca, m_ab) = (n + e_bc, n + e_ca, n + e_ab);
            triangles.push([a, m_ab, m_ca]);
            triangles.push([m_ab, b, m_bc]);
            triangles.push([m_ca, m_bc, c]);
            triangles.push([m_ab, m_bc, m_ca]);
            let i_a = interior(&mut edges, m_ab, m_ca);
            let ca_a = half(&mut edges, e_ca, a);
            let ab_a = half(&mut edges, e_ab, a);
            let bc_b = half(&mut edges, e_bc, b);
            let i_b = interior(&mut edges, m_bc, m_ab);
            let ab_b = half(&mut edges, e_ab, b);
            let bc_c = half(&mut edges, e_bc, c);
            let ca_c = half(&mut edges, e_ca, c);
            let i_c = interior(&mut edges, m_ca, m_bc);
            triangle_edges.push([i_a, ca_a, ab_a]);
            triangle_edges.push([bc_b, i_b, ab_b]);
            triangle_edges.push([bc_c, ca_c, i_c]);
            triangle_edges.push([i_c, i_a, i_b]);
        }
        debug_assert_eq!(edges.len(), n_edges);

        for (t, tri) in triangles.iter().enumerate() {
            if let Some(bad) = BadShape::of(tri.map(|v| vertices[v])) {
                let advice = match bad {
                    BadShape::NotFinite => "",
                    _ => {
                        "; the coarse triangle is valid, so a new boundary vertex placed \
                         on its circle spoils it: the coarse mesh is too coarse along \
                         the curve (refine it, e.g. a larger mesh.n)"
                    }
                };
                return Err(Error::mesh(
                    self.source.clone(),
                    format!(
                        "{}: triangle {t} (zero-based; vertices {} {} {}; child {} of coarse \
                         triangle {}): {}{advice}",
                        refinement(),
                        tri[0],
                        tri[1],
                        tri[2],
                        t % 4,
                        t / 4,
                        bad.what()
                    ),
                ));
            }
        }

        Ok(Mesh {
            vertices,
            triangles,
            boundary_edges,
            physical_names: self.physical_names.clone(),
            edges,
            triangle_edges,
            source: self.source.clone(),
        })
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
        for k in 1..=refinements {
            let next = levels[k - 1]
                .refine_uniform(&geometry)
                .map_err(|e| match e {
                    Error::Mesh { file, reason } => Error::Mesh {
                        file,
                        reason: format!("refinement {k} of {refinements}: {reason}"),
                    },
                    e => e,
                })?;
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A quarter disk of radius 1 around the origin: the centre, a ring of
    /// radius 0.5 and the arc, five points each at angles 0, π/8, .., π/2.
    /// Tags: 1 the x-axis side, 2 the arc, 3 the y-axis side. Triangles and
    /// boundary edges are listed out of order, some turned, so that edge
    /// numbering by first appearance is not the natural one.
    fn quarter_disk() -> Mesh {
        let point = |r: f64, j: usize| {
            let a = j as f64 * std::f64::consts::FRAC_PI_8;
            [r * a.cos(), r * a.sin()]
        };
        let mut vertices = vec![[0.0, 0.0]];
        vertices.extend((0..5).map(|j| point(0.5, j)));
        vertices.extend((0..5).map(|j| point(1.0, j)));
        let (inner, outer) = (|j: usize| 1 + j, |j: usize| 6 + j);
        let mut triangles = Vec::new();
        for j in 0..4 {
            triangles.push([0, inner(j), inner(j + 1)]);
            triangles.push([inner(j), outer(j), outer(j + 1)]);
            triangles.push([inner(j), outer(j + 1), inner(j + 1)]);
        }
        let mut shuffled: Vec<[usize; 3]> = (0..triangles.len())
            .map(|k| triangles[(5 * k + 3) % triangles.len()])
            .collect();
        for (k, tri) in shuffled.iter_mut().enumerate() {
            tri.rotate_left(k % 3);
        }
        let b = |vertices: [usize; 2], tag| BoundaryEdge { vertices, tag };
        let boundary_edges = vec![
            b([outer(2), outer(3)], 2),
            b([inner(0), 0], 1),
            b([outer(4), inner(4)], 3),
            b([outer(1), outer(0)], 2),
            b([0, inner(4)], 3),
            b([outer(3), outer(4)], 2),
            b([inner(0), outer(0)], 1),
            b([outer(1), outer(2)], 2),
            // A second line element on an arc edge (another physical line).
            b([outer(3), outer(2)], 5),
        ];
        let names = BTreeMap::from([(2, "arc".to_string()), (4, "domain".to_string())]);
        Mesh::from_parts(
            vertices,
            shuffled,
            boundary_edges,
            names,
            PathBuf::from("quarter.msh"),
        )
        .unwrap()
    }

    fn assert_same(built: &Mesh, validated: &Mesh) {
        assert_eq!(built.vertices, validated.vertices);
        assert_eq!(built.triangles, validated.triangles);
        assert_eq!(built.boundary_edges, validated.boundary_edges);
        assert_eq!(built.physical_names, validated.physical_names);
        assert_eq!(built.edges, validated.edges);
        assert_eq!(built.triangle_edges, validated.triangle_edges);
        assert_eq!(built.source, validated.source);
    }

    /// The refinement built from the coarse topology is the mesh that
    /// validating its vertices, triangles and boundary edges gives, field by
    /// field, on every level (arc snapped onto its circle, straight sides).
    #[test]
    fn refinement_by_construction_is_the_validated_mesh() {
        let geometry = BoundaryGeometry::circle(2, [0.0, 0.0], 1.0);
        let h = Hierarchy::new(quarter_disk(), 3, geometry).unwrap();
        for fine in &h.levels[1..] {
            let validated = build(
                fine.vertices.clone(),
                fine.triangles.clone(),
                fine.boundary_edges.clone(),
                fine.physical_names.clone(),
                fine.source.clone(),
                &Labels::Parts,
            )
            .unwrap();
            assert_same(fine, &validated);
        }
        let finest = h.finest();
        assert_eq!(finest.n_triangles(), 12 * 4usize.pow(3));
        for be in finest.boundary_edges.iter().filter(|be| be.tag == 2) {
            for v in be.vertices {
                let [x, y] = finest.vertices[v];
                assert!((x.hypot(y) - 1.0).abs() < 1e-15);
            }
        }
    }

    /// A vertex snapped across the opposite side inverts child triangles:
    /// an error naming the refinement, the child and its coarse triangle.
    #[test]
    fn a_snap_that_inverts_a_triangle_is_an_error() {
        let b = |vertices: [usize; 2], tag| BoundaryEdge { vertices, tag };
        let coarse = Mesh::from_parts(
            vec![[0.0, 0.0], [1.0, 0.0], [0.5, 0.1]],
            vec![[0, 1, 2]],
            vec![b([0, 1], 1), b([1, 2], 2), b([2, 0], 2)],
            BTreeMap::new(),
            PathBuf::from("thin.msh"),
        )
        .unwrap();
        // The bottom side on a circle below it, of radius 1.2: its midpoint
        // (0.5, 0) goes to (0.5, 0.2), above the apex.
        let geometry = BoundaryGeometry::circle(1, [0.5, -1.0], 1.2);
        let e = Hierarchy::new(coarse, 2, geometry).unwrap_err().to_string();
        for part in [
            "thin.msh",
            "refinement 1 of 2",
            "triangle 0 (zero-based",
            "child 0 of coarse triangle 0",
            "inverted",
        ] {
            assert!(e.contains(part), "`{e}` does not mention `{part}`");
        }
    }
}
