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
        "scene/ imports only error, names, expression and the solver vocabulary",
        only_imports("scene/", &["error", "names", "expression", "solvers"]),
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
    assert_none(
        "linalg knows no finite elements",
        only_imports("linalg/", &["error", "linalg"]),
    );
    assert_none(
        "mesh/ does not run gmsh",
        only_imports("mesh/", &["error", "output"]),
    );
    assert_none(
        "multigrid/ builds prolongations from meshes and spaces; its V-cycle is linalg's",
        only_imports(
            "multigrid/",
            &["error", "mesh", "quadrature", "space", "assembly", "linalg"],
        ),
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
        only_imports("plot/", &["error", "mesh", "solvers", "output", "numbers"]),
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
            "multigrid",
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
        if runs && !["gmsh.rs", "freefem.rs", "bench/child.rs"].contains(&rel.as_str()) {
            violations.push(format!(
                "src/{rel} starts a subprocess (only gmsh.rs, freefem.rs, bench/child.rs may)"
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

/// The module of a file under `src/` ("output::xdmf"; `mod.rs` is its
/// folder's module, `scene.rs` the module `scene`).
fn module_of(rel: &str) -> String {
    let path = rel.trim_end_matches(".rs").trim_end_matches("/mod");
    path.replace('/', "::")
}

/// The paths (segments after `crate::` or `super::`, `use` groups
/// expanded) that a file's code names.
fn named_paths(code: &str) -> Vec<(bool, Vec<String>)> {
    fn ident(s: &[u8], i: &mut usize) -> Option<String> {
        let start = *i;
        while *i < s.len() && (s[*i].is_ascii_alphanumeric() || s[*i] == b'_') {
            *i += 1;
        }
        (*i > start).then(|| String::from_utf8_lossy(&s[start..*i]).into_owned())
    }
    /// The paths from `i` on, each starting with `prefix`.
    fn paths(s: &[u8], i: &mut usize, prefix: Vec<String>, out: &mut Vec<Vec<String>>) {
        let mut segments = prefix;
        loop {
            if s.get(*i) != Some(&b'{') {
                match ident(s, i) {
                    Some(name) => segments.push(name),
                    None => break,
                }
                if !s[*i..].starts_with(b"::") {
                    break;
                }
                *i += 2;
            }
            if s.get(*i) == Some(&b'{') {
                *i += 1;
                loop {
                    while *i < s.len() && (s[*i] as char).is_whitespace() {
                        *i += 1;
                    }
                    paths(s, i, segments.clone(), out);
                    // Skip `as name`, `*` and the like up to the next item.
                    let mut depth = 0;
                    while *i < s.len() {
                        match s[*i] {
                            b'{' => depth += 1,
                            b'}' if depth == 0 => break,
                            b'}' => depth -= 1,
                            b',' if depth == 0 => break,
                            _ => {}
                        }
                        *i += 1;
                    }
                    if *i >= s.len() || s[*i] == b'}' {
                        *i += 1;
                        return;
                    }
                    *i += 1;
                }
            }
        }
        out.push(segments);
    }
    let code: String = code
        .lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n");
    let s = code.as_bytes();
    let mut found = Vec::new();
    for (marker, from_crate) in [("crate::", true), ("super::", false)] {
        for (k, _) in code.match_indices(marker) {
            // `$crate::` in macros and paths like `foo::crate::` are not ours.
            if k > 0 && (s[k - 1].is_ascii_alphanumeric() || s[k - 1] == b'_' || s[k - 1] == b'$') {
                continue;
            }
            let mut i = k + marker.len();
            let mut out = Vec::new();
            paths(s, &mut i, Vec::new(), &mut out);
            found.extend(out.into_iter().map(|p| (from_crate, p)));
        }
    }
    found
}

/// No module imports, through others, a module that imports it: the module
/// graph of `src/` (a module and its own submodules apart) has no cycle.
#[test]
fn the_module_graph_has_no_cycles() {
    let files: Vec<(String, String)> = sources()
        .into_iter()
        .filter(|(rel, _)| rel != "lib.rs" && rel != "main.rs")
        .collect();
    let modules: Vec<String> = files.iter().map(|(rel, _)| module_of(rel)).collect();
    let within = |a: &str, b: &str| a == b || a.starts_with(&format!("{b}::"));
    let mut edges: std::collections::BTreeMap<String, std::collections::BTreeSet<String>> =
        Default::default();
    for ((_, text), module) in files.iter().zip(&modules) {
        for (from_crate, path) in named_paths(non_test_code(text)) {
            let mut full: Vec<String> = match from_crate {
                true => Vec::new(),
                false => module.split("::").map(String::from).collect(),
            };
            if !from_crate {
                full.pop();
            }
            full.extend(path);
            // The longest prefix that is a module.
            let target = (1..=full.len())
                .rev()
                .map(|k| full[..k].join("::"))
                .find(|m| modules.contains(m));
            if let Some(target) = target {
                if !within(module, &target) && !within(&target, module) {
                    edges.entry(module.clone()).or_default().insert(target);
                }
            }
        }
    }
    // Depth-first search; a back edge closes a cycle.
    fn visit(
        m: &str,
        edges: &std::collections::BTreeMap<String, std::collections::BTreeSet<String>>,
        state: &mut std::collections::BTreeMap<String, u8>,
        stack: &mut Vec<String>,
        cycles: &mut Vec<String>,
    ) {
        state.insert(m.to_string(), 1);
        stack.push(m.to_string());
        for next in edges.get(m).into_iter().flatten() {
            match state.get(next.as_str()).copied().unwrap_or(0) {
                0 => visit(next, edges, state, stack, cycles),
                1 => {
                    let from = stack.iter().position(|s| s == next).unwrap();
                    let mut cycle = stack[from..].to_vec();
                    cycle.push(next.clone());
                    cycles.push(cycle.join(" → "));
                }
                _ => {}
            }
        }
        stack.pop();
        state.insert(m.to_string(), 2);
    }
    let mut state = std::collections::BTreeMap::new();
    let mut cycles = Vec::new();
    for m in &modules {
        if !state.contains_key(m.as_str()) {
            visit(m, &edges, &mut state, &mut Vec::new(), &mut cycles);
        }
    }
    assert!(
        edges.get("pipeline").is_some_and(|e| e.contains("solvers")),
        "the graph is read (pipeline → solvers): {edges:?}"
    );
    assert_none("modules importing each other", cycles);
}
