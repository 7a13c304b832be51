//! The invariants of ARCHITECTURE.md that a grep can check: which modules a
//! module may import (`crate::…` paths), where HDF5 and subprocesses appear.
//! A failure names the file, the line and the rule it breaks.

use std::path::{Path, PathBuf};

/// Every `.rs` file under `src/`, with its path relative to `src/`.
fn sources() -> Vec<(String, String)> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(&path, out);
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path);
            }
        }
    }
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    walk(&src, &mut files);
    files.sort();
    files
        .into_iter()
        .map(|p| {
            let rel = p.strip_prefix(&src).unwrap().display().to_string();
            (rel, std::fs::read_to_string(&p).unwrap())
        })
        .collect()
}

/// The code of a file without its `#[cfg(test)]` module (unit tests may
/// build whatever they check with).
fn non_test_code(text: &str) -> &str {
    text.find("#[cfg(test)]").map_or(text, |i| &text[..i])
}

/// The top-level modules a file names as `crate::<module>` (in `use`
/// lines and paths alike), with the line number of each.
fn crate_modules(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    for (i, line) in non_test_code(text).lines().enumerate() {
        let line = line.trim_start();
        if line.starts_with("//") {
            continue;
        }
        let mut rest = line;
        while let Some(k) = rest.find("crate::") {
            rest = &rest[k + "crate::".len()..];
            let name: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            // `crate::outln!(…)`: the exported macros are console.rs's.
            let is_macro = rest[name.len()..].starts_with('!');
            if !name.is_empty() {
                out.push((i + 1, if is_macro { "console".into() } else { name }));
            }
        }
        // `use crate::{a, b}` groups.
        if let Some(k) = line.find("crate::{") {
            let group = &line[k + "crate::{".len()..];
            for name in group.split([',', '}']) {
                let name: String = name
                    .trim()
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if !name.is_empty() {
                    out.push((i + 1, name));
                }
            }
        }
    }
    out
}

/// Checks that the files under `prefix` import only the modules `allowed`
/// (their own module always).
fn only_imports(prefix: &str, allowed: &[&str]) -> Vec<String> {
    let own = prefix.trim_end_matches(".rs").trim_end_matches('/');
    sources()
        .into_iter()
        .filter(|(rel, _)| rel.starts_with(prefix))
        .flat_map(|(rel, text)| {
            crate_modules(&text)
                .into_iter()
                .filter(|(_, m)| m != own && !allowed.contains(&m.as_str()))
                .map(move |(line, m)| {
                    format!("src/{rel}:{line} imports crate::{m} (allowed: {allowed:?})")
                })
                .collect::<Vec<_>>()
        })
        .collect()
}

fn assert_none(rule: &str, violations: Vec<String>) {
    assert!(
        violations.is_empty(),
        "{rule}:\n  {}",
        violations.join("\n  ")
    );
}

#[test]
fn solvers_know_no_meshes_scenes_models_or_files() {
    assert_none(
        "solvers/ import only linalg, error and progress",
        only_imports("solvers/", &["linalg", "error", "progress"]),
    );
}

#[test]
fn the_scene_declares_and_imports_no_model() {
    assert_none(
        "scene.rs imports only error, names, expression and the solver vocabulary",
        only_imports("scene.rs", &["error", "names", "expression", "solvers"]),
    );
}

#[test]
fn fe_machinery_knows_no_models_scenes_or_solvers() {
    for file in ["quadrature.rs", "space.rs", "assembly.rs"] {
        assert_none(
            "quadrature, space and assembly sit on mesh and linalg",
            only_imports(file, &["error", "mesh", "quadrature", "space", "linalg"]),
        );
    }
    for prefix in ["linalg.rs", "linalg/"] {
        assert_none(
            "linalg knows no finite elements",
            only_imports(prefix, &["error", "linalg"]),
        );
    }
    assert_none(
        "mesh/ does not run gmsh",
        only_imports("mesh/", &["error", "output"]),
    );
}

#[test]
fn output_and_plots_know_no_scenes_or_models() {
    assert_none(
        "output/ knows mesh, space and its own types, no model, scene or transfer",
        only_imports(
            "output/",
            &[
                "error",
                "mesh",
                "space",
                "quadrature",
                "assembly",
                "console",
            ],
        ),
    );
    assert_none(
        "plot/ draws arrays on a mesh",
        only_imports("plot/", &["error", "mesh", "solvers", "output"]),
    );
}

#[test]
fn models_run_no_solver_and_read_no_files() {
    let forbidden = ["pipeline", "gmsh", "freefem", "study", "bench", "hard"];
    let violations = only_imports(
        "models/",
        &[
            "error",
            "mesh",
            "quadrature",
            "space",
            "assembly",
            "linalg",
            "scene",
            "expression",
            "solvers",
            "output",
            "plot",
            "models",
        ],
    );
    assert_none("models/ sit below the pipeline", violations);
    for (rel, text) in sources() {
        if rel.starts_with("models/") {
            for m in forbidden {
                assert!(!text.contains(&format!("crate::{m}")), "src/{rel} uses {m}");
            }
        }
    }
}

#[test]
fn hdf5_and_subprocesses_stay_in_their_modules() {
    let mut violations = Vec::new();
    for (rel, text) in sources() {
        let code = non_test_code(&text);
        if code.contains("hdf5::") && !rel.starts_with("output/") {
            violations.push(format!("src/{rel} uses hdf5 (only output/ may)"));
        }
        let runs = code.contains("Command::new");
        if runs && !["gmsh.rs", "freefem.rs", "bench.rs"].contains(&rel.as_str()) {
            violations.push(format!(
                "src/{rel} starts a subprocess (only gmsh.rs, freefem.rs, bench.rs may)"
            ));
        }
    }
    assert_none("HDF5 and subprocesses", violations);
}

#[test]
fn linear_solves_go_through_the_seam() {
    let direct = ["ReusableFactorization", "factorize_checked", "set_threads"];
    let mut violations = Vec::new();
    for (rel, text) in sources() {
        if rel.starts_with("linalg") {
            continue;
        }
        let code: String = non_test_code(&text)
            .lines()
            .filter(|l| !l.trim_start().starts_with("//"))
            .collect();
        for name in direct {
            if code.contains(name) {
                violations.push(format!(
                    "src/{rel} names {name} (factorise through linalg::analyse or factor_once)"
                ));
            }
        }
    }
    assert_none("the linear-solver seam", violations);
}
