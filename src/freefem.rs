//! The FreeFEM twin of a scene: `freefem/membrane-obstacle.edp`,
//! `freefem/naghdi-contact.edp` (shell element `p1b-p0`) or
//! `freefem/naghdi-psri.edp` (the shell's PSRI element) run on the very
//! mesh file the Rust run uses, with every parameter taken from the scene and
//! passed on the command line (`getARGV`), and its text output converted to a
//! docs/formulation.md §5 result file with the field and dof names of the Rust run (so
//! `obstacle info` and `obstacle compare` read both alike).
//!
//! The PSRI script takes its boundary conditions as
//! `-fix "LABEL:u1,u2,…;…"` (whole labels, per field): [`psri_fix_spec`]
//! translates the scene's `shell.clamped` and `[[shell.boundary]]` into it,
//! and refuses what that cannot express (a symmetry plane whose fixed θ
//! component changes along the part).
//!
//! The scripts run Uzawa only. How a scene's stop maps (see [`uzawa_plan`]):
//! `--iterations K` runs exactly K iterations; otherwise `stop = "thesis"`
//! runs the scene's thesis criterion (‖λ^k − λ^{k−1}‖ < thesis_tol in
//! `dual_norm`, at most max_iter iterations), as Rust does; `stop = "kkt"`
//! (FreeFEM does not compute the KKT measures) runs exactly
//! min(max_iter, [`KKT_FIXED_ITERATIONS`]) iterations. `alpha = "auto"` is
//! resolved by the Rust Lanczos estimate (the number the Rust run uses).
//!
//! The helpers that run FreeFEM and read its text files are public: the
//! FreeFEM tests use the same code.

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use crate::models::naghdi::forms::{psri_weight, FieldRole, ShellElementKind, ShellLayout};
use crate::models::naghdi::geometry::Chart;
use crate::models::{self, named_boundary_tags, FreefemTwin};
use crate::output::{write_result, AttrValue, OutputTransaction, ResultData};
use crate::pipeline::scene_mesh;
use crate::scene::{
    Alpha, BoundaryCondition, ContactMultiplier, ElementPair, Expression, ObstacleShape, Scene,
    ShellSpec, StepForm, StopRule,
};
use crate::solvers::uzawa::uzawa_alpha_of;
use crate::solvers::{ContactProblem, SolveReport};
use crate::space::{Element, Space};
use crate::subprocess::{output_with_timeout, RunError};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Instant;

/// The FreeFEM executable.
pub const FREEFEM: &str = "FreeFem++";
/// Where Debian's FreeFEM plugins (gmsh reader) live; `FF_LOADPATH` overrides.
pub const DEFAULT_LOADPATH: &str = "/usr/lib/freefem++";
/// Iterations run for a scene that stops on the KKT measures (FreeFEM has none).
pub const KKT_FIXED_ITERATIONS: usize = 1000;
/// The algorithm name written to `/solver`.
pub const ALGORITHM: &str = "uzawa (FreeFEM)";

/// The folder of the FreeFEM scripts: `$OBSTACLE_FREEFEM_DIR`, else the
/// crate's `freefem/`.
pub fn script_dir() -> PathBuf {
    std::env::var_os("OBSTACLE_FREEFEM_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("freefem"))
}

/// The FreeFEM twin of a scene's model and element
/// ([`ModelKind::freefem_twin`](crate::models::ModelKind::freefem_twin)).
fn twin_of(scene: &Scene) -> Result<FreefemTwin> {
    models::kind(scene.model)
        .freefem_twin(scene.element)
        .ok_or_else(|| {
            scene.error(
                "model",
                format!("the model \"{}\" has no FreeFEM twin", scene.model.name()),
            )
        })
}

/// The script of a scene: its twin's file in [`script_dir`].
pub fn script_for_scene(scene: &Scene) -> Result<PathBuf> {
    Ok(script_dir().join(match twin_of(scene)? {
        FreefemTwin::Membrane => "membrane-obstacle.edp",
        FreefemTwin::ShellThesis => "naghdi-contact.edp",
        FreefemTwin::ShellPsri => PSRI_SCRIPT,
    }))
}

/// The FreeFEM twin of the shell's PSRI element.
pub const PSRI_SCRIPT: &str = "naghdi-psri.edp";

fn tool_error(script: &Path, reason: impl Into<String>) -> Error {
    Error::Tool {
        tool: format!("{FREEFEM} {}", script.display()),
        reason: reason.into(),
    }
}

/// The last `n` lines of a process output.
fn tail(bytes: &[u8], n: usize) -> String {
    let text = String::from_utf8_lossy(bytes);
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(n)..].join("\n")
}

/// Runs `FF_LOADPATH=… FreeFem++ -nw -v 0 SCRIPT ARGS` (single-threaded BLAS,
/// so timings compare with the Rust side). Returns the output and the wall
/// time of the whole process. A missing FreeFEM or gmsh plugin is an
/// [`Error::Tool`]; a failing script is not (see [`run_script_checked`]).
pub fn run_script(script: &Path, args: &[String]) -> Result<(Output, f64)> {
    let loadpath = std::env::var("FF_LOADPATH").unwrap_or_else(|_| DEFAULT_LOADPATH.into());
    let plugin = Path::new(&loadpath).join("gmsh.so");
    if !plugin.is_file() {
        return Err(tool_error(
            script,
            format!(
                "FreeFEM's gmsh plugin {} is missing (Debian package libfreefem++; `make deps`)",
                plugin.display()
            ),
        ));
    }
    let start = Instant::now();
    let out = output_with_timeout(
        Command::new(FREEFEM)
            .env("FF_LOADPATH", &loadpath)
            .env("OPENBLAS_NUM_THREADS", "1")
            .env("OMP_NUM_THREADS", "1")
            .args(["-nw", "-v", "0"])
            .arg(script)
            .args(args),
    )
    .map_err(|e| match e {
        RunError::Spawn(e) => tool_error(
            script,
            format!("cannot run {FREEFEM} ({e}): install the Debian packages freefem++ libfreefem++ (`make deps`)"),
        ),
        e => tool_error(script, e.describe(FREEFEM)),
    })?;
    Ok((out, start.elapsed().as_secs_f64()))
}

/// [`run_script`], and an [`Error::Tool`] naming the script and the tail of
/// its output when it fails.
pub fn run_script_checked(script: &Path, args: &[String]) -> Result<f64> {
    let (out, seconds) = run_script(script, args)?;
    if !out.status.success() {
        return Err(tool_error(
            script,
            format!(
                "failed ({}); stderr tail:\n{}\nstdout tail:\n{}",
                out.status,
                tail(&out.stderr, 15),
                tail(&out.stdout, 15)
            ),
        ));
    }
    Ok(seconds)
}

/// A text file of whitespace-separated numbers.
pub fn read_numbers(path: &Path) -> Result<Vec<f64>> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::output(path, format!("cannot read: {e}")))?;
    text.split_whitespace()
        .map(|s| {
            s.parse::<f64>()
                .map_err(|e| Error::output(path, format!("bad number {s:?}: {e}")))
        })
        .collect()
}

/// A `PREFIX.info.txt` file: "key value" lines.
#[derive(Debug, Clone)]
pub struct Info {
    pub path: PathBuf,
    pub values: HashMap<String, String>,
}

impl Info {
    pub fn read(path: &Path) -> Result<Info> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| Error::output(path, format!("cannot read: {e}")))?;
        let values = text
            .lines()
            .filter_map(|l| l.split_once(' '))
            .map(|(k, v)| (k.to_string(), v.trim().to_string()))
            .collect();
        Ok(Info {
            path: path.to_path_buf(),
            values,
        })
    }
    pub fn text(&self, key: &str) -> Result<&str> {
        self.values
            .get(key)
            .map(String::as_str)
            .ok_or_else(|| Error::output(&self.path, format!("has no `{key}`")))
    }
    pub fn f64(&self, key: &str) -> Result<f64> {
        let v = self.text(key)?;
        v.parse()
            .map_err(|e| Error::output(&self.path, format!("`{key}`: bad number {v:?}: {e}")))
    }
    pub fn usize(&self, key: &str) -> Result<usize> {
        let v = self.text(key)?;
        v.parse()
            .map_err(|e| Error::output(&self.path, format!("`{key}`: bad count {v:?}: {e}")))
    }
}

/// A mesh as FreeFEM listed it: vertices and triangles.
pub type MeshText = (Vec<[f64; 2]>, Vec<[usize; 3]>);

/// `PREFIX.mesh.txt`: "nv nt", nv lines "x y", nt lines "a b c" (zero-based).
pub fn read_mesh_text(path: &Path) -> Result<MeshText> {
    let v = read_numbers(path)?;
    let bad = || {
        Error::output(
            path,
            "not a FreeFEM mesh listing \"nv nt\", vertices, triangles",
        )
    };
    if v.len() < 2 {
        return Err(bad());
    }
    let (nv, nt) = (v[0] as usize, v[1] as usize);
    if v.len() != 2 + 2 * nv + 3 * nt {
        return Err(bad());
    }
    let verts = (0..nv).map(|i| [v[2 + 2 * i], v[3 + 2 * i]]).collect();
    let o = 2 + 2 * nv;
    let tris = (0..nt)
        .map(|t| std::array::from_fn(|j| v[o + 3 * t + j] as usize))
        .collect();
    Ok((verts, tris))
}

/// Checks that FreeFEM read `mesh` in our order: same vertices (to 1e-15
/// relative to the mesh size), same triangles with the same vertex order.
pub fn check_mesh_order(mesh: &Mesh, path: &Path) -> Result<()> {
    let (verts, tris) = read_mesh_text(path)?;
    let fail = |r: String| Error::mesh(&mesh.source, format!("FreeFEM ({}) {r}", path.display()));
    if verts.len() != mesh.n_vertices() || tris.len() != mesh.n_triangles() {
        return Err(fail(format!(
            "read {} vertices and {} triangles, the Rust mesh has {} and {}",
            verts.len(),
            tris.len(),
            mesh.n_vertices(),
            mesh.n_triangles()
        )));
    }
    let scale = mesh
        .vertices
        .iter()
        .fold(1.0f64, |m, v| m.max(v[0].abs()).max(v[1].abs()));
    for (i, (a, b)) in verts.iter().zip(&mesh.vertices).enumerate() {
        if (a[0] - b[0]).abs() > 1e-15 * scale || (a[1] - b[1]).abs() > 1e-15 * scale {
            return Err(fail(format!(
                "vertex {i} is {a:?}, Rust has {b:?}: the vertex orders differ"
            )));
        }
    }
    if let Some(t) = (0..tris.len()).find(|&t| tris[t] != mesh.triangles[t]) {
        return Err(fail(format!(
            "triangle {t} is {:?}, Rust has {:?}: the triangle (or in-triangle vertex) orders differ",
            tris[t], mesh.triangles[t]
        )));
    }
    Ok(())
}

/// How the FreeFEM Uzawa iteration runs for a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct UzawaPlan {
    pub alpha: f64,
    pub step_form: StepForm,
    /// Exactly this many iterations, or at most this many with `thesis_tol`.
    pub iterations: usize,
    /// Some((tol, "l2"|"inf")): stop on the thesis criterion.
    pub thesis_stop: Option<(f64, &'static str)>,
}

/// The Uzawa iteration FreeFEM runs for `scene` (module docs); `alpha` is the
/// resolved step.
pub fn uzawa_plan(scene: &Scene, alpha: f64, iterations: Option<usize>) -> UzawaPlan {
    let s = &scene.solver;
    let max_iter = s.max_iter.max(1) as usize;
    let (iterations, thesis_stop) = match (iterations, s.stop) {
        (Some(k), _) => (k, None),
        (None, StopRule::Thesis) => (
            max_iter,
            Some((
                s.thesis_tol,
                match s.dual_norm {
                    crate::scene::DualNorm::L2 => "l2",
                    crate::scene::DualNorm::Inf => "inf",
                },
            )),
        ),
        (None, StopRule::Kkt) => (max_iter.min(KKT_FIXED_ITERATIONS), None),
    };
    UzawaPlan {
        alpha,
        step_form: s.step_form.unwrap_or(StepForm::Mean),
        iterations,
        thesis_stop,
    }
}

/// The scene's α; "auto" is the Rust run's choice, 2/(s_max + s_min) capped
/// at 1.9/s_max from 50 Lanczos steps on the Rust-assembled `problem`. A scene
/// without a step (an active-set or dual-accelerated scene: the twin runs
/// Uzawa whatever the scene's method) gets "auto".
pub fn resolve_alpha(scene: &Scene, problem: &ContactProblem) -> Result<f64> {
    let solver = &scene.solver;
    if let (None, Some(Alpha::Value(a))) = (solver.alpha_factor, solver.alpha) {
        return Ok(a);
    }
    // α = auto or alpha_factor × 2/s_max: the Rust run's rule and Lanczos estimate.
    uzawa_alpha_of(
        problem,
        crate::pipeline::uzawa_step(solver),
        solver.step_form.unwrap_or(StepForm::Mean),
        &crate::pipeline::linear_options(solver),
    )
}

/// The script's command line for `scene` (mesh file, data, Uzawa plan);
/// `mesh` is the mesh read from `msh` (the PSRI element's boundary parts).
pub fn script_args(
    scene: &Scene,
    mesh: &Mesh,
    msh: &Path,
    plan: Option<&UzawaPlan>,
    prefix: &Path,
) -> Result<Vec<String>> {
    let f = |x: f64| format!("{x:e}");
    let mut a: Vec<String> = vec!["-mesh".into(), msh.display().to_string()];
    if scene.element == ElementPair::P2bMitc {
        return Err(scene.error(
            "element",
            "the FreeFEM twins are p1b-p0 and p2b-psri; p2b-mitc has none (docs/shell-benchmarks.md says what it is compared with)",
        ));
    }
    if scene.mesh.dirichlet.is_some() {
        return Err(scene.error(
            "mesh.dirichlet",
            "the FreeFEM script clamps the whole boundary: remove the key to compare",
        ));
    }
    match twin_of(scene)? {
        FreefemTwin::Membrane => {
            let Some(obstacle) = &scene.obstacle else {
                return Err(
                    scene.error("obstacle", "the FreeFEM membrane script needs an obstacle")
                );
            };
            // An expression load or obstacle reaches the script as `func`s
            // (`scene_functions`); -g, -height, -curvature stay its defaults.
            let g = scene
                .load
                .as_ref()
                .and_then(|l| l.g.as_ref())
                .map_or(Some(0.0), Expression::as_constant)
                .unwrap_or(0.0);
            if let Some(g_d) = &scene.mesh.dirichlet_value {
                if g_d.as_constant() != Some(0.0) {
                    return Err(scene.error(
                        "mesh.dirichlet_value",
                        "the FreeFEM membrane script holds u = 0 on the boundary: remove the key to compare",
                    ));
                }
            }
            a.extend([
                "-element".into(),
                scene.element.name().into(),
                "-g".into(),
                f(g),
                "-height".into(),
                f(obstacle.level()),
                "-curvature".into(),
                f(obstacle.curvature.unwrap_or(0.0)),
            ]);
        }
        FreefemTwin::ShellPsri => {
            a.extend(psri_args(scene, mesh)?);
        }
        FreefemTwin::ShellThesis => {
            let shell = scene.shell.as_ref().expect("validated: naghdi has [shell]");
            let Chart::HyperbolicParaboloid { r, offset } = shell.chart else {
                return Err(scene.error(
                    "shell.chart",
                    format!(
                        "the FreeFEM script has the hyperbolic-paraboloid chart only, not {}",
                        shell.chart.kind()
                    ),
                ));
            };
            if shell.clamped.is_some() {
                return Err(scene.error(
                    "shell.clamped",
                    "the FreeFEM script clamps the whole boundary: remove the key to compare",
                ));
            }
            if scene.load.as_ref().is_some_and(|l| !l.edge.is_empty()) {
                return Err(scene.error("load.edge", "the FreeFEM script has no edge loads"));
            }
            if scene
                .obstacle
                .as_ref()
                .is_some_and(|o| o.multiplier == Some(ContactMultiplier::P1))
            {
                return Err(scene.error(
                    "obstacle.multiplier",
                    "the FreeFEM script has P0 contact multipliers only (multiplier = \"p0\", the default)",
                ));
            }
            a.extend([
                "-R".into(),
                f(r),
                "-offset".into(),
                f(offset),
                "-rho".into(),
                f(shell.rho.unwrap_or(0.0)),
            ]);
            a.extend(material_and_load_args(scene, shell)?);
            a.extend(plane_level_args(scene)?);
        }
    }
    match plan {
        Some(p) => {
            a.extend([
                "-alpha".into(),
                f(p.alpha),
                "-stepform".into(),
                match p.step_form {
                    StepForm::Mean => "mean",
                    StepForm::Integral => "integral",
                }
                .into(),
                "-iterations".into(),
                p.iterations.to_string(),
            ]);
            if let Some((tol, norm)) = p.thesis_stop {
                a.extend(["-thesistol".into(), f(tol), "-dualnorm".into(), norm.into()]);
            }
        }
        None => a.extend(["-iterations".into(), "0".into()]),
    }
    a.extend(["-out".into(), prefix.display().to_string()]);
    Ok(a)
}

/// The data options of `naghdi-psri.edp` for a PSRI scene: spaces, weight rule, chart,
/// material, body force, `-fix` ([`psri_fix_spec`]) and the plane's level.
fn psri_args(scene: &Scene, mesh: &Mesh) -> Result<Vec<String>> {
    let f = |x: f64| format!("{x:e}");
    let shell = scene.shell.as_ref().expect("validated: naghdi has [shell]");
    let spaces = PsriSpaces::of(mesh);
    let rule = psri_weight_rule(scene, mesh, shell.thickness)?;
    if let Some(load) = &scene.load {
        for (key, given) in [
            ("load.edge", !load.edge.is_empty()),
            ("load.pressure", load.pressure.is_some()),
            ("load.point", !load.point.is_empty()),
        ] {
            if given {
                return Err(scene.error(
                    key,
                    format!("the FreeFEM script {PSRI_SCRIPT} has constant body forces only, not `{key}`"),
                ));
            }
        }
    }
    let (chart, params): (&str, Vec<(&str, f64)>) = match shell.chart {
        Chart::HyperbolicParaboloid { r, offset } => {
            ("hypar", vec![("-R", r), ("-offset", offset)])
        }
        Chart::Plate { height } => ("plate", vec![("-height", height)]),
        Chart::Cylinder { radius, height } => {
            ("cylinder", vec![("-R", radius), ("-height", height)])
        }
        Chart::CurvatureKink { r, offset } => ("kink", vec![("-R", r), ("-offset", offset)]),
        Chart::Sphere { .. } | Chart::Cone { .. } | Chart::Parametric(_) | Chart::Graph(_) => {
            ("parametric", vec![])
        }
    };
    let mut a: Vec<String> = vec![
        format!("-DUSPACE={}", spaces.u.tag()),
        format!("-DTSPACE={}", spaces.theta.tag()),
        "-psriweight".into(),
        rule.name().into(),
        "-element".into(),
        scene.element.name().into(),
        "-chart".into(),
        chart.into(),
    ];
    for (key, value) in params {
        a.extend([key.into(), f(value)]);
    }
    a.extend(material_and_load_args(scene, shell)?);
    let fix = psri_fix_spec(scene, mesh)?;
    if !fix.is_empty() {
        a.extend(["-fix".into(), fix]);
    }
    a.extend(plane_level_args(scene)?);
    Ok(a)
}

/// `-E -nu -eps` and the body force `-f1 -f2 -f3` of a shell scene, as both
/// shell scripts take them.
fn material_and_load_args(scene: &Scene, shell: &ShellSpec) -> Result<Vec<String>> {
    let f = scene.load.as_ref().and_then(|l| l.f.as_ref());
    let mut load = [0.0; 3];
    for (c, value) in load.iter_mut().enumerate() {
        *value = constant_only(scene, &format!("load.f[{c}]"), f.map(|f| &f[c]))?;
    }
    Ok([
        ("-E", shell.young),
        ("-nu", shell.poisson),
        ("-eps", shell.thickness),
        ("-f1", load[0]),
        ("-f2", load[1]),
        ("-f3", load[2]),
    ]
    .into_iter()
    .flat_map(|(key, value)| [key.to_string(), format!("{value:e}")])
    .collect())
}

/// The `func`s of a membrane scene with expressions, in FreeFEM's syntax, for
/// the script's "scene functions" block; None when the script's defaults
/// (constant g, the paraboloid) are the scene.
fn scene_functions(scene: &Scene) -> Option<String> {
    if let Some(shell) = &scene.shell {
        return chart_functions(&shell.chart);
    }
    let g = scene.load.as_ref().and_then(|l| l.g.as_ref());
    let obstacle = scene.obstacle.as_ref()?;
    let expression_load = g.is_some_and(|g| g.as_constant().is_none());
    let membrane =
        models::kind(scene.model).freefem_twin(scene.element) == Some(FreefemTwin::Membrane);
    if !membrane || (obstacle.lower.is_none() && !expression_load) {
        return None;
    }
    let mut text = match g {
        Some(g) => format!("func gFun = {};\n", g.freefem()),
        None => "func gFun = 0.;\n".to_string(),
    };
    match &obstacle.lower {
        Some(lower) => text.push_str(&format!("func phi = {};\n", lower.freefem())),
        None => text.push_str("func phi = height - curvature * (x^2 + y^2);\n"),
    }
    match &obstacle.upper {
        Some(upper) => text.push_str(&format!(
            "func phiUpper = {};\nbool twoSided = true;\n",
            upper.freefem()
        )),
        None => text.push_str("func phiUpper = 0.;\nbool twoSided = false;\n"),
    }
    Some(text)
}

/// The `func`s of a chart the shell script takes as `-chart parametric`: φ_z
/// and the exact first and second derivatives of φ, in FreeFEM's syntax (the
/// parametric and graph charts' expressions and their symbolic derivatives;
/// the sphere and cone presets spelled as parametric charts). None for the
/// presets the script has built in.
fn chart_functions(chart: &Chart) -> Option<String> {
    let spelled;
    let e = match chart {
        Chart::Sphere { radius, height } => {
            let r = format!("{radius:e}");
            spelled = Chart::parametric([
                &format!("{r}*cos(y)*cos(x)"),
                &format!("{r}*cos(y)*sin(x)"),
                &format!("{height:e} + {r}*sin(y)"),
            ]);
            spelled.as_ref().ok()?.expressions()?
        }
        Chart::Cone { half_angle, height } => {
            let (s, c) = half_angle.sin_cos();
            spelled = Chart::parametric([
                &format!("x*{s:e}*cos(y)"),
                &format!("x*{s:e}*sin(y)"),
                &format!("{height:e} + x*{c:e}"),
            ]);
            spelled.as_ref().ok()?.expressions()?
        }
        chart => chart.expressions()?,
    };
    let mut text = format!(
        "func parZ = {};
",
        e.phi[2].freefem()
    );
    for (name, k) in [("A1", 0), ("A2", 1)] {
        for (c, axis) in ["x", "y", "z"].into_iter().enumerate() {
            text.push_str(&format!(
                "func par{name}{axis} = {};
",
                e.d[c][k].freefem()
            ));
        }
    }
    for (name, k) in [("D11", 0), ("D12", 1), ("D22", 2)] {
        for (c, axis) in ["x", "y", "z"].into_iter().enumerate() {
            text.push_str(&format!(
                "func par{name}{axis} = {};
",
                e.dd[c][k].freefem()
            ));
        }
    }
    Some(text)
}

/// A copy of `script` in `folder` whose "scene functions" block (between its
/// `// BEGIN scene functions` and `// END scene functions` lines) is `functions`.
fn with_scene_functions(script: &Path, functions: &str, folder: &Path) -> Result<PathBuf> {
    let text = std::fs::read_to_string(script)
        .map_err(|e| tool_error(script, format!("cannot read: {e}")))?;
    let (Some(begin), Some(end)) = (
        text.find("// BEGIN scene functions"),
        text.find("// END scene functions"),
    ) else {
        return Err(tool_error(
            script,
            "has no `// BEGIN scene functions` … `// END scene functions` block for the scene's expressions",
        ));
    };
    let copy = folder.join(script.file_name().unwrap_or_default());
    let body = format!("{}{functions}{}", &text[..begin], &text[end..]);
    std::fs::write(&copy, body).map_err(|e| Error::output(&copy, format!("cannot write: {e}")))?;
    Ok(copy)
}

/// A scene value the FreeFEM scripts take as a number (0 when absent).
fn constant_only(scene: &Scene, key: &str, value: Option<&Expression>) -> Result<f64> {
    match value {
        None => Ok(0.0),
        Some(e) => e.as_constant().ok_or_else(|| {
            scene.error(
                key,
                format!(
                    "the FreeFEM script takes a number here, not the expression \"{}\"",
                    e.text()
                ),
            )
        }),
    }
}

/// `-level Z` of a shell scene's rigid plane (nothing without an obstacle).
fn plane_level_args(scene: &Scene) -> Result<Vec<String>> {
    match &scene.obstacle {
        None => Ok(Vec::new()),
        Some(o) if o.shape != ObstacleShape::RigidPlane => {
            Err(scene.error("obstacle.shape", "the shell's obstacle is the rigid plane"))
        }
        Some(o) => Ok(vec!["-level".into(), format!("{:e}", o.level())]),
    }
}

/// The spaces of u and θ of the PSRI element (the Rust layout's).
#[derive(Debug, Clone, Copy)]
struct PsriSpaces {
    u: Element,
    theta: Element,
}

impl PsriSpaces {
    fn of(mesh: &Mesh) -> PsriSpaces {
        let layout = ShellLayout::for_element(mesh, PSRI_KIND);
        let element = |role| {
            let f = layout.field_of(role).expect("the PSRI layout has u and θ");
            layout.fields[f].element
        };
        PsriSpaces {
            u: element(FieldRole::Displacement(0)),
            theta: element(FieldRole::TangentRotation(0)),
        }
    }
}

/// The shell element kind `naghdi-psri.edp` twins.
const PSRI_KIND: ShellElementKind = ShellElementKind::P2bPsri;

/// The rules of the PSRI weight α the script knows (`-psriweight`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PsriWeightRule {
    /// α = min(1, ε²/ℓ²), ℓ the diagonal of the mesh's bounding box.
    Diameter,
    /// α_T = min(1, ε²/h_T²), h_T the longest edge of T.
    Triangle,
}

impl PsriWeightRule {
    fn name(self) -> &'static str {
        match self {
            PsriWeightRule::Diameter => "diameter",
            PsriWeightRule::Triangle => "triangle",
        }
    }

    fn weight(self, mesh: &Mesh, t: usize, thickness: f64) -> f64 {
        let length = match self {
            PsriWeightRule::Diameter => {
                let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
                for v in &mesh.vertices {
                    for k in 0..2 {
                        lo[k] = lo[k].min(v[k]);
                        hi[k] = hi[k].max(v[k]);
                    }
                }
                (hi[0] - lo[0]).hypot(hi[1] - lo[1])
            }
            PsriWeightRule::Triangle => {
                let v = mesh.triangles[t].map(|i| mesh.vertices[i]);
                (0..3)
                    .map(|i| (v[i][0] - v[(i + 1) % 3][0]).hypot(v[i][1] - v[(i + 1) % 3][1]))
                    .fold(0.0, f64::max)
            }
        };
        (thickness * thickness / (length * length)).min(1.0)
    }
}

/// The PSRI weight of every triangle, as the Rust assembly takes it
/// (forms.rs `psri_weight`).
fn rust_psri_weights(mesh: &Mesh, thickness: f64) -> Vec<f64> {
    (0..mesh.n_triangles())
        .map(|t| psri_weight(mesh, t, thickness))
        .collect()
}

/// Whether two weights agree to round-off.
fn same_weight(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * a.abs().max(b.abs())
}

/// The script's rule that gives the Rust weights on this mesh.
fn psri_weight_rule(scene: &Scene, mesh: &Mesh, thickness: f64) -> Result<PsriWeightRule> {
    let rust = rust_psri_weights(mesh, thickness);
    [PsriWeightRule::Diameter, PsriWeightRule::Triangle]
        .into_iter()
        .find(|rule| {
            rust.iter()
                .enumerate()
                .all(|(t, &w)| same_weight(w, rule.weight(mesh, t, thickness)))
        })
        .ok_or_else(|| {
            scene.error(
                "element",
                format!(
                    "the Rust PSRI weight (forms.rs psri_weight) follows neither rule of {PSRI_SCRIPT} (-psriweight diameter, triangle)"
                ),
            )
        })
}

/// The fields of the PSRI element in `-fix` (and Rust's field names).
const PSRI_FIELDS: [&str; 5] = ["u1", "u2", "u3", "theta1", "theta2"];

/// The scene's boundary conditions for `naghdi-psri.edp`'s `-fix`:
/// `"TAG:field,…;TAG:field,…"`, one item per boundary part (physical tag)
/// with a fixed field, the fields in `u1, u2, u3, theta1, theta2` order. As
/// `NaghdiSystem::setup` resolves them: `shell.clamped` (default: all of
/// ∂ω when no `[[shell.boundary]]` is given) fixes all five fields; simply
/// supported u1, u2, u3; a diaphragm with normal e_n the u_c with c ≠ n;
/// fixed the named fields; free nothing; a symmetry plane with normal e_n
/// fixes u_n and the θ^β whose a_β leaves the plane, which `-fix` states
/// only when that is the same component at every node of the part (plate,
/// cylinder lines): otherwise, and where neither tangent lies in the plane,
/// an error names the part.
pub fn psri_fix_spec(scene: &Scene, mesh: &Mesh) -> Result<String> {
    let shell = scene.shell.as_ref().expect("validated: naghdi has [shell]");
    let mut fixed: BTreeMap<i32, BTreeSet<usize>> = BTreeMap::new();
    let all = 0..PSRI_FIELDS.len();
    match &shell.clamped {
        None if shell.boundary.is_empty() => {
            for e in &mesh.boundary_edges {
                fixed.entry(e.tag).or_default().extend(all.clone());
            }
        }
        None => {}
        Some(names) => {
            let tags = named_boundary_tags(mesh, scene, "shell.clamped", Some(names))?
                .expect("names given");
            for tag in tags {
                fixed.entry(tag).or_default().extend(all.clone());
            }
        }
    }
    for (i, b) in shell.boundary.iter().enumerate() {
        let field = format!("shell.boundary[{i}]");
        let tag = named_boundary_tags(
            mesh,
            scene,
            &format!("{field}.part"),
            Some(std::slice::from_ref(&b.part)),
        )?
        .expect("one name given")[0];
        if b.normal.is_some_and(|n| n.axis().is_none()) {
            return Err(scene.error(&format!("{field}.normal"),
                format!("the FreeFEM twin {PSRI_SCRIPT} fixes fields on whole boundary parts (-fix) and cannot state a symmetry plane of oblique normal"),
            ));
        }
        let n = b
            .normal
            .and_then(crate::scene::PlaneNormal::axis)
            .map(|a| a.index());
        let fields: Vec<usize> = match b.condition {
            BoundaryCondition::Clamped => all.clone().collect(),
            BoundaryCondition::SimplySupported => vec![0, 1, 2],
            BoundaryCondition::Diaphragm => (0..3).filter(|&c| Some(c) != n).collect(),
            BoundaryCondition::Free => Vec::new(),
            BoundaryCondition::Symmetry => {
                let Some(n) = n else {
                    return Err(scene.error(
                        &format!("{field}.normal"),
                        "a symmetry plane needs its normal",
                    ));
                };
                let mut f = vec![n];
                f.extend(symmetry_rotations(
                    scene,
                    mesh,
                    &shell.chart,
                    tag,
                    n,
                    &b.part,
                )?);
                f
            }
            BoundaryCondition::Fixed => b
                .fix
                .as_deref()
                .unwrap_or_default()
                .iter()
                .map(|name| {
                    PSRI_FIELDS.iter().position(|f| f == name).ok_or_else(|| {
                        scene.error(
                            &format!("{field}.fix"),
                            format!(
                                "part `{}`: `{name}` is no field of element {}: {}",
                                b.part,
                                scene.element.name(),
                                PSRI_FIELDS.join(", ")
                            ),
                        )
                    })
                })
                .collect::<Result<_>>()?,
        };
        fixed.entry(tag).or_default().extend(fields);
    }
    Ok(fixed
        .iter()
        .filter(|(_, f)| !f.is_empty())
        .map(|(tag, f)| {
            let names: Vec<&str> = f.iter().map(|&k| PSRI_FIELDS[k]).collect();
            format!("{tag}:{}", names.join(","))
        })
        .collect::<Vec<_>>()
        .join(";"))
}

/// The θ fields (3 + β) a symmetry plane with normal e_n fixes on the part
/// `tag`: at each boundary node (vertices and edge midpoints of its edges)
/// θ^β with a_β·e_n ≠ 0 where the other tangent lies in the plane (as
/// `NaghdiSystem::setup`, same tolerance); an error unless the set is the
/// same at every node.
fn symmetry_rotations(
    scene: &Scene,
    mesh: &Mesh,
    chart: &Chart,
    tag: i32,
    n: usize,
    part: &str,
) -> Result<Vec<usize>> {
    let mut common: Option<(Vec<usize>, [f64; 2])> = None;
    for e in mesh.boundary_edges.iter().filter(|e| e.tag == tag) {
        let [p, q] = e.vertices.map(|v| mesh.vertices[v]);
        for x in [p, q, [0.5 * (p[0] + q[0]), 0.5 * (p[1] + q[1])]] {
            let sp = chart.at(x);
            let along = |b: usize| sp.a(b)[n].abs() <= 1e-12 * sp.a(b).norm();
            let mut here = Vec::new();
            for be in 0..2 {
                if along(be) {
                    continue;
                }
                if !along(1 - be) {
                    return Err(scene.error(
                        "shell.boundary.normal",
                        format!(
                            "part `{part}`: at ({:.6}, {:.6}) neither tangent a_1 nor a_2 of the {} chart lies in the symmetry plane (normal e{}), so r·e{} = 0 is no condition on one rotation component",
                            x[0], x[1], chart.kind(), n + 1, n + 1
                        ),
                    ));
                }
                here.push(3 + be);
            }
            match &common {
                None => common = Some((here, x)),
                Some((c, x0)) if *c != here => {
                    let names = |f: &[usize]| -> String {
                        let v: Vec<&str> = f.iter().map(|&k| PSRI_FIELDS[k]).collect();
                        if v.is_empty() {
                            "none".into()
                        } else {
                            v.join(", ")
                        }
                    };
                    return Err(scene.error(
                        "shell.boundary.normal",
                        format!(
                            "part `{part}`: the symmetry plane (normal e{}) fixes θ component(s) {} at ({:.6}, {:.6}) but {} at ({:.6}, {:.6}) on the {} chart; the FreeFEM twin {PSRI_SCRIPT} fixes fields on whole boundary parts (-fix) and cannot state this condition",
                            n + 1,
                            names(c),
                            x0[0],
                            x0[1],
                            names(&here),
                            x[0],
                            x[1],
                            chart.kind()
                        ),
                    ));
                }
                Some(_) => {}
            }
        }
    }
    Ok(common.map(|(c, _)| c).unwrap_or_default())
}

/// What a FreeFEM run reports besides its result file.
#[derive(Debug, Clone)]
pub struct FreefemRun {
    pub iterations: usize,
    pub stop_reason: String,
    pub alpha: Option<f64>,
    /// The FreeFem++ process, start to end.
    pub wall_seconds: f64,
    /// The Uzawa loop alone (the script's clock).
    pub loop_seconds: f64,
    pub seconds_per_iteration: f64,
    pub result_file: PathBuf,
}

/// Runs the FreeFEM twin of `scene` and writes `out` (+ `.xdmf`, and the
/// `.msh` beside it as `solve` does). `iterations`: exactly K Uzawa iterations.
pub fn run_freefem_scene(
    scene: &Scene,
    out: &Path,
    iterations: Option<usize>,
) -> Result<FreefemRun> {
    let folder = crate::pipeline::output_folder(out)?;
    let stem = out.file_stem().and_then(|s| s.to_str()).unwrap_or("result");
    let script = script_for_scene(scene)?;
    let mut inputs = scene.input_files();
    inputs.push(script.clone());
    // The result, its XDMF and the mesh appear together or not at all.
    let outputs = OutputTransaction::new(folder, stem, &inputs)?;
    // A shell's result has its 3D surface and a parameter-domain XDMF.
    let staged_out = outputs.stage_result(out, models::kind(scene.model).has_surface())?;
    let msh = match &scene.mesh.file {
        Some(f) => scene.resolve(f),
        None => outputs.stage(&out.with_extension("msh"))?,
    };
    let mesh = scene_mesh(scene, &msh)?;
    // The Rust model of the same scene: α = auto comes from its problem, and
    // its result builder turns FreeFEM's coefficients into the result file.
    // (Assembled in Rust whatever α is: the checks of `pipeline::assemble`,
    // finite data and no multiplier without free unknowns, hold for the twin too.)
    let (system, problem) = crate::pipeline::assembled(scene, &mesh)?;
    let plan = match &scene.obstacle {
        Some(_) => Some(uzawa_plan(
            scene,
            resolve_alpha(scene, &problem)?,
            iterations,
        )),
        None => None,
    };
    let work = tempfile::Builder::new()
        .prefix("obstacle-freefem-")
        .tempdir()
        .map_err(|e| Error::output(std::env::temp_dir(), format!("cannot create a folder: {e}")))?;
    let _on_signal = crate::output::transaction::RemoveOnSignal::new(work.path());
    let prefix = work.path().join("ff");
    // A user's MSH 4 file reaches gmshload as gmsh's MSH 2.2 conversion, the
    // file the Rust side read.
    let msh = match &scene.mesh.file {
        Some(_) => crate::pipeline::msh22_of(&msh, work.path())?,
        None => msh,
    };
    let args = script_args(scene, &mesh, &msh, plan.as_ref(), &prefix)?;
    let run_script = match scene_functions(scene) {
        None => script.clone(),
        Some(functions) => with_scene_functions(&script, &functions, work.path())?,
    };
    let wall_seconds = run_script_checked(&run_script, &args)?;

    let file = |ext: &str| PathBuf::from(format!("{}.{ext}", prefix.display()));
    check_mesh_order(&mesh, &file("mesh.txt"))?;
    let info = Info::read(&file("info.txt"))?;
    let twin = TwinSolution::read(scene, &mesh, &info, &file)?;
    let report = SolveReport {
        x: system.primal_from_dofs(&twin.dofs)?,
        lambda: twin.lambda.clone(),
        ..Default::default()
    };
    let mut data =
        crate::pipeline::results_on_solver_threads(scene, system.as_ref(), &problem, &report);
    twin.check_contact_fields(&data)?;
    let it = info.usize("iterations")?;
    let stop_reason = match &plan {
        Some(_) => info.text("stop_reason")?.to_string(),
        None => "linear".to_string(),
    };
    let loop_seconds = info.f64("loop_wall_seconds")?;
    let per_iteration = if it > 0 {
        loop_seconds / it as f64
    } else {
        0.0
    };
    let mut attrs: Vec<(String, AttrValue)> = vec![
        ("algorithm".into(), AttrValue::Str(ALGORITHM.into())),
        (
            "program".into(),
            AttrValue::Str(script.display().to_string()),
        ),
        ("iterations".into(), AttrValue::I64(it as i64)),
        ("stop_reason".into(), AttrValue::Str(stop_reason.clone())),
        ("wall_seconds".into(), AttrValue::F64(wall_seconds)),
        (
            "assembly_seconds".into(),
            AttrValue::F64(info.f64("assembly_seconds")?),
        ),
        (
            "factor_seconds".into(),
            AttrValue::F64(info.f64("factor_seconds")?),
        ),
        ("loop_seconds".into(), AttrValue::F64(loop_seconds)),
        (
            "seconds_per_iteration".into(),
            AttrValue::F64(per_iteration),
        ),
        (
            "loop_cpu_seconds".into(),
            AttrValue::F64(info.f64("loop_cpu_seconds")?),
        ),
        ("solver".into(), AttrValue::Str(info.text("solver")?.into())),
    ];
    if let Some(p) = &plan {
        attrs.extend([
            ("alpha".into(), AttrValue::F64(p.alpha)),
            (
                "step_form".into(),
                AttrValue::Str(format!("{:?}", p.step_form).to_lowercase()),
            ),
            ("max_iter".into(), AttrValue::I64(p.iterations as i64)),
            (
                "stop".into(),
                AttrValue::Str(
                    if p.thesis_stop.is_some() {
                        "thesis"
                    } else {
                        "fixed"
                    }
                    .into(),
                ),
            ),
            (
                "dual_step".into(),
                AttrValue::F64(info.f64("last_dual_step")?),
            ),
            (
                "dual_step_inf".into(),
                AttrValue::F64(info.f64("last_dual_step_inf")?),
            ),
        ]);
        if let Some((tol, norm)) = p.thesis_stop {
            attrs.push(("thesis_tol".into(), AttrValue::F64(tol)));
            attrs.push(("dual_norm".into(), AttrValue::Str(norm.into())));
        }
        attrs.extend(contact_measures(&data));
    }
    data.solver_attrs = attrs;
    data.scene_text = scene.text.clone();
    data.root_attrs
        .push(("program".into(), AttrValue::Str("FreeFEM".into())));
    if scene.element == ElementPair::P2bPsri {
        data.root_attrs.push((
            "psri_weight".into(),
            AttrValue::Str(info.text("psri_weight")?.into()),
        ));
    }
    write_result(&staged_out, &mesh, &data)?;
    outputs.commit()?;
    Ok(FreefemRun {
        iterations: it,
        stop_reason,
        alpha: plan.map(|p| p.alpha),
        wall_seconds,
        loop_seconds,
        seconds_per_iteration: per_iteration,
        result_file: out.to_path_buf(),
    })
}

/// Penetration, dual_min, complementarity and active count (docs/formulation.md §4) from
/// the stored λ and ḡ; stationarity and tangency need the matrices and are
/// not recorded.
fn contact_measures(data: &ResultData) -> Vec<(String, AttrValue)> {
    let get = |n: &str| {
        data.fields
            .iter()
            .find(|f| f.name == n)
            .map(|f| &f.values[..])
    };
    let (Some(l), Some(g)) = (get("lambda"), get("gap_mean")) else {
        return vec![];
    };
    let pen = g.iter().fold(0.0f64, |m, x| m.max(-x));
    let dmin = l.iter().fold(f64::INFINITY, |m, x| m.min(*x));
    let comp = l
        .iter()
        .zip(g)
        .fold(0.0f64, |m, (a, b)| m.max((a * b).abs()));
    let active = l.iter().filter(|&&x| x > 0.0).count();
    vec![
        ("penetration".into(), AttrValue::F64(pen)),
        ("dual_min".into(), AttrValue::F64(dmin)),
        ("complementarity".into(), AttrValue::F64(comp)),
        ("active".into(), AttrValue::I64(active as i64)),
    ]
}

fn read_len(path: &Path, n: usize) -> Result<Vec<f64>> {
    let v = read_numbers(path)?;
    if v.len() != n {
        return Err(Error::output(
            path,
            format!("{} values, expected {n}", v.len()),
        ));
    }
    Ok(v)
}

/// FreeFEM's solution, read from the script's text files: the coefficient
/// vectors named and laid out as the Rust result's `/dofs`, λ, and the
/// obstacle Φ_h and mean gaps FreeFEM computed itself (checked against the
/// Rust model's from the same coefficients).
struct TwinSolution {
    dofs: Vec<(String, Vec<f64>)>,
    lambda: Vec<f64>,
    /// (field name, FreeFEM's values, the file they came from).
    contact: Vec<(&'static str, Vec<f64>, PathBuf)>,
}

impl TwinSolution {
    fn read(
        scene: &Scene,
        mesh: &Mesh,
        info: &Info,
        file: &dyn Fn(&str) -> PathBuf,
    ) -> Result<TwinSolution> {
        let (nv, nt) = (mesh.n_vertices(), mesh.n_triangles());
        let ns = nv + nt;
        let (dofs, n_lambda) = match (twin_of(scene)?, scene.element) {
            (FreefemTwin::Membrane, ElementPair::P1bP0) => {
                (vec![("u".into(), read_len(&file("u.txt"), ns)?)], nt)
            }
            (FreefemTwin::Membrane, _) => {
                let nu = nv + mesh.n_edges();
                (vec![("u".into(), read_len(&file("u.txt"), nu)?)], nv)
            }
            (FreefemTwin::ShellPsri, _) => {
                check_psri_layout(scene, mesh, info, file)?;
                let spaces = PsriSpaces::of(mesh);
                let np = Space::new(mesh, spaces.u).n_dofs();
                let nb = Space::new(mesh, spaces.theta).n_dofs();
                let dofs = vec![
                    ("u".into(), read_len(&file("u.txt"), 3 * np)?),
                    ("theta".into(), read_len(&file("theta.txt"), 2 * nb)?),
                ];
                (dofs, nv)
            }
            (FreefemTwin::ShellThesis, _) => {
                let mut full = read_len(&file("u.txt"), 6 * ns)?;
                let r = full.split_off(3 * ns);
                let dofs = vec![
                    ("u".into(), full),
                    ("r".into(), r),
                    ("psi".into(), read_len(&file("psi.txt"), ns)?),
                ];
                (dofs, nt)
            }
        };
        let mut twin = TwinSolution {
            dofs,
            lambda: Vec::new(),
            contact: Vec::new(),
        };
        if let Some(obstacle) = &scene.obstacle {
            // Two-sided: the lower then the upper multipliers.
            let n_lambda = n_lambda * if obstacle.upper.is_some() { 2 } else { 1 };
            twin.lambda = read_len(&file("lambda.txt"), n_lambda)?;
            twin.contact = vec![
                ("phi", read_len(&file("phi.txt"), nv)?, file("phi.txt")),
                (
                    "gap_mean",
                    read_len(&file("gap.txt"), n_lambda)?,
                    file("gap.txt"),
                ),
            ];
        }
        Ok(twin)
    }

    /// FreeFEM's Φ_h and mean gaps against the Rust model's (from the same
    /// coefficients): they must agree to round-off, 1e-9 of the largest value.
    fn check_contact_fields(&self, data: &ResultData) -> Result<()> {
        for (name, freefem, path) in &self.contact {
            let rust = data
                .fields
                .iter()
                .find(|f| f.name == *name)
                .map(|f| &f.values)
                .ok_or_else(|| Error::output(path, format!("the Rust result has no `{name}`")))?;
            let scale = freefem
                .iter()
                .chain(rust)
                .fold(1.0f64, |m, v| m.max(v.abs()));
            if let Some(i) = (0..rust.len()).find(|&i| {
                let d = (freefem[i] - rust[i]).abs();
                d.is_nan() || d > 1e-9 * scale
            }) {
                return Err(Error::output(
                    path,
                    format!(
                        "{name}[{i}] = {:e}, the Rust model has {:e} from the same coefficients",
                        freefem[i], rust[i]
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// The PSRI script's layout against the Rust one: the P2 edge order, the
/// PSRI weight α of every triangle ([`psri_weight`]) and the spaces.
fn check_psri_layout(
    scene: &Scene,
    mesh: &Mesh,
    info: &Info,
    file: &dyn Fn(&str) -> PathBuf,
) -> Result<()> {
    let shell = scene.shell.as_ref().expect("validated: naghdi has [shell]");
    let (ne, nt) = (mesh.n_edges(), mesh.n_triangles());
    let edges_path = file("edges.txt");
    let edges = read_len(&edges_path, 2 * ne)?;
    if let Some(e) =
        (0..ne).find(|&e| [edges[2 * e], edges[2 * e + 1]] != mesh.edges[e].map(|v| v as f64))
    {
        return Err(Error::mesh(
            &mesh.source,
            format!(
                "FreeFEM ({}) edge {e} is [{}, {}], Rust has {:?}: the P2 edge orders differ",
                edges_path.display(),
                edges[2 * e],
                edges[2 * e + 1],
                mesh.edges[e]
            ),
        ));
    }
    let alpha_path = file("psri_alpha.txt");
    let alpha = read_len(&alpha_path, nt)?;
    let expected = rust_psri_weights(mesh, shell.thickness);
    if let Some(t) = (0..nt).find(|&t| !same_weight(alpha[t], expected[t])) {
        return Err(Error::output(
            &alpha_path,
            format!(
                "triangle {t}: PSRI weight {:e}, Rust's psri_weight is {:e}",
                alpha[t], expected[t]
            ),
        ));
    }
    let spaces = PsriSpaces::of(mesh);
    for (key, element) in [("u_space", spaces.u), ("theta_space", spaces.theta)] {
        if info.text(key)? != element.tag() {
            return Err(Error::output(
                &info.path,
                format!(
                    "{key} = {}, the Rust layout has {}",
                    info.text(key)?,
                    element.tag()
                ),
            ));
        }
    }
    Ok(())
}

/// `obstacle freefem`: runs the twin and prints one line.
pub fn command(scene: &Scene, out: Option<PathBuf>, iterations: Option<usize>) -> Result<()> {
    let out = out.unwrap_or_else(|| PathBuf::from(format!("build/freefem/{}.h5", scene.name)));
    if iterations.is_none() && scene.obstacle.is_some() && scene.solver.stop == StopRule::Kkt {
        eprintln!(
            "note: {} stops on the KKT measures, which the FreeFEM script does not compute: \
             running exactly min(max_iter, {KKT_FIXED_ITERATIONS}) Uzawa iterations (--iterations K to choose)",
            scene.name
        );
    }
    let r = run_freefem_scene(scene, &out, iterations)?;
    crate::outln!(
        "{}: FreeFEM {ALGORITHM}, α = {}, {} iterations (stop: {}), process {:.3} s, loop {:.3} s ({:.3e} s/iteration) → {}",
        scene.name,
        r.alpha.map_or("-".into(), |a| format!("{a}")),
        r.iterations,
        r.stop_reason,
        r.wall_seconds,
        r.loop_seconds,
        r.seconds_per_iteration,
        out.display()
    );
    Ok(())
}
