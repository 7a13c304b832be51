//! Result files: the HDF5 layout of docs/formulation.md §5 (a contract other tools read),
//! its XDMF companion for ParaView/VisIt, and the reader behind `obstacle info`.
//!
//! Models fill a [`ResultData`]; this module knows nothing about membranes or shells.

pub mod blocks;
pub mod compare;
pub mod hdf5_io;
pub mod marker;
pub mod transaction;
pub mod xdmf;

/// A scalar attribute value.
#[derive(Debug, Clone, PartialEq)]
pub enum AttrValue {
    F64(f64),
    I64(i64),
    Bool(bool),
    Str(String),
}

/// The value of the numeric attribute `name` in `attrs` (integers as f64);
/// None when absent or not a number.
pub fn numeric_attr(attrs: &[(String, AttrValue)], name: &str) -> Option<f64> {
    attrs
        .iter()
        .find(|(k, _)| k == name)
        .and_then(|(_, v)| match v {
            AttrValue::F64(x) => Some(*x),
            AttrValue::I64(x) => Some(*x as f64),
            _ => None,
        })
}

/// A field sampled at vertices (`[Nv]` or `[Nv, components]`) or cells (`[Nt]`).
#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    pub name: String,
    /// Row-major, length Nv*components (vertex) or Nt*components (cell).
    pub values: Vec<f64>,
    pub components: usize,
    pub location: Location,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Location {
    Vertex,
    Cell,
}

/// Everything one solve writes. Names follow docs/formulation.md §5.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ResultData {
    /// `/fields/<name>`.
    pub fields: Vec<Field>,
    /// `/dofs/<name>`: full coefficient vectors.
    pub dofs: Vec<(String, Vec<f64>)>,
    /// The `space` attribute of `/dofs/<name>` ([`space_tag`]); vectors
    /// without one (older files) are told apart by their length.
    pub dof_spaces: Vec<(String, String)>,
    /// Write `/mesh/edges` (needed when a P2 coefficient vector is stored).
    pub write_edges: bool,
    /// `/mesh/surface`: the points φ(x) of a shell's midsurface at the
    /// vertices, [Nv, 3]; the XDMF then shows the shell in 3D.
    pub surface: Option<Vec<[f64; 3]>>,
    /// Attributes of the `/solver` group.
    pub solver_attrs: Vec<(String, AttrValue)>,
    /// `/solver/history/<measure>`: one value per iteration, all of equal length.
    pub history: Vec<(String, Vec<f64>)>,
    /// Root attributes besides `scene` and `version` (e.g. what was simulated).
    pub root_attrs: Vec<(String, AttrValue)>,
    /// The scene file's text (root attribute `scene`).
    pub scene_text: String,
}

/// A result file read back (for `info`, `compare` and tests).
#[derive(Debug, Clone, PartialEq)]
pub struct ResultFile {
    pub vertices: Vec<[f64; 2]>,
    pub triangles: Vec<[usize; 3]>,
    pub edges: Option<Vec<[usize; 2]>>,
    pub data: ResultData,
    /// Root attribute `version`.
    pub version: String,
}

pub use hdf5_io::{program_version, read_result, read_steps, write_adaptive_result, write_result};
pub use transaction::OutputTransaction;
pub use xdmf::{domain_xdmf_path, xdmf_path};

impl std::fmt::Display for AttrValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AttrValue::F64(x) => f.write_str(&format_number(*x)),
            AttrValue::I64(x) => write!(f, "{x}"),
            AttrValue::Bool(x) => write!(f, "{x}"),
            AttrValue::Str(s) => write!(f, "{s:?}"),
        }
    }
}

impl Location {
    /// The value of the `location` attribute: "vertex" or "cell".
    pub fn as_str(self) -> &'static str {
        hdf5_io::location_name(self)
    }
}

/// A number as written by people: plain between 1e-3 and 1e6 (and 0),
/// scientific otherwise; always the shortest text that reads back exactly.
pub fn format_number(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-3..1e6).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// Scene lines shown by [`summary`].
const SUMMARY_SCENE_LINES: usize = 40;

fn min_max(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    values.fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

fn range_text(values: impl Iterator<Item = f64>) -> String {
    match min_max(values) {
        Some((lo, hi)) => format!("min {lo:>13.6e}  max {hi:>13.6e}"),
        None => "empty".to_string(),
    }
}

/// A human-readable summary of a result file (the `obstacle info FILE.h5` command):
/// version, mesh counts, each field (location, shape, min/max, per component for
/// vector fields), dof vector lengths, solver attributes, the history length and
/// its last row, other root attributes and the first lines of the scene.
pub fn summary(file: &ResultFile) -> String {
    use std::fmt::Write as _;
    let d = &file.data;
    let nv = file.vertices.len();
    let nt = file.triangles.len();
    let mut s = String::new();
    let _ = writeln!(s, "version: {}", file.version);
    let _ = write!(s, "mesh: {nv} vertices, {nt} triangles");
    if let Some(e) = &file.edges {
        let _ = write!(s, ", {} edges", e.len());
    }
    s.push('\n');

    let _ = writeln!(s, "fields: {}", d.fields.len());
    let width = d.fields.iter().map(|f| f.name.len()).max().unwrap_or(0);
    for f in &d.fields {
        let c = f.components.max(1);
        let rows = f.values.len() / c;
        let shape = if f.components == 1 {
            format!("[{rows}]")
        } else {
            format!("[{rows}, {c}]")
        };
        let _ = writeln!(
            s,
            "  {:width$}  {:6}  {:10}  {}",
            f.name,
            f.location.as_str(),
            shape,
            range_text(f.values.iter().copied())
        );
        if f.components > 1 {
            for k in 0..c {
                let _ = writeln!(
                    s,
                    "  {:width$}  {:6}  {:10}  {}",
                    "",
                    "",
                    format!("[:, {k}]"),
                    range_text(f.values.iter().skip(k).step_by(c).copied())
                );
            }
        }
    }

    let _ = writeln!(s, "dofs: {}", d.dofs.len());
    for (name, v) in &d.dofs {
        let _ = writeln!(s, "  {name}: {} values", v.len());
    }

    let _ = writeln!(s, "solver:");
    for (name, v) in &d.solver_attrs {
        let _ = writeln!(s, "  {name} = {v}");
    }
    let k = d.history.first().map_or(0, |(_, v)| v.len());
    if d.history.is_empty() {
        let _ = writeln!(s, "history: none");
    } else {
        let _ = writeln!(
            s,
            "history: {} measures × {k} iterations{}",
            d.history.len(),
            if k > 0 { "; last row:" } else { "" }
        );
        if k > 0 {
            for (name, v) in &d.history {
                if let Some(last) = v.last() {
                    let _ = writeln!(s, "  {name} = {}", format_number(*last));
                }
            }
        }
    }

    if !d.root_attrs.is_empty() {
        let _ = writeln!(s, "attributes:");
        for (name, v) in &d.root_attrs {
            let _ = writeln!(s, "  {name} = {v}");
        }
    }

    let lines: Vec<&str> = d.scene_text.lines().collect();
    let _ = writeln!(s, "scene: {} lines", lines.len());
    for line in lines.iter().take(SUMMARY_SCENE_LINES) {
        let _ = writeln!(s, "    {line}");
    }
    if lines.len() > SUMMARY_SCENE_LINES {
        let _ = writeln!(
            s,
            "    ... ({} more lines)",
            lines.len() - SUMMARY_SCENE_LINES
        );
    }
    s
}

/// The `space` attribute of a `/dofs` vector: the element's tag (P0, P1,
/// P1b, P2, P2b), with `^k` when it holds k component blocks in a row.
pub fn space_tag(element: crate::space::Element, blocks: usize) -> String {
    if blocks == 1 {
        element.tag().to_string()
    } else {
        format!("{}^{blocks}", element.tag())
    }
}

/// The element and number of blocks of a [`space_tag`].
pub fn parse_space_tag(tag: &str) -> Option<(crate::space::Element, usize)> {
    let (name, blocks) = match tag.split_once('^') {
        Some((name, k)) => (name, k.parse::<usize>().ok().filter(|k| *k >= 1)?),
        None => (tag, 1),
    };
    Some((crate::space::Element::from_tag(name)?, blocks))
}

/// Renames a finished temporary file into `path` with mode 0644 (tempfile
/// creates 0600): the one way every output file appears, whole or not at all.
pub fn persist_readable(
    tmp: tempfile::NamedTempFile,
    path: &std::path::Path,
) -> crate::error::Result<()> {
    use crate::error::Error;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(tmp.path(), std::fs::Permissions::from_mode(0o644))
            .map_err(|e| Error::output(path, format!("cannot set the file mode: {e}")))?;
    }
    tmp.persist(path)
        .map_err(|e| Error::output(path, format!("cannot rename into place: {e}")))?;
    Ok(())
}

/// Writes `text` to `path` atomically: a temporary file beside it, renamed
/// into place ([`persist_readable`]).
pub fn write_text_atomically(path: &std::path::Path, text: &str) -> crate::error::Result<()> {
    use crate::error::Error;
    use std::io::Write as _;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => std::path::Path::new("."),
    };
    let mut tmp = tempfile::NamedTempFile::new_in(dir)
        .map_err(|e| Error::output(path, format!("cannot create a temporary file: {e}")))?;
    tmp.write_all(text.as_bytes())
        .map_err(|e| Error::output(path, format!("cannot write: {e}")))?;
    persist_readable(tmp, path)
}
