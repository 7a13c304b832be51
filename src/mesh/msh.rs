//! MSH 2.2 ASCII: the reader (`Mesh::read_msh` and its parser) and the
//! writer (`Mesh::write_msh`, for meshes made here: `mesh.refine`).

use super::*;

impl Mesh {
    /// Read and validate an MSH 2.2 ASCII file.
    ///
    /// `$PhysicalNames` may name the same tag in several dimensions (gmsh numbers
    /// physical groups per dimension); `physical_names` then keeps the curve
    /// (dimension 1) name, since boundary tags are what the tags index, then
    /// the surface name, then any other.
    pub fn read_msh(path: &Path) -> Result<Mesh> {
        let bytes = std::fs::read(path)
            .map_err(|e| Error::mesh(path, format!("cannot read the mesh file: {e}")))?;
        let text = String::from_utf8_lossy(&bytes);
        let parsed = parse_msh(&text).map_err(|reason| Error::mesh(path, reason))?;
        let labels = Labels::File {
            node_tags: parsed.node_tags,
            triangle_elements: parsed.triangle_elements,
            line_elements: parsed.line_elements,
        };
        build(
            parsed.vertices,
            parsed.triangles,
            parsed.boundary_edges,
            parsed.physical_names,
            path.to_path_buf(),
            &labels,
        )
    }
}

impl Mesh {
    /// Writes the mesh as MSH 2.2 ASCII, as gmsh does for the repository's
    /// geometries: the boundary edges as lines with their tags, the
    /// triangles with the surface's tag (the one named tag no boundary edge
    /// carries; 0 without one), the names in `$PhysicalNames`.
    /// [`Mesh::read_msh`] reads back the same mesh.
    pub fn write_msh(&self, path: &Path) -> Result<()> {
        use std::io::Write;
        let error = |e: std::io::Error| Error::mesh(path, format!("cannot write the mesh: {e}"));
        let file = std::fs::File::create(path).map_err(error)?;
        let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
        let boundary_tags: std::collections::BTreeSet<i32> =
            self.boundary_edges.iter().map(|e| e.tag).collect();
        let surfaces: Vec<i32> = self
            .physical_names
            .keys()
            .copied()
            .filter(|t| !boundary_tags.contains(t))
            .collect();
        let surface = match surfaces[..] {
            [t] => t,
            _ => 0,
        };
        // Streamed: the text of a large mesh is never held whole. The node and
        // element lines, millions of them, are formatted by `Line`.
        let mut write = || -> std::io::Result<()> {
            writeln!(w, "$MeshFormat\n2.2 0 8\n$EndMeshFormat")?;
            if !self.physical_names.is_empty() {
                writeln!(w, "$PhysicalNames\n{}", self.physical_names.len())?;
                for (tag, name) in &self.physical_names {
                    let dim = if boundary_tags.contains(tag) { 1 } else { 2 };
                    writeln!(w, "{dim} {tag} \"{name}\"")?;
                }
                writeln!(w, "$EndPhysicalNames")?;
            }
            let mut line = Line::default();
            writeln!(w, "$Nodes\n{}", self.n_vertices())?;
            for (i, &[x, y]) in self.vertices.iter().enumerate() {
                line.int(i + 1).float(x).float(y).int(0);
                line.write_to(&mut w)?;
            }
            writeln!(w, "$EndNodes")?;
            let n_elements = self.boundary_edges.len() + self.n_triangles();
            writeln!(w, "$Elements\n{n_elements}")?;
            for (k, e) in self.boundary_edges.iter().enumerate() {
                let [a, b] = e.vertices;
                line.int(k + 1).int(1).int(2).int(e.tag).int(e.tag);
                line.int(a + 1).int(b + 1);
                line.write_to(&mut w)?;
            }
            let offset = self.boundary_edges.len() + 1;
            for (k, [a, b, c]) in self.triangles.iter().enumerate() {
                line.int(k + offset).int(2).int(2).int(surface).int(surface);
                line.int(a + 1).int(b + 1).int(c + 1);
                line.write_to(&mut w)?;
            }
            writeln!(w, "$EndElements")?;
            w.flush()
        };
        write().map_err(error)
    }
}

/// One line of the MSH writer: numbers separated by spaces, formatted by
/// itoa and ryu rather than `core::fmt` (the writer's time on millions of
/// node and element lines is mostly formatting). The text is that of `{}`
/// for integers and, but for ties ([`Line::float`]), `{:?}` for floats.
#[derive(Default)]
pub(super) struct Line {
    text: Vec<u8>,
    ints: itoa::Buffer,
    floats: ryu::Buffer,
}

impl Line {
    fn separate(&mut self) {
        if !self.text.is_empty() {
            self.text.push(b' ');
        }
    }

    /// Appends an integer.
    pub(super) fn int<I: itoa::Integer>(&mut self, n: I) -> &mut Self {
        self.separate();
        self.text.extend_from_slice(self.ints.format(n).as_bytes());
        self
    }

    /// Appends a float as `{:?}` writes it: the shortest decimal that reads
    /// back to the same f64, with a `.0` on whole numbers, in exponent form
    /// below 1e-4 and from 1e16 in magnitude. ryu writes the same digits,
    /// but for exact ties between two shortest decimals (rounded to even
    /// by ryu, up by `core::fmt`; both read back to x), and switches to
    /// exponent form below 1e-5 instead: the values between (and the
    /// non-finite ones, which a valid mesh has none of) go through
    /// `core::fmt`.
    pub(super) fn float(&mut self, x: f64) -> &mut Self {
        self.separate();
        let a = x.abs();
        if x.is_finite() && !(1e-5..1e-4).contains(&a) {
            self.text
                .extend_from_slice(self.floats.format_finite(x).as_bytes());
        } else {
            use std::io::Write;
            let _ = write!(self.text, "{x:?}");
        }
        self
    }

    /// Writes the line and its newline to `w`, and starts the next line.
    pub(super) fn write_to(&mut self, w: &mut impl std::io::Write) -> std::io::Result<()> {
        self.text.push(b'\n');
        let written = w.write_all(&self.text);
        self.text.clear();
        written
    }
}

// ---------------------------------------------------------------------------
// MSH 2.2 ASCII parser
// ---------------------------------------------------------------------------

pub(super) struct Parsed {
    vertices: Vec<[f64; 2]>,
    node_tags: Vec<usize>,
    triangles: Vec<[usize; 3]>,
    triangle_elements: Vec<usize>,
    boundary_edges: Vec<BoundaryEdge>,
    line_elements: Vec<usize>,
    physical_names: BTreeMap<i32, String>,
}

/// Lines of the file with their (one-based) numbers, blank lines skipped.
pub(super) struct Lines<'a> {
    inner: std::iter::Enumerate<std::str::Lines<'a>>,
}

impl<'a> Lines<'a> {
    fn next(&mut self) -> Option<(usize, &'a str)> {
        for (i, line) in self.inner.by_ref() {
            let line = line.trim();
            if !line.is_empty() {
                return Some((i + 1, line));
            }
        }
        None
    }
}

/// A short, safe excerpt of a line for error messages.
pub(super) fn excerpt(line: &str) -> String {
    let mut s: String = line.chars().take(60).collect();
    if line.chars().nth(60).is_some() {
        s.push('…');
    }
    s
}

pub(super) const MAX_PREALLOC: usize = 1 << 20;

/// Name of an MSH element type, for error messages.
pub(super) fn element_type_name(t: i64) -> &'static str {
    match t {
        1 => "2-node line",
        2 => "3-node triangle",
        3 => "4-node quadrangle",
        4 => "4-node tetrahedron",
        5 => "8-node hexahedron",
        6 => "6-node prism",
        7 => "5-node pyramid",
        8 => "3-node second-order line",
        9 => "6-node second-order triangle",
        10 => "9-node second-order quadrangle",
        11 => "10-node second-order tetrahedron",
        15 => "1-node point",
        16 => "8-node second-order quadrangle",
        20 => "9-node third-order incomplete triangle",
        21 => "10-node third-order triangle",
        26 => "4-node third-order edge",
        _ => "unknown type",
    }
}

pub(super) fn parse_msh(text: &str) -> std::result::Result<Parsed, String> {
    let mut lines = Lines {
        inner: text.lines().enumerate(),
    };
    let mut format_seen = false;
    let mut nodes: Option<NodeTable> = None;
    let mut elements_seen = false;
    let mut names_by_dim: Vec<(i64, i32, String)> = Vec::new();
    let mut names_seen = false;
    let mut triangles = Vec::new();
    let mut triangle_elements = Vec::new();
    let mut boundary_edges = Vec::new();
    let mut line_elements = Vec::new();

    if text.trim().is_empty() {
        return Err("empty file: not an MSH 2.2 mesh".into());
    }

    while let Some((ln, line)) = lines.next() {
        let Some(section) = line.strip_prefix('$') else {
            return Err(format!(
                "line {ln}: expected a section header such as `$Nodes`, found `{}`{}",
                excerpt(line),
                if format_seen {
                    ""
                } else {
                    " (not an MSH 2.2 ASCII file?)"
                }
            ));
        };
        let section = section.split_whitespace().next().unwrap_or("");
        if !format_seen && section != "MeshFormat" {
            return Err(match section {
                "NOD" | "ELM" | "NOE" => format!(
                    "line {ln}: MSH 1 format (${section}) is not supported; \
                     write MSH 2.2 with `gmsh -format msh22`"
                ),
                _ => format!(
                    "line {ln}: `${section}` before `$MeshFormat`: \
                     the file must start with a $MeshFormat section (MSH 2.2 ASCII)"
                ),
            });
        }
        match section {
            "MeshFormat" => {
                if format_seen {
                    return Err(format!("line {ln}: second $MeshFormat section"));
                }
                parse_format(&mut lines, ln)?;
                format_seen = true;
            }
            "PhysicalNames" => {
                if names_seen {
                    return Err(format!("line {ln}: second $PhysicalNames section"));
                }
                names_seen = true;
                names_by_dim = parse_physical_names(&mut lines, ln)?;
            }
            "Nodes" => {
                if nodes.is_some() {
                    return Err(format!("line {ln}: second $Nodes section"));
                }
                nodes = Some(parse_nodes(&mut lines, ln)?);
            }
            "Elements" => {
                if elements_seen {
                    return Err(format!("line {ln}: second $Elements section"));
                }
                let Some((_, _, tag_to_index)) = nodes.as_ref() else {
                    return Err(format!(
                        "line {ln}: $Elements before $Nodes (node index not defined)"
                    ));
                };
                elements_seen = true;
                parse_elements(
                    &mut lines,
                    ln,
                    tag_to_index,
                    &mut triangles,
                    &mut triangle_elements,
                    &mut boundary_edges,
                    &mut line_elements,
                )?;
            }
            s if s.starts_with("End") => {
                return Err(format!(
                    "line {ln}: `${s}` without a matching `${}`",
                    &s[3..]
                ));
            }
            other => skip_section(&mut lines, ln, other)?,
        }
    }

    if !format_seen {
        return Err("missing $MeshFormat section: not an MSH 2.2 file".into());
    }
    let Some((vertices, node_tags, _)) = nodes else {
        return Err("truncated file: missing $Nodes section".into());
    };
    if !elements_seen {
        return Err("truncated file: missing $Elements section".into());
    }

    // Names by tag; dimension 1 wins, then 2, then the others.
    let mut physical_names = BTreeMap::new();
    for pass in [Some(1), Some(2), None] {
        for (dim, tag, name) in &names_by_dim {
            let take = match pass {
                Some(d) => *dim == d,
                None => *dim != 1 && *dim != 2,
            };
            if take {
                physical_names.entry(*tag).or_insert_with(|| name.clone());
            }
        }
    }

    Ok(Parsed {
        vertices,
        node_tags,
        triangles,
        triangle_elements,
        boundary_edges,
        line_elements,
        physical_names,
    })
}

/// The next line of a section, or a clear error at a truncation or an early `$End…`.
pub(super) fn entry<'a>(
    lines: &mut Lines<'a>,
    section: &str,
    start: usize,
    what: &str,
    declared: usize,
    found: usize,
) -> std::result::Result<(usize, &'a str), String> {
    match lines.next() {
        None => Err(format!(
            "truncated file: section ${section} (line {start}) declares {declared} {what} \
             but the file ends after {found} (missing $End{section})"
        )),
        Some((ln, l)) if l.starts_with('$') => Err(format!(
            "line {ln}: section ${section} (line {start}) declares {declared} {what} \
             but only {found} come before `{}`",
            excerpt(l)
        )),
        Some(x) => Ok(x),
    }
}

pub(super) fn expect_end(
    lines: &mut Lines<'_>,
    section: &str,
    start: usize,
    declared: Option<(usize, &str)>,
) -> std::result::Result<(), String> {
    let end = format!("$End{section}");
    match lines.next() {
        None => Err(format!(
            "truncated file: missing {end} (section ${section} starts at line {start})"
        )),
        Some((_, l)) if l.split_whitespace().next() == Some(end.as_str()) => Ok(()),
        Some((ln, l)) => Err(match declared {
            Some((n, what)) => format!(
                "line {ln}: expected {end} after the {n} {what} declared at line {start}, \
                 found `{}`",
                excerpt(l)
            ),
            None => format!("line {ln}: expected {end}, found `{}`", excerpt(l)),
        }),
    }
}

pub(super) fn parse_count(
    lines: &mut Lines<'_>,
    section: &str,
    start: usize,
) -> std::result::Result<usize, String> {
    match lines.next() {
        None => Err(format!(
            "truncated file: section ${section} (line {start}) ends before its count"
        )),
        Some((ln, l)) => {
            let mut it = l.split_whitespace();
            let n = it.next().and_then(|t| t.parse::<usize>().ok());
            match (n, it.next()) {
                (Some(n), None) => Ok(n),
                _ => Err(format!(
                    "line {ln}: expected the number of entries of ${section}, found `{}`",
                    excerpt(l)
                )),
            }
        }
    }
}

pub(super) fn parse_format(lines: &mut Lines<'_>, start: usize) -> std::result::Result<(), String> {
    let Some((ln, l)) = lines.next() else {
        return Err("truncated file: $MeshFormat has no version line".into());
    };
    let tokens: Vec<&str> = l.split_whitespace().collect();
    let [version, file_type, data_size] = tokens.as_slice() else {
        return Err(format!(
            "line {ln}: expected `version file-type data-size` (e.g. `2.2 0 8`), found `{}`",
            excerpt(l)
        ));
    };
    let major = version.split('.').next().unwrap_or("");
    if version.parse::<f64>().is_err() {
        return Err(format!(
            "line {ln}: cannot parse the MSH version `{}`",
            excerpt(version)
        ));
    }
    if major != "2" {
        return Err(format!(
            "line {ln}: MSH version {} is not supported: only MSH 2.x ASCII is read \
             (FreeFEM's gmshload reads it too); write it with `gmsh -format msh22`",
            excerpt(version)
        ));
    }
    match *file_type {
        "0" => {}
        "1" => {
            return Err(format!(
                "line {ln}: binary MSH file (file-type 1) is not supported: write ASCII \
                 MSH 2.2 (`gmsh -format msh22`, without `-bin`)"
            ))
        }
        other => {
            return Err(format!(
                "line {ln}: unknown MSH file-type `{}` (0 = ASCII expected)",
                excerpt(other)
            ))
        }
    }
    if data_size.parse::<usize>().is_err() {
        return Err(format!(
            "line {ln}: cannot parse the data size `{}`",
            excerpt(data_size)
        ));
    }
    expect_end(lines, "MeshFormat", start, None)
}

pub(super) fn parse_physical_names(
    lines: &mut Lines<'_>,
    start: usize,
) -> std::result::Result<Vec<(i64, i32, String)>, String> {
    let n = parse_count(lines, "PhysicalNames", start)?;
    let mut out = Vec::with_capacity(n.min(MAX_PREALLOC));
    for k in 0..n {
        let (ln, l) = entry(lines, "PhysicalNames", start, "names", n, k)?;
        let mut it = l.split_whitespace();
        let dim = it.next().and_then(|t| t.parse::<i64>().ok());
        let tag = it.next().and_then(|t| t.parse::<i32>().ok());
        let (Some(dim), Some(tag)) = (dim, tag) else {
            return Err(format!(
                "line {ln}: expected `dimension tag \"name\"`, found `{}`",
                excerpt(l)
            ));
        };
        // The name is quoted and may contain blanks.
        let name = match (l.find('"'), l.rfind('"')) {
            (Some(i), Some(j)) if j > i => l[i + 1..j].to_string(),
            _ => it.collect::<Vec<_>>().join(" "),
        };
        out.push((dim, tag, name));
    }
    expect_end(lines, "PhysicalNames", start, Some((n, "names")))?;
    Ok(out)
}

pub(super) type NodeTable = (Vec<[f64; 2]>, Vec<usize>, HashMap<usize, usize>);

pub(super) fn parse_nodes(
    lines: &mut Lines<'_>,
    start: usize,
) -> std::result::Result<NodeTable, String> {
    let n = parse_count(lines, "Nodes", start)?;
    let cap = n.min(MAX_PREALLOC);
    let mut vertices = Vec::with_capacity(cap);
    let mut tags = Vec::with_capacity(cap);
    let mut index: HashMap<usize, usize> = HashMap::with_capacity(cap);
    for k in 0..n {
        let (ln, l) = entry(lines, "Nodes", start, "nodes", n, k)?;
        let tokens: Vec<&str> = l.split_whitespace().collect();
        let [tag, x, y, z] = tokens.as_slice() else {
            return Err(format!(
                "line {ln}: expected a node `tag x y z`, found `{}`",
                excerpt(l)
            ));
        };
        let Ok(tag) = tag.parse::<usize>() else {
            return Err(format!(
                "line {ln}: cannot parse the node tag `{}`",
                excerpt(tag)
            ));
        };
        let mut coord = [0.0f64; 3];
        for (c, s) in coord.iter_mut().zip([x, y, z]) {
            *c = s.parse::<f64>().map_err(|_| {
                format!(
                    "line {ln}: node {tag}: cannot parse the coordinate `{}`",
                    excerpt(s)
                )
            })?;
        }
        let [x, y, z] = coord;
        if !(x.is_finite() && y.is_finite() && z.is_finite()) {
            return Err(format!(
                "line {ln}: node {tag}: non-finite coordinates ({x}, {y}, {z})"
            ));
        }
        if z.abs() > 1e-12 * x.abs().max(y.abs()).max(1.0) {
            return Err(format!(
                "line {ln}: node {tag}: z = {z} is not 0; only planar meshes in the plane \
                 z = 0 are supported"
            ));
        }
        if let Some(&first) = index.get(&tag) {
            return Err(format!(
                "line {ln}: node tag {tag} is defined twice (first as node #{} of $Nodes)",
                first + 1
            ));
        }
        index.insert(tag, vertices.len());
        vertices.push([x, y]);
        tags.push(tag);
    }
    expect_end(lines, "Nodes", start, Some((n, "nodes")))?;
    Ok((vertices, tags, index))
}

#[allow(clippy::too_many_arguments)]
pub(super) fn parse_elements(
    lines: &mut Lines<'_>,
    start: usize,
    tag_to_index: &HashMap<usize, usize>,
    triangles: &mut Vec<[usize; 3]>,
    triangle_elements: &mut Vec<usize>,
    boundary_edges: &mut Vec<BoundaryEdge>,
    line_elements: &mut Vec<usize>,
) -> std::result::Result<(), String> {
    let n = parse_count(lines, "Elements", start)?;
    for k in 0..n {
        let (ln, l) = entry(lines, "Elements", start, "elements", n, k)?;
        let mut fields = Vec::with_capacity(8);
        for t in l.split_whitespace() {
            match t.parse::<i64>() {
                Ok(v) => fields.push(v),
                Err(_) => {
                    return Err(format!(
                        "line {ln}: cannot parse the element field `{}` (integers expected)",
                        excerpt(t)
                    ))
                }
            }
        }
        let [num, typ, ntags, ..] = fields[..] else {
            return Err(format!(
                "line {ln}: expected an element `number type ntags tags… nodes…`, found `{}`",
                excerpt(l)
            ));
        };
        let n_nodes = match typ {
            1 => 2,
            2 => 3,
            15 => 1,
            _ => {
                return Err(format!(
                    "line {ln}: element {num}: element type {typ} ({}) is not supported; \
                     only 2-node lines (1), 3-node triangles (2) and points (15) are read \
                     (mesh with first-order elements, Mesh.ElementOrder = 1)",
                    element_type_name(typ)
                ))
            }
        };
        let expected = usize::try_from(ntags)
            .ok()
            .and_then(|nt| nt.checked_add(3 + n_nodes));
        if expected != Some(fields.len()) {
            return Err(format!(
                "line {ln}: element {num} ({}): expected 3 + {ntags} tags + {n_nodes} nodes \
                 fields, found {}",
                element_type_name(typ),
                fields.len()
            ));
        }
        let num = usize::try_from(num)
            .map_err(|_| format!("line {ln}: element number {num} is negative"))?;
        let ntags = fields.len() - 3 - n_nodes;
        let node_fields = &fields[3 + ntags..];
        let mut idx = [0usize; 3];
        for (slot, &node) in idx.iter_mut().zip(node_fields) {
            let found = usize::try_from(node)
                .ok()
                .and_then(|t| tag_to_index.get(&t).copied());
            match found {
                Some(i) => *slot = i,
                None => {
                    return Err(format!(
                        "line {ln}: element {num} ({}): node index {node} is not defined \
                         in $Nodes",
                        element_type_name(typ)
                    ))
                }
            }
        }
        match typ {
            1 => {
                let tag = if ntags >= 1 { fields[3] } else { 0 };
                let tag = i32::try_from(tag).map_err(|_| {
                    format!("line {ln}: element {num}: physical tag {tag} out of range")
                })?;
                boundary_edges.push(BoundaryEdge {
                    vertices: [idx[0], idx[1]],
                    tag,
                });
                line_elements.push(num);
            }
            2 => {
                triangles.push(idx);
                triangle_elements.push(num);
            }
            _ => {} // points: ignored
        }
    }
    expect_end(lines, "Elements", start, Some((n, "elements")))
}

pub(super) fn skip_section(
    lines: &mut Lines<'_>,
    start: usize,
    name: &str,
) -> std::result::Result<(), String> {
    let end = format!("$End{name}");
    while let Some((_, l)) = lines.next() {
        if l.split_whitespace().next() == Some(end.as_str()) {
            return Ok(());
        }
    }
    Err(format!(
        "truncated file: missing {end} (section ${name} starts at line {start})"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    /// An MSH 2.2 file from node and element lines (counts computed).
    fn msh(nodes: &[&str], elements: &[&str]) -> String {
        format!(
            "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$PhysicalNames\n3\n1 1 \"bottom\"\n\
             1 2 \"rest\"\n2 3 \"domain\"\n$EndPhysicalNames\n$Nodes\n{}\n{}\n$EndNodes\n\
             $Elements\n{}\n{}\n$EndElements\n",
            nodes.len(),
            nodes.join("\n"),
            elements.len(),
            elements.join("\n")
        )
    }

    const SQ_NODES: [&str; 4] = ["1 0 0 0", "2 1 0 0", "3 1 1 0", "4 0 1 0"];
    const SQ_LINES: [&str; 4] = [
        "1 1 2 1 1 1 2",
        "2 1 2 2 2 2 3",
        "3 1 2 2 2 3 4",
        "4 1 2 2 2 4 1",
    ];

    fn square(triangles: &[&str]) -> String {
        let mut el: Vec<&str> = SQ_LINES.to_vec();
        el.extend_from_slice(triangles);
        msh(&SQ_NODES, &el)
    }

    fn read_text(text: &str) -> Result<Mesh> {
        read_bytes(text.as_bytes())
    }

    fn read_bytes(bytes: &[u8]) -> Result<Mesh> {
        let mut f = tempfile::Builder::new().suffix(".msh").tempfile().unwrap();
        f.write_all(bytes).unwrap();
        f.flush().unwrap();
        Mesh::read_msh(f.path())
    }

    /// The error message of reading `text`; panics if it reads fine.
    fn error_of(text: &str) -> String {
        match read_text(text) {
            Ok(m) => panic!(
                "expected an error, got a mesh with {} triangles",
                m.n_triangles()
            ),
            Err(e) => {
                assert!(matches!(e, Error::Mesh { .. }), "{e:?}");
                eprintln!("{e}");
                e.to_string()
            }
        }
    }

    fn assert_mentions(msg: &str, parts: &[&str]) {
        for p in parts {
            assert!(msg.contains(p), "message `{msg}` does not mention `{p}`");
        }
    }

    #[test]
    fn valid_square() {
        let m = read_text(&square(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4"])).unwrap();
        assert_eq!(m.n_vertices(), 4);
        assert_eq!(m.n_triangles(), 2);
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(m.vertices[2], [1.0, 1.0]);
        assert_eq!(m.n_edges(), 5);
        assert_eq!(m.edges, vec![[1, 2], [0, 2], [0, 1], [2, 3], [0, 3]]);
        assert_eq!(m.triangle_edges, vec![[0, 1, 2], [3, 4, 1]]);
        assert_eq!(m.area(0), 0.5);
        assert_eq!(m.area(1), 0.5);
        assert_eq!(m.total_area(), 1.0);
        assert!((m.h_max() - 2f64.sqrt()).abs() < 1e-15);
        assert_eq!(m.boundary_edges.len(), 4);
        assert_eq!(
            m.boundary_edges[0],
            BoundaryEdge {
                vertices: [0, 1],
                tag: 1
            }
        );
        assert_eq!(m.tag_by_name("bottom"), Some(1));
        assert_eq!(m.tag_by_name("rest"), Some(2));
        assert_eq!(m.tag_by_name("domain"), Some(3));
        assert_eq!(m.tag_by_name("nothing"), None);
        assert_eq!(
            m.boundary_vertex_mask(Some(&[1])),
            vec![true, true, false, false]
        );
        assert_eq!(m.boundary_vertex_mask(None), vec![true; 4]);
        assert_eq!(
            m.boundary_edge_mask(Some(&[1])),
            vec![false, false, true, false, false]
        );
        assert_eq!(
            m.boundary_edge_mask(None),
            vec![true, false, true, true, true]
        );
        assert_eq!(m.boundary_edge_mask(Some(&[7])), vec![false; 5]);
        assert_eq!(m.boundary_edge_global_indices(), vec![2, 0, 3, 4]);
        assert_eq!(m.edge_index(2, 0), Some(1));
        assert_eq!(m.edge_index(1, 3), None);
        assert!(m.source.ends_with(m.source.file_name().unwrap()));
    }

    #[test]
    fn keeps_file_order_with_noncontiguous_tags() {
        // Node tags 10, 7, 30, 4 in this order: vertex i is the i-th node line.
        let text = msh(
            &["10 0 0 0", "7 1 0 0", "30 1 1 0", "4 0 1 0"],
            &[
                "1 15 2 9 1 10",
                "11 1 2 1 1 10 7",
                "12 1 2 1 2 7 30",
                "13 1 2 1 3 30 4",
                "14 1 2 1 4 4 10",
                "20 2 2 3 1 30 4 7",
                "21 2 2 3 1 4 10 7",
            ],
        );
        let m = read_text(&text).unwrap();
        assert_eq!(
            m.vertices,
            vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
        );
        assert_eq!(m.triangles, vec![[2, 3, 1], [3, 0, 1]]);
        assert_eq!(m.boundary_edges[1].vertices, [1, 2]);
    }

    #[test]
    fn name_collision_across_dimensions_keeps_curve_name() {
        let text = square(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4"])
            .replace("2 3 \"domain\"", "2 1 \"domain\"");
        let m = read_text(&text).unwrap();
        assert_eq!(m.physical_names.get(&1).map(String::as_str), Some("bottom"));
        assert_eq!(m.tag_by_name("domain"), None);
    }

    #[test]
    fn unknown_sections_and_crlf_are_accepted() {
        let text = square(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4"])
            .replace("$Nodes", "$Comments\nhello $Nodes\n$EndComments\n$Nodes")
            .replace('\n', "\r\n");
        let m = read_text(&text).unwrap();
        assert_eq!(m.n_triangles(), 2);
    }

    #[test]
    fn rejects_msh4() {
        let text = square(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4"]).replace("2.2 0 8", "4.1 0 8");
        assert_mentions(&error_of(&text), &["version 4.1", "not supported", "msh22"]);
    }

    #[test]
    fn rejects_binary() {
        let mut bytes = b"$MeshFormat\n2.2 1 8\n".to_vec();
        bytes.extend_from_slice(&[1, 0, 0, 0, 0xff, 0xfe, b'\n']);
        bytes.extend_from_slice(b"$EndMeshFormat\n");
        let e = read_bytes(&bytes).unwrap_err().to_string();
        assert_mentions(&e, &["binary", "not supported"]);
    }

    #[test]
    fn rejects_missing_format() {
        let text =
            square(&["5 2 2 3 1 1 2 3"]).replace("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n", "");
        assert_mentions(&error_of(&text), &["$MeshFormat"]);
        assert_mentions(&error_of(""), &["empty"]);
        assert_mentions(&error_of("hello world\n"), &["line 1", "section header"]);
        assert_mentions(&error_of("$NOD\n1\n1 0 0 0\n$ENDNOD\n"), &["MSH 1"]);
    }

    #[test]
    fn rejects_degenerate_triangle() {
        let text = msh(
            &["1 0 0 0", "2 1 0 0", "3 2 0 0"],
            &["1 1 2 1 1 1 2", "7 2 2 3 1 1 2 3"],
        );
        assert_mentions(&error_of(&text), &["element 7", "degenerate"]);
        // Tiny but relative to its size: a sliver below 1e-12 is degenerate.
        let text = msh(
            &["1 0 0 0", "2 1 0 0", "3 0.5 1e-13 0"],
            &["1 1 2 1 1 1 2", "7 2 2 3 1 1 2 3"],
        );
        assert_mentions(&error_of(&text), &["element 7", "degenerate"]);
    }

    #[test]
    fn rejects_inverted_triangle() {
        let e = error_of(&square(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 4 3"]));
        assert_mentions(&e, &["element 6", "inverted", "clockwise", "nodes 1 4 3"]);
    }

    #[test]
    fn rejects_duplicate_triangle() {
        let e = error_of(&square(&[
            "5 2 2 3 1 1 2 3",
            "6 2 2 3 1 1 3 4",
            "9 2 2 3 1 2 3 1",
        ]));
        assert_mentions(&e, &["element 9", "duplicate", "element 5"]);
    }

    #[test]
    fn rejects_undefined_node() {
        let e = error_of(&square(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 17"]));
        assert_mentions(&e, &["element 6", "node index 17", "not defined"]);
    }

    #[test]
    fn rejects_stray_vertex() {
        let mut nodes = SQ_NODES.to_vec();
        nodes.push("5 0.5 0.5 0");
        let mut el = SQ_LINES.to_vec();
        el.extend_from_slice(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4"]);
        let e = error_of(&msh(&nodes, &el));
        assert_mentions(&e, &["node 5", "used by no triangle"]);
    }

    #[test]
    fn rejects_missing_boundary_tag() {
        let mut el = SQ_LINES[..3].to_vec();
        el.extend_from_slice(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4"]);
        let e = error_of(&msh(&SQ_NODES, &el));
        assert_mentions(&e, &["missing boundary tag", "nodes 1 and 4", "element 6"]);
    }

    #[test]
    fn rejects_line_that_is_not_a_boundary_edge() {
        // The interior diagonal 1-3.
        let mut el = SQ_LINES.to_vec();
        el.extend_from_slice(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4", "8 1 2 5 5 1 3"]);
        let e = error_of(&msh(&SQ_NODES, &el));
        assert_mentions(&e, &["element 8", "not a boundary edge", "interior"]);
        // An edge of no triangle (2-4 is the other diagonal).
        let mut el = SQ_LINES.to_vec();
        el.extend_from_slice(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4", "8 1 2 5 5 2 4"]);
        let e = error_of(&msh(&SQ_NODES, &el));
        assert_mentions(&e, &["element 8", "not a boundary edge"]);
    }

    #[test]
    fn rejects_no_triangles() {
        let e = error_of(&msh(&SQ_NODES, &SQ_LINES));
        assert_mentions(&e, &["no triangles"]);
        let e = error_of(&msh(&[], &[]));
        assert_mentions(&e, &["no triangles"]);
    }

    #[test]
    fn rejects_non_finite_coordinates() {
        for bad in ["nan", "inf", "-inf", "1e400"] {
            let text = square(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4"])
                .replace("3 1 1 0", &format!("3 1 {bad} 0"));
            assert_mentions(&error_of(&text), &["node 3", "non-finite"]);
        }
        let e = Mesh::from_parts(
            vec![[0.0, 0.0], [1.0, 0.0], [f64::NAN, 1.0]],
            vec![[0, 1, 2]],
            vec![],
            BTreeMap::new(),
            PathBuf::new(),
        )
        .unwrap_err()
        .to_string();
        assert_mentions(&e, &["vertex 2", "non-finite"]);
    }

    #[test]
    fn rejects_truncated_files() {
        let full = square(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4"]);
        let no_end = full.replace("$EndElements\n", "");
        assert_mentions(&error_of(&no_end), &["truncated", "$EndElements"]);
        let cut = &full[..full.find("4 0 1 0").unwrap()];
        assert_mentions(&error_of(cut), &["truncated", "$Nodes", "declares 4 nodes"]);
        let no_elements = &full[..full.find("$Elements").unwrap()];
        assert_mentions(&error_of(no_elements), &["missing $Elements"]);
        let short = full.replace("$Elements\n6\n", "$Elements\n7\n");
        assert_mentions(&error_of(&short), &["declares 7 elements", "only 6"]);
        let long = full.replace("$Elements\n6\n", "$Elements\n5\n");
        assert_mentions(&error_of(&long), &["expected $EndElements"]);
        let no_end_nodes = full.replace("$EndNodes\n", "");
        assert_mentions(&error_of(&no_end_nodes), &["$EndNodes"]);
    }

    #[test]
    fn rejects_second_order_elements() {
        let text = msh(
            &[
                "1 0 0 0",
                "2 1 0 0",
                "3 0 1 0",
                "4 0.5 0 0",
                "5 0.5 0.5 0",
                "6 0 0.5 0",
            ],
            &["1 8 2 1 1 1 2 4", "42 9 2 3 1 1 2 3 4 5 6"],
        );
        assert_mentions(&error_of(&text), &["element 1", "type 8", "second-order"]);
        let text = msh(
            &[
                "1 0 0 0",
                "2 1 0 0",
                "3 0 1 0",
                "4 0.5 0 0",
                "5 0.5 0.5 0",
                "6 0 0.5 0",
            ],
            &["42 9 2 3 1 1 2 3 4 5 6"],
        );
        assert_mentions(&error_of(&text), &["element 42", "type 9", "not supported"]);
    }

    #[test]
    fn rejects_malformed_lines() {
        let full = square(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4"]);
        let e = error_of(&full.replace("6 2 2 3 1 1 3 4", "6 2 2 3 1 1 3"));
        assert_mentions(&e, &["element 6", "expected"]);
        let e = error_of(&full.replace("6 2 2 3 1 1 3 4", "6 2 2 3 1 1 x 4"));
        assert_mentions(&e, &["cannot parse", "`x`"]);
        let e = error_of(&full.replace("3 1 1 0", "3 1 1"));
        assert_mentions(&e, &["expected a node"]);
        let e = error_of(&full.replace("3 1 1 0", "3 1 1 0.5"));
        assert_mentions(&e, &["node 3", "z = 0.5"]);
        let e = error_of(&full.replace("4 0 1 0", "1 0 1 0"));
        assert_mentions(&e, &["node tag 1", "twice"]);
        let e = error_of(&full.replace("$Nodes\n4", "$Nodes\n-4"));
        assert_mentions(&e, &["number of entries"]);
        let e = error_of(&full.replace("6 2 2 3 1 1 3 4", "6 2 99999999999999999999 3 1 1 3 4"));
        assert_mentions(&e, &["cannot parse"]);
        let e = error_of(&full.replace("6 2 2 3 1 1 3 4", "6 2 -5 3 1 1 3 4"));
        assert_mentions(&e, &["element 6"]);
    }

    #[test]
    fn rejects_overlapping_and_non_manifold() {
        // Triangles 1 2 3 and 1 2 4 with 3, 4 on the same side of edge 1-2.
        let text = msh(
            &["1 0 0 0", "2 1 0 0", "3 0 1 0", "4 0.2 0.5 0"],
            &["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 2 4"],
        );
        assert_mentions(&error_of(&text), &["overlap", "element 5", "element 6"]);
        // Three triangles on the edge 1-2.
        let text = msh(
            &["1 0 0 0", "2 1 0 0", "3 0 1 0", "4 0 -1 0", "5 0.2 0.5 0"],
            &["5 2 2 3 1 1 2 3", "6 2 2 3 1 2 1 4", "7 2 2 3 1 1 2 5"],
        );
        assert_mentions(&error_of(&text), &["more than two"]);
    }

    #[test]
    fn from_parts_validates() {
        let v = vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        let b = |a, c, tag| BoundaryEdge {
            vertices: [a, c],
            tag,
        };
        let be = vec![b(0, 1, 1), b(1, 2, 2), b(2, 3, 2), b(3, 0, 2)];
        let m = Mesh::from_parts(
            v.clone(),
            vec![[0, 1, 2], [0, 2, 3]],
            be.clone(),
            BTreeMap::new(),
            PathBuf::new(),
        )
        .unwrap();
        assert_eq!(m.n_edges(), 5);
        let e = Mesh::from_parts(
            v.clone(),
            vec![[0, 1, 2], [0, 3, 2]],
            be.clone(),
            BTreeMap::new(),
            PathBuf::new(),
        )
        .unwrap_err()
        .to_string();
        assert_mentions(&e, &["triangle 1", "inverted"]);
        let e = Mesh::from_parts(
            v.clone(),
            vec![[0, 1, 2], [0, 2, 9]],
            be.clone(),
            BTreeMap::new(),
            PathBuf::new(),
        )
        .unwrap_err()
        .to_string();
        assert_mentions(&e, &["triangle 1", "node index 9", "not defined"]);
        let e = Mesh::from_parts(
            v,
            vec![[0, 1, 2], [0, 2, 3]],
            be[..3].to_vec(),
            BTreeMap::new(),
            PathBuf::new(),
        )
        .unwrap_err()
        .to_string();
        assert_mentions(&e, &["missing boundary tag"]);
    }

    /// `Line` writes numbers as `{}` (integers) and `{:?}` (floats) do:
    /// special values, the edges of the decimal range, random bit patterns
    /// and random values of every magnitude.
    #[test]
    fn line_numbers_read_as_core_fmt_writes_them() {
        let mut floats = vec![
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.1,
            0.5,
            -2.0,
            1e-4,
            9.999999999999999e-5,
            1e-5,
            9.999999999999999e-6,
            1e15,
            9.999999999999998e15,
            1e16,
            1e21,
            1e22,
            123456789.125,
            std::f64::consts::PI,
            6.123233995736766e-17,
            5e-324,
            f64::MIN_POSITIVE,
            f64::MAX,
            f64::MIN,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        let mut state: u64 = 0x2545_F491_4F6C_DD1D;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..100_000 {
            floats.push(f64::from_bits(rnd()));
            let unit = (rnd() >> 11) as f64 / (1u64 << 53) as f64;
            let exponent = (rnd() % 60) as i32 - 30;
            floats.push((unit - 0.5) * 10f64.powi(exponent));
        }
        let mut line = Line::default();
        let mut ties = 0;
        for x in floats {
            let mut text = Vec::new();
            line.float(x).write_to(&mut text).unwrap();
            let text = String::from_utf8(text).unwrap();
            let text = text.strip_suffix('\n').unwrap();
            let read: f64 = text.parse().unwrap();
            assert!(
                read.to_bits() == x.to_bits() || (read.is_nan() && x.is_nan()),
                "{x:?} written as {text} reads back as {read:?}"
            );
            let core = format!("{x:?}");
            if text != core {
                // An exact tie between two shortest decimals (x has one
                // decimal digit more, a 5), ryu rounding to even and
                // core::fmt up: the last digit of the mantissa differs.
                let split = |s: &str| {
                    let (m, e) = s.split_once('e').unwrap_or((s, ""));
                    (m[..m.len() - 1].to_string(), e.to_string())
                };
                assert_eq!(split(text), split(&core), "{text} and {core}");
                ties += 1;
            }
        }
        assert!(ties < 1000, "{ties} ties");
        let mut text = Vec::new();
        line.int(i32::MIN)
            .int(0)
            .int(-7)
            .int(usize::MAX)
            .int(1usize);
        line.write_to(&mut text).unwrap();
        line.int(42).float(0.25).write_to(&mut text).unwrap();
        let expected = format!("{} 0 -7 {} 1\n42 0.25\n", i32::MIN, usize::MAX);
        assert_eq!(String::from_utf8(text).unwrap(), expected);
    }

    #[test]
    fn missing_file_is_an_error() {
        let e = Mesh::read_msh(Path::new("/nonexistent/dir/x.msh")).unwrap_err();
        assert_mentions(&e.to_string(), &["x.msh", "cannot read"]);
    }

    /// Never panics: every prefix of a valid file, and deterministic random
    /// byte mutations of it, give Ok or Err.
    #[test]
    fn never_panics_on_corrupted_input() {
        let full = square(&["5 2 2 3 1 1 2 3", "6 2 2 3 1 1 3 4"]);
        let bytes = full.as_bytes();
        // Parse from memory (no tempfile per case) through the same code path.
        let parse_only = |b: &[u8]| {
            let text = String::from_utf8_lossy(b);
            if let Ok(p) = parse_msh(&text) {
                let labels = Labels::File {
                    node_tags: p.node_tags,
                    triangle_elements: p.triangle_elements,
                    line_elements: p.line_elements,
                };
                let _ = build(
                    p.vertices,
                    p.triangles,
                    p.boundary_edges,
                    p.physical_names,
                    PathBuf::new(),
                    &labels,
                );
            }
        };
        for cut in 0..=bytes.len() {
            parse_only(&bytes[..cut]);
        }
        let alphabet = b"0123456789-+.eE $\n\"x";
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..20000 {
            let mut b = bytes.to_vec();
            for _ in 0..(1 + rnd() % 4) {
                let i = (rnd() % b.len() as u64) as usize;
                match rnd() % 3 {
                    0 => b[i] = alphabet[(rnd() % alphabet.len() as u64) as usize],
                    1 => {
                        b.remove(i);
                    }
                    _ => b.insert(i, alphabet[(rnd() % alphabet.len() as u64) as usize]),
                }
            }
            parse_only(&b);
        }
        // Valid file still reads.
        assert!(read_text(&full).is_ok());
    }
}
