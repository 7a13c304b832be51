//! Edges and boundary tags: edge lookup, boundary edge indices and masks.

use super::*;

impl Mesh {
    /// Global edge index of the edge joining vertices a and b (either order).
    /// A linear scan: for repeated queries use [`Mesh::edge_lookup`].
    pub fn edge_index(&self, a: usize, b: usize) -> Option<usize> {
        let key = [a.min(b), a.max(b)];
        self.edges.iter().position(|&e| e == key)
    }
    /// Map from [a, b] (a < b) to the global edge index.
    pub fn edge_lookup(&self) -> HashMap<[usize; 2], usize> {
        self.edges
            .iter()
            .enumerate()
            .map(|(i, &e)| (e, i))
            .collect()
    }
    /// For each global edge, the triangles on either side: `[t, None]` on the
    /// boundary, `[t1, Some(t2)]` inside (t1 < t2).
    pub fn edge_triangles(&self) -> Vec<[Option<usize>; 2]> {
        let mut sides = vec![[None, None]; self.n_edges()];
        for (t, edges) in self.triangle_edges.iter().enumerate() {
            for &e in edges {
                let side = if sides[e][0].is_none() { 0 } else { 1 };
                sides[e][side] = Some(t);
            }
        }
        sides
    }
    /// For each entry of `boundary_edges`, its global edge index. A line
    /// element is an edge that one triangle holds (validated), so only
    /// those edges are put in the map, not every edge.
    pub fn boundary_edge_global_indices(&self) -> Vec<usize> {
        let mut sides = vec![0u8; self.n_edges()];
        for te in &self.triangle_edges {
            for &e in te {
                sides[e] = sides[e].saturating_add(1);
            }
        }
        let boundary: VertexMap<[usize; 2], usize> = (self.edges.iter().enumerate())
            .filter(|&(e, _)| sides[e] == 1)
            .map(|(e, &key)| (key, e))
            .collect();
        self.boundary_edges
            .iter()
            .filter_map(|be| {
                let [a, b] = be.vertices;
                boundary.get(&[a.min(b), a.max(b)]).copied()
            })
            .collect()
    }
    /// Flags the vertices on boundary edges whose tag is in `tags` (all tags if None).
    pub fn boundary_vertex_mask(&self, tags: Option<&[i32]>) -> Vec<bool> {
        let mut mask = vec![false; self.n_vertices()];
        for be in self
            .boundary_edges
            .iter()
            .filter(|be| tag_selected(be.tag, tags))
        {
            for &v in &be.vertices {
                if let Some(m) = mask.get_mut(v) {
                    *m = true;
                }
            }
        }
        mask
    }
    /// Flags the global edges that are boundary edges with a tag in `tags` (all if None).
    pub fn boundary_edge_mask(&self, tags: Option<&[i32]>) -> Vec<bool> {
        let mut mask = vec![false; self.n_edges()];
        let indices = self.boundary_edge_global_indices();
        for (be, e) in self.boundary_edges.iter().zip(indices) {
            if tag_selected(be.tag, tags) {
                mask[e] = true;
            }
        }
        mask
    }
}

pub(super) fn tag_selected(tag: i32, tags: Option<&[i32]>) -> bool {
    tags.is_none_or(|ts| ts.contains(&tag))
}
