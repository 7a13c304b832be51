//! Validation: builds a `Mesh` from parsed or given parts, rejecting bad
//! triangles, references and boundary tags with a message naming the element.

use super::*;

/// How error messages name vertices, triangles and line elements.
pub(super) enum Labels {
    /// Built in memory: zero-based indices.
    Parts,
    /// Read from a file: node tags and element numbers of the file.
    File {
        node_tags: Vec<usize>,
        triangle_elements: Vec<usize>,
        line_elements: Vec<usize>,
    },
}

impl Labels {
    fn node(&self, v: usize) -> String {
        match self {
            Labels::Parts => format!("{v}"),
            Labels::File { node_tags, .. } => match node_tags.get(v) {
                Some(tag) => format!("{tag}"),
                None => format!("#{v}"),
            },
        }
    }
    fn vertex(&self, v: usize) -> String {
        match self {
            Labels::Parts => format!("vertex {v} (zero-based)"),
            Labels::File { .. } => format!("node {}", self.node(v)),
        }
    }
    fn triangle_id(&self, t: usize) -> String {
        match self {
            Labels::Parts => format!("triangle {t} (zero-based)"),
            Labels::File {
                triangle_elements, ..
            } => match triangle_elements.get(t) {
                Some(num) => format!("element {num} (triangle)"),
                None => format!("triangle #{t}"),
            },
        }
    }
    fn triangle(&self, t: usize, tri: &[usize; 3]) -> String {
        let nodes = |s: &Self| tri.iter().map(|&v| s.node(v)).collect::<Vec<_>>().join(" ");
        match self {
            Labels::Parts => format!("triangle {t} (zero-based; vertices {})", nodes(self)),
            Labels::File {
                triangle_elements, ..
            } => match triangle_elements.get(t) {
                Some(num) => format!("element {num} (triangle, nodes {})", nodes(self)),
                None => format!("triangle #{t} (nodes {})", nodes(self)),
            },
        }
    }
    fn line(&self, l: usize, edge: &BoundaryEdge) -> String {
        let [a, b] = edge.vertices;
        match self {
            Labels::Parts => format!(
                "boundary edge {l} (zero-based; vertices {a} {b}, tag {})",
                edge.tag
            ),
            Labels::File { line_elements, .. } => {
                let nodes = format!("nodes {} {}, tag {}", self.node(a), self.node(b), edge.tag);
                match line_elements.get(l) {
                    Some(num) => format!("element {num} (line, {nodes})"),
                    None => format!("line #{l} ({nodes})"),
                }
            }
        }
    }
}

/// What is wrong with the shape of a triangle.
pub(super) enum BadShape {
    /// The area or the longest edge is not finite.
    NotFinite,
    /// |area| <= [`DEGENERATE_RTOL`] · longest edge².
    Degenerate { area: f64, longest: f64 },
    /// Clockwise: negative signed area.
    Inverted { area: f64 },
}

impl BadShape {
    /// The triangle (p0, p1, p2)'s fault, if it has one.
    pub(super) fn of([p0, p1, p2]: [[f64; 2]; 3]) -> Option<BadShape> {
        let area = signed_area(p0, p1, p2);
        // Most triangles pass by far: the squared edge lengths (no hypot)
        // show it. They lie within a few ulps of the squared `dist`s when
        // normal, so the margin of 2 over the test below leaves no doubt;
        // the others take the test itself.
        let squared = |p: [f64; 2], q: [f64; 2]| {
            let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
            dx * dx + dy * dy
        };
        let longest2 = squared(p0, p1).max(squared(p1, p2)).max(squared(p2, p0));
        if longest2.is_finite()
            && longest2 >= 1e6 * f64::MIN_POSITIVE
            && area.is_finite()
            && area > 2.0 * DEGENERATE_RTOL * longest2
        {
            return None;
        }
        let longest = dist(p0, p1).max(dist(p1, p2)).max(dist(p2, p0));
        if !area.is_finite() || !longest.is_finite() {
            Some(BadShape::NotFinite)
        } else if area.abs() <= DEGENERATE_RTOL * longest * longest {
            Some(BadShape::Degenerate { area, longest })
        } else if area < 0.0 {
            Some(BadShape::Inverted { area })
        } else {
            None
        }
    }

    /// What the fault is, for an error message.
    pub(super) fn what(&self) -> String {
        match self {
            BadShape::NotFinite => "the area is not finite (coordinates too large)".into(),
            BadShape::Degenerate { area, longest } => format!(
                "degenerate triangle (area {area:e}, longest edge {longest:e}; \
                 |area| <= {DEGENERATE_RTOL:e} * longest edge^2)"
            ),
            BadShape::Inverted { area } => {
                format!("inverted (clockwise) triangle, signed area {area:e} < 0")
            }
        }
    }
}

pub(super) fn build(
    vertices: Vec<[f64; 2]>,
    triangles: Vec<[usize; 3]>,
    boundary_edges: Vec<BoundaryEdge>,
    physical_names: BTreeMap<i32, String>,
    source: PathBuf,
    labels: &Labels,
) -> Result<Mesh> {
    let err = |reason: String| Error::mesh(source.clone(), reason);
    let nv = vertices.len();

    if triangles.is_empty() {
        return Err(err(
            "no triangles: the mesh has no 3-node triangle elements (MSH type 2); \
             mesh in 2-D (`gmsh -2`) and put the surface in a Physical Surface"
                .into(),
        ));
    }
    for (v, p) in vertices.iter().enumerate() {
        if !(p[0].is_finite() && p[1].is_finite()) {
            return Err(err(format!(
                "{}: non-finite coordinates ({}, {})",
                labels.vertex(v),
                p[0],
                p[1]
            )));
        }
    }
    for (t, tri) in triangles.iter().enumerate() {
        if let Some(&bad) = tri.iter().find(|&&v| v >= nv) {
            return Err(err(format!(
                "{}: node index {bad} is not defined (the mesh has {nv} vertices)",
                labels.triangle_id(t),
            )));
        }
    }
    for (l, be) in boundary_edges.iter().enumerate() {
        if let Some(&bad) = be.vertices.iter().find(|&&v| v >= nv) {
            return Err(err(format!(
                "boundary edge {l} (zero-based): node index {bad} is not defined \
                 (the mesh has {nv} vertices)"
            )));
        }
    }

    // Per-triangle geometry.
    for (t, tri) in triangles.iter().enumerate() {
        if let Some(bad) = BadShape::of(tri.map(|v| vertices[v])) {
            let advice = match bad {
                BadShape::Inverted { .. } => {
                    "; triangles must be counter-clockwise (they are not reoriented: \
                     FreeFEM rejects them too); fix the orientation of the surface \
                     in the .geo file"
                }
                _ => "",
            };
            return Err(err(format!(
                "{}: {}{advice}",
                labels.triangle(t, tri),
                bad.what()
            )));
        }
    }

    // Duplicate triangles (same vertex set).
    let mut seen: VertexMap<[usize; 3], usize> =
        VertexMap::with_capacity_and_hasher(triangles.len(), Default::default());
    for (t, tri) in triangles.iter().enumerate() {
        let mut key = *tri;
        key.sort_unstable();
        if let Some(&first) = seen.get(&key) {
            return Err(err(format!(
                "{}: duplicate triangle, same vertices as {}",
                labels.triangle(t, tri),
                labels.triangle(first, &triangles[first])
            )));
        }
        seen.insert(key, t);
    }
    drop(seen);

    // Vertices used by no triangle.
    let mut used = vec![false; nv];
    for tri in &triangles {
        for &v in tri {
            used[v] = true;
        }
    }
    if let Some(v) = used.iter().position(|&u| !u) {
        let n_unused = used.iter().filter(|&&u| !u).count();
        return Err(err(format!(
            "{}: vertex used by no triangle ({n_unused} such vertices in all); \
             stray nodes are not allowed",
            labels.vertex(v)
        )));
    }

    // Edges, in order of first appearance.
    let mut edge_index: VertexMap<[usize; 2], usize> =
        VertexMap::with_capacity_and_hasher(2 * triangles.len(), Default::default());
    let mut edges: Vec<[usize; 2]> = Vec::with_capacity(2 * triangles.len());
    // For each edge: the triangles that hold it and the direction in the first one.
    let mut edge_tris: Vec<(usize, Option<usize>, bool)> = Vec::with_capacity(2 * triangles.len());
    let mut triangle_edges: Vec<[usize; 3]> = Vec::with_capacity(triangles.len());
    for (t, tri) in triangles.iter().enumerate() {
        let mut te = [0usize; 3];
        for (i, slot) in te.iter_mut().enumerate() {
            let a = tri[(i + 1) % 3];
            let b = tri[(i + 2) % 3];
            let key = [a.min(b), a.max(b)];
            let forward = a < b;
            let e = match edge_index.get(&key) {
                Some(&e) => {
                    let (t0, second, dir0) = edge_tris[e];
                    if let Some(t1) = second {
                        return Err(err(format!(
                            "the edge between nodes {} and {} is shared by more than two \
                             triangles ({}, {}, {}): not a valid 2-D triangulation",
                            labels.node(key[0]),
                            labels.node(key[1]),
                            labels.triangle(t0, &triangles[t0]),
                            labels.triangle(t1, &triangles[t1]),
                            labels.triangle(t, tri)
                        )));
                    }
                    if dir0 == forward {
                        return Err(err(format!(
                            "{} and {} overlap: both run along the edge between nodes {} and {} \
                             in the same direction",
                            labels.triangle(t0, &triangles[t0]),
                            labels.triangle(t, tri),
                            labels.node(key[0]),
                            labels.node(key[1])
                        )));
                    }
                    edge_tris[e].1 = Some(t);
                    e
                }
                None => {
                    let e = edges.len();
                    edges.push(key);
                    edge_tris.push((t, None, forward));
                    edge_index.insert(key, e);
                    e
                }
            };
            *slot = e;
        }
        triangle_edges.push(te);
    }

    // Line elements must be boundary edges of the triangulation.
    let mut covered = vec![false; edges.len()];
    for (l, be) in boundary_edges.iter().enumerate() {
        let [a, b] = be.vertices;
        let key = [a.min(b), a.max(b)];
        match edge_index.get(&key) {
            None => {
                return Err(err(format!(
                    "{}: the line element is not a boundary edge of the triangulation \
                     (it is not an edge of any triangle)",
                    labels.line(l, be)
                )))
            }
            Some(&e) => {
                if edge_tris[e].1.is_some() {
                    return Err(err(format!(
                        "{}: the line element is not a boundary edge of the triangulation \
                         (it is an interior edge, shared by two triangles); only boundary \
                         curves may be physical lines",
                        labels.line(l, be)
                    )));
                }
                covered[e] = true;
            }
        }
    }

    // Every boundary edge of the triangulation carries a tag.
    let missing: Vec<usize> = (0..edges.len())
        .filter(|&e| edge_tris[e].1.is_none() && !covered[e])
        .collect();
    if let Some(&e) = missing.first() {
        let [a, b] = edges[e];
        let t = edge_tris[e].0;
        return Err(err(format!(
            "missing boundary tag: the boundary edge between nodes {} and {} (of {}) is \
             covered by no tagged line element ({} such edges in all); put every boundary \
             curve in a Physical Curve",
            labels.node(a),
            labels.node(b),
            labels.triangle(t, &triangles[t]),
            missing.len()
        )));
    }

    Ok(Mesh {
        vertices,
        triangles,
        boundary_edges,
        physical_names,
        edges,
        triangle_edges,
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The test without the squared-length shortcut.
    fn slow(p: [[f64; 2]; 3]) -> Option<String> {
        let [p0, p1, p2] = p;
        let area = signed_area(p0, p1, p2);
        let longest = dist(p0, p1).max(dist(p1, p2)).max(dist(p2, p0));
        if !area.is_finite() || !longest.is_finite() {
            Some("not finite".into())
        } else if area.abs() <= DEGENERATE_RTOL * longest * longest {
            Some(format!("degenerate {area:e} {longest:e}"))
        } else if area < 0.0 {
            Some(format!("inverted {area:e}"))
        } else {
            None
        }
    }

    fn fast(p: [[f64; 2]; 3]) -> Option<String> {
        BadShape::of(p).map(|b| match b {
            BadShape::NotFinite => "not finite".into(),
            BadShape::Degenerate { area, longest } => format!("degenerate {area:e} {longest:e}"),
            BadShape::Inverted { area } => format!("inverted {area:e}"),
        })
    }

    /// The shortcut decides as the full test does: triangles of every
    /// scale, with the apex at heights around the degenerate threshold, on
    /// either side.
    #[test]
    fn the_shortcut_decides_as_the_full_test() {
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut unit = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut flagged = 0;
        for _ in 0..200_000 {
            let scale = 10f64.powf(unit() * 640.0 - 320.0);
            let a = [unit() * scale, unit() * scale];
            let b = [a[0] + (unit() + 0.1) * scale, a[1] + (unit() - 0.5) * scale];
            // Height over the base as a multiple of the threshold's.
            let h = (unit() - 0.5) * 8.0 * DEGENERATE_RTOL * 10f64.powf(unit() * 13.0);
            let t = unit();
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let c = [a[0] + t * dx - h * dy, a[1] + t * dy + h * dx];
            let p = [a, b, c];
            assert_eq!(fast(p), slow(p), "{p:?}");
            flagged += usize::from(slow(p).is_some());
        }
        assert!(flagged > 1000, "{flagged}");
    }
}
