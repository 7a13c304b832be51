//! Helpers shared by the FreeFEM cross-check tests. Running FreeFEM and
//! reading its text output is library code (`obstacle_fem::freefem`); these
//! wrap it for tests: a missing FreeFEM FAILS a test (CI installs it), it is
//! never skipped.
#![allow(dead_code)]

use obstacle_fem::freefem;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn manifest_path(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// Runs FreeFEM's `script` (a path below `freefem/`) with `args`: the
/// output and the wall time of the process. Panics when FreeFEM or its gmsh
/// plugin is missing.
pub fn run_freefem(script: &str, args: &[String]) -> (Output, f64) {
    freefem::run_script(&freefem::script_dir().join(script), args).unwrap_or_else(|e| panic!("{e}"))
}

pub fn check_success(what: &str, out: &Output) {
    assert!(
        out.status.success(),
        "{what} failed ({}):\n--- stdout\n{}\n--- stderr\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A script call that must fail with a message prefixed by the script's name.
pub fn check_rejected(what: &str, out: &Output, script: &str) {
    assert!(
        !out.status.success(),
        "{what}: the script should fail, but succeeded:\n{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains(&format!("{script}:")), "{what}: {text}");
}

/// Runs the `obstacle` binary; its output, whatever the exit status.
pub fn obstacle_output(args: &[String]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_obstacle"))
        .args(args)
        .output()
        .expect("cannot run the obstacle binary")
}

/// Runs the `obstacle` binary and asserts it succeeds.
pub fn obstacle(args: &[String]) -> Output {
    let out = obstacle_output(args);
    check_success(&format!("obstacle {}", args.join(" ")), &out);
    out
}

pub fn read_numbers(path: &Path) -> Vec<f64> {
    freefem::read_numbers(path).unwrap_or_else(|e| panic!("{e}"))
}

pub fn read_info(path: &Path) -> HashMap<String, String> {
    freefem::Info::read(path)
        .unwrap_or_else(|e| panic!("{e}"))
        .values
}

/// FreeFEM's `PREFIX.mesh.txt`: vertices and triangles.
pub fn read_ff_mesh(path: &Path) -> (Vec<[f64; 2]>, Vec<[usize; 3]>) {
    freefem::read_mesh_text(path).unwrap_or_else(|e| panic!("{e}"))
}

pub fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

/// max |a − b| / max |a| (a: Rust), and where.
pub fn rel_diff(a: &[f64], b: &[f64]) -> (f64, usize) {
    assert_eq!(a.len(), b.len());
    let scale = max_abs(a);
    assert!(scale > 0.0, "the Rust vector is zero");
    let (i, d) = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .enumerate()
        .fold(
            (0, 0.0),
            |(bi, bd), (i, d)| if d > bd { (i, d) } else { (bi, bd) },
        );
    (d / scale, i)
}
