//! Outputs (issue 16, part 1; each test fails on the code before the output
//! transaction): a run's files appear together or not at all,
//! never over an input of the run or a file of another kind; names cannot
//! leave their folder; an interrupted run leaves no temporary behind.

mod common;

use common::{
    assert_one_error, manifest_path, run_obstacle, run_obstacle_env, solve_membrane as solve, text,
};
use std::path::{Path, PathBuf};
use std::process::Output;

const MEMBRANE: &str = "pipelines/scenes/obstacle-disk.toml";

/// Temporaries of any kind under `dir` (staging folders, gmsh's folders,
/// partial files), searched recursively.
fn leftovers(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.contains(".obstacle-tmp-") || name.starts_with(".gmsh-") || name.contains("partial")
        {
            found.push(entry.path());
        } else if entry.file_type().unwrap().is_dir() {
            found.extend(leftovers(&entry.path()));
        }
    }
    found
}

/// A target that is a directory (the `.xdmf`, a plot) makes the run fail
/// before anything moves: the earlier .h5, .msh and plot stay byte for byte.
#[test]
fn a_failing_output_keeps_the_previous_result() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o = solve(&out, &["mesh.n=6", "output.plots=[\"u\"]"]);
    assert!(o.status.success(), "{}", text(&o));
    let files: Vec<PathBuf> = ["h5", "xdmf", "msh", "u.png"]
        .iter()
        .map(|e| out.with_extension(e))
        .collect();
    let before: Vec<Vec<u8>> = files.iter().map(|f| std::fs::read(f).unwrap()).collect();

    for blocked in [out.with_extension("xdmf"), out.with_extension("u.png")] {
        std::fs::remove_file(&blocked).unwrap();
        std::fs::create_dir(&blocked).unwrap();
        // Different data: a new result would differ from the old one.
        let o = solve(&out, &["mesh.n=8", "output.plots=[\"u\"]"]);
        let name = blocked.file_name().unwrap().to_str().unwrap();
        assert_one_error(&o, &[name, "is a directory", "not replacing it"], name);
        for (f, b) in files.iter().zip(&before).filter(|(f, _)| **f != blocked) {
            assert!(
                std::fs::read(f).unwrap() == *b,
                "{name}: {} changed",
                f.display()
            );
        }
        assert_eq!(leftovers(dir.path()), Vec::<PathBuf>::new(), "{name}");
        std::fs::remove_dir(&blocked).unwrap();
        let i = files.iter().position(|f| *f == blocked).unwrap();
        std::fs::write(&blocked, &before[i]).unwrap();
    }
}

/// A scene on its own `.geo` in a fresh folder, meshed coarsely.
fn scene_with_geo(dir: &Path) -> PathBuf {
    std::fs::copy(manifest_path("meshes/disk.geo"), dir.join("disk.geo")).unwrap();
    let text = std::fs::read_to_string(manifest_path(MEMBRANE))
        .unwrap()
        .replace("../../meshes/disk.geo", "disk.geo")
        .replace("h = 0.1 ", "h = 0.4 ");
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, text).unwrap();
    scene
}

/// `mesh --out` writes only a `.msh`, never over the scene, its `.geo`, a
/// mesh file the scene reads, or a `.msh` that is not a mesh; a `mesh.file`
/// scene's mesh is validated and copied to `--out`.
#[test]
fn mesh_out_never_replaces_inputs_or_other_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = scene_with_geo(d);
    let mesh = |scene: &Path, out: &Path| {
        run_obstacle(&[
            "mesh",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let notes = d.join("notes.txt");
    std::fs::write(&notes, "my notes").unwrap();
    let not_a_mesh = d.join("old.msh");
    std::fs::write(&not_a_mesh, "hello").unwrap();
    for (target, reason) in [
        (scene.clone(), "must end in .msh"),
        (d.join("disk.geo"), "must end in .msh"),
        (notes.clone(), "must end in .msh"),
        (not_a_mesh.clone(), "is not a gmsh mesh"),
    ] {
        let before = std::fs::read(&target).unwrap();
        let o = mesh(&scene, &target);
        let name = target.file_name().unwrap().to_str().unwrap();
        assert_one_error(&o, &[name, reason], name);
        assert_eq!(std::fs::read(&target).unwrap(), before, "{name} changed");
    }

    let fresh = d.join("fresh.msh");
    let o = mesh(&scene, &fresh);
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        text(&o).starts_with(&format!("{}: ", fresh.display())),
        "{}",
        text(&o)
    );
    let meshed = std::fs::read(&fresh).unwrap();
    assert!(meshed.starts_with(b"$MeshFormat"));

    // A scene that reads fresh.msh: it is an input, and is copied elsewhere.
    let from_file = d.join("from-file.toml");
    let text_file = std::fs::read_to_string(&scene)
        .unwrap()
        .replace("geo = \"disk.geo\"", "file = \"fresh.msh\"")
        .replace("h = 0.4 ", "");
    std::fs::write(&from_file, text_file).unwrap();
    let o = mesh(&from_file, &fresh);
    assert_one_error(
        &o,
        &["fresh.msh", "an input of this run"],
        "mesh.file onto itself",
    );
    assert_eq!(std::fs::read(&fresh).unwrap(), meshed);
    let copy = d.join("copy.msh");
    let o = mesh(&from_file, &copy);
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(std::fs::read(&copy).unwrap(), meshed);
    assert_eq!(leftovers(d), Vec::<PathBuf>::new());
}

/// gmsh's mesh is validated before it moves: a `.geo` whose boundary has
/// no Physical Curve fails, naming the `.geo`, and the old `--out` stays.
#[test]
fn a_mesh_that_fails_validation_is_not_kept() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = scene_with_geo(d);
    std::fs::write(
        d.join("disk.geo"),
        "Point(1) = {0, 0, 0, 0.3}; Point(2) = {1, 0, 0, 0.3};\n\
         Point(3) = {1, 1, 0, 0.3}; Point(4) = {0, 1, 0, 0.3};\n\
         Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};\n\
         Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};\n\
         Physical Surface(\"domain\") = {1};\n",
    )
    .unwrap();
    let out = d.join("old.msh");
    std::fs::write(&out, "$MeshFormat\nthe old mesh\n").unwrap();
    let o = run_obstacle(&[
        "mesh",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_one_error(
        &o,
        &["disk.geo", "missing boundary tag"],
        "untagged boundary",
    );
    assert_eq!(
        std::fs::read_to_string(&out).unwrap(),
        "$MeshFormat\nthe old mesh\n"
    );
    assert_eq!(leftovers(d), Vec::<PathBuf>::new());
}

/// A study file in `dir/a/b/` with the given `name` line and sweeps.
fn study_file(dir: &Path, name_line: &str, sweeps: &str) -> PathBuf {
    let folder = dir.join("a").join("b");
    std::fs::create_dir_all(&folder).unwrap();
    let path = folder.join("study.toml");
    let text = format!(
        "{name_line}\nscene = {:?}\nset = [\"output.plots=[]\"]\n{sweeps}",
        manifest_path(MEMBRANE).display().to_string()
    );
    std::fs::write(&path, text).unwrap();
    path
}

fn run_study(study: &Path) -> Output {
    common::run_study(study, &study.parent().unwrap().join("out"), &[])
}

/// Study names become file names: `../../x`, NUL and 300 characters are
/// refused with the study file and the key `name`, and nothing is written
/// (in particular not two levels up).
#[test]
fn study_names_cannot_leave_the_out_dir() {
    let sweep = "[[sweep]]\nkey = \"mesh.n\"\nvalues = [4]\n";
    let long = "x".repeat(300);
    for (name_line, reason) in [
        ("name = \"../../x\"".to_string(), "must not contain `/`"),
        ("name = \"a\\u0000b\"".to_string(), "U+0000"),
        (format!("name = \"{long}\""), "300 characters long"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let study = study_file(dir.path(), &name_line, sweep);
        let o = run_study(&study);
        let file = study.to_str().unwrap();
        assert_one_error(&o, &[file, "field `name`", reason], &name_line);
        let names = |p: &Path| -> Vec<String> {
            let mut v: Vec<String> = std::fs::read_dir(p)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            v.sort();
            v
        };
        assert_eq!(names(dir.path()), ["a"]);
        assert_eq!(names(&dir.path().join("a")), ["b"]);
        assert_eq!(names(&dir.path().join("a/b")), ["study.toml"]);
    }
}

/// Scene names get the same check, through the file or `--set`.
#[test]
fn scene_names_with_nul_or_300_characters_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let long = format!("name=\"{}\"", "y".repeat(300));
    for (set, reason) in [
        ("name=\"a\\u0000b\"", "U+0000"),
        (long.as_str(), "300 characters long"),
        ("name=\"../up\"", "must not contain `/`"),
        ("name=\".hidden\"", "must not start with `.`"),
    ] {
        let o = solve(&out, &[set, "mesh.n=4"]);
        assert_one_error(&o, &["obstacle-disk.toml", "field `name`", reason], set);
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

/// Two sweeps (or a sweep and a `with`) of one key would label runs wrongly
/// and write two CSV columns of that key: refused, naming the file and key.
#[test]
fn a_key_swept_twice_is_refused() {
    for sweeps in [
        "[[sweep]]\nkey = \"mesh.n\"\nvalues = [4]\n[[sweep]]\nkey = \"mesh.n\"\nvalues = [6]\n",
        "[[sweep]]\nkey = \"element\"\nvalues = [\"p1b-p0\"]\nwith = { \"mesh.n\" = [4] }\n\
         [[sweep]]\nkey = \"mesh.n\"\nvalues = [6]\n",
    ] {
        let dir = tempfile::tempdir().unwrap();
        let study = study_file(dir.path(), "name = \"twice\"", sweeps);
        let o = run_study(&study);
        assert_one_error(
            &o,
            &[study.to_str().unwrap(), "`mesh.n` is swept twice"],
            sweeps,
        );
        assert!(!study.parent().unwrap().join("out").exists());
    }
}

/// An unknown boundary part is named against the `.geo` the user wrote,
/// not a temporary mesh file that no longer exists.
#[test]
fn an_unknown_part_names_the_geo() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o = solve(&out, &["mesh.n=4", "mesh.dirichlet=[\"nowhere\"]"]);
    assert_one_error(
        &o,
        &["mesh.dirichlet", "meshes/disk.geo", "nowhere"],
        "part",
    );
    let t = text(&o);
    assert!(!t.contains("partial") && !t.contains("obstacle-tmp"), "{t}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

/// A FreeFEM run that fails after meshing leaves no FILE.msh behind.
#[test]
fn a_failed_freefem_run_leaves_no_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let scripts = dir.path().join("no-scripts");
    std::fs::create_dir(&scripts).unwrap();
    let out = dir.path().join("r.h5");
    let o = run_obstacle_env(
        &[
            "freefem",
            MEMBRANE,
            "--set",
            "mesh.n=4",
            "--out",
            out.to_str().unwrap(),
        ],
        &[("OBSTACLE_FREEFEM_DIR", scripts.to_str().unwrap())],
    );
    assert_one_error(&o, &["membrane-obstacle.edp"], "freefem without its script");
    let mut left: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["no-scripts"]);
}

/// SIGINT while the solver runs and SIGTERM as soon as the run has begun
/// (gmsh may be meshing): exit 130 / 143, and no staging folder, gmsh
/// folder or partial file is left.
#[test]
fn an_interrupted_run_leaves_nothing_behind() {
    for (signal, code, wait_for_mesh) in [("-INT", 130, true), ("-TERM", 143, false)] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("r.h5");
        // A mid-size run (Uzawa to 1e-8 on about 10⁴ triangles takes minutes).
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_obstacle"))
            .args(["solve", MEMBRANE, "--quiet", "--set", "mesh.n=64"])
            .args(["--out", out.to_str().unwrap()])
            .env("CI", "1")
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let started = std::time::Instant::now();
        // Ready once a temporary exists; for SIGINT, once it holds the mesh
        // (the solver is running then).
        let meshed = |p: &PathBuf| {
            p.join("r.msh").exists()
                || std::fs::metadata(p).is_ok_and(|m| m.is_file() && m.len() > 0)
        };
        loop {
            let temporaries = leftovers(dir.path());
            if temporaries.iter().any(|p| !wait_for_mesh || meshed(p)) {
                break;
            }
            if let Some(status) = child.try_wait().unwrap() {
                panic!("the run ended ({status}) before it could be interrupted");
            }
            assert!(started.elapsed().as_secs() < 300, "no temporary appeared");
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        let kill = std::process::Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .unwrap();
        assert!(kill.success());
        let o = child.wait_with_output().unwrap();
        assert_eq!(o.status.code(), Some(code), "{signal}: {}", text(&o));
        assert_eq!(leftovers(dir.path()), Vec::<PathBuf>::new(), "{signal}");
        assert!(!out.exists(), "{signal}");
    }
}

/// `solve --failure-marker X` only ever writes or removes a marker: X is
/// refused before the run when it is the scene, the result, a file named
/// after the result, or an existing file that is no marker (an unrelated
/// text, an earlier result), and those stay as they were. A marker is
/// written on a numerical failure (exit 0), replaced by the next failure and
/// removed by the next success.
#[test]
fn a_failure_marker_never_replaces_or_removes_another_file() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("disk.toml");
    let text_of_scene = std::fs::read_to_string("pipelines/scenes/obstacle-disk.toml")
        .unwrap()
        .replace(
            "../../meshes/",
            &format!("{}/meshes/", env!("CARGO_MANIFEST_DIR")),
        );
    std::fs::write(&scene, &text_of_scene).unwrap();
    let out = dir.path().join("r.h5");
    let solve = |marker: &Path, diverge: bool| {
        let mut args = vec![
            "solve",
            scene.to_str().unwrap(),
            "--quiet",
            "--out",
            out.to_str().unwrap(),
            "--failure-marker",
            marker.to_str().unwrap(),
        ];
        for s in ["mesh.n=4", "output.plots=[]", "solver.stop=kkt"] {
            args.extend(["--set", s]);
        }
        if diverge {
            args.extend(["--set", "solver.alpha=100"]);
        }
        run_obstacle(&args)
    };
    let notes = dir.path().join("notes.txt");
    std::fs::write(&notes, "keep me\n").unwrap();
    let refused: [(&Path, &str); 4] = [
        (&scene, "an input of this run"),
        (&out, "it is the result file"),
        (&out.with_extension("xdmf"), "named r.*"),
        (&notes, "not an obstacle failure marker"),
    ];
    for (marker, reason) in refused {
        for diverge in [false, true] {
            let o = solve(marker, diverge);
            common::assert_one_error(&o, &["--failure-marker", reason], reason);
        }
        assert!(!out.exists(), "{reason}: the run went ahead");
    }
    assert_eq!(std::fs::read_to_string(&scene).unwrap(), text_of_scene);
    assert_eq!(std::fs::read_to_string(&notes).unwrap(), "keep me\n");

    // An earlier result named as the marker: neither replaced nor removed.
    let earlier = dir.path().join("earlier.h5");
    let marker = dir.path().join("r.failed");
    common::check_success("a first run", &solve(&marker, false));
    std::fs::rename(&out, &earlier).unwrap();
    let bytes = std::fs::read(&earlier).unwrap();
    for diverge in [false, true] {
        let o = solve(&earlier, diverge);
        common::assert_one_error(&o, &["earlier.h5", "not an obstacle failure marker"], "h5");
    }
    assert_eq!(std::fs::read(&earlier).unwrap(), bytes);

    // Its own marker: written, replaced, removed.
    for _ in 0..2 {
        let o = solve(&marker, true);
        assert_eq!(o.status.code(), Some(0), "{}", common::text(&o));
        let text = std::fs::read_to_string(&marker).unwrap();
        assert!(
            text.starts_with(obstacle_fem::output::marker::HEADER) && text.contains("diverged"),
            "{text}"
        );
    }
    common::check_success("a run after a failure", &solve(&marker, false));
    assert!(!marker.exists() && out.exists());
}
