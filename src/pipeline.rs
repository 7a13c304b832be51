//! One run of a scene, end to end: mesh (gmsh or a file) → model setup →
//! assembly → factorisation → solver → result file. Each step is visible here.

use crate::error::{Error, Result};
use crate::gmsh::run_gmsh;
use crate::guards;
use crate::linalg::{factorize_checked, Solves};
use crate::mesh::{Mesh, PointLocator};
use crate::models::membrane::{ExactErrors, MembraneSystem};
use crate::models::naghdi::system::NaghdiSystem;
use crate::models::ModelSystem;
use crate::output::{numeric_attr, write_result, AttrValue, Location, ResultData};
use crate::plot;
use crate::scene::{Alpha, ColdStartSpec, Method, Model, PlotKind, Scene, SolverSpec, StepForm};
use crate::solvers::active_set::{active_set, ActiveSetOptions, ColdStart};
use crate::solvers::dual_accelerated::{dual_accelerated, DualAcceleratedOptions};
use crate::solvers::spectrum::{estimate_dual_spectrum, SpectrumEstimate};
use crate::solvers::uzawa::{solve_linear, uzawa, UzawaOptions};
use crate::solvers::uzawa_split::{uzawa_split, UzawaSplitOptions};
use crate::solvers::{ContactProblem, History, KktMeasures, SolveReport};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What a run reports besides its result file (one row of a study table).
#[derive(Debug, Clone, Default)]
pub struct RunSummary {
    pub scene: String,
    pub model: String,
    pub element: String,
    pub h: f64,
    pub n_vertices: usize,
    pub n_triangles: usize,
    pub n_dofs: usize,
    pub algorithm: String,
    pub iterations: usize,
    pub converged: bool,
    pub stop_reason: String,
    /// ‖λ^k − λ^{k−1}‖ of the last iteration (the thesis criterion).
    pub last_dual_step: f64,
    pub measures: KktMeasures,
    pub alpha: Option<f64>,
    pub spectrum: Option<SpectrumEstimate>,
    pub errors: Option<ExactErrors>,
    /// The model's root attributes of the result file (u3 range, contact area, ...).
    pub attrs: Vec<(String, AttrValue)>,
    pub history: History,
    /// Solver time after the factorisation (the iterations).
    pub solve_seconds: f64,
    pub wall_seconds: f64,
    pub result_file: PathBuf,
}

impl RunSummary {
    /// A numeric root attribute of the result, by name.
    pub fn attr(&self, name: &str) -> Option<f64> {
        numeric_attr(&self.attrs, name)
    }
}

/// The mesh a scene asks for: its `mesh.file`, or gmsh run on its `.geo`
/// (writing `msh_path`).
pub fn scene_mesh(scene: &Scene, msh_path: &Path) -> Result<Mesh> {
    let mesh = match &scene.mesh.file {
        Some(file) => Mesh::read_msh(&scene.resolve(file))?,
        None => {
            if let Some(e) = guards::estimate_before_meshing(scene) {
                guards::check_memory(scene, &e, "before meshing")?;
            }
            gmsh_scene_mesh(scene, msh_path)?
        }
    };
    guards::check_mesh_scale(&mesh)?;
    let e = guards::estimate(scene, mesh.n_triangles() as f64);
    guards::check_memory(scene, &e, &format!("the mesh {}", mesh.source.display()))?;
    Ok(mesh)
}

fn gmsh_scene_mesh(scene: &Scene, msh_path: &Path) -> Result<Mesh> {
    let geo = scene.resolve(scene.mesh.geo.as_deref().expect("validated: geo or file"));
    let mut params: Vec<(String, f64)> = match (scene.mesh.n, scene.mesh.h) {
        (Some(n), _) => vec![("n".into(), n as f64)],
        (None, Some(h)) => vec![("n".into(), 0.0), ("h".into(), h)],
        (None, None) => unreachable!("validated: n or h"),
    };
    params.extend(scene.mesh.parameters.iter().map(|(k, v)| (k.clone(), *v)));
    run_gmsh(&geo, msh_path, &params)?;
    Mesh::read_msh(msh_path)
}

/// The scene's mesh, meshed into a temporary folder (kept alive by the
/// returned handle) when nothing is to be kept beside a result.
pub fn scene_mesh_in_temp(scene: &Scene) -> Result<(tempfile::TempDir, Mesh)> {
    let dir = tempfile::tempdir().map_err(|e| {
        Error::output(
            std::env::temp_dir(),
            format!("cannot create a temporary folder: {e}"),
        )
    })?;
    let mesh = scene_mesh(scene, &dir.path().join("mesh.msh"))?;
    Ok((dir, mesh))
}

/// The dual step: the scene's number, or "auto" from a Lanczos estimate of
/// the spectrum of S: 2/(s_max + s_min), the optimal fixed Richardson step,
/// capped at 95% of the stability bound 2/s_max.
pub fn choose_alpha(alpha: Alpha, spectrum: Option<SpectrumEstimate>) -> f64 {
    match (alpha, spectrum) {
        (Alpha::Value(a), _) => a,
        (Alpha::Keyword(_), Some(s)) => (2.0 / (s.s_max + s.s_min)).min(1.9 / s.s_max),
        (Alpha::Keyword(_), None) => 1.0,
    }
}

/// Uzawa's step for a solver spec: `alpha_factor` × 2/s_max (the hard
/// cases), else [`choose_alpha`]. None when a factor is given but there is
/// no estimate of s_max (no constraint rows); the caller says so.
pub fn uzawa_step(solver: &SolverSpec, spectrum: Option<SpectrumEstimate>) -> Option<f64> {
    match (solver.alpha_factor, spectrum) {
        (Some(factor), Some(s)) => Some(factor * 2.0 / s.s_max),
        (Some(_), None) => None,
        (None, _) => Some(choose_alpha(
            solver.alpha.expect("validated with an obstacle"),
            spectrum,
        )),
    }
}

/// Checks a result path (`*.h5`) and creates its folder; returns the folder.
pub fn output_folder(out: &Path) -> Result<&Path> {
    if out.extension().and_then(|e| e.to_str()) != Some("h5") {
        return Err(Error::output(out, "the result file name must end in .h5"));
    }
    let dir = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)
        .map_err(|e| Error::output(dir, format!("cannot create the output folder: {e}")))?;
    Ok(dir)
}

/// Runs a scene and writes `out` (HDF5, plus the `.xdmf` and `.msh` beside it).
pub fn run_scene(scene: &Scene, out: &Path, show_progress: bool) -> Result<RunSummary> {
    let start = Instant::now();
    let dir = output_folder(out)?;
    // The mesh is written under a temporary name and renamed beside the
    // result only when the run succeeds: a failed run never clobbers FILE.msh.
    let stem = out.file_stem().and_then(|s| s.to_str()).unwrap_or("result");
    let msh_tmp = tempfile::Builder::new()
        .prefix(&format!("{stem}."))
        .suffix(".msh.partial")
        .tempfile_in(dir)
        .map_err(|e| Error::output(dir, format!("cannot create a temporary mesh file: {e}")))?
        .into_temp_path();
    let mesh = scene_mesh(scene, &msh_tmp)?;

    // Setup and assembly of the scene's model.
    let system = setup_model(scene, &mesh)?;
    let problem = assemble(scene, &mesh, system.as_ref())?;

    // The solver the scene names; without an obstacle, one linear solve.
    let start_lambda = nested_start(scene, &mesh)?;
    let (report, alpha, spectrum) = solve(
        scene,
        &problem,
        system.as_ref(),
        start_lambda,
        show_progress,
    )
    .map_err(|e| guards::name_matrix_inputs(scene, e))?;

    let mut data = system.results(scene, &problem, &report);
    let errors = if scene.output.errors {
        system.exact_errors(scene, &problem, &report)
    } else {
        None
    };
    record_solver(&mut data, scene, &report, spectrum);
    write_result(out, &mesh, &data)?;
    if scene.mesh.file.is_none() {
        let msh = out.with_extension("msh");
        msh_tmp
            .persist(&msh)
            .map_err(|e| Error::output(&msh, format!("cannot write the mesh file: {e}")))?;
        use std::os::unix::fs::PermissionsExt;
        let _ = std::fs::set_permissions(&msh, std::fs::Permissions::from_mode(0o644));
    }
    write_plots(scene, out, &mesh, &data, &report, errors.as_ref())?;
    Ok(RunSummary {
        scene: scene.name.clone(),
        model: scene.model.name().into(),
        element: scene.element.name().into(),
        h: mesh.h_max(),
        n_vertices: mesh.n_vertices(),
        n_triangles: mesh.n_triangles(),
        n_dofs: system.n_dofs(),
        algorithm: report.algorithm.clone(),
        iterations: report.iterations,
        converged: report.converged,
        stop_reason: report.stop_reason.clone(),
        last_dual_step: report.last_dual_step(),
        measures: report.measures,
        alpha,
        spectrum,
        errors,
        attrs: data.root_attrs.clone(),
        history: report.history.clone(),
        solve_seconds: report.wall_seconds - report.factor_seconds,
        wall_seconds: start.elapsed().as_secs_f64(),
        result_file: out.to_path_buf(),
    })
}

/// The model's contact problem, checked: finite, every multiplier acting
/// on a free unknown (`guards::check_assembled`).
pub fn assemble(scene: &Scene, mesh: &Mesh, system: &dyn ModelSystem) -> Result<ContactProblem> {
    let problem = system.assemble(scene)?;
    guards::check_assembled(scene, mesh, &problem)?;
    Ok(problem)
}

/// The scene's model set up on the mesh.
pub fn setup_model<'m>(scene: &Scene, mesh: &'m Mesh) -> Result<Box<dyn ModelSystem + 'm>> {
    Ok(match scene.model {
        Model::Membrane => Box::new(MembraneSystem::setup(mesh, scene)?),
        Model::Naghdi => Box::new(NaghdiSystem::setup(mesh, scene)?),
    })
}

/// Nested iteration (`solver.nested`): the scene solved on the mesh with
/// n/2 (itself nested, down to n < 8), its P0 multiplier carried to this
/// mesh triangle by triangle (the coarse value at each centroid). None when
/// not asked for, when there is no coarser level, or without contact.
fn nested_start(scene: &Scene, mesh: &Mesh) -> Result<Option<Vec<f64>>> {
    let (true, Some(n), Some(_)) = (scene.solver.nested, scene.mesh.n, &scene.obstacle) else {
        return Ok(None);
    };
    if n < 8 || n % 2 != 0 {
        return Ok(None);
    }
    let mut coarse = scene.clone();
    coarse.mesh.n = Some(n / 2);
    let (_dir, coarse_mesh) = scene_mesh_in_temp(&coarse)?;
    let system = setup_model(&coarse, &coarse_mesh)?;
    let problem = system.assemble(&coarse)?;
    if problem.n_multipliers() != coarse_mesh.n_triangles() {
        return Ok(None); // not a P0 multiplier: no triangle-wise transfer
    }
    let start = nested_start(&coarse, &coarse_mesh)?;
    let (report, _, _) = solve(&coarse, &problem, system.as_ref(), start, false)?;
    let locator = PointLocator::new(&coarse_mesh);
    let lambda = mesh
        .triangles
        .iter()
        .map(|tri| {
            let c = tri.iter().fold([0.0, 0.0], |c, &v| {
                [
                    c[0] + mesh.vertices[v][0] / 3.0,
                    c[1] + mesh.vertices[v][1] / 3.0,
                ]
            });
            locator.locate(c).map_or(0.0, |(t, _)| report.lambda[t])
        })
        .collect();
    Ok(Some(lambda))
}

/// Runs the scene's solver on the problem. Uzawa and the linear solve share
/// the one factorisation done here; the other methods factorise what they
/// need. `start_lambda` warm-starts the methods that take one.
fn solve(
    scene: &Scene,
    problem: &ContactProblem,
    system: &dyn ModelSystem,
    start_lambda: Option<Vec<f64>>,
    show_progress: bool,
) -> Result<(SolveReport, Option<f64>, Option<SpectrumEstimate>)> {
    let solver = &scene.solver;
    let max_iter = solver.max_iter as usize;
    if problem.constraint.is_some() && solver.method != Method::Uzawa {
        let report = match solver.method {
            Method::ActiveSet => active_set(
                problem,
                &ActiveSetOptions {
                    tol: solver.tol,
                    max_iter,
                    show_progress,
                    initial_lambda: start_lambda,
                    cold_start: match solver.cold_start {
                        ColdStartSpec::DepthBisection => ColdStart::DEPTH_BISECTION,
                        ColdStartSpec::Plain => ColdStart::Plain,
                    },
                    ..Default::default()
                },
            )?,
            Method::DualAccelerated => dual_accelerated(
                problem,
                &DualAcceleratedOptions {
                    tol: solver.tol,
                    max_iter,
                    show_progress,
                    initial_lambda: start_lambda,
                    ..Default::default()
                },
            )?,
            Method::UzawaSplit => uzawa_split(
                problem,
                &UzawaSplitOptions {
                    tol: solver.tol,
                    max_iter,
                    show_progress,
                    ..Default::default()
                },
            )?,
            Method::Uzawa => unreachable!("handled below"),
        };
        return Ok((report, None, None));
    }
    // One factorisation, reused by every iteration.
    let t = Instant::now();
    let what = problem.kind.describe();
    // Uzawa: one solve per iteration; without contact: one solve.
    let solves = if problem.constraint.is_some() {
        Solves::Many
    } else {
        Solves::Few
    };
    let factorization = factorize_checked(&problem.matrix, problem.kind, solves, what)?;
    let factor_seconds = t.elapsed().as_secs_f64();
    if problem.constraint.is_none() {
        return Ok((
            solve_linear(problem, &factorization, factor_seconds)?,
            None,
            None,
        ));
    }
    let step_form = solver.step_form.unwrap_or(StepForm::Mean);
    let spectrum = estimate_dual_spectrum(problem, &factorization, step_form, 50);
    let alpha = uzawa_step(solver, spectrum).ok_or_else(|| {
        Error::numerical(
            "Uzawa",
            "solver.alpha_factor",
            "no estimate of s_max (no constraint rows): give `alpha` instead",
        )
    })?;
    let options = UzawaOptions {
        alpha,
        step_form,
        max_iter,
        tol: solver.tol,
        stop: solver.stop,
        thesis_tol: solver.thesis_tol,
        dual_norm: solver.dual_norm,
        show_progress,
    };
    let report = uzawa(
        problem,
        &factorization,
        factor_seconds,
        &options,
        &system.probes(),
    )?;
    Ok((report, Some(alpha), spectrum))
}

/// The plots the scene asks for, beside the result file; nothing else is drawn.
fn write_plots(
    scene: &Scene,
    out: &Path,
    mesh: &Mesh,
    data: &ResultData,
    report: &SolveReport,
    errors: Option<&ExactErrors>,
) -> Result<()> {
    let ext = scene.output.plot_format.extension();
    let field = |name: &str| data.fields.iter().find(|f| f.name == name);
    for kind in &scene.output.plots {
        let name = format!("{kind:?}").to_lowercase();
        let path = out.with_extension(format!("{name}.{ext}"));
        let title = format!("{}: {name} ({})", scene.name, scene.element.name());
        match kind {
            PlotKind::History => {
                if report.history.is_empty() {
                    continue;
                }
                let mut columns = vec!["dual_step", "penetration", "complementarity", "kkt"];
                if report.history.column("gap_origin").is_some() {
                    columns.push("gap_origin");
                }
                plot::plot_history(&path, &report.history, &columns, &title)?
            }
            PlotKind::Contact => {
                if let Some(f) = field("contact") {
                    let active: Vec<bool> = f.values.iter().map(|&v| v > 0.0).collect();
                    plot::plot_contact_zone(
                        &path,
                        mesh,
                        &active,
                        &title,
                        errors.map(|e| e.exact_contact_radius),
                    )?;
                }
            }
            PlotKind::U1 | PlotKind::U2 | PlotKind::U3 => {
                let c = match kind {
                    PlotKind::U1 => 0,
                    PlotKind::U2 => 1,
                    _ => 2,
                };
                if let Some(f) = field("u") {
                    let values: Vec<f64> = f.values.iter().skip(c).step_by(3).copied().collect();
                    plot::plot_vertex_field(&path, mesh, &values, &title)?;
                }
            }
            PlotKind::Constraint => {
                if let (Some(w), Some(phi)) = (field("constraint"), field("phi")) {
                    write_constraint_plots(&path, mesh, &w.values, &phi.values, &title)?;
                }
            }
            PlotKind::U | PlotKind::Lambda | PlotKind::Gap => {
                let name = match kind {
                    PlotKind::U => "u",
                    PlotKind::Lambda => "lambda",
                    _ => "gap_mean",
                };
                if let Some(f) = field(name) {
                    match f.location {
                        Location::Vertex => {
                            plot::plot_vertex_field(&path, mesh, &f.values, &title)?
                        }
                        Location::Cell => plot::plot_cell_field(&path, mesh, &f.values, &title)?,
                    }
                }
            }
        }
    }
    Ok(())
}

/// The shell's constraint w = (u − ε/2 r)·e3 against Φ_h (thesis Fig. 5.6):
/// a colour map of w − Φ_h (zero on the contact zone) at `path`, and the
/// profiles of w and Φ_h along the axes y = 0 and x = 0 (through the
/// vertices that lie on them) at `<stem>-profiles.<ext>`.
fn write_constraint_plots(
    path: &Path,
    mesh: &Mesh,
    w: &[f64],
    phi: &[f64],
    title: &str,
) -> Result<()> {
    let gap: Vec<f64> = w.iter().zip(phi).map(|(a, b)| a - b).collect();
    plot::plot_vertex_field(path, mesh, &gap, &format!("{title}: (u − ε/2 r)·e3 − Φ_h"))?;
    let diameter = mesh.h_max().max(
        mesh.vertices
            .iter()
            .fold(0.0f64, |m, v| m.max(v[0].abs()).max(v[1].abs())),
    );
    let mut series = Vec::new();
    for (axis, along, across) in [("y = 0", 0, 1), ("x = 0", 1, 0)] {
        let on_axis: Vec<usize> = (0..mesh.n_vertices())
            .filter(|&v| mesh.vertices[v][across].abs() <= 1e-9 * diameter)
            .collect();
        if on_axis.len() < 3 {
            continue;
        }
        let line = |f: &[f64]| -> Vec<(f64, f64)> {
            on_axis
                .iter()
                .map(|&v| (mesh.vertices[v][along], f[v]))
                .collect()
        };
        series.push((format!("(u − ε/2 r)·e3 on {axis}"), line(w)));
        series.push((format!("Φ_h on {axis}"), line(phi)));
    }
    if series.is_empty() {
        return Ok(());
    }
    let stem = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("constraint");
    let ext = path.extension().and_then(|s| s.to_str()).unwrap_or("png");
    let profiles = path.with_file_name(format!("{stem}-profiles.{ext}"));
    plot::plot_lines(
        &profiles,
        &series,
        "x or y",
        "z",
        &format!("{title}: profiles"),
    )
}

/// The `/solver` attributes and history of docs/formulation.md §5.
fn record_solver(
    data: &mut ResultData,
    scene: &Scene,
    report: &SolveReport,
    spectrum: Option<SpectrumEstimate>,
) {
    let m = &report.measures;
    let s = &scene.solver;
    let mut attrs: Vec<(String, AttrValue)> = vec![
        ("algorithm".into(), AttrValue::Str(report.algorithm.clone())),
        ("method".into(), AttrValue::Str(s.method.name().into())),
        (
            "iterations".into(),
            AttrValue::I64(report.iterations as i64),
        ),
        ("converged".into(), AttrValue::Bool(report.converged)),
        (
            "stop_reason".into(),
            AttrValue::Str(report.stop_reason.clone()),
        ),
        ("penetration".into(), AttrValue::F64(m.penetration)),
        ("dual_min".into(), AttrValue::F64(m.dual_min)),
        ("complementarity".into(), AttrValue::F64(m.complementarity)),
        ("stationarity".into(), AttrValue::F64(m.stationarity)),
        ("tangency".into(), AttrValue::F64(m.tangency)),
        ("kkt".into(), AttrValue::F64(m.kkt)),
        ("active".into(), AttrValue::I64(m.active as i64)),
        ("dual_step".into(), AttrValue::F64(report.last_dual_step())),
        ("wall_seconds".into(), AttrValue::F64(report.wall_seconds)),
        (
            "factor_seconds".into(),
            AttrValue::F64(report.factor_seconds),
        ),
        ("tol".into(), AttrValue::F64(s.tol)),
        ("thesis_tol".into(), AttrValue::F64(s.thesis_tol)),
        ("max_iter".into(), AttrValue::I64(s.max_iter)),
        (
            "stop".into(),
            AttrValue::Str(format!("{:?}", s.stop).to_lowercase()),
        ),
        (
            "dual_norm".into(),
            AttrValue::Str(format!("{:?}", s.dual_norm).to_lowercase()),
        ),
    ];
    if let Some(f) = s.step_form {
        attrs.push((
            "step_form".into(),
            AttrValue::Str(format!("{f:?}").to_lowercase()),
        ));
    }
    // The solver's own parameters and estimates; a name the scene already
    // gave (e.g. tol) keeps the scene's value.
    for (name, v) in &report.parameters {
        if !attrs.iter().any(|(n, _)| n == name) {
            attrs.push((name.clone(), AttrValue::F64(*v)));
        }
    }
    if let Some(sp) = spectrum {
        attrs.push(("s_max_estimate".into(), AttrValue::F64(sp.s_max)));
        attrs.push(("s_min_ritz".into(), AttrValue::F64(sp.s_min)));
        attrs.push(("stability_bound".into(), AttrValue::F64(2.0 / sp.s_max)));
    }
    data.solver_attrs = attrs;
    data.history = report.history.columns.clone();
}
