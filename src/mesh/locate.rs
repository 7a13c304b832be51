//! `PointLocator`: the triangle containing a point.

use super::*;

/// Finds the triangle containing a point, with a uniform bucket grid over
/// the triangles' bounding boxes (built once, O(1) expected per query).
/// Used to evaluate a field of one mesh at points of another (errors against
/// a finer mesh) and at probe points (the gap at the origin).
pub struct PointLocator<'m> {
    mesh: &'m Mesh,
    origin: [f64; 2],
    cell: [f64; 2],
    dims: [usize; 2],
    buckets: Vec<Vec<usize>>,
}

impl<'m> PointLocator<'m> {
    pub fn new(mesh: &'m Mesh) -> Self {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for v in &mesh.vertices {
            for d in 0..2 {
                lo[d] = lo[d].min(v[d]);
                hi[d] = hi[d].max(v[d]);
            }
        }
        // About one triangle per bucket.
        let side = (mesh.n_triangles().max(1) as f64).sqrt().ceil() as usize;
        let dims = [side.max(1), side.max(1)];
        let cell = [0, 1].map(|d| ((hi[d] - lo[d]) / dims[d] as f64).max(f64::MIN_POSITIVE));
        let mut locator = PointLocator {
            mesh,
            origin: lo,
            cell,
            dims,
            buckets: vec![Vec::new(); dims[0] * dims[1]],
        };
        for (t, tri) in mesh.triangles.iter().enumerate() {
            let (mut a, mut b) = ([usize::MAX; 2], [0usize; 2]);
            for &v in tri {
                let c = locator.cell_of(mesh.vertices[v]);
                for d in 0..2 {
                    a[d] = a[d].min(c[d]);
                    b[d] = b[d].max(c[d]);
                }
            }
            for i in a[0]..=b[0] {
                for j in a[1]..=b[1] {
                    locator.buckets[i * dims[1] + j].push(t);
                }
            }
        }
        locator
    }

    fn cell_of(&self, x: [f64; 2]) -> [usize; 2] {
        [0, 1].map(|d| {
            let i = ((x[d] - self.origin[d]) / self.cell[d]).floor();
            (i.max(0.0) as usize).min(self.dims[d] - 1)
        })
    }

    /// The triangle containing `x` and its barycentric coordinates, allowing
    /// points up to a relative 1e-10 outside a triangle (edges, round-off);
    /// None outside the mesh.
    pub fn locate(&self, x: [f64; 2]) -> Option<(usize, [f64; 3])> {
        let c = self.cell_of(x);
        let mut best: Option<(usize, [f64; 3], f64)> = None;
        for &t in &self.buckets[c[0] * self.dims[1] + c[1]] {
            let l = self.barycentric(t, x);
            let worst = l.iter().fold(f64::INFINITY, |m, v| m.min(*v));
            if best.as_ref().is_none_or(|b| worst > b.2) {
                best = Some((t, l, worst));
            }
        }
        best.filter(|b| b.2 >= -1e-10).map(|(t, l, _)| (t, l))
    }

    fn barycentric(&self, t: usize, x: [f64; 2]) -> [f64; 3] {
        let [p0, p1, p2] = self.mesh.triangles[t].map(|v| self.mesh.vertices[v]);
        let area = signed_area(p0, p1, p2);
        [
            signed_area(x, p1, p2) / area,
            signed_area(p0, x, p2) / area,
            signed_area(p0, p1, x) / area,
        ]
    }
}
