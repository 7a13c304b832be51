//! The HDF5 result file of docs/formulation.md §5: writer (validated, atomic) and reader.
//!
//! Layout written by [`write_result`]:
//!
//! ```text
//! /mesh/vertices        f64 [Nv, 2]
//! /mesh/triangles       u64 [Nt, 3]      zero-based, mesh order
//! /mesh/edges           u64 [Ne, 2]      only when ResultData::write_edges
//! /mesh/surface         f64 [Nv, 3]      shells: the midsurface point φ(x) of each vertex
//! /fields/<name>        f64 [N] or [N, components], attribute `location` = "vertex" | "cell"
//! /dofs/<name>          f64 [len], attribute `space` = "P1b^3", "P2b^3", "P2^2", "P0", …
//!                       (element and number of component blocks; absent in
//!                       files before it: readers then go by the length)
//! /solver               group; ResultData::solver_attrs as scalar attributes
//! /solver/history/<m>   f64 [K]          all of the same length K
//! root attributes       scene, version ("obstacle-fem X.Y.Z"), ResultData::root_attrs
//! ```
//!
//! Attributes are scalars: f64, i64, bool (HDF5 enum FALSE/TRUE over i8, as
//! h5py writes it) and variable-length UTF-8 strings. Groups track link and
//! attribute creation order, so names come back in the order they were written;
//! object modification times are not stored, so writing the same data twice
//! gives the same file.
//!
//! Writing is atomic: everything is validated first (no NaN/inf anywhere, field
//! lengths match the mesh, names non-empty without '/'), the file is written to a
//! temporary `.<name>.XXXXXX.tmp` in the same directory, closed, synced, given
//! mode 0644 and renamed onto the target; the same for the `.xdmf` companion. On
//! any error the temporary files are removed and an existing result is left as
//! it was. The output directory must exist: it is not created (a typo in a path
//! should not scatter directories), and a missing one is a clear error.

use super::xdmf::{self, step_group};
use super::{AttrValue, Field, Location, ResultData, ResultFile};
use crate::error::{Error, Result};
use crate::mesh::Mesh;
use hdf5::plist::file_access::FileCloseDegree;
use hdf5::plist::group_create::{AttrCreationOrder, LinkCreationOrder};
use hdf5::types::{FixedAscii, FixedUnicode, TypeDescriptor, VarLenAscii, VarLenUnicode};
use hdf5::{
    Attribute, Conversion, Dataset, File, Group, IndexType, IterationOrder, Location as H5Loc,
};
use std::collections::HashSet;
use std::fmt::Display;
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// The program version stored in the root attribute `version`.
pub fn program_version() -> String {
    format!("obstacle-fem {}", env!("CARGO_PKG_VERSION"))
}

/// Root attribute names the writer sets itself.
const RESERVED_ROOT_ATTRS: [&str; 2] = ["scene", "version"];

type Res<T> = std::result::Result<T, String>;

/// Adds what was being done to an error message.
trait Ctx<T> {
    fn ctx(self, what: impl FnOnce() -> String) -> Res<T>;
}

impl<T, E: Display> Ctx<T> for std::result::Result<T, E> {
    fn ctx(self, what: impl FnOnce() -> String) -> Res<T> {
        self.map_err(|e| format!("{}: {e}", what()))
    }
}

// ---------------------------------------------------------------------------
// Validation
// ---------------------------------------------------------------------------

/// Checks a dataset/attribute name: non-empty, no '/', no NUL or control
/// characters, not "." or "..".
fn check_name(kind: &str, name: &str) -> Res<()> {
    if name.is_empty() {
        return Err(format!("{kind}: empty name"));
    }
    if name == "." || name == ".." {
        return Err(format!("{kind} `{name}`: reserved name"));
    }
    if name.contains('/') {
        return Err(format!("{kind} `{name}`: name must not contain '/'"));
    }
    if name.chars().any(char::is_control) {
        return Err(format!(
            "{kind} {name:?}: name must not contain control characters"
        ));
    }
    Ok(())
}

/// First non-finite value of a row-major array with `cols` columns (1 = 1-D).
fn check_finite(dataset: &str, values: &[f64], cols: usize) -> Res<()> {
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        let at = if cols <= 1 {
            format!("{i}")
        } else {
            format!("[{}, {}]", i / cols, i % cols)
        };
        return Err(format!(
            "{dataset}: non-finite value {} at index {at} (a result file must not contain NaN or inf)",
            values[i]
        ));
    }
    Ok(())
}

fn check_attr(owner: &str, name: &str, value: &AttrValue) -> Res<()> {
    check_name(&format!("attribute of {owner}"), name)?;
    match value {
        AttrValue::F64(x) if !x.is_finite() => Err(format!(
            "attribute `{name}` of {owner}: non-finite value {x} (a result file must not contain NaN or inf)"
        )),
        AttrValue::Str(s) if s.contains('\0') => Err(format!(
            "attribute `{name}` of {owner}: string contains a NUL character"
        )),
        _ => Ok(()),
    }
}

fn check_unique<'a>(kind: &str, names: impl IntoIterator<Item = &'a str>) -> Res<()> {
    let mut seen = HashSet::new();
    for n in names {
        if !seen.insert(n) {
            return Err(format!("{kind}: duplicate name `{n}`"));
        }
    }
    Ok(())
}

/// Everything [`write_result`] refuses, checked before any file is touched.
pub(crate) fn validate(mesh: &Mesh, data: &ResultData) -> Res<()> {
    let nv = mesh.vertices.len();
    let nt = mesh.triangles.len();
    if nv == 0 {
        return Err("/mesh/vertices: the mesh has no vertices".into());
    }
    if nt == 0 {
        return Err("/mesh/triangles: the mesh has no triangles".into());
    }
    let flat: Vec<f64> = mesh.vertices.iter().flatten().copied().collect();
    check_finite("/mesh/vertices", &flat, 2)?;
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if let Some(&v) = tri.iter().find(|&&v| v >= nv) {
            return Err(format!(
                "/mesh/triangles: triangle {t} refers to vertex {v}, but Nv = {nv}"
            ));
        }
    }
    if data.write_edges {
        if mesh.edges.is_empty() {
            return Err("/mesh/edges: write_edges is set but the mesh has no edges".into());
        }
        for (e, edge) in mesh.edges.iter().enumerate() {
            if let Some(&v) = edge.iter().find(|&&v| v >= nv) {
                return Err(format!(
                    "/mesh/edges: edge {e} refers to vertex {v}, but Nv = {nv}"
                ));
            }
        }
    }

    if let Some(surface) = &data.surface {
        if surface.len() != nv {
            return Err(format!(
                "/mesh/surface: {} points, but Nv = {nv}",
                surface.len()
            ));
        }
        let flat: Vec<f64> = surface.iter().flatten().copied().collect();
        check_finite("/mesh/surface", &flat, 3)?;
    }

    check_unique("/fields", data.fields.iter().map(|f| f.name.as_str()))?;
    for f in &data.fields {
        check_name("/fields", &f.name)?;
        let ds = format!("/fields/{}", f.name);
        if f.components == 0 {
            return Err(format!("{ds}: zero components"));
        }
        let (n, what) = match f.location {
            Location::Vertex => (nv, "Nv"),
            Location::Cell => (nt, "Nt"),
        };
        let expected = n.checked_mul(f.components);
        if expected != Some(f.values.len()) {
            return Err(format!(
                "{ds}: {} values, expected {what} × components = {n} × {} (location {})",
                f.values.len(),
                f.components,
                location_name(f.location)
            ));
        }
        check_finite(&ds, &f.values, f.components)?;
    }

    check_unique("/dofs", data.dofs.iter().map(|(n, _)| n.as_str()))?;
    for (name, values) in &data.dofs {
        check_name("/dofs", name)?;
        check_finite(&format!("/dofs/{name}"), values, 1)?;
    }

    check_unique(
        "attributes of /solver",
        data.solver_attrs.iter().map(|(n, _)| n.as_str()),
    )?;
    for (name, value) in &data.solver_attrs {
        check_attr("/solver", name, value)?;
    }

    check_unique(
        "/solver/history",
        data.history.iter().map(|(n, _)| n.as_str()),
    )?;
    if let Some((first, v0)) = data.history.first() {
        for (name, values) in &data.history {
            check_name("/solver/history", name)?;
            if values.len() != v0.len() {
                return Err(format!(
                    "/solver/history/{name}: {} values, but /solver/history/{first} has {} (all history measures must have the same length)",
                    values.len(),
                    v0.len()
                ));
            }
            check_finite(&format!("/solver/history/{name}"), values, 1)?;
        }
    }

    check_unique(
        "root attributes",
        data.root_attrs.iter().map(|(n, _)| n.as_str()),
    )?;
    for (name, value) in &data.root_attrs {
        if RESERVED_ROOT_ATTRS.contains(&name.as_str()) {
            return Err(format!(
                "root attribute `{name}`: reserved (written from scene_text / the program version)"
            ));
        }
        check_attr("/", name, value)?;
    }
    if data.scene_text.contains('\0') {
        return Err("root attribute `scene`: scene text contains a NUL character".into());
    }
    Ok(())
}

pub(crate) fn location_name(loc: Location) -> &'static str {
    match loc {
        Location::Vertex => "vertex",
        Location::Cell => "cell",
    }
}

// ---------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------

fn new_group(parent: &Group, name: &str) -> Res<Group> {
    parent
        .create_group_builder()
        .obj_track_times(false)
        .with_gcpl(|p| {
            p.link_creation_order(LinkCreationOrder::Indexed)
                .attr_creation_order(AttrCreationOrder::Indexed)
        })
        .create(name)
        .ctx(|| format!("creating group `{name}`"))
}

fn write_f64(
    group: &Group,
    path: &str,
    name: &str,
    shape: &[usize],
    values: &[f64],
) -> Res<Dataset> {
    let ds = group
        .new_dataset::<f64>()
        .shape(shape)
        .obj_track_times(false)
        .create(name)
        .ctx(|| format!("creating {path}"))?;
    ds.write_raw(values).ctx(|| format!("writing {path}"))?;
    Ok(ds)
}

fn write_u64(group: &Group, path: &str, name: &str, shape: &[usize], values: &[u64]) -> Res<()> {
    let ds = group
        .new_dataset::<u64>()
        .shape(shape)
        .obj_track_times(false)
        .create(name)
        .ctx(|| format!("creating {path}"))?;
    ds.write_raw(values).ctx(|| format!("writing {path}"))
}

fn write_str_attr(loc: &H5Loc, owner: &str, name: &str, s: &str) -> Res<()> {
    let what = || format!("writing attribute `{name}` of {owner}");
    let v: VarLenUnicode = s.parse().ctx(what)?;
    loc.new_attr::<VarLenUnicode>()
        .shape(())
        .create(name)
        .ctx(what)?
        .write_scalar(&v)
        .ctx(what)
}

fn write_attr(loc: &H5Loc, owner: &str, name: &str, value: &AttrValue) -> Res<()> {
    let what = || format!("writing attribute `{name}` of {owner}");
    match value {
        AttrValue::F64(x) => loc
            .new_attr::<f64>()
            .shape(())
            .create(name)
            .ctx(what)?
            .write_scalar(x)
            .ctx(what),
        AttrValue::I64(x) => loc
            .new_attr::<i64>()
            .shape(())
            .create(name)
            .ctx(what)?
            .write_scalar(x)
            .ctx(what),
        AttrValue::Bool(x) => loc
            .new_attr::<bool>()
            .shape(())
            .create(name)
            .ctx(what)?
            .write_scalar(x)
            .ctx(what),
        AttrValue::Str(s) => write_str_attr(loc, owner, name, s),
    }
}

/// Writes the whole layout into a new file's root or a step's group
/// (`/steps/NNN`). All handles it opens are dropped on return, so the caller
/// can close the file.
fn write_layout(root: &Group, mesh: &Mesh, data: &ResultData) -> Res<()> {
    let g = new_group(root, "mesh")?;
    let nv = mesh.vertices.len();
    let nt = mesh.triangles.len();
    let verts: Vec<f64> = mesh.vertices.iter().flatten().copied().collect();
    write_f64(&g, "/mesh/vertices", "vertices", &[nv, 2], &verts)?;
    let tris: Vec<u64> = mesh.triangles.iter().flatten().map(|&v| v as u64).collect();
    write_u64(&g, "/mesh/triangles", "triangles", &[nt, 3], &tris)?;
    if data.write_edges {
        let edges: Vec<u64> = mesh.edges.iter().flatten().map(|&v| v as u64).collect();
        write_u64(&g, "/mesh/edges", "edges", &[mesh.edges.len(), 2], &edges)?;
    }
    if let Some(surface) = &data.surface {
        let points: Vec<f64> = surface.iter().flatten().copied().collect();
        write_f64(&g, "/mesh/surface", "surface", &[nv, 3], &points)?;
    }
    drop(g);

    let g = new_group(root, "fields")?;
    for f in &data.fields {
        let path = format!("/fields/{}", f.name);
        let n = f.values.len() / f.components;
        let shape: Vec<usize> = if f.components == 1 {
            vec![n]
        } else {
            vec![n, f.components]
        };
        let ds = write_f64(&g, &path, &f.name, &shape, &f.values)?;
        write_str_attr(&ds, &path, "location", location_name(f.location))?;
    }
    drop(g);

    let g = new_group(root, "dofs")?;
    for (name, values) in &data.dofs {
        let path = format!("/dofs/{name}");
        let ds = write_f64(&g, &path, name, &[values.len()], values)?;
        if let Some((_, space)) = data.dof_spaces.iter().find(|(n, _)| n == name) {
            write_str_attr(&ds, &path, "space", space)?;
        }
    }
    drop(g);

    let g = new_group(root, "solver")?;
    for (name, value) in &data.solver_attrs {
        write_attr(&g, "/solver", name, value)?;
    }
    let h = new_group(&g, "history")?;
    for (name, values) in &data.history {
        write_f64(
            &h,
            &format!("/solver/history/{name}"),
            name,
            &[values.len()],
            values,
        )?;
    }
    drop(h);
    drop(g);

    write_str_attr(root, "/", "scene", &data.scene_text)?;
    write_str_attr(root, "/", "version", &program_version())?;
    for (name, value) in &data.root_attrs {
        write_attr(root, "/", name, value)?;
    }
    Ok(())
}

/// Creates the HDF5 file at `tmp` (truncating it), writes the layout (and
/// each of `steps` in its `/steps/NNN` group) and closes it.
fn write_h5_file(
    tmp: &Path,
    mesh: &Mesh,
    data: &ResultData,
    steps: &[(&Mesh, &ResultData)],
) -> Res<()> {
    let file = File::with_options()
        .with_fcpl(|p| {
            p.obj_track_times(false)
                .attr_creation_order(AttrCreationOrder::Indexed)
        })
        .with_fapl(|p| p.fclose_degree(FileCloseDegree::Strong).file_locking(false))
        .create(tmp)
        .ctx(|| "creating the HDF5 file".to_string())?;
    let written = write_layout(&file, mesh, data).and_then(|()| {
        if steps.is_empty() {
            return Ok(());
        }
        let g = new_group(&file, "steps")?;
        steps.iter().enumerate().try_for_each(|(k, (m, d))| {
            let name = step_group(k);
            write_layout(&new_group(&g, &name["/steps/".len()..])?, m, d)
        })
    });
    // Close in every case (an error leaves a temporary that is removed anyway).
    let closed = file.close().ctx(|| "closing the HDF5 file".to_string());
    written?;
    closed
}

/// Syncs a finished temporary file and gives it mode 0644.
fn finish_temp(tmp: &tempfile::NamedTempFile) -> Res<()> {
    tmp.as_file()
        .sync_all()
        .ctx(|| format!("syncing {}", tmp.path().display()))?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(tmp.path(), std::fs::Permissions::from_mode(0o644))
            .ctx(|| format!("setting the mode of {}", tmp.path().display()))?;
    }
    Ok(())
}

fn temp_in(dir: &Path, file_name: &str) -> Res<tempfile::NamedTempFile> {
    tempfile::Builder::new()
        .prefix(&format!(".{file_name}."))
        .suffix(".tmp")
        .tempfile_in(dir)
        .ctx(|| format!("creating a temporary file in {}", dir.display()))
}

/// Writes the result file `path` (docs/formulation.md §5 layout) and its companion
/// `path.with_extension("xdmf")`, both atomically. See the module docs.
///
/// Errors are [`Error::Output`] naming `path`; nothing is written unless all the
/// data are valid, and an existing `path` is left untouched on failure.
pub fn write_result(path: &Path, mesh: &Mesh, data: &ResultData) -> Result<()> {
    write_result_with_steps(path, mesh, data, &[])
}

/// An adaptive run's result (docs/formulation.md §5): the last step's layout at
/// the root (what [`read_result`] and `obstacle info` read), every step's in
/// `/steps/NNN`, and an XDMF temporal collection of the steps.
pub fn write_adaptive_result(path: &Path, steps: &[(&Mesh, &ResultData)]) -> Result<()> {
    let Some((mesh, data)) = steps.last() else {
        return Err(Error::output(
            path,
            "an adaptive result needs at least one step",
        ));
    };
    write_result_with_steps(path, mesh, data, steps)
}

fn write_result_with_steps(
    path: &Path,
    mesh: &Mesh,
    data: &ResultData,
    steps: &[(&Mesh, &ResultData)],
) -> Result<()> {
    let fail = |reason: String| Error::output(path, reason);
    validate(mesh, data).map_err(fail)?;
    for (k, (m, d)) in steps.iter().enumerate() {
        validate(m, d).map_err(|e| fail(format!("{}: {e}", step_group(k))))?;
    }

    let file_name = path
        .file_name()
        .ok_or_else(|| fail("the output path has no file name".into()))?
        .to_str()
        .ok_or_else(|| {
            fail("the output file name is not valid UTF-8 (the XDMF file must reference it)".into())
        })?
        .to_string();
    if file_name.contains(':') {
        return Err(fail(
            "the output file name contains ':', which an XDMF reference `FILE:/dataset` cannot hold".into(),
        ));
    }
    let xdmf_path = xdmf::xdmf_path(path);
    if xdmf_path == path {
        return Err(fail(
            "the result file must not have the extension .xdmf (its XDMF companion takes that name)".into(),
        ));
    }
    let dir: PathBuf = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if !dir.is_dir() {
        return Err(fail(format!(
            "the output directory {} does not exist (it is not created automatically)",
            dir.display()
        )));
    }
    let xdmf_name = xdmf_path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("result.xdmf")
        .to_string();
    let xdmf_text = if steps.is_empty() {
        xdmf::render(&file_name, mesh, data)
    } else {
        xdmf::render_steps(&file_name, steps)
    };
    // A shell's parameter domain gets its own companion (the main one is 3D).
    let domain = data.surface.as_ref().map(|_| {
        (
            xdmf::domain_xdmf_path(path),
            xdmf::render_domain(&file_name, mesh, data),
        )
    });

    hdf5::silence_errors(true);
    // Both temporaries are removed when dropped, i.e. on every early return.
    let h5_tmp = temp_in(&dir, &file_name).map_err(fail)?;
    write_h5_file(h5_tmp.path(), mesh, data, steps).map_err(fail)?;
    finish_temp(&h5_tmp).map_err(fail)?;

    let mut x_tmp = temp_in(&dir, &xdmf_name).map_err(fail)?;
    x_tmp
        .write_all(xdmf_text.as_bytes())
        .and_then(|_| x_tmp.flush())
        .map_err(|e| fail(format!("writing the XDMF companion: {e}")))?;
    finish_temp(&x_tmp).map_err(fail)?;
    let domain_tmp = match &domain {
        Some((domain_path, text)) => {
            let name = domain_path
                .file_name()
                .and_then(|n| n.to_str())
                .unwrap_or("result.domain.xdmf");
            let mut tmp = temp_in(&dir, name).map_err(fail)?;
            tmp.write_all(text.as_bytes())
                .and_then(|_| tmp.flush())
                .map_err(|e| fail(format!("writing the parameter-domain XDMF: {e}")))?;
            finish_temp(&tmp).map_err(fail)?;
            Some((domain_path, tmp))
        }
        None => None,
    };

    h5_tmp.persist(path).map_err(|e| {
        fail(format!(
            "renaming the finished file onto the target: {}",
            e.error
        ))
    })?;
    for (target, tmp) in [(&xdmf_path, x_tmp)].into_iter().chain(domain_tmp) {
        tmp.persist(target).map_err(|e| {
            Error::output(
                target,
                format!(
                    "renaming the finished XDMF file onto the target (the .h5 file was written): {}",
                    e.error
                ),
            )
        })?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------
// Reading
// ---------------------------------------------------------------------------

/// Names of a group's members in creation order (our files), else by name.
fn member_names(g: &Group) -> Res<Vec<String>> {
    match g.member_names_by(IndexType::CreationOrder, IterationOrder::Increasing) {
        Ok(names) => Ok(names),
        Err(_) => g.member_names().ctx(|| format!("listing {}", g.name())),
    }
}

/// Attribute names in creation order (our files), else by name.
fn attr_names(loc: &H5Loc) -> Res<Vec<String>> {
    match loc.attr_names_by(IndexType::CreationOrder, IterationOrder::Increasing) {
        Ok(names) => Ok(names),
        Err(_) => loc
            .attr_names()
            .ctx(|| format!("listing attributes of {}", loc.name())),
    }
}

fn open_group(parent: &Group, name: &str, path: &str) -> Res<Group> {
    if !parent.link_exists(name) {
        return Err(format!("missing group {path}"));
    }
    parent.group(name).ctx(|| format!("{path} is not a group"))
}

fn open_dataset(parent: &Group, name: &str, path: &str) -> Res<Dataset> {
    if !parent.link_exists(name) {
        return Err(format!("missing dataset {path}"));
    }
    parent
        .dataset(name)
        .ctx(|| format!("{path} is not a dataset"))
}

fn is_float(ds: &Dataset) -> bool {
    matches!(
        ds.dtype().and_then(|t| t.to_descriptor()),
        Ok(TypeDescriptor::Float(_))
    )
}

fn is_integer(ds: &Dataset) -> bool {
    matches!(
        ds.dtype().and_then(|t| t.to_descriptor()),
        Ok(TypeDescriptor::Integer(_) | TypeDescriptor::Unsigned(_))
    )
}

/// A dataset's declared size against the file's: a corrupted or hostile
/// shape (1e9 entries in a 200 KB file) is refused before HDF5 allocates it.
/// Unfiltered data is stored whole, so it cannot exceed the file; compressed
/// data may, by a bounded ratio.
fn check_declared_size(ds: &Dataset, path: &str) -> Res<()> {
    const MAX_COMPRESSION: u64 = 1000;
    let declared = (ds.size() as u64).saturating_mul(8);
    let file_size = ds.file().map(|f| f.size()).unwrap_or(0);
    let bound = if ds.filters().is_empty() {
        file_size
    } else {
        file_size.saturating_mul(MAX_COMPRESSION)
    };
    if declared > bound {
        return Err(format!(
            "{path}: shape {:?} declares {declared} bytes, more than the file ({file_size} bytes) can hold: a corrupted or foreign file",
            ds.shape()
        ));
    }
    Ok(())
}

/// Reads a numeric dataset as f64 (integers are converted).
fn read_f64(ds: &Dataset, path: &str) -> Res<Vec<f64>> {
    check_declared_size(ds, path)?;
    if !is_float(ds) && !is_integer(ds) {
        let t = ds
            .dtype()
            .and_then(|t| t.to_descriptor())
            .map(|d| d.to_string())
            .unwrap_or_else(|_| "unknown type".into());
        return Err(format!("{path}: expected floating-point values, found {t}"));
    }
    ds.as_reader()
        .conversion(Conversion::Soft)
        .read_raw::<f64>()
        .ctx(|| format!("reading {path}"))
}

/// Reads an integer index dataset of shape [n, cols] with every entry < bound.
fn read_indices<const C: usize>(ds: &Dataset, path: &str, bound: usize) -> Res<Vec<[usize; C]>> {
    let shape = ds.shape();
    if shape.len() != 2 || shape[1] != C {
        return Err(format!("{path}: shape {shape:?}, expected [n, {C}]"));
    }
    if !is_integer(ds) {
        return Err(format!("{path}: expected integer indices"));
    }
    check_declared_size(ds, path)?;
    let raw = ds
        .as_reader()
        .conversion(Conversion::Soft)
        .read_raw::<u64>()
        .ctx(|| format!("reading {path}"))?;
    if raw.len() != shape[0] * C {
        return Err(format!(
            "{path}: read {} values for shape {shape:?}",
            raw.len()
        ));
    }
    let mut out = Vec::with_capacity(shape[0]);
    for (row, chunk) in raw.chunks_exact(C).enumerate() {
        let mut r = [0usize; C];
        for (k, &v) in chunk.iter().enumerate() {
            if v >= bound as u64 {
                return Err(format!(
                    "{path}: row {row} refers to vertex {v}, but Nv = {bound}"
                ));
            }
            r[k] = v as usize;
        }
        out.push(r);
    }
    Ok(out)
}

/// Reads a scalar (or one-element) attribute. `Ok(None)` for types that
/// [`AttrValue`] cannot hold (arrays, compounds, ...), which are skipped.
fn read_attr(attr: &Attribute, what: &str) -> Res<Option<AttrValue>> {
    if attr.size() != 1 {
        return Ok(None);
    }
    let desc = attr
        .dtype()
        .and_then(|t| t.to_descriptor())
        .ctx(|| format!("reading the type of {what}"))?;
    let reader = attr.as_reader().conversion(Conversion::Soft);
    fn first<T>(v: Vec<T>) -> Option<T> {
        v.into_iter().next()
    }
    let ctx = || format!("reading {what}");
    let value = match desc {
        TypeDescriptor::Float(_) => first(reader.read_raw::<f64>().ctx(ctx)?).map(AttrValue::F64),
        TypeDescriptor::Integer(_) | TypeDescriptor::Unsigned(_) => {
            first(reader.read_raw::<i64>().ctx(ctx)?).map(AttrValue::I64)
        }
        TypeDescriptor::Boolean => first(reader.read_raw::<bool>().ctx(ctx)?).map(AttrValue::Bool),
        TypeDescriptor::VarLenUnicode => first(reader.read_raw::<VarLenUnicode>().ctx(ctx)?)
            .map(|s| utf8_attr(s.as_bytes(), what))
            .transpose()?,
        TypeDescriptor::VarLenAscii => first(reader.read_raw::<VarLenAscii>().ctx(ctx)?)
            .map(|s| utf8_attr(s.as_bytes(), what))
            .transpose()?,
        TypeDescriptor::FixedAscii(n) if n <= 4096 => {
            first(reader.read_raw::<FixedAscii<4096>>().ctx(ctx)?)
                .map(|s| utf8_attr(s.as_bytes(), what))
                .transpose()?
        }
        TypeDescriptor::FixedUnicode(n) if n <= 4096 => {
            first(reader.read_raw::<FixedUnicode<4096>>().ctx(ctx)?)
                .map(|s| utf8_attr(s.as_bytes(), what))
                .transpose()?
        }
        _ => None,
    };
    Ok(value)
}

/// A string attribute's bytes as text. The hdf5 crate's `as_str` trusts the
/// file's bytes to be UTF-8 (its declared character set is only a label), and
/// a result file is untrusted input: the bytes are checked here.
fn utf8_attr(bytes: &[u8], what: &str) -> Res<AttrValue> {
    match std::str::from_utf8(bytes) {
        Ok(s) => Ok(AttrValue::Str(s.to_string())),
        Err(e) => Err(format!(
            "{what} is not valid UTF-8 (byte {} of {}: {:#04x})",
            e.valid_up_to(),
            bytes.len(),
            bytes[e.valid_up_to()]
        )),
    }
}

/// All readable attributes of an object, in creation order, except `skip`.
fn read_attrs(loc: &H5Loc, owner: &str, skip: &[&str]) -> Res<Vec<(String, AttrValue)>> {
    let mut out = Vec::new();
    for name in attr_names(loc)? {
        if skip.contains(&name.as_str()) {
            continue;
        }
        let what = format!("attribute `{name}` of {owner}");
        let attr = loc.attr(&name).ctx(|| format!("opening {what}"))?;
        if let Some(v) = read_attr(&attr, &what)? {
            out.push((name, v));
        }
    }
    Ok(out)
}

fn read_str_attr(loc: &H5Loc, owner: &str, name: &str) -> Res<String> {
    let what = format!("attribute `{name}` of {owner}");
    let attr = loc.attr(name).map_err(|_| format!("missing {what}"))?;
    match read_attr(&attr, &what)? {
        Some(AttrValue::Str(s)) => Ok(s),
        _ => Err(format!("{what} is not a string")),
    }
}

fn read_field(g: &Group, name: &str, nv: usize, nt: usize) -> Res<Field> {
    let path = format!("/fields/{name}");
    let ds = open_dataset(g, name, &path)?;
    let shape = ds.shape();
    let (n, components) = match shape.as_slice() {
        [n] => (*n, 1),
        [n, c] if *c >= 1 => (*n, *c),
        _ => {
            return Err(format!(
                "{path}: shape {shape:?}, expected [N] or [N, components]"
            ))
        }
    };
    let location = if ds
        .attr_names()
        .map(|a| a.iter().any(|s| s == "location"))
        .unwrap_or(false)
    {
        match read_str_attr(&ds, &path, "location")?.as_str() {
            "vertex" => Location::Vertex,
            "cell" => Location::Cell,
            other => {
                return Err(format!(
                    "{path}: attribute `location` is {other:?}, expected \"vertex\" or \"cell\""
                ))
            }
        }
    } else if n == nv {
        Location::Vertex
    } else if n == nt {
        Location::Cell
    } else {
        return Err(format!(
            "{path}: no `location` attribute and {n} rows match neither Nv = {nv} nor Nt = {nt}"
        ));
    };
    let expected = match location {
        Location::Vertex => nv,
        Location::Cell => nt,
    };
    if n != expected {
        return Err(format!(
            "{path}: {n} rows, but a {} field needs {expected}",
            location_name(location)
        ));
    }
    let values = read_f64(&ds, &path)?;
    Ok(Field {
        name: name.to_string(),
        values,
        components,
        location,
    })
}

fn read_vector(g: &Group, name: &str, path: &str) -> Res<Vec<f64>> {
    let ds = open_dataset(g, name, path)?;
    let shape = ds.shape();
    if shape.len() != 1 {
        return Err(format!("{path}: shape {shape:?}, expected one dimension"));
    }
    read_f64(&ds, path)
}

fn read_layout(root: &Group) -> Res<ResultFile> {
    let mesh = open_group(root, "mesh", "/mesh")
        .map_err(|e| format!("{e} (not an obstacle-fem result file?)"))?;
    let ds = open_dataset(&mesh, "vertices", "/mesh/vertices")?;
    let shape = ds.shape();
    if shape.len() != 2 || shape[1] != 2 {
        return Err(format!("/mesh/vertices: shape {shape:?}, expected [Nv, 2]"));
    }
    if !is_float(&ds) {
        return Err("/mesh/vertices: expected floating-point coordinates".into());
    }
    let flat = read_f64(&ds, "/mesh/vertices")?;
    let vertices: Vec<[f64; 2]> = flat.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
    let nv = vertices.len();
    let ds = open_dataset(&mesh, "triangles", "/mesh/triangles")?;
    let triangles = read_indices::<3>(&ds, "/mesh/triangles", nv)?;
    let nt = triangles.len();
    let edges = if mesh.link_exists("edges") {
        let ds = open_dataset(&mesh, "edges", "/mesh/edges")?;
        Some(read_indices::<2>(&ds, "/mesh/edges", nv)?)
    } else {
        None
    };

    let surface = if mesh.link_exists("surface") {
        let ds = open_dataset(&mesh, "surface", "/mesh/surface")?;
        let shape = ds.shape();
        if shape != [nv, 3] {
            return Err(format!(
                "/mesh/surface: shape {shape:?}, expected [Nv, 3] = [{nv}, 3]"
            ));
        }
        let flat = read_f64(&ds, "/mesh/surface")?;
        Some(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
    } else {
        None
    };

    let mut data = ResultData {
        write_edges: edges.is_some(),
        surface,
        ..ResultData::default()
    };

    let g = open_group(root, "fields", "/fields")?;
    for name in member_names(&g)? {
        data.fields.push(read_field(&g, &name, nv, nt)?);
    }

    if root.link_exists("dofs") {
        let g = open_group(root, "dofs", "/dofs")?;
        for name in member_names(&g)? {
            let path = format!("/dofs/{name}");
            let v = read_vector(&g, &name, &path)?;
            let ds = open_dataset(&g, &name, &path)?;
            if ds
                .attr_names()
                .is_ok_and(|a| a.iter().any(|s| s == "space"))
            {
                let space = read_str_attr(&ds, &path, "space")?;
                if crate::output::parse_space_tag(&space).is_none() {
                    return Err(format!("{path}: attribute `space` = \"{space}\" names no element (P0, P1, P1b, P2, P2b, optionally ^k)"));
                }
                data.dof_spaces.push((name.clone(), space));
            }
            data.dofs.push((name, v));
        }
    }

    let solver = open_group(root, "solver", "/solver")?;
    data.solver_attrs = read_attrs(&solver, "/solver", &[])?;
    if solver.link_exists("history") {
        let h = open_group(&solver, "history", "/solver/history")?;
        for name in member_names(&h)? {
            let path = format!("/solver/history/{name}");
            let v = read_vector(&h, &name, &path)?;
            if let Some((first, v0)) = data.history.first() {
                if v0.len() != v.len() {
                    return Err(format!(
                        "{path}: {} values, but /solver/history/{first} has {}",
                        v.len(),
                        v0.len()
                    ));
                }
            }
            data.history.push((name, v));
        }
    }

    let version = read_str_attr(root, "/", "version")?;
    data.scene_text = read_str_attr(root, "/", "scene")?;
    data.root_attrs = read_attrs(root, "/", &RESERVED_ROOT_ATTRS)?;

    Ok(ResultFile {
        vertices,
        triangles,
        edges,
        data,
        version,
    })
}

/// Reads a result file written by [`write_result`] (or any file with the docs/formulation.md §5
/// layout). Missing or malformed parts give [`Error::Output`] naming the file
/// and the dataset; HDF5's own error printing is silenced.
///
/// A field's location comes from its `location` attribute, or, without one,
/// from its row count (Nv → vertex, else Nt → cell). `/dofs` and
/// `/solver/history` may be absent (read as empty); attributes of types that
/// [`AttrValue`] cannot hold are skipped.
pub fn read_result(path: &Path) -> Result<ResultFile> {
    let fail = |reason: String| Error::output(path, reason);
    hdf5::silence_errors(true);
    let meta = std::fs::metadata(path).map_err(|e| fail(format!("cannot read: {e}")))?;
    if !meta.is_file() {
        return Err(fail("not a regular file".into()));
    }
    // No HDF5 file locks: results are renamed into place whole, so a reader
    // never sees a file being written, and locks only cause spurious EAGAIN
    // failures when one process opens several files.
    let file = File::with_options()
        .with_fapl(|p| p.file_locking(false))
        .open(path)
        .map_err(|e| {
            fail(format!(
                "not a readable HDF5 file (truncated, or another format?): {e}"
            ))
        })?;
    check_global_heaps(path).map_err(fail)?;
    read_layout(&file).map_err(fail)
}

/// The steps of an adaptive result (`/steps/NNN`, in order), each read like a
/// result file; empty for a result of one solve.
pub fn read_steps(path: &Path) -> Result<Vec<ResultFile>> {
    let fail = |reason: String| Error::output(path, reason);
    read_result(path)?; // the file's checks, and its root layout
    let file = File::with_options()
        .with_fapl(|p| p.file_locking(false))
        .open(path)
        .map_err(|e| fail(format!("not a readable HDF5 file: {e}")))?;
    if !file.link_exists("steps") {
        return Ok(Vec::new());
    }
    let g = open_group(&file, "steps", "/steps").map_err(fail)?;
    let names = member_names(&g).map_err(fail)?;
    names
        .iter()
        .enumerate()
        .map(|(k, name)| {
            if *name != step_group(k)["/steps/".len()..] {
                return Err(fail(format!(
                    "/steps/{name}: expected {} (steps are numbered 000, 001, ... in order)",
                    step_group(k)
                )));
            }
            let step = open_group(&g, name, &step_group(k)).map_err(fail)?;
            read_layout(&step).map_err(|e| fail(format!("{}: {e}", step_group(k))))
        })
        .collect()
}

/// The global heap collections ("GCOL", where variable-length strings live)
/// are walked before HDF5 reads them: libhdf5 trusts a stored object size
/// and copies that many bytes, so one flipped bit there crashes or hangs the
/// reader (tests/parsers_prop.rs, corrupted files). Every object must lie
/// inside its collection, and every collection inside the file.
fn check_global_heaps(path: &Path) -> Res<()> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read: {e}"))?;
    let u64_at = |i: usize| -> Option<u64> {
        Some(u64::from_le_bytes(bytes.get(i..i + 8)?.try_into().ok()?))
    };
    let corrupt = |at: usize, what: &str| {
        format!("global heap collection at byte {at}: {what} (a corrupted file)")
    };
    let mut from = 0;
    while let Some(k) = bytes[from..].windows(4).position(|w| w == b"GCOL") {
        let start = from + k;
        from = start + 4;
        if bytes.get(start + 4) != Some(&1) {
            continue; // not a version-1 collection: data that happens to read "GCOL"
        }
        let size = u64_at(start + 8).ok_or_else(|| corrupt(start, "truncated header"))?;
        let end = usize::try_from(size)
            .ok()
            .and_then(|s| start.checked_add(s))
            .filter(|&e| e <= bytes.len() && size >= 16)
            .ok_or_else(|| corrupt(start, &format!("size {size} does not fit the file")))?;
        // Objects: index (2), references (2), reserved (4), size (8), data
        // padded to 8 bytes; index 0 is the free space and ends the list.
        let mut at = start + 16;
        while at + 16 <= end {
            let index = u16::from_le_bytes([bytes[at], bytes[at + 1]]);
            let object = u64_at(at + 8).unwrap_or(u64::MAX);
            if index == 0 {
                break;
            }
            let padded = object
                .checked_add(7)
                .map(|v| v / 8 * 8)
                .and_then(|v| usize::try_from(v).ok())
                .and_then(|v| (at + 16).checked_add(v))
                .filter(|&next| next <= end)
                .ok_or_else(|| {
                    corrupt(
                        start,
                        &format!("object {index} of {object} bytes overruns the collection"),
                    )
                })?;
            at = padded;
        }
    }
    Ok(())
}
