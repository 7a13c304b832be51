//! Integration tests of `meshes/*.geo` → real gmsh → `Mesh::read_msh`, and a
//! cross-check with FreeFEM's `gmshload` (same vertex, triangle and in-triangle
//! order). Needs `gmsh` and `FreeFem++` (with `libfreefem++`) on PATH.

mod common;

use common::mirror_map;

use obstacle_fem::gmsh::{gmsh_version, run_gmsh};
use obstacle_fem::mesh::Mesh;
use obstacle_fem::Error;
use std::collections::HashSet;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::process::Command;

const R: f64 = 50.0 * std::f64::consts::SQRT_2;

fn geo_file(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("meshes")
        .join(name)
}

fn params(list: &[(&str, f64)]) -> Vec<(String, f64)> {
    list.iter().map(|&(k, v)| (k.to_string(), v)).collect()
}

/// Mesh `name` with `p` into a fresh temporary directory and read it.
fn mesh(name: &str, p: &[(&str, f64)]) -> (tempfile::TempDir, PathBuf, Mesh) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sub").join("out.msh");
    run_gmsh(&geo_file(name), &out, &params(p)).unwrap_or_else(|e| panic!("{e}"));
    let m = Mesh::read_msh(&out).unwrap_or_else(|e| panic!("{e}"));
    (dir, out, m)
}

fn n_boundary_vertices(m: &Mesh) -> usize {
    m.boundary_vertex_mask(None).iter().filter(|&&b| b).count()
}

fn has_vertex_at(m: &Mesh, p: [f64; 2], tol: f64) -> bool {
    m.vertices
        .iter()
        .any(|v| (v[0] - p[0]).abs() <= tol && (v[1] - p[1]).abs() <= tol)
}

fn report(what: &str, m: &Mesh) {
    eprintln!(
        "{what}: {} vertices, {} triangles, {} edges, {} boundary edges, h_max = {:.6}, \
         area = {:.15}, min area = {:.3e}",
        m.n_vertices(),
        m.n_triangles(),
        m.n_edges(),
        m.boundary_edges.len(),
        m.h_max(),
        m.total_area(),
        (0..m.n_triangles())
            .map(|t| m.area(t))
            .fold(f64::INFINITY, f64::min)
    );
}

/// Checks shared by all meshes: positive areas (validated, asserted again).
fn common_checks(m: &Mesh) {
    assert!(m.n_triangles() > 0);
    for t in 0..m.n_triangles() {
        assert!(m.area(t) > 0.0, "triangle {t} has area {}", m.area(t));
    }
    // Euler: V - E + F = 1 for a disk-like domain.
    assert_eq!(
        m.n_vertices() as i64 - m.n_edges() as i64 + m.n_triangles() as i64,
        1
    );
}

/// Disk checks; returns the boundary segments' angles.
fn check_disk(m: &Mesh) -> Vec<f64> {
    common_checks(m);
    assert_eq!(m.tag_by_name("boundary"), Some(1));
    assert_eq!(m.tag_by_name("domain"), Some(2));
    assert!(m.boundary_edges.iter().all(|e| e.tag == 1));
    let on_boundary = m.boundary_vertex_mask(None);
    for (v, p) in m.vertices.iter().enumerate() {
        let r = p[0].hypot(p[1]);
        if on_boundary[v] {
            assert!((r - 1.0).abs() < 1e-9, "boundary vertex {v} at radius {r}");
        } else {
            assert!(r < 1.0, "interior vertex {v} at radius {r}");
        }
    }
    assert_eq!(n_boundary_vertices(m), m.boundary_edges.len());
    assert!(
        has_vertex_at(m, [0.0, 0.0], 0.0),
        "the centre is not a vertex"
    );
    // The mesh is the inscribed polygon: pi - area is exactly the sum of the
    // circular segments cut off by the boundary chords.
    let angles: Vec<f64> = m
        .boundary_edges
        .iter()
        .map(|e| {
            let [a, b] = e.vertices.map(|v| m.vertices[v]);
            2.0 * (0.5 * (b[0] - a[0]).hypot(b[1] - a[1])).asin()
        })
        .collect();
    let total_angle: f64 = angles.iter().sum();
    assert!((total_angle - 2.0 * PI).abs() < 1e-9, "{total_angle}");
    let segments: f64 = angles.iter().map(|t| 0.5 * (t - t.sin())).sum();
    let area = m.total_area();
    assert!(
        (PI - area - segments).abs() < 1e-12,
        "pi - area = {}, segments = {segments}",
        PI - area
    );
    angles
}

#[test]
fn gmsh_is_available() {
    let v = gmsh_version().expect("gmsh not found on PATH");
    eprintln!("gmsh version {v}");
    assert!(v.starts_with('4'), "{v}");
}

#[test]
fn disk_structured() {
    for n in [4usize, 8, 16] {
        let (_d, _f, m) = mesh("disk.geo", &[("n", n as f64)]);
        report(&format!("disk n = {n}"), &m);
        let angles = check_disk(&m);
        assert_eq!(m.boundary_edges.len(), 4 * n);
        // Equal segments: theta = pi/(2n) each.
        let theta = PI / (2 * n) as f64;
        for t in &angles {
            assert!(
                (t - theta).abs() < 1e-12,
                "segment angle {t}, expected {theta}"
            );
        }
        // The exact inscribed regular 4n-gon, area (4n/2) sin(2 pi/(4n)) ...
        let polygon = 2.0 * n as f64 * theta.sin();
        let area = m.total_area();
        assert!((area - polygon).abs() < 1e-12, "{area} vs {polygon}");
        // ... and the stated bounds: 0 < pi - area <= (pi/6) theta^2 < 2 pi theta^2.
        assert!(PI - area > 0.0);
        assert!(PI - area <= PI / 6.0 * theta * theta);
        assert!((area - PI).abs() < 2.0 * PI * theta * theta);
        // Quasi-uniform: h_max close to the target (pi/2)/n.
        assert!(m.h_max() < 2.0 * theta, "h_max {} vs {theta}", m.h_max());
        // Exact symmetry of the boundary points under x -> -x, y -> -y, x <-> y.
        let bmask = m.boundary_vertex_mask(None);
        let bset: HashSet<[u64; 2]> = m
            .vertices
            .iter()
            .zip(&bmask)
            .filter(|(_, &b)| b)
            .map(|(p, _)| [(p[0] + 0.0).to_bits(), (p[1] + 0.0).to_bits()])
            .collect();
        for (p, _) in m.vertices.iter().zip(&bmask).filter(|(_, &b)| b) {
            for q in [[-p[0], p[1]], [p[0], -p[1]], [p[1], p[0]]] {
                let key = [(q[0] + 0.0).to_bits(), (q[1] + 0.0).to_bits()];
                if !bset.contains(&key) {
                    // x <-> y is exact only up to cos/sin rounding.
                    assert!(
                        bmask.iter().zip(&m.vertices).any(|(&b, v)| b
                            && (v[0] - q[0]).abs() < 1e-15
                            && (v[1] - q[1]).abs() < 1e-15),
                        "mirror {q:?} of {p:?} missing"
                    );
                }
            }
        }
    }
}

#[test]
fn disk_unstructured() {
    let h = 0.2;
    let (_d, _f, m) = mesh("disk.geo", &[("n", 0.0), ("h", h)]);
    report("disk h = 0.2", &m);
    let angles = check_disk(&m);
    let theta_max = angles.iter().cloned().fold(0.0, f64::max);
    let area = m.total_area();
    eprintln!(
        "disk h = 0.2: {} boundary segments, largest angle {theta_max:.4}, pi - area = {:.3e}",
        angles.len(),
        PI - area
    );
    assert!(PI - area > 0.0 && PI - area <= PI / 6.0 * theta_max * theta_max);
    assert!(theta_max < 1.5 * h, "boundary segment angle {theta_max}");
    assert!(m.h_max() < 2.0 * h, "h_max {}", m.h_max());
    assert!(m.h_max() > 0.5 * h, "h_max {}", m.h_max());
}

#[test]
fn meshing_is_reproducible() {
    for (name, p) in [
        ("disk.geo", vec![("n", 8.0)]),
        ("disk.geo", vec![("n", 0.0), ("h", 0.1)]),
        ("diamond.geo", vec![("n", 0.0), ("h", 10.0)]),
        ("diamond.geo", vec![("n", 16.0)]),
        ("lshape.geo", vec![("n", 8.0)]),
        ("lshape.geo", vec![("n", 0.0), ("h", 0.1)]),
    ] {
        let (_d1, f1, _) = mesh(name, &p);
        let (_d2, f2, _) = mesh(name, &p);
        let (a, b) = (std::fs::read(&f1).unwrap(), std::fs::read(&f2).unwrap());
        assert!(a == b, "{name} {p:?}: two runs differ");
    }
}

fn assert_mirror_symmetric(m: &Mesh, f: impl Fn([f64; 2]) -> [f64; 2], what: &str) {
    let map = mirror_map(&m.vertices, f, 1e-9 * R);
    let set: HashSet<[usize; 3]> = m
        .triangles
        .iter()
        .map(|t| {
            let mut s = *t;
            s.sort_unstable();
            s
        })
        .collect();
    // The map is a bijection ...
    let image: HashSet<usize> = map.iter().copied().collect();
    assert_eq!(
        image.len(),
        m.n_vertices(),
        "{what}: mirror is not a bijection"
    );
    // ... and maps the triangle set onto itself.
    for t in &m.triangles {
        let mut s = t.map(|v| map[v]);
        s.sort_unstable();
        assert!(set.contains(&s), "{what}: mirror of triangle {t:?} missing");
    }
    eprintln!("{what}: vertex and triangle sets are mirror-symmetric");
}

fn check_diamond(m: &Mesh) {
    common_checks(m);
    for (name, tag) in [("se", 1), ("ne", 2), ("nw", 3), ("sw", 4), ("domain", 5)] {
        assert_eq!(m.tag_by_name(name), Some(tag), "{name}");
    }
    let on_boundary = m.boundary_vertex_mask(None);
    for (v, p) in m.vertices.iter().enumerate() {
        let s = p[0].abs() + p[1].abs();
        if on_boundary[v] {
            assert!((s - R).abs() < 1e-9, "boundary vertex {v}: |x|+|y| = {s}");
        } else {
            assert!(s < R - 1e-9, "interior vertex {v}: |x|+|y| = {s}");
        }
    }
    // Each side carries its own tag: se (x > 0, y < 0), ne, nw, sw.
    for e in &m.boundary_edges {
        let [a, b] = e.vertices.map(|v| m.vertices[v]);
        let mid = [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])];
        let expected = match (mid[0] > 0.0, mid[1] > 0.0) {
            (true, false) => 1,
            (true, true) => 2,
            (false, true) => 3,
            (false, false) => 4,
        };
        assert_eq!(e.tag, expected, "boundary edge at {mid:?}");
    }
    let area = m.total_area();
    assert!((area - 2.0 * R * R).abs() < 1e-9, "area {area}");
}

fn check_structured_diamond(m: &Mesh, n: usize) {
    check_diamond(m);
    assert_eq!(m.n_vertices(), (n + 1) * (n + 1));
    assert_eq!(m.n_triangles(), 2 * n * n);
    assert_eq!(m.boundary_edges.len(), 4 * n);
    for tag in 1..=4 {
        assert_eq!(m.boundary_edges.iter().filter(|e| e.tag == tag).count(), n);
    }
    // Every cell is cut along its horizontal diagonal: each triangle has one
    // horizontal edge of length 2R/n, and equal area R^2/n^2.
    for (t, tri) in m.triangles.iter().enumerate() {
        let horizontal = (0..3)
            .filter(|&i| {
                let (p, q) = (m.vertices[tri[i]], m.vertices[tri[(i + 1) % 3]]);
                (p[1] - q[1]).abs() < 1e-9
                    && ((p[0] - q[0]).abs() - 2.0 * R / n as f64).abs() < 1e-9
            })
            .count();
        assert_eq!(horizontal, 1, "triangle {t}");
        assert!((m.area(t) - R * R / (n * n) as f64).abs() < 1e-9);
    }
    assert_mirror_symmetric(m, |p| [-p[0], p[1]], &format!("diamond n = {n}, x -> -x"));
    assert_mirror_symmetric(m, |p| [p[0], -p[1]], &format!("diamond n = {n}, y -> -y"));
    if n.is_multiple_of(2) {
        assert!(has_vertex_at(m, [0.0, 0.0], 1e-12), "centre not a vertex");
    }
}

#[test]
fn diamond_structured() {
    let (_d, _f, m) = mesh("diamond.geo", &[("n", 16.0)]);
    report("diamond n = 16", &m);
    assert_eq!(m.n_vertices(), 289);
    assert_eq!(m.n_triangles(), 512);
    assert_eq!(m.boundary_edges.len(), 64);
    check_structured_diamond(&m, 16);

    let (_d, _f, m) = mesh("diamond.geo", &[("n", 32.0)]);
    report("diamond n = 32", &m);
    assert_eq!(m.n_vertices(), 1089);
    assert_eq!(m.n_triangles(), 2048);
    assert_eq!(m.boundary_edges.len(), 128);
    check_structured_diamond(&m, 32);
}

#[test]
fn diamond_unstructured() {
    let h = 10.0;
    let (_d, _f, m) = mesh("diamond.geo", &[("n", 0.0), ("h", h)]);
    report("diamond h = 10", &m);
    check_diamond(&m);
    for tag in 1..=4 {
        assert!(m.boundary_edges.iter().any(|e| e.tag == tag), "tag {tag}");
    }
    assert!(m.h_max() < 2.0 * h && m.h_max() > 0.5 * h, "{}", m.h_max());
    for c in [[R, 0.0], [0.0, R], [-R, 0.0], [0.0, -R]] {
        assert!(has_vertex_at(&m, c, 1e-9), "corner {c:?}");
    }
}

#[test]
fn broken_geo_gives_gmsh_error() {
    let dir = tempfile::tempdir().unwrap();
    let geo = dir.path().join("broken.geo");
    std::fs::write(&geo, "Point(1) = {0, 0, 0, 1};\nLine(1) = {1, 2;\n").unwrap();
    let out = dir.path().join("broken.msh");
    std::fs::write(&out, "previous content").unwrap();
    let e = run_gmsh(&geo, &out, &[]).unwrap_err();
    eprintln!("broken .geo: {e}");
    match &e {
        Error::Gmsh { geo: g, reason } => {
            assert_eq!(g, &geo);
            assert!(reason.contains("syntax error"), "{reason}");
            assert!(reason.contains("line 2"), "{reason}");
        }
        other => panic!("expected Error::Gmsh, got {other:?}"),
    }
    // The existing output is untouched and no temporary file is left behind.
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "previous content");
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left.len(), 2, "{left:?}");

    // gmsh exits 0 but meshes no surface: no Physical Surface.
    let geo = dir.path().join("nosurface.geo");
    std::fs::write(
        &geo,
        "Point(1) = {0, 0, 0, 0.5}; Point(2) = {1, 0, 0, 0.5}; Point(3) = {0, 1, 0, 0.5};\n\
         Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 1};\n\
         Curve Loop(1) = {1, 2, 3}; Plane Surface(1) = {1};\n\
         Physical Curve(1) = {1, 2, 3};\n",
    )
    .unwrap();
    let e = run_gmsh(&geo, &out, &[]).unwrap_err();
    eprintln!("no surface: {e}");
    assert!(matches!(&e, Error::Gmsh { reason, .. } if reason.contains("no triangles")));
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "previous content");

    // The .geo's own parameter check.
    let e = run_gmsh(
        &geo_file("disk.geo"),
        &out,
        &params(&[("n", 0.0), ("h", -1.0)]),
    )
    .unwrap_err();
    eprintln!("bad parameter: {e}");
    assert!(matches!(&e, Error::Gmsh { reason, .. } if reason.contains("need n > 0 or h > 0")));
}

/// What FreeFEM's gmshload makes of a mesh file.
struct FfMesh {
    vertices: Vec<[f64; 2]>,
    triangles: Vec<[usize; 3]>,
    /// Boundary edges in FreeFEM's order: vertices and label.
    boundary: Vec<([usize; 2], i32)>,
}

fn freefem_load(msh: &Path) -> FfMesh {
    let dir = tempfile::tempdir().unwrap();
    let script = dir.path().join("load.edp");
    let msh_str = msh.to_str().unwrap();
    assert!(!msh_str.contains('"'));
    std::fs::write(
        &script,
        format!(
            r#"load "gmsh"
mesh Th = gmshload("{msh_str}");
cout.precision(17);
cout << "@NV " << Th.nv << " NT " << Th.nt << " NBE " << Th.nbe << endl;
cout << "@FIRST " << Th(0).x << " " << Th(0).y << " " << Th[0][0] << " " << Th[0][1] << " " << Th[0][2] << endl;
for (int i = 0; i < Th.nv; i++) cout << "@V " << Th(i).x << " " << Th(i).y << endl;
for (int k = 0; k < Th.nt; k++) cout << "@T " << Th[k][0] << " " << Th[k][1] << " " << Th[k][2] << endl;
for (int k = 0; k < Th.nbe; k++) cout << "@E " << Th.be(k)[0] << " " << Th.be(k)[1] << " " << Th.be(k).label << endl;
"#
        ),
    )
    .unwrap();
    let out = Command::new("FreeFem++")
        .env("FF_LOADPATH", "/usr/lib/freefem++")
        .arg("-nw")
        .arg(&script)
        .current_dir(dir.path())
        .output()
        .expect("FreeFem++ not found on PATH (apt-get install freefem++ libfreefem++)");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "FreeFem++ failed: {}\n{stdout}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let mut ff = FfMesh {
        vertices: vec![],
        triangles: vec![],
        boundary: vec![],
    };
    let mut counts = None;
    for line in stdout.lines() {
        let mut t = line.split_whitespace();
        let tag = t.next().unwrap_or("");
        let rest: Vec<&str> = t.collect();
        let f = |i: usize| rest[i].parse::<f64>().unwrap();
        let u = |i: usize| rest[i].parse::<usize>().unwrap();
        match tag {
            "@NV" => counts = Some((u(0), u(2), u(4))),
            "@FIRST" => eprintln!(
                "FreeFEM: Th(0) = ({}, {}), Th[0] = [{}, {}, {}]",
                f(0),
                f(1),
                u(2),
                u(3),
                u(4)
            ),
            "@V" => ff.vertices.push([f(0), f(1)]),
            "@T" => ff.triangles.push([u(0), u(1), u(2)]),
            "@E" => ff
                .boundary
                .push(([u(0), u(1)], rest[2].parse::<i32>().unwrap())),
            _ => {}
        }
    }
    let (nv, nt, nbe) = counts.expect("FreeFEM printed no counts");
    assert_eq!(ff.vertices.len(), nv);
    assert_eq!(ff.triangles.len(), nt);
    assert_eq!(ff.boundary.len(), nbe);
    ff
}

fn compare_with_freefem(what: &str, msh: &Path, m: &Mesh) {
    let ff = freefem_load(msh);
    eprintln!(
        "{what}: ours NV {} NT {} NBE {}, FreeFEM NV {} NT {} NBE {}",
        m.n_vertices(),
        m.n_triangles(),
        m.boundary_edges.len(),
        ff.vertices.len(),
        ff.triangles.len(),
        ff.boundary.len()
    );
    eprintln!(
        "{what}: ours vertex 0 = {:?}, triangle 0 = {:?}",
        m.vertices[0], m.triangles[0]
    );
    assert_eq!(ff.vertices.len(), m.n_vertices(), "{what}: vertex count");
    assert_eq!(
        ff.triangles.len(),
        m.n_triangles(),
        "{what}: triangle count"
    );
    // Vertex 0 and triangle 0 (the brief's check), then everything.
    let scale = m
        .vertices
        .iter()
        .map(|p| p[0].abs().max(p[1].abs()))
        .fold(1.0, f64::max);
    let close = |a: [f64; 2], b: [f64; 2]| {
        (a[0] - b[0]).abs() <= 1e-15 * scale && (a[1] - b[1]).abs() <= 1e-15 * scale
    };
    assert!(close(ff.vertices[0], m.vertices[0]), "{what}: vertex 0");
    assert_eq!(ff.triangles[0], m.triangles[0], "{what}: triangle 0");
    for (i, (a, b)) in ff.vertices.iter().zip(&m.vertices).enumerate() {
        assert!(
            close(*a, *b),
            "{what}: vertex {i}: FreeFEM {a:?}, ours {b:?}"
        );
    }
    for (k, (a, b)) in ff.triangles.iter().zip(&m.triangles).enumerate() {
        assert_eq!(a, b, "{what}: triangle {k}: FreeFEM {a:?}, ours {b:?}");
    }
    // Boundary edges: same set with the same labels (and report the order).
    let ours: Vec<([usize; 2], i32)> = m
        .boundary_edges
        .iter()
        .map(|e| (e.vertices, e.tag))
        .collect();
    let normalise = |v: &[([usize; 2], i32)]| {
        let mut s: Vec<([usize; 2], i32)> = v
            .iter()
            .map(|&([a, b], l)| ([a.min(b), a.max(b)], l))
            .collect();
        s.sort_unstable();
        s
    };
    assert_eq!(
        normalise(&ff.boundary),
        normalise(&ours),
        "{what}: boundary edges"
    );
    eprintln!(
        "{what}: FreeFEM keeps the vertex order, the triangle order and the in-triangle \
         order; boundary edges in the same order: {}",
        ff.boundary == ours
    );
}

#[test]
fn freefem_reads_the_same_meshes() {
    let (_d, f, m) = mesh("diamond.geo", &[("n", 16.0)]);
    compare_with_freefem("diamond n = 16", &f, &m);
    let (_d, f, m) = mesh("disk.geo", &[("n", 8.0)]);
    compare_with_freefem("disk n = 8", &f, &m);
    let (_d, f, m) = mesh("disk.geo", &[("n", 0.0), ("h", 0.2)]);
    compare_with_freefem("disk h = 0.2", &f, &m);
}

/// gmsh's default output, MSH 4.1 (ASCII and binary), is read as a scene's
/// `mesh.file`: gmsh converts it to MSH 2.2 first, so the solution equals
/// the one on the same mesh written as MSH 2.2, and the FreeFEM twin reads
/// the conversion too.
#[test]
fn msh41_files_are_read_through_gmsh() {
    let dir = tempfile::tempdir().unwrap();
    let geo = geo_file("disk.geo");
    let write = |name: &str, extra: &[&str]| {
        let path = dir.path().join(name);
        let status = Command::new("gmsh")
            .arg(&geo)
            .args(["-2", "-setnumber", "n", "4", "-v", "0"])
            .args(extra)
            .arg("-o")
            .arg(&path)
            .status()
            .expect("gmsh runs");
        assert!(status.success(), "gmsh {extra:?}");
        path
    };
    let (ascii, binary, v22) = (
        write("a41.msh", &[]),
        write("b41.msh", &["-bin"]),
        write("c22.msh", &["-format", "msh22"]),
    );
    assert_eq!(obstacle_fem::gmsh::msh_major_version(&ascii), Some(4));
    assert_eq!(obstacle_fem::gmsh::msh_major_version(&binary), Some(4));
    assert_eq!(obstacle_fem::gmsh::msh_major_version(&v22), Some(2));
    let solve = |file: &Path| {
        let out = dir.path().join("r.h5");
        let set = format!("mesh.file={}", file.display());
        let o = common::solve_scene("obstacle-disk", &out, &[&set]);
        assert!(o.status.success(), "{}", common::text(&o));
        let r = obstacle_fem::output::read_result(&out).unwrap();
        common::field(&r, "u").to_vec()
    };
    let reference = solve(&v22);
    for file in [&ascii, &binary] {
        assert_eq!(solve(file), reference, "{}", file.display());
    }
    let out = dir.path().join("ff.h5");
    let args: Vec<String> = [
        "freefem",
        &common::scene_arg("obstacle-disk"),
        "--set",
        &format!("mesh.file={}", ascii.display()),
        "--iterations",
        "10",
        "--out",
        out.to_str().unwrap(),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    common::obstacle(&args);
    assert!(out.exists());
}
