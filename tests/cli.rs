//! The `obstacle` command line: a user's mesh file, `info`, and clear errors
//! (file, field, reason; non-zero exit; nothing half-written).

mod common;

use common::{run_obstacle, text};

use std::path::Path;

const SCENE: &str = "pipelines/scenes/obstacle-disk.toml";

#[test]
fn solve_on_a_users_mesh_file_and_info() {
    let dir = tempfile::tempdir().unwrap();
    let msh = dir.path().join("user.msh");
    let o = run_obstacle(&[
        "mesh",
        SCENE,
        "--set",
        "mesh.n=6",
        "--out",
        msh.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("vertices"));
    // mesh.file replaces geo (relative paths are relative to the scene; absolute here).
    let out = dir.path().join("r.h5");
    let o = run_obstacle(&[
        "solve",
        SCENE,
        "--set",
        &format!("mesh.file=\"{}\"", msh.display()),
        "--out",
        out.to_str().unwrap(),
    ]);
    // `geo` and `file` together are rejected; a scene text without `geo` is needed.
    assert!(!o.status.success());
    assert!(text(&o).contains("not both"), "{}", text(&o));
    let scene_text = std::fs::read_to_string(SCENE)
        .unwrap()
        .replace(
            "geo = \"../../meshes/disk.geo\"",
            &format!("file = \"{}\"", msh.display()),
        )
        .replace("h = 0.1 ", "# h = 0.1 ");
    let scene = dir.path().join("user.toml");
    std::fs::write(&scene, scene_text).unwrap();
    let o = run_obstacle(&[
        "solve",
        scene.to_str().unwrap(),
        "--set",
        "output.plots=[]",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(out.exists() && out.with_extension("xdmf").exists());
    let o = run_obstacle(&["info", out.to_str().unwrap()]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    for word in ["lambda", "gap_mean", "kkt", "iterations", "converged"] {
        assert!(t.contains(word), "info lacks {word}: {t}");
    }
}

#[test]
fn bad_input_is_one_clear_error_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bad.h5");
    let o_str = out.to_str().unwrap();
    let cases: &[(&[&str], &[&str])] = &[
        (
            &["--set", "solver.alpah=1"],
            &["obstacle-disk.toml", "alpah"],
        ),
        (&["--set", "solver.alpha=-1"], &["solver.alpha", "> 0"]),
        (
            &["--set", "mesh.dirichlet=[\"nowhere\"]", "--set", "mesh.n=4"],
            &["mesh.dirichlet", "nowhere", "boundary"],
        ),
        (&["--set", "mesh.geo=\"missing.geo\""], &["missing.geo"]),
        (
            &["--set", "mesh.n=4", "--set", "solver.alpha=30"],
            &["diverged", "2/s_max"],
        ),
    ];
    for (args, expected) in cases {
        let mut all = vec!["solve", SCENE, "--out", o_str];
        all.extend_from_slice(args);
        let o = run_obstacle(&all);
        let t = text(&o);
        assert!(!o.status.success(), "{args:?} should fail: {t}");
        assert!(t.starts_with("error: ") || t.contains("\nerror: "), "{t}");
        for e in *expected {
            assert!(t.contains(e), "{args:?}: message lacks `{e}`: {t}");
        }
        assert!(!t.contains("panicked"), "{t}");
        assert!(!out.exists(), "{args:?} left a result file");
    }
    // An unwritable output folder, and a foreign file given to `info`.
    let o = run_obstacle(&[
        "solve",
        SCENE,
        "--set",
        "mesh.n=4",
        "--out",
        "/proc/forbidden/r.h5",
    ]);
    assert!(
        !o.status.success() && text(&o).contains("/proc/forbidden"),
        "{}",
        text(&o)
    );
    let foreign = dir.path().join("foreign.h5");
    std::fs::write(&foreign, b"not hdf5 at all").unwrap();
    let o = run_obstacle(&["info", foreign.to_str().unwrap()]);
    assert!(
        !o.status.success() && text(&o).contains("foreign.h5"),
        "{}",
        text(&o)
    );
    assert!(!Path::new(&foreign).with_extension("xdmf").exists());
}
