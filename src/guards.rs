//! Guards of a run: what the machine can hold, and which input a
//! non-finite number came from.
//!
//! - **Resources**: the unknowns and memory a scene needs are estimated from
//!   (model, element, triangles); before meshing from `mesh.n` (2 n²
//!   triangles on the diamond and the rectangle, 2.9 n² on the disk, 3 n²
//!   assumed elsewhere), after meshing from the mesh itself.
//!   An estimate above the limit (half of `MemAvailable` in /proc/meminfo,
//!   or the scene's `mesh.memory_limit_gb`) is refused with both numbers.
//! - **Degenerate problems**: a multiplier that acts on no free unknown (every
//!   dof of its support on the Dirichlet boundary) is refused, naming the mesh.
//! - **Tracing**: non-finite assembled entries are reported against the
//!   scene keys (or the mesh) that feed them, never as "entry 0 is not finite".

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use crate::models;
use crate::scene::Scene;
use crate::solvers::ContactProblem;

/// The part of `MemAvailable` a run may use by default.
const MEMORY_FRACTION: f64 = 0.5;

/// What a scene needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    pub triangles: f64,
    pub unknowns: f64,
    pub bytes: f64,
}

/// The estimate for a mesh of `triangles` triangles.
pub fn estimate(scene: &Scene, triangles: f64) -> Estimate {
    let model = models::kind(scene.model);
    let unknowns = triangles * model.unknowns_per_triangle(scene.element);
    let bytes_per_unknown = match scene.solver.method {
        crate::scene::Method::Multigrid => model.multigrid_bytes_per_unknown(),
        _ => model.bytes_per_unknown(scene.solver.condense),
    };
    Estimate {
        triangles,
        unknowns,
        bytes: unknowns * bytes_per_unknown,
    }
}

/// The estimate before meshing: structured meshes (`mesh.n`) have
/// `triangles_per_n2` n² triangles. None for a target size `h` (the
/// triangles depend on the domain, known after meshing).
pub fn estimate_before_meshing(scene: &Scene) -> Option<Estimate> {
    let n = scene.mesh.n? as f64;
    let refinements = 4f64.powi(scene.mesh.refine as i32);
    Some(estimate(
        scene,
        triangles_per_n2(scene.mesh.geo.as_deref()) * n * n * refinements,
    ))
}

/// Triangles per n² of the repository's geometries: the diamond (and its
/// variants) and the rectangle 2, the disk 2.9; any other 3 (an upper
/// bound of the others). Counting 3 for the diamond refused `make bench`'s
/// shell n = 128 (6.8 GB estimated, 2.2 GB used) on a busy machine.
fn triangles_per_n2(geo: Option<&str>) -> f64 {
    let stem = geo
        .and_then(|g| std::path::Path::new(g).file_stem())
        .and_then(|s| s.to_str())
        .unwrap_or("");
    match stem {
        s if s.starts_with("diamond") || s == "rectangle" => 2.0,
        "disk" => 2.9,
        _ => 3.0,
    }
}

/// Peak resident set size of this process so far (kB), from
/// /proc/self/status VmHWM; None where it cannot be read.
pub fn peak_rss_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

/// `MemAvailable` of /proc/meminfo in bytes; None where it cannot be read.
fn memory_available() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0)
}

/// Refuses an estimate above the limit: `mesh.memory_limit_gb`, else half of
/// `MemAvailable`. `when` says which estimate ("before meshing", ...).
pub fn check_memory(scene: &Scene, e: &Estimate, when: &str) -> Result<()> {
    let (limit, source) = match scene.mesh.memory_limit_gb {
        Some(gb) => (gb * 1e9, "mesh.memory_limit_gb".to_string()),
        None => match memory_available() {
            Some(avail) => (
                MEMORY_FRACTION * avail,
                format!("{MEMORY_FRACTION} × MemAvailable ({:.1} GB)", avail / 1e9),
            ),
            None => return Ok(()),
        },
    };
    if e.bytes <= limit {
        return Ok(());
    }
    let field = if scene.mesh.n.is_some() {
        "mesh.n"
    } else {
        "mesh.h"
    };
    Err(scene.error(field, format!(
            "{when}: about {:.3e} triangles and {:.3e} unknowns need ~{:.3} GB, above the limit {:.3} GB = {source}; a coarser mesh, or set mesh.memory_limit_gb to allow more",
            e.triangles,
            e.unknowns,
            e.bytes / 1e9,
            limit / 1e9
        )))
}

/// The length scales a mesh may have: coordinates up to 1e50 and edges
/// down to 1e-50, so that areas, their squares and the stiffness (∝ 1/h²
/// per area) stay within f64.
const MESH_SCALE_LIMIT: f64 = 1e50;

/// The mesh's coordinates and edge lengths lie within [1e-50, 1e50]; an
/// error naming the mesh file otherwise.
pub fn check_mesh_scale(mesh: &Mesh) -> Result<()> {
    let extent = mesh
        .vertices
        .iter()
        .fold(0.0f64, |m, p| m.max(p[0].abs()).max(p[1].abs()));
    let shortest = (0..mesh.n_edges())
        .map(|e| mesh.edge_length(e))
        .fold(f64::INFINITY, f64::min);
    if extent > MESH_SCALE_LIMIT || shortest < 1.0 / MESH_SCALE_LIMIT {
        return Err(Error::mesh(
            &mesh.source,
            format!(
                "coordinates up to {extent:e} and edges down to {shortest:e}: a mesh must lie within [1e-50, 1e50] in size (areas and stiffness overflow f64 beyond); rescale the geometry"
            ),
        ));
    }
    Ok(())
}

/// The assembled problem is finite, and every multiplier acts on at least
/// one free unknown; otherwise an error naming the scene keys and the mesh.
pub fn check_assembled(scene: &Scene, mesh: &Mesh, p: &ContactProblem) -> Result<()> {
    let blame = |field: &str, what: &str, keys: &str, k: usize, v: f64| {
        scene.error(field, format!(
            "the assembled {what} is not finite (entry {k} = {v}) on the mesh {}: {keys} overflow f64 (too large or too small in magnitude)",
            mesh.source.display()
        ))
    };
    let first_bad = |v: &[f64]| v.iter().position(|x| !x.is_finite()).map(|k| (k, v[k]));
    if let Some((k, v)) = first_bad(p.matrix.val()) {
        let (field, keys) = models::kind(scene.model).matrix_inputs();
        return Err(blame(field, "stiffness matrix", keys, k, v));
    }
    if let Some((k, v)) = first_bad(&p.rhs) {
        let (field, keys) = models::kind(scene.model).load_inputs();
        return Err(blame(field, "load vector", keys, k, v));
    }
    let Some(c) = &p.constraint else {
        return Ok(());
    };
    if let Some((k, v)) = first_bad(&c.obstacle) {
        return Err(blame(
            "obstacle",
            "obstacle vector",
            "obstacle.height, obstacle.curvature",
            k,
            v,
        ));
    }
    if let Some((k, v)) = first_bad(c.matrix.val()).or(first_bad(&c.weights)) {
        return Err(blame(
            "mesh",
            "contact constraint",
            "the mesh coordinates",
            k,
            v,
        ));
    }
    let mut touches_free = vec![false; c.matrix.nrows()];
    let m = c.matrix.as_ref();
    for j in 0..m.ncols().min(p.n_primal) {
        for (i, v) in m.row_idx_of_col(j).zip(m.val_of_col(j)) {
            touches_free[i] |= *v != 0.0;
        }
    }
    if let Some(i) = touches_free.iter().position(|t| !t) {
        return Err(Error::mesh(
            &mesh.source,
            format!(
                "element {}: contact multiplier {i} acts on no free unknown (its support lies on the Dirichlet boundary; {} free unknowns in all): the contact is decided by the boundary data alone; use a finer mesh or another element",
                scene.element.name(),
                p.n_primal
            ),
        ));
    }
    Ok(())
}

/// A singular or non-finite factorisation met while solving, traced to the
/// scene keys that build the matrix: an error naming them (the solver's
/// message kept), instead of an anonymous "matrix is singular".
pub fn name_matrix_inputs(scene: &Scene, e: Error) -> Error {
    match e {
        Error::Numerical {
            stage,
            measure,
            reason,
        } if measure.starts_with("factorisation") || measure == "matrix entries" => {
            let (field, keys) = models::kind(scene.model).matrix_inputs();
            scene.error(field, format!(
                    "{stage}: {measure}: {reason}; the matrix is built from {keys}: check their magnitudes and ratios"
                ))
        }
        e => e,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn hypar(sets: &[&str]) -> Scene {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/scenes/naghdi-hypar.toml");
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        Scene::load(&path, &sets).unwrap()
    }

    /// The thesis shell's mesh (the diamond) has 2 n² triangles.
    fn shell_estimate(n: f64, condense: bool) -> Estimate {
        let scene = hypar(&[&format!("solver.condense={condense}")]);
        estimate(&scene, 2.0 * n * n)
    }

    #[test]
    fn the_estimate_covers_the_measured_peaks() {
        // (n, condensed, measured peak RSS in MB of active set to 1e-8;
        // docs/work-precision.md "Scale" and "Scale after condensation").
        let measured = [
            (64.0, true, 265.0),
            (128.0, true, 1069.0),
            (256.0, true, 4778.0),
            (512.0, true, 20157.0),
            (128.0, false, 1796.0),
            (256.0, false, 7408.0),
        ];
        for (n, condense, mb) in measured {
            let e = shell_estimate(n, condense);
            let ratio = e.bytes / (mb * 1e6);
            // Conservative, but not by more than this (1.02 … 1.29 measured).
            assert!(
                (1.0..=1.3).contains(&ratio),
                "n = {n}, condense = {condense}: {:.3} GB estimated against {mb} MB measured ({ratio:.2}×)",
                e.bytes / 1e9
            );
        }
        // The disk at n = 512 (P1⊕B3–P0, 1,158,566 unknowns at 2.5 per
        // triangle, 2606 MB measured).
        let disk = Scene::load(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/scenes/obstacle-disk.toml"),
            &["element=p1b-p0".to_string()],
        )
        .unwrap();
        let ratio = estimate(&disk, 1_158_566.0 / 2.5).bytes / 2606e6;
        assert!((1.0..=1.5).contains(&ratio), "disk n = 512: {ratio:.2}×");
        // n = 512 (≈ 6.03M unknowns): within 24 GB condensed only.
        assert!(shell_estimate(512.0, false).bytes > 30e9);
        assert!(shell_estimate(512.0, true).bytes < 24e9);
    }

    #[test]
    fn before_meshing_the_triangles_follow_the_geometry() {
        // The diamond (2 n²: measured 2 n² exactly by the shell runs) and
        // the disk (2.9 n²); a target size gives no estimate before meshing.
        let shell = estimate_before_meshing(&hypar(&["mesh.n=128"])).unwrap();
        assert_eq!(shell.triangles, 2.0 * 128.0 * 128.0);
        let disk = Scene::load(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/scenes/obstacle-disk.toml"),
            &["mesh.n=64".to_string()],
        )
        .unwrap();
        assert_eq!(
            estimate_before_meshing(&disk).unwrap().triangles,
            2.9 * 64.0 * 64.0
        );
        assert_eq!(triangles_per_n2(Some("elsewhere/custom.geo")), 3.0);
        assert_eq!(triangles_per_n2(None), 3.0);
    }

    #[test]
    fn a_refusal_names_both_numbers_and_the_limit() {
        let tight = hypar(&["mesh.memory_limit_gb=7", "solver.condense=false"]);
        let e = estimate(&tight, 2.0 * 256.0 * 256.0);
        let message = check_memory(&tight, &e, "the mesh")
            .unwrap_err()
            .to_string();
        for part in [
            "mesh.n",
            "1.311e5 triangles",
            "1.507e6 unknowns",
            "~7.537 GB",
            "limit 7.000 GB = mesh.memory_limit_gb",
            "a coarser mesh",
        ] {
            assert!(message.contains(part), "{part:?} not in {message}");
        }
        // n = 256 fits 8 GB condensed or not (5.4 and 7.5 GB).
        for (condense, bytes) in [(true, 5.426e9), (false, 7.536e9)] {
            let roomy = hypar(&[
                "mesh.memory_limit_gb=8",
                &format!("solver.condense={condense}"),
            ]);
            let e = estimate(&roomy, 2.0 * 256.0 * 256.0);
            assert!((e.bytes - bytes).abs() < 1e7, "{}", e.bytes);
            check_memory(&roomy, &e, "the mesh").unwrap();
        }
    }
}
