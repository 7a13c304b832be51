//! Triangle meshes: the MSH 2.2 reader (the format gmsh writes for FreeFEM's
//! `gmshload`), validation, edges and boundary tags.
//!
//! The reader keeps the file's vertex order, triangle order and the vertex
//! order inside each triangle (FreeFEM's `gmshload` does the same, so results
//! can be compared vertex by vertex). Node tags may be non-contiguous: vertex
//! `i` is the `i`-th node of `$Nodes`, whatever its tag.
//!
//! Validation rejects (naming the element number or node tag of the file):
//! degenerate triangles (|area| <= 1e-12 · longest edge²), clockwise
//! (inverted) triangles — they are NOT silently reoriented, FreeFEM fails on
//! them too —, duplicate triangles, undefined node references, vertices used
//! by no triangle, edges shared by more than two triangles or by two
//! overlapping triangles, boundary edges of the triangulation without a tagged
//! line element ("missing boundary tag"), line elements that are not boundary
//! edges, meshes without triangles, non-finite coordinates, and truncated or
//! malformed files. The reader never panics on any input.

use crate::error::{Error, Result};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

mod locate;
mod msh;
mod refine;
mod topology;
mod validate;

pub use locate::PointLocator;
pub use refine::{BoundaryGeometry, Circle, Hierarchy};
use validate::*;

/// A boundary segment read from the mesh file (gmsh line element).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoundaryEdge {
    /// Vertex indices (zero-based, file order).
    pub vertices: [usize; 2],
    /// Physical tag of the line element (first tag in MSH 2.2).
    pub tag: i32,
}

/// A 2-D triangle mesh. Vertex and triangle orders are those of the file;
/// triangles are counter-clockwise (positive area) after validation.
#[derive(Debug, Clone)]
pub struct Mesh {
    pub vertices: Vec<[f64; 2]>,
    pub triangles: Vec<[usize; 3]>,
    pub boundary_edges: Vec<BoundaryEdge>,
    /// Physical names of the file's `$PhysicalNames` section, by tag.
    pub physical_names: BTreeMap<i32, String>,
    /// All edges as [a, b] with a < b, in order of first appearance when
    /// scanning triangles in order and, in each, local edges 0, 1, 2.
    pub edges: Vec<[usize; 2]>,
    /// For each triangle, the global edge opposite its local vertex i
    /// (local edge i joins local vertices i+1 and i+2, mod 3).
    pub triangle_edges: Vec<[usize; 3]>,
    /// The file the mesh came from (for error messages); empty if built in memory.
    pub source: PathBuf,
}

/// A hash map keyed by vertex indices ([a, b] edges, sorted triangles):
/// the keys are the mesh's own small integers, so a multiplicative hash
/// serves (SipHash's protection against chosen keys buys nothing here, and
/// costs half of validating a mesh of 2M triangles).
pub(crate) type VertexMap<K, V> = HashMap<K, V, std::hash::BuildHasherDefault<VertexHasher>>;

/// The hash of [`VertexMap`]: each 8 bytes folded in by a multiply and a
/// rotation (the constant of rustc's FxHash).
#[derive(Default, Clone, Copy)]
pub(crate) struct VertexHasher(u64);

impl std::hash::Hasher for VertexHasher {
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut word = [0u8; 8];
            word[..chunk.len()].copy_from_slice(chunk);
            self.write_u64(u64::from_le_bytes(word));
        }
    }
    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_usize(&mut self, i: usize) {
        self.write_u64(i as u64);
    }
    fn finish(&self) -> u64 {
        self.0
    }
}

/// Relative threshold of the degenerate-triangle test:
/// |area| <= DEGENERATE_RTOL · (longest edge)².
pub const DEGENERATE_RTOL: f64 = 1e-12;

impl Mesh {
    /// Build from parts and validate (no degenerate, inverted or duplicate triangles,
    /// every boundary edge of the triangulation carries a tag).
    ///
    /// Error messages name vertices, triangles and boundary edges by their
    /// zero-based index in the given vectors.
    pub fn from_parts(
        vertices: Vec<[f64; 2]>,
        triangles: Vec<[usize; 3]>,
        boundary_edges: Vec<BoundaryEdge>,
        physical_names: BTreeMap<i32, String>,
        source: PathBuf,
    ) -> Result<Mesh> {
        build(
            vertices,
            triangles,
            boundary_edges,
            physical_names,
            source,
            &Labels::Parts,
        )
    }
    /// A mesh from vertices and triangles alone (e.g. read back from a result
    /// file): every boundary edge gets the tag 0, with no physical name.
    pub fn from_triangles(
        vertices: Vec<[f64; 2]>,
        triangles: Vec<[usize; 3]>,
        source: PathBuf,
    ) -> Result<Mesh> {
        let mut count: VertexMap<[usize; 2], (usize, [usize; 2])> = VertexMap::default();
        let mut order = Vec::new();
        for tri in &triangles {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let key = [a.min(b), a.max(b)];
                let entry = count.entry(key).or_insert_with(|| {
                    order.push(key);
                    (0, [a, b])
                });
                entry.0 += 1;
            }
        }
        let boundary_edges = order
            .iter()
            .filter(|k| count[*k].0 == 1)
            .map(|k| BoundaryEdge {
                vertices: count[k].1,
                tag: 0,
            })
            .collect();
        Mesh::from_parts(vertices, triangles, boundary_edges, BTreeMap::new(), source)
    }

    pub fn n_vertices(&self) -> usize {
        self.vertices.len()
    }
    pub fn n_triangles(&self) -> usize {
        self.triangles.len()
    }
    pub fn n_edges(&self) -> usize {
        self.edges.len()
    }
    /// Signed area of triangle t (positive after validation).
    pub fn area(&self, t: usize) -> f64 {
        let [a, b, c] = self.triangles[t];
        signed_area(self.vertices[a], self.vertices[b], self.vertices[c])
    }
    /// Sum of the triangle areas.
    pub fn total_area(&self) -> f64 {
        (0..self.n_triangles()).map(|t| self.area(t)).sum()
    }
    /// Length of global edge e.
    pub fn edge_length(&self, e: usize) -> f64 {
        let [a, b] = self.edges[e];
        dist(self.vertices[a], self.vertices[b])
    }
    /// Longest edge over all triangles (the mesh size h).
    pub fn h_max(&self) -> f64 {
        (0..self.n_edges())
            .map(|e| self.edge_length(e))
            .fold(0.0, f64::max)
    }
    /// Shortest edge (the smallest element of a graded mesh).
    pub fn h_min(&self) -> f64 {
        (0..self.n_edges())
            .map(|e| self.edge_length(e))
            .fold(f64::INFINITY, f64::min)
    }
    /// Tag of a physical name, if the file named it.
    pub fn tag_by_name(&self, name: &str) -> Option<i32> {
        self.physical_names
            .iter()
            .find(|(_, n)| n.as_str() == name)
            .map(|(&t, _)| t)
    }
}

/// Signed area of the triangle (p0, p1, p2): positive when counter-clockwise.
pub fn signed_area(p0: [f64; 2], p1: [f64; 2], p2: [f64; 2]) -> f64 {
    0.5 * ((p1[0] - p0[0]) * (p2[1] - p0[1]) - (p2[0] - p0[0]) * (p1[1] - p0[1]))
}

fn dist(p: [f64; 2], q: [f64; 2]) -> f64 {
    (q[0] - p[0]).hypot(q[1] - p[1])
}
