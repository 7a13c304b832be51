//! Result files as ParaView itself reads them (issue 15): `pvbatch` (Debian's
//! `paraview`) opens each `.xdmf` with its own XDMF reader through
//! `pipelines/paraview/inspect.py`, and the arrays, their ranges and the
//! bounds must be those of the HDF5 file. A shell is a 3D surface (its bounds
//! are those of `/mesh/surface`; warped by u they move by u) with its flat
//! parameter domain beside it; a membrane warps by its scalar u. These tests
//! fail, never skip, when `pvbatch` is missing: `.ci/install-deps.sh`
//! installs it.

mod common;
use common::{field, manifest_path, solve_scene, text};
use obstacle_fem::output::{read_result, Location, ResultFile};
use std::path::Path;
use std::process::Command;

/// What ParaView reports of an XDMF file (optionally warped).
struct Seen {
    bounds: [f64; 6],
    points: usize,
    cells: usize,
    /// name → (location, per-component [min, max]).
    arrays: Vec<(String, String, Vec<[f64; 2]>)>,
}

fn paraview_sees(xdmf: &Path, warp: Option<&str>) -> Seen {
    let script = manifest_path("pipelines/paraview/inspect.py");
    let mut cmd = Command::new("pvbatch");
    cmd.arg(&script).arg(xdmf);
    if let Some(w) = warp {
        cmd.arg(w);
    }
    let out = cmd.output().unwrap_or_else(|e| {
        panic!("pvbatch (Debian package paraview + python3-paraview, installed by .ci/install-deps.sh) cannot run: {e}")
    });
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout
        .lines()
        .find_map(|l| l.strip_prefix("PARAVIEW-JSON "))
        .unwrap_or_else(|| {
            panic!(
                "pvbatch printed no result for {}: {stdout}{}",
                xdmf.display(),
                String::from_utf8_lossy(&out.stderr)
            )
        });
    let v: serde_json::Value = serde_json::from_str(line).unwrap();
    let f = |x: &serde_json::Value| x.as_f64().unwrap();
    let b: Vec<f64> = v["bounds"].as_array().unwrap().iter().map(f).collect();
    let arrays = v["arrays"]
        .as_object()
        .unwrap()
        .iter()
        .map(|(name, a)| {
            let ranges = a["ranges"]
                .as_array()
                .unwrap()
                .iter()
                .map(|r| [f(&r[0]), f(&r[1])])
                .collect();
            (
                name.clone(),
                a["location"].as_str().unwrap().to_string(),
                ranges,
            )
        })
        .collect();
    Seen {
        bounds: b.try_into().unwrap(),
        points: v["points"].as_u64().unwrap() as usize,
        cells: v["cells"].as_u64().unwrap() as usize,
        arrays,
    }
}

fn close(a: f64, b: f64, scale: f64) -> bool {
    (a - b).abs() <= 1e-12 * scale.max(1.0)
}

fn min_max(v: impl Iterator<Item = f64>) -> [f64; 2] {
    v.fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], x| {
        [lo.min(x), hi.max(x)]
    })
}

/// Every field of the result is an array ParaView sees, at the same place,
/// with the same range per component.
fn assert_fields_seen(result: &ResultFile, seen: &Seen) {
    assert_eq!(seen.points, result.vertices.len());
    assert_eq!(seen.cells, result.triangles.len());
    for field in &result.data.fields {
        let (_, location, ranges) = seen
            .arrays
            .iter()
            .find(|(n, _, _)| *n == field.name)
            .unwrap_or_else(|| panic!("ParaView does not see `{}`", field.name));
        let expected = match field.location {
            Location::Vertex => "point",
            Location::Cell => "cell",
        };
        assert_eq!(location, expected, "{}", field.name);
        assert_eq!(ranges.len(), field.components, "{}", field.name);
        for (c, range) in ranges.iter().enumerate() {
            let want = min_max(
                field
                    .values
                    .iter()
                    .skip(c)
                    .step_by(field.components)
                    .copied(),
            );
            let scale = want[0].abs().max(want[1].abs());
            assert!(
                close(range[0], want[0], scale) && close(range[1], want[1], scale),
                "{}[{c}]: ParaView {range:?}, HDF5 {want:?}",
                field.name
            );
        }
    }
}

fn solve(scene: &str, dir: &Path, overrides: &[&str]) -> std::path::PathBuf {
    let out = dir.join(format!("{scene}.h5"));
    let o = solve_scene(scene, &out, overrides);
    assert!(o.status.success(), "{}", text(&o));
    out
}

/// ParaView's bounds along each axis against `want(k)` = [min, max] of axis k.
fn assert_bounds(seen: &Seen, want: impl Fn(usize) -> [f64; 2], what: &str) {
    for k in 0..3 {
        let (got, want) = ([seen.bounds[2 * k], seen.bounds[2 * k + 1]], want(k));
        assert!(
            close(got[0], want[0], 100.0) && close(got[1], want[1], 100.0),
            "bounds[{k}]: ParaView {got:?}, {what} {want:?}"
        );
    }
}

#[test]
fn a_shell_is_a_3d_surface_that_warps_by_u() {
    let dir = tempfile::tempdir().unwrap();
    let h5 = solve(
        "naghdi-hypar",
        dir.path(),
        &[
            "mesh.n=8",
            "output.plots=[]",
            "solver.method=\"active-set\"",
        ],
    );
    let result = read_result(&h5).unwrap();
    let surface = result
        .data
        .surface
        .clone()
        .expect("a shell stores its surface");

    // The 3D view: bounds of φ(x) at the vertices, z not flat.
    let seen = paraview_sees(&h5.with_extension("xdmf"), None);
    assert_fields_seen(&result, &seen);
    assert_bounds(
        &seen,
        |k| min_max(surface.iter().map(|p| p[k])),
        "/mesh/surface",
    );
    assert!(seen.bounds[5] - seen.bounds[4] > 1.9, "{:?}", seen.bounds);

    // Warp By Vector u: the deformed shell, φ(x) + u(x).
    let warped = paraview_sees(&h5.with_extension("xdmf"), Some("vector:u"));
    let u = field(&result, "u");
    let deformed = |k: usize| min_max(surface.iter().enumerate().map(|(v, p)| p[k] + u[3 * v + k]));
    assert_bounds(&warped, deformed, "φ + u");

    // The parameter domain stays available, flat.
    let flat = paraview_sees(&h5.with_extension("domain.xdmf"), None);
    assert_fields_seen(&result, &flat);
    assert_eq!([flat.bounds[4], flat.bounds[5]], [0.0, 0.0]);
    let x = min_max(result.vertices.iter().map(|p| p[0]));
    assert!(close(flat.bounds[0], x[0], 100.0) && close(flat.bounds[1], x[1], 100.0));
}

#[test]
fn a_membrane_warps_by_its_scalar_u() {
    let dir = tempfile::tempdir().unwrap();
    let h5 = solve(
        "obstacle-disk",
        dir.path(),
        &["mesh.h=0.3", "output.plots=[]"],
    );
    let result = read_result(&h5).unwrap();
    assert!(result.data.surface.is_none());
    assert!(!h5.with_extension("domain.xdmf").exists());
    let seen = paraview_sees(&h5.with_extension("xdmf"), None);
    assert_fields_seen(&result, &seen);
    assert_eq!([seen.bounds[4], seen.bounds[5]], [0.0, 0.0]);
    let warped = paraview_sees(&h5.with_extension("xdmf"), Some("scalar:u"));
    let want = min_max(field(&result, "u").iter().copied());
    // Warp By Scalar writes single-precision points: 1e-7 relative.
    let near = |a: f64, b: f64| (a - b).abs() <= 1e-7 * want[0].abs().max(want[1].abs());
    assert!(
        near(warped.bounds[4], want[0]) && near(warped.bounds[5], want[1]),
        "warped z: ParaView {:?}, u {want:?}",
        &warped.bounds[4..]
    );
}
