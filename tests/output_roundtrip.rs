//! The HDF5 result file (docs/formulation.md §5) and its XDMF companion: round trip, atomic
//! writes, refusal of NaN, reading foreign or broken files.

use obstacle_fem::mesh::Mesh;
use obstacle_fem::output::{
    read_result, summary, write_result, AttrValue, Field, Location, ResultData, ResultFile,
};
use obstacle_fem::Error;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// A 3×3-vertex grid on the unit square, 8 counter-clockwise triangles, with
/// edges numbered as `Mesh` documents (first appearance, local edge i opposite
/// local vertex i).
fn square_mesh() -> Mesh {
    let mut vertices = Vec::new();
    for j in 0..3 {
        for i in 0..3 {
            vertices.push([0.5 * i as f64, 0.5 * j as f64]);
        }
    }
    let mut triangles = Vec::new();
    for j in 0..2 {
        for i in 0..2 {
            let a = 3 * j + i;
            let (b, c, d) = (a + 1, a + 4, a + 3);
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    let mut edges: Vec<[usize; 2]> = Vec::new();
    let mut index: HashMap<[usize; 2], usize> = HashMap::new();
    let mut triangle_edges = Vec::new();
    for t in &triangles {
        let mut te = [0; 3];
        for (i, slot) in te.iter_mut().enumerate() {
            let (p, q) = (t[(i + 1) % 3], t[(i + 2) % 3]);
            let key = [p.min(q), p.max(q)];
            *slot = *index.entry(key).or_insert_with(|| {
                edges.push(key);
                edges.len() - 1
            });
        }
        triangle_edges.push(te);
    }
    Mesh {
        vertices,
        triangles,
        boundary_edges: vec![],
        physical_names: Default::default(),
        edges,
        triangle_edges,
        source: PathBuf::new(),
    }
}

fn sample_data(mesh: &Mesh) -> ResultData {
    let nv = mesh.vertices.len();
    let nt = mesh.triangles.len();
    let u: Vec<f64> = mesh
        .vertices
        .iter()
        .map(|p| 0.3 - p[0] * p[0] - p[1] * p[1])
        .collect();
    let r: Vec<f64> = (0..3 * nv).map(|k| (k as f64).sin() * 1e-3).collect();
    let grad: Vec<f64> = (0..2 * nv).map(|k| k as f64 / 7.0).collect();
    let lambda: Vec<f64> = (0..nt).map(|t| if t < 3 { 8.0 } else { 0.0 }).collect();
    let gap: Vec<f64> = (0..nt).map(|t| -1e-12 + t as f64 * 0.125).collect();
    let mut dofs_u = u.clone();
    dofs_u.extend((0..nt).map(|t| 0.01 * t as f64));
    let k: usize = 5;
    ResultData {
        fields: vec![
            Field {
                name: "u".into(),
                values: u,
                components: 1,
                location: Location::Vertex,
            },
            Field {
                name: "r".into(),
                values: r,
                components: 3,
                location: Location::Vertex,
            },
            Field {
                name: "grad_u".into(),
                values: grad,
                components: 2,
                location: Location::Vertex,
            },
            Field {
                name: "lambda".into(),
                values: lambda,
                components: 1,
                location: Location::Cell,
            },
            Field {
                name: "gap_mean".into(),
                values: gap,
                components: 1,
                location: Location::Cell,
            },
        ],
        dofs: vec![
            ("u".into(), dofs_u),
            (
                "p2_like".into(),
                (0..nv + mesh.edges.len()).map(|i| i as f64).collect(),
            ),
        ],
        dof_spaces: vec![("u".into(), "P1b".into())],
        write_edges: true,
        solver_attrs: vec![
            ("algorithm".into(), AttrValue::Str("uzawa".into())),
            ("iterations".into(), AttrValue::I64(k as i64)),
            ("converged".into(), AttrValue::Bool(true)),
            ("alpha".into(), AttrValue::F64(11.5)),
            ("tol".into(), AttrValue::F64(1e-8)),
            ("penetration".into(), AttrValue::F64(3.25e-17)),
            ("diverged".into(), AttrValue::Bool(false)),
            ("seed".into(), AttrValue::I64(-42)),
        ],
        history: vec![
            (
                "penetration".into(),
                (0..k).map(|i| 0.5f64.powi(i as i32)).collect(),
            ),
            (
                "step".into(),
                (0..k).map(|i| 1.0 / (1 + i) as f64).collect(),
            ),
            ("complementarity".into(), vec![0.0; k]),
        ],
        root_attrs: vec![
            ("model".into(), AttrValue::Str("membrane".into())),
            ("refinements".into(), AttrValue::I64(2)),
        ],
        scene_text: "# obstacle-disk — λ ≥ 0\n[model]\nkind = \"membrane\"\nalpha = 11.5\n".into(),
        surface: None,
    }
}

fn dir_entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn output_reason(err: Error) -> (PathBuf, String) {
    match err {
        Error::Output { file, reason } => (file, reason),
        other => panic!("expected Error::Output, got {other:?}"),
    }
}

#[cfg(unix)]
fn mode(path: &Path) -> u32 {
    use std::os::unix::fs::PermissionsExt;
    std::fs::metadata(path).unwrap().permissions().mode() & 0o777
}

#[test]
fn round_trip_preserves_everything() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.h5");
    let mesh = square_mesh();
    let data = sample_data(&mesh);
    write_result(&path, &mesh, &data).unwrap();

    let back: ResultFile = read_result(&path).unwrap();
    assert_eq!(back.vertices, mesh.vertices);
    assert_eq!(back.triangles, mesh.triangles);
    assert_eq!(back.edges.as_deref(), Some(mesh.edges.as_slice()));
    assert_eq!(
        back.version,
        format!("obstacle-fem {}", env!("CARGO_PKG_VERSION"))
    );
    assert_eq!(back.data, data, "all data must come back, in order");

    // Only the two result files are left: no temporaries.
    assert_eq!(dir_entries(dir.path()), ["run.h5", "run.xdmf"]);
    #[cfg(unix)]
    {
        assert_eq!(mode(&path), 0o644);
        assert_eq!(mode(&dir.path().join("run.xdmf")), 0o644);
    }

    let text = summary(&back);
    for needle in [
        "obstacle-fem",
        "9 vertices, 8 triangles, 16 edges",
        "lambda",
        "cell",
        "[9, 3]",
        "algorithm = \"uzawa\"",
        "converged = true",
        "iterations = 5",
        "3 measures × 5 iterations",
        "penetration = 0.0625",
        "tol = 1e-8",
        "alpha = 11.5",
        "model = \"membrane\"",
        "    [model]",
    ] {
        assert!(text.contains(needle), "summary lacks {needle:?}:\n{text}");
    }
}

#[test]
fn without_edges_and_empty_parts() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bare.h5");
    let mesh = square_mesh();
    let data = ResultData {
        fields: vec![],
        dofs: vec![("empty".into(), vec![])],
        dof_spaces: vec![],
        write_edges: false,
        solver_attrs: vec![],
        history: vec![("r".into(), vec![])],
        root_attrs: vec![],
        scene_text: String::new(),
        surface: None,
    };
    write_result(&path, &mesh, &data).unwrap();
    let back = read_result(&path).unwrap();
    assert_eq!(back.edges, None);
    assert_eq!(back.data, data);
    let text = summary(&back);
    assert!(text.contains("9 vertices, 8 triangles\n"), "{text}");
}

#[test]
fn h5dump_reads_the_layout() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dump.h5");
    let mesh = square_mesh();
    write_result(&path, &mesh, &sample_data(&mesh)).unwrap();
    let out = match Command::new("h5dump").arg("-H").arg(&path).output() {
        Ok(out) => out,
        Err(e) => {
            println!("note: h5dump not available ({e}); skipping the h5dump check");
            return;
        }
    };
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "h5dump failed: {}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    for needle in [
        "GROUP \"mesh\"",
        "DATASET \"vertices\"",
        "H5T_IEEE_F64LE",
        "( 9, 2 )",
        "DATASET \"triangles\"",
        "H5T_STD_U64LE",
        "( 8, 3 )",
        "DATASET \"edges\"",
        "( 16, 2 )",
        "GROUP \"fields\"",
        "ATTRIBUTE \"location\"",
        "( 9, 3 )",
        "GROUP \"dofs\"",
        "GROUP \"solver\"",
        "ATTRIBUTE \"converged\"",
        "GROUP \"history\"",
        "ATTRIBUTE \"scene\"",
        "ATTRIBUTE \"version\"",
    ] {
        assert!(
            stdout.contains(needle),
            "h5dump -H lacks {needle:?}:\n{stdout}"
        );
    }
    // Values too: the location attribute and the triangles.
    let out = Command::new("h5dump")
        .args(["-a", "/fields/lambda/location"])
        .arg(&path)
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&out.stdout).contains("\"cell\""));
}

#[test]
fn nan_is_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.h5");
    let mesh = square_mesh();
    let mut data = sample_data(&mesh);
    data.fields[1].values[7] = f64::NAN; // "r", row 2, component 1
    let (file, reason) = output_reason(write_result(&path, &mesh, &data).unwrap_err());
    assert_eq!(file, path);
    assert!(reason.contains("/fields/r"), "{reason}");
    assert!(reason.contains("[2, 1]"), "{reason}");
    assert!(
        dir_entries(dir.path()).is_empty(),
        "{:?}",
        dir_entries(dir.path())
    );

    let mut data = sample_data(&mesh);
    data.history[1].1[3] = f64::INFINITY;
    let (_, reason) = output_reason(write_result(&path, &mesh, &data).unwrap_err());
    assert!(
        reason.contains("/solver/history/step") && reason.contains("index 3"),
        "{reason}"
    );

    let mut data = sample_data(&mesh);
    data.solver_attrs
        .push(("residual".into(), AttrValue::F64(f64::NAN)));
    let (_, reason) = output_reason(write_result(&path, &mesh, &data).unwrap_err());
    assert!(reason.contains("residual"), "{reason}");
    assert!(dir_entries(dir.path()).is_empty());
}

#[test]
fn invalid_data_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.h5");
    let mesh = square_mesh();
    type Breaker = Box<dyn Fn(&mut ResultData)>;
    let cases: Vec<(Breaker, &str)> = vec![
        (
            Box::new(|d| d.fields[0].values.pop().map(|_| ()).unwrap()),
            "/fields/u",
        ),
        (
            Box::new(|d| d.fields[3].location = Location::Vertex),
            "/fields/lambda",
        ),
        (Box::new(|d| d.fields[0].name = "a/b".into()), "'/'"),
        (Box::new(|d| d.dofs[0].0 = String::new()), "empty name"),
        (Box::new(|d| d.history[2].1.push(0.0)), "same length"),
        (Box::new(|d| d.fields[1].name = "u".into()), "duplicate"),
        (
            Box::new(|d| d.root_attrs.push(("version".into(), AttrValue::I64(1)))),
            "reserved",
        ),
    ];
    for (break_it, expected) in cases {
        let mut data = sample_data(&mesh);
        break_it(&mut data);
        let (_, reason) = output_reason(write_result(&path, &mesh, &data).unwrap_err());
        assert!(reason.contains(expected), "{expected:?} not in {reason:?}");
    }
    assert!(dir_entries(dir.path()).is_empty());

    let missing = dir.path().join("no_such_dir").join("x.h5");
    let (file, reason) =
        output_reason(write_result(&missing, &mesh, &sample_data(&mesh)).unwrap_err());
    assert_eq!(file, missing);
    assert!(reason.contains("does not exist"), "{reason}");
}

#[test]
fn failed_write_leaves_existing_result_untouched() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("keep.h5");
    let xdmf = dir.path().join("keep.xdmf");
    let mesh = square_mesh();
    write_result(&path, &mesh, &sample_data(&mesh)).unwrap();
    let h5_before = std::fs::read(&path).unwrap();
    let xdmf_before = std::fs::read(&xdmf).unwrap();

    let mut data = sample_data(&mesh);
    data.fields.clear();
    data.dofs[0].1[0] = f64::NAN;
    write_result(&path, &mesh, &data).unwrap_err();
    assert_eq!(std::fs::read(&path).unwrap(), h5_before);
    assert_eq!(std::fs::read(&xdmf).unwrap(), xdmf_before);
    assert_eq!(dir_entries(dir.path()), ["keep.h5", "keep.xdmf"]);
    // And the old file still reads as before.
    assert_eq!(read_result(&path).unwrap().data, sample_data(&mesh));
}

#[test]
fn failure_after_writing_removes_temporaries() {
    // The target is a non-empty directory: the data are fine and fully written
    // to a temporary, but the final rename fails.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("taken.h5");
    std::fs::create_dir(&path).unwrap();
    std::fs::write(path.join("inside"), "x").unwrap();
    let mesh = square_mesh();
    let (file, reason) =
        output_reason(write_result(&path, &mesh, &sample_data(&mesh)).unwrap_err());
    assert_eq!(file, path);
    assert!(reason.contains("renaming"), "{reason}");
    assert_eq!(dir_entries(dir.path()), ["taken.h5"]);
    assert_eq!(dir_entries(&path), ["inside"]);
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn writing_twice_gives_identical_data() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("twice.h5");
    let mesh = square_mesh();
    let data = sample_data(&mesh);
    write_result(&path, &mesh, &data).unwrap();
    let first_bytes = std::fs::read(&path).unwrap();
    let first = read_result(&path).unwrap();
    write_result(&path, &mesh, &data).unwrap();
    let second_bytes = std::fs::read(&path).unwrap();
    let second = read_result(&path).unwrap();

    let vbits = |r: &ResultFile| bits(&r.vertices.iter().flatten().copied().collect::<Vec<_>>());
    assert_eq!(vbits(&first), vbits(&second));
    assert_eq!(first.triangles, second.triangles);
    for (a, b) in first.data.fields.iter().zip(&second.data.fields) {
        assert_eq!(a.name, b.name);
        assert_eq!(bits(&a.values), bits(&b.values), "field {}", a.name);
        assert_eq!(
            bits(&a.values),
            bits(
                &data
                    .fields
                    .iter()
                    .find(|f| f.name == a.name)
                    .unwrap()
                    .values
            )
        );
    }
    for ((na, a), (nb, b)) in first.data.dofs.iter().zip(&second.data.dofs) {
        assert_eq!(na, nb);
        assert_eq!(bits(a), bits(b));
    }
    for ((na, a), (nb, b)) in first.data.history.iter().zip(&second.data.history) {
        assert_eq!(na, nb);
        assert_eq!(bits(a), bits(b));
    }
    // No timestamps are stored, so the whole file is reproducible.
    assert_eq!(first_bytes, second_bytes, "the two files differ byte-wise");
    assert_eq!(dir_entries(dir.path()), ["twice.h5", "twice.xdmf"]);
}

#[test]
fn non_hdf5_and_foreign_files_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();

    let text = dir.path().join("notes.h5");
    std::fs::write(&text, "this is not HDF5\n").unwrap();
    let err = read_result(&text).unwrap_err();
    assert!(
        err.to_string().contains(&text.display().to_string()),
        "{err}"
    );
    let (file, reason) = output_reason(err);
    assert_eq!(file, text);
    assert!(reason.contains("HDF5"), "{reason}");

    let missing = dir.path().join("missing.h5");
    let (file, _) = output_reason(read_result(&missing).unwrap_err());
    assert_eq!(file, missing);

    let foreign = dir.path().join("foreign.h5");
    {
        let f = hdf5::File::create(&foreign).unwrap();
        let g = f.create_group("data").unwrap();
        g.new_dataset::<f64>()
            .shape([3])
            .create("x")
            .unwrap()
            .write_raw(&[1.0, 2.0, 3.0])
            .unwrap();
    }
    let err = read_result(&foreign).unwrap_err();
    assert!(
        err.to_string().contains(&foreign.display().to_string()),
        "{err}"
    );
    let (_, reason) = output_reason(err);
    assert!(reason.contains("/mesh"), "{reason}");

    // /mesh present but incomplete.
    let partial = dir.path().join("partial.h5");
    {
        let f = hdf5::File::create(&partial).unwrap();
        let g = f.create_group("mesh").unwrap();
        g.new_dataset::<f64>()
            .shape([3, 2])
            .create("vertices")
            .unwrap()
            .write_raw(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0])
            .unwrap();
    }
    let (_, reason) = output_reason(read_result(&partial).unwrap_err());
    assert!(reason.contains("/mesh/triangles"), "{reason}");

    // A truncated result file.
    let mesh = square_mesh();
    let good = dir.path().join("good.h5");
    write_result(&good, &mesh, &sample_data(&mesh)).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let cut = dir.path().join("cut.h5");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let (file, reason) = output_reason(read_result(&cut).unwrap_err());
    assert_eq!(file, cut);
    assert!(!reason.is_empty());

    // Triangles referring to a vertex that does not exist.
    let broken = dir.path().join("broken.h5");
    {
        let f = hdf5::File::create(&broken).unwrap();
        let g = f.create_group("mesh").unwrap();
        g.new_dataset::<f64>()
            .shape([3, 2])
            .create("vertices")
            .unwrap()
            .write_raw(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0])
            .unwrap();
        g.new_dataset::<u64>()
            .shape([1, 3])
            .create("triangles")
            .unwrap()
            .write_raw(&[0u64, 1, 3])
            .unwrap();
    }
    let (_, reason) = output_reason(read_result(&broken).unwrap_err());
    assert!(
        reason.contains("/mesh/triangles") && reason.contains("Nv = 3"),
        "{reason}"
    );
}

#[test]
fn reads_files_from_other_writers() {
    // Our layout, extended by another tool: attributes of other scalar types,
    // a field without a `location` attribute, an array attribute (skipped).
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("extended.h5");
    let mesh = square_mesh();
    let data = sample_data(&mesh);
    write_result(&path, &mesh, &data).unwrap();
    {
        use hdf5::types::FixedAscii;
        let f = hdf5::File::open_rw(&path).unwrap();
        let fixed = FixedAscii::<8>::from_ascii("abc").unwrap();
        f.new_attr::<FixedAscii<8>>()
            .shape(())
            .create("fixed")
            .unwrap()
            .write_scalar(&fixed)
            .unwrap();
        f.new_attr::<i32>()
            .shape(())
            .create("small")
            .unwrap()
            .write_scalar(&7)
            .unwrap();
        f.new_attr::<f32>()
            .shape(())
            .create("single")
            .unwrap()
            .write_scalar(&0.5f32)
            .unwrap();
        f.new_attr::<f64>()
            .shape([2])
            .create("pair")
            .unwrap()
            .write_raw(&[1.0, 2.0])
            .unwrap();
        let fields = f.group("fields").unwrap();
        fields
            .new_dataset::<f32>()
            .shape([8])
            .create("extra")
            .unwrap()
            .write_raw(&[1.0f32; 8])
            .unwrap();
    }
    let back = read_result(&path).unwrap();
    let extra = back.data.fields.iter().find(|f| f.name == "extra").unwrap();
    assert_eq!(extra.location, Location::Cell);
    assert_eq!(extra.values, vec![1.0; 8]);
    let attr = |n: &str| {
        back.data
            .root_attrs
            .iter()
            .find(|(k, _)| k == n)
            .map(|(_, v)| v.clone())
    };
    assert_eq!(attr("fixed"), Some(AttrValue::Str("abc".into())));
    assert_eq!(attr("small"), Some(AttrValue::I64(7)));
    assert_eq!(attr("single"), Some(AttrValue::F64(0.5)));
    assert_eq!(attr("pair"), None);
    assert_eq!(attr("model"), Some(AttrValue::Str("membrane".into())));
}

/// `Dimensions="..."` of the DataItem following `marker` in the XDMF text.
fn dims_after(xdmf: &str, marker: &str) -> String {
    let start = xdmf
        .find(marker)
        .unwrap_or_else(|| panic!("{marker} not in\n{xdmf}"));
    let rest = &xdmf[start..];
    let d = rest.find("Dimensions=\"").unwrap() + "Dimensions=\"".len();
    let end = rest[d..].find('"').unwrap();
    rest[d..d + end].to_string()
}

/// A shell's result: `/mesh/surface` round-trips, the main XDMF describes the
/// 3D surface (XYZ) and `FILE.domain.xdmf` the flat parameter domain; a
/// surface of the wrong length or with a NaN is refused before writing.
#[test]
fn shell_surface_in_3d_and_its_parameter_domain() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("shell.h5");
    let mesh = square_mesh();
    let surface: Vec<[f64; 3]> = mesh
        .vertices
        .iter()
        .map(|p| [p[0], p[1], p[0] * p[0] - p[1] * p[1] + 1.4])
        .collect();
    let data = ResultData {
        surface: Some(surface.clone()),
        ..sample_data(&mesh)
    };
    write_result(&path, &mesh, &data).unwrap();
    let back = read_result(&path).unwrap();
    assert_eq!(back.data.surface.as_deref(), Some(&surface[..]));
    assert_eq!(back.data, data);
    let main = std::fs::read_to_string(dir.path().join("shell.xdmf")).unwrap();
    assert!(main.contains("GeometryType=\"XYZ\""), "{main}");
    assert_eq!(dims_after(&main, "<Geometry"), "9 3");
    assert!(main.contains(">shell.h5:/mesh/surface<"), "{main}");
    let flat = std::fs::read_to_string(dir.path().join("shell.domain.xdmf")).unwrap();
    assert!(flat.contains("GeometryType=\"XY\""), "{flat}");
    assert_eq!(dims_after(&flat, "<Geometry"), "9 2");
    assert!(flat.contains(">shell.h5:/fields/r<"), "{flat}");
    // Refused, nothing written.
    for (bad, why) in [
        (surface[..8].to_vec(), "8 points"),
        (
            {
                let mut s = surface.clone();
                s[4][2] = f64::NAN;
                s
            },
            "surface",
        ),
    ] {
        let target = dir.path().join("bad.h5");
        let err = write_result(
            &target,
            &mesh,
            &ResultData {
                surface: Some(bad),
                ..sample_data(&mesh)
            },
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("/mesh/surface") && err.contains(why), "{err}");
        assert!(!target.exists() && !dir.path().join("bad.domain.xdmf").exists());
    }
}

#[test]
fn xdmf_companion_describes_mesh_and_fields() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("view.h5");
    let mesh = square_mesh();
    let data = sample_data(&mesh);
    write_result(&path, &mesh, &data).unwrap();
    let xdmf_path = dir.path().join("view.xdmf");
    let xdmf = std::fs::read_to_string(&xdmf_path).unwrap();

    assert!(xdmf.contains("TopologyType=\"Triangle\""));
    assert!(xdmf.contains("NumberOfElements=\"8\""));
    assert!(xdmf.contains("GeometryType=\"XY\""));
    assert_eq!(dims_after(&xdmf, "<Topology"), "8 3");
    assert_eq!(dims_after(&xdmf, "<Geometry"), "9 2");
    assert!(
        xdmf.contains(">view.h5:/mesh/triangles<"),
        "relative reference:\n{xdmf}"
    );
    assert!(
        !xdmf.contains(&dir.path().display().to_string()),
        "absolute path in\n{xdmf}"
    );
    for (name, dims, center, kind) in [
        ("u", "9", "Node", "Scalar"),
        ("r", "9 3", "Node", "Vector"),
        ("grad_u", "9 2", "Node", "Matrix"),
        ("lambda", "8", "Cell", "Scalar"),
        ("gap_mean", "8", "Cell", "Scalar"),
    ] {
        let marker = format!("<Attribute Name=\"{name}\"");
        assert_eq!(dims_after(&xdmf, &marker), dims, "{name}");
        let line = xdmf.lines().find(|l| l.contains(&marker)).unwrap();
        assert!(line.contains(&format!("Center=\"{center}\"")), "{line}");
        assert!(
            line.contains(&format!("AttributeType=\"{kind}\"")),
            "{line}"
        );
        assert!(xdmf.contains(&format!(">view.h5:/fields/{name}<")));
    }

    // Well-formed XML, if a Python is around to check it.
    let check = "import sys, xml.etree.ElementTree as ET\n\
                 r = ET.parse(sys.argv[1]).getroot()\n\
                 assert r.tag == 'Xdmf'\n\
                 g = r.find('Domain/Grid')\n\
                 print(len(g.findall('Attribute')))\n";
    match Command::new("python3")
        .args(["-c", check])
        .arg(&xdmf_path)
        .output()
    {
        Ok(out) if out.status.success() => {
            assert_eq!(String::from_utf8_lossy(&out.stdout).trim(), "5");
        }
        Ok(out) => panic!(
            "the XDMF file is not well-formed XML: {}",
            String::from_utf8_lossy(&out.stderr)
        ),
        Err(e) => println!("note: python3 not available ({e}); skipping the XML check"),
    }
}
