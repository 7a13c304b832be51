//! One run of a scene, end to end: mesh (gmsh or a file) → model setup →
//! assembly → solver options → `solvers::solve` → result file. Each step is
//! visible here.

use crate::error::{Error, Result};
use crate::gmsh::run_gmsh;
use crate::guards;
use crate::linalg::beside;
use crate::mesh::{BoundaryGeometry, Hierarchy, Mesh};
use crate::models::{self, ExactErrors, FigureData, ModelSystem};
use crate::multigrid::{MultigridOptions, Smoother};
use crate::output::transaction::RemoveOnSignal;
use crate::output::{
    numeric_attr, write_result, AttrValue, Field, Location, OutputTransaction, ResultData,
};
use crate::plot;
use crate::scene::{Alpha, ColdStartSpec, Method, Model, PlotKind, Scene, SolverSpec, StepForm};
use crate::solvers::active_set::{ActiveSetOptions, ColdStart};
use crate::solvers::dual_accelerated::DualAcceleratedOptions;
use crate::solvers::multigrid_newton::{LevelsHandle, MultigridLevels, MultigridNewtonOptions};
use crate::solvers::spectrum::SpectrumEstimate;
use crate::solvers::uzawa::{UzawaOptions, UzawaStep};
use crate::solvers::uzawa_split::UzawaSplitOptions;
use crate::solvers::{
    ContactProblem, History, KktMeasures, LinearOptions, SolveReport, SolverOptions,
};
use crate::transfer::prolong_dofs;
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
    /// The solver's wall time (`/solver/wall_seconds`: factorisations and
    /// iterations; meshing, assembly and output excluded).
    pub solver_seconds: f64,
    /// The solver's factorisation time (`/solver/factor_seconds`).
    pub factor_seconds: f64,
    /// Solver time after the factorisation (the iterations).
    pub solve_seconds: f64,
    /// The whole run's wall time.
    pub wall_seconds: f64,
    /// Peak RSS (MB, VmHWM) at the end of each phase: meshing, assembly,
    /// solve (nested levels and factorisations included); the `/solver`
    /// attributes `peak_rss_mb_<phase>`. Empty where /proc cannot be read.
    pub peak_rss_mb: Vec<(String, f64)>,
    /// The active set's interior-point steps (`/solver`
    /// `interior_point_steps`); None for the other methods.
    pub interior_point_steps: Option<usize>,
    pub result_file: PathBuf,
}

impl RunSummary {
    /// Whether the run ended as its scene asked: converged (the KKT measures
    /// within `solver.tol`), or stopped by the scene's own rule (`stop =
    /// "thesis"` met), not by running out of iterations (`solver.max_iter`).
    pub fn stopped_as_asked(&self) -> bool {
        self.converged || self.stop_reason != crate::solvers::STOP_MAX_ITER
    }

    /// The summary of a finished run: `data` is what was written to `out`,
    /// `start` when the run began.
    pub fn of_run(
        scene: &Scene,
        system: &dyn ModelSystem,
        report: &SolveReport,
        errors: Option<ExactErrors>,
        data: &ResultData,
        start: Instant,
        out: &Path,
    ) -> RunSummary {
        let mesh = system.mesh();
        RunSummary {
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
            alpha: report.alpha,
            spectrum: report.spectrum,
            errors,
            attrs: data.root_attrs.clone(),
            history: report.history.clone(),
            solver_seconds: report.wall_seconds,
            factor_seconds: report.factor_seconds,
            solve_seconds: report.wall_seconds - report.factor_seconds,
            wall_seconds: start.elapsed().as_secs_f64(),
            peak_rss_mb: peak_rss_of(&data.solver_attrs),
            interior_point_steps: interior_point_steps(&data.solver_attrs),
            result_file: out.to_path_buf(),
        }
    }

    /// Whether the run ended inside the active set's interior-point start
    /// (`max_iter` there, as the bench's re-runs to a looser tolerance do):
    /// its (x, λ) is then an interior iterate, every λ_i > 0, which meets
    /// the KKT measure but is no complementary pair (docs/work-precision.md,
    /// "Where an interior-point step's time goes").
    pub fn ended_in_interior_point(&self) -> bool {
        matches!(self.interior_point_steps, Some(k) if k >= 1 && k + 1 == self.iterations)
    }

    /// A numeric root attribute of the result, by name.
    pub fn attr(&self, name: &str) -> Option<f64> {
        numeric_attr(&self.attrs, name)
    }

    /// The summary of a run read back from its result file (root and
    /// `/solver` attributes, `/solver/history`, the mesh): what [`crate::run::run_scene`]
    /// returned, but `wall_seconds`, which is the run's time up to writing the
    /// file (`/solver/run_seconds`), and what the file does not hold: the
    /// measures' `gap_scale` and the Lanczos step count (both 0).
    pub fn from_result(path: &Path, scene: &Scene) -> Result<RunSummary> {
        let file = crate::output::read_result(path)?;
        let d = &file.data;
        // A result left from an edited study (other scene text or overrides)
        // would put another run's numbers in this row.
        if d.scene_text != scene.text {
            return Err(Error::output(
                path,
                format!(
                    "root attribute `scene`: this result was run from another scene than {} with these overrides (the study or its scene changed since): rerun the workflow",
                    scene.source.display()
                ),
            ));
        }
        let missing = |group: &str, name: &str| {
            Error::output(path, format!("no {group} attribute `{name}` (not a result of `obstacle solve`, or one written before `{RUN_SECONDS}` was recorded: rerun it)"))
        };
        let attr = |attrs: &[(String, AttrValue)], group: &str, name: &str| {
            attrs
                .iter()
                .find(|(k, _)| k == name)
                .map(|(_, v)| v.clone())
                .ok_or_else(|| missing(group, name))
        };
        let text = |attrs: &[(String, AttrValue)], group: &str, name: &str| match attr(
            attrs, group, name,
        )? {
            AttrValue::Str(s) => Ok(s),
            other => Ok(other.to_string()),
        };
        let number = |attrs: &[(String, AttrValue)], group: &str, name: &str| {
            numeric_attr(attrs, name).ok_or_else(|| missing(group, name))
        };
        let (root, solver) = (d.root_attrs.as_slice(), d.solver_attrs.as_slice());
        let scene: toml::Table = d
            .scene_text
            .parse()
            .map_err(|e| Error::output(path, format!("root attribute `scene` is not TOML: {e}")))?;
        let algorithm = text(solver, "/solver", "algorithm")?;
        let measures = KktMeasures {
            penetration: number(solver, "/solver", "penetration")?,
            dual_min: number(solver, "/solver", "dual_min")?,
            complementarity: number(solver, "/solver", "complementarity")?,
            stationarity: number(solver, "/solver", "stationarity")?,
            tangency: number(solver, "/solver", "tangency")?,
            active: number(solver, "/solver", "active")? as usize,
            gap_scale: 0.0,
            kkt: number(solver, "/solver", "kkt")?,
        };
        // Uzawa alone has a fixed step and its Lanczos estimate (`SolveReport::alpha`).
        let uzawa = algorithm == "uzawa";
        let spectrum = match (
            numeric_attr(solver, "s_max_estimate"),
            numeric_attr(solver, "s_min_ritz"),
        ) {
            (Some(s_max), Some(s_min)) => Some(SpectrumEstimate {
                s_max,
                s_min,
                steps: 0,
            }),
            _ => None,
        };
        let errors = match numeric_attr(root, "error_l2_u") {
            Some(l2) => Some(ExactErrors {
                l2,
                h1: number(root, "root", "error_h1_u")?,
                lambda_l2: number(root, "root", "error_l2_lambda")?,
                contact_radius: number(root, "root", "contact_radius")?,
                exact_contact_radius: number(root, "root", "exact_contact_radius")?,
            }),
            None => None,
        };
        let solver_seconds = number(solver, "/solver", "wall_seconds")?;
        let factor_seconds = number(solver, "/solver", "factor_seconds")?;
        Ok(RunSummary {
            scene: scene
                .get("name")
                .and_then(|n| n.as_str())
                .ok_or_else(|| Error::output(path, "root attribute `scene` has no `name`"))?
                .to_string(),
            model: text(root, "root", "model")?,
            element: text(root, "root", "element")?,
            h: number(root, "root", "h")?,
            n_vertices: file.vertices.len(),
            n_triangles: file.triangles.len(),
            n_dofs: number(root, "root", "n_dofs")? as usize,
            iterations: number(solver, "/solver", "iterations")? as usize,
            converged: matches!(attr(solver, "/solver", "converged")?, AttrValue::Bool(true)),
            stop_reason: text(solver, "/solver", "stop_reason")?,
            last_dual_step: number(solver, "/solver", "dual_step")?,
            measures,
            alpha: numeric_attr(solver, "alpha").filter(|_| uzawa),
            spectrum: spectrum.filter(|_| uzawa),
            errors,
            attrs: d.root_attrs.clone(),
            history: History {
                columns: d.history.clone(),
            },
            solver_seconds,
            factor_seconds,
            peak_rss_mb: peak_rss_of(solver),
            interior_point_steps: interior_point_steps(solver),
            solve_seconds: solver_seconds - factor_seconds,
            wall_seconds: number(solver, "/solver", RUN_SECONDS)?,
            result_file: path.to_path_buf(),
            algorithm,
        })
    }
}

/// `/solver` `interior_point_steps` (the active set's), if present.
fn interior_point_steps(solver: &[(String, AttrValue)]) -> Option<usize> {
    numeric_attr(solver, "interior_point_steps").map(|k| k as usize)
}

/// The `/solver` attribute with the run's wall time up to writing its result.
const RUN_SECONDS: &str = "run_seconds";
/// `/solver` attribute prefix of the peak RSS (MB) at each phase's end.
const PEAK_RSS_PREFIX: &str = "peak_rss_mb_";
/// `/solver` attributes: the run's seconds at the end of each phase
/// (meshing, assembly, solve), so a run's time splits by phase.
const PHASE_END_PREFIX: &str = "seconds_at_end_of_";

/// The mesh a scene asks for: the finest of [`scene_hierarchy`], its file
/// written to `msh_path` ([`write_refined_msh`]).
pub fn scene_mesh(scene: &Scene, msh_path: &Path) -> Result<Mesh> {
    let mut hierarchy = scene_hierarchy(scene, msh_path)?;
    write_refined_msh(scene, &hierarchy, msh_path)?;
    Ok(hierarchy.levels.pop().expect("a hierarchy has a level"))
}

/// The finest level of a `.geo` scene's refined hierarchy written to
/// `msh_path`, in the place of gmsh's coarse mesh. Nothing to write for a
/// scene's own mesh file, or without refinement (gmsh's file is the mesh).
pub fn write_refined_msh(scene: &Scene, hierarchy: &Hierarchy, msh_path: &Path) -> Result<()> {
    match scene.mesh.refine > 0 && scene.mesh.file.is_none() {
        true => hierarchy.finest().write_msh(msh_path),
        false => Ok(()),
    }
}

/// The meshes a scene asks for, coarsest first: its `mesh.file`, or gmsh
/// run on its `.geo` (writing its mesh to `msh_path`), refined
/// `mesh.refine` times (the finest's file is [`write_refined_msh`]'s). The
/// memory guard judges the finest before it is made.
pub fn scene_hierarchy(scene: &Scene, msh_path: &Path) -> Result<Hierarchy> {
    let base = match &scene.mesh.file {
        Some(file) => read_mesh_file(&scene.resolve(file))?,
        None => {
            if let Some(e) = guards::estimate_before_meshing(scene) {
                guards::check_memory(scene, &e, "before meshing")?;
            }
            gmsh_scene_mesh(scene, msh_path)?
        }
    };
    let refinements = scene.mesh.refine as usize;
    let finest_triangles = base.n_triangles() as f64 * 4f64.powi(refinements as i32);
    let e = guards::estimate(scene, finest_triangles);
    let what = match refinements {
        0 => format!("the mesh {}", base.source.display()),
        k => format!("the mesh {} refined {k} times", base.source.display()),
    };
    guards::check_memory(scene, &e, &what)?;
    // The circles are looked for only where refinement places vertices.
    let hierarchy = match refinements {
        0 => Hierarchy::new(base, 0, BoundaryGeometry::straight())?,
        k => Hierarchy::detected(base, k)?,
    };
    guards::check_mesh_scale(hierarchy.finest())?;
    Ok(hierarchy)
}

/// A user's mesh file as MSH 2.2 ASCII, the format the reader and FreeFEM's
/// `gmshload` take: the file itself, or, for MSH 4 (gmsh's default format,
/// ASCII or binary), its conversion by gmsh into `folder`.
pub fn msh22_of(file: &Path, folder: &Path) -> Result<PathBuf> {
    match crate::gmsh::msh_major_version(file) {
        Some(v) if v >= 4 => {
            let name = file.file_name().unwrap_or(std::ffi::OsStr::new("mesh.msh"));
            let converted = folder.join(name).with_extension("msh");
            crate::gmsh::convert_to_msh22(file, &converted)?;
            Ok(converted)
        }
        _ => Ok(file.to_path_buf()),
    }
}

/// Reads a user's mesh file, converting MSH 4 first ([`msh22_of`]); the mesh
/// and its errors name the user's file.
fn read_mesh_file(file: &Path) -> Result<Mesh> {
    let dir = tempfile::tempdir()
        .map_err(|e| Error::mesh(file, format!("cannot create a temporary folder: {e}")))?;
    let _on_signal = crate::output::transaction::RemoveOnSignal::new(dir.path());
    let path = msh22_of(file, dir.path())?;
    let mut mesh = Mesh::read_msh(&path).map_err(|e| match e {
        Error::Mesh { reason, .. } if path != file => {
            Error::mesh(file, format!("converted to MSH 2.2 by gmsh: {reason}"))
        }
        other => other,
    })?;
    mesh.source = file.to_path_buf();
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
    // msh_path is a temporary the user never sees: errors and the mesh name the .geo.
    let mut mesh = Mesh::read_msh(msh_path).map_err(|e| match e {
        Error::Mesh { reason, .. } => Error::mesh(&geo, format!("the mesh gmsh made: {reason}")),
        other => other,
    })?;
    mesh.source = geo;
    Ok(mesh)
}

/// The scene's mesh when no file is to be kept: meshed into a temporary
/// folder, removed once read (or on SIGINT/SIGTERM).
pub fn scene_mesh_in_temp(scene: &Scene) -> Result<Mesh> {
    let dir = tempfile::tempdir().map_err(|e| {
        Error::output(
            std::env::temp_dir(),
            format!("cannot create a temporary folder: {e}"),
        )
    })?;
    let _on_signal = RemoveOnSignal::new(dir.path());
    scene_mesh(scene, &dir.path().join("mesh.msh"))
}

/// Uzawa's step rule of a solver spec: `alpha_factor` × 2/s_max (the hard
/// cases), else the scene's α or "auto". Without `alpha` (allowed only
/// without an obstacle, where Uzawa does not run) "auto".
pub fn uzawa_step(solver: &SolverSpec) -> UzawaStep {
    match (solver.alpha_factor, solver.alpha) {
        (Some(factor), _) => UzawaStep::StabilityFactor(factor),
        (None, Some(Alpha::Value(a))) => UzawaStep::Given(a),
        (None, Some(Alpha::Keyword(_)) | None) => UzawaStep::Auto,
    }
}

/// The linear solver of a scene's `[solver]` table: `solver.linear` on
/// `solver.threads` threads.
pub fn linear_options(solver: &SolverSpec) -> LinearOptions {
    LinearOptions {
        method: solver.linear,
        threads: solver.threads as usize,
    }
}

/// A warm start carried from a coarser level (nested iteration): the
/// primal iterate x (all of the problem's unknowns) and the multiplier λ.
#[derive(Debug, Clone)]
pub struct WarmStart {
    pub x: Vec<f64>,
    pub lambda: Vec<f64>,
}

/// The relative KKT tolerance of the multigrid method's coarser levels,
/// whose solutions start the next level: at 1025² the finest level takes 7
/// Newton steps from levels solved to 1e-4, 9 from 1e-3 (docs/solvers.md,
/// "Newton multigrid").
const MULTIGRID_COARSE_TOL: f64 = 1e-4;
/// CG iterations per Newton step of the multigrid method.
const MULTIGRID_MAX_CG: usize = 200;

/// The solver options of a scene's `[solver]` table; `start` warm-starts
/// the methods that take one (active-set: x and λ; dual-accelerated: λ),
/// `show_progress` draws their progress.
pub fn solver_options(
    solver: &SolverSpec,
    model: Model,
    start: Option<WarmStart>,
    show_progress: bool,
) -> SolverOptions {
    let max_iter = solver.max_iter as usize;
    let linear = linear_options(solver);
    match solver.method {
        Method::ActiveSet => SolverOptions::ActiveSet(ActiveSetOptions {
            tol: solver.tol,
            max_iter,
            show_progress,
            initial_x: start.as_ref().map(|s| s.x.clone()),
            initial_lambda: start.as_ref().map(|s| s.lambda.clone()),
            cold_start: match models::cold_start(solver.cold_start, model) {
                ColdStartSpec::DepthBisection | ColdStartSpec::Auto => ColdStart::DEPTH_BISECTION,
                ColdStartSpec::InteriorPoint => ColdStart::INTERIOR_POINT,
                ColdStartSpec::Plain => ColdStart::Plain,
            },
            linear,
            ..Default::default()
        }),
        Method::Multigrid => SolverOptions::Multigrid(MultigridNewtonOptions {
            tol: solver.tol,
            coarse_tol: MULTIGRID_COARSE_TOL,
            max_iter,
            max_cg: MULTIGRID_MAX_CG,
            show_progress,
            levels: None,
            threads: linear.threads,
            cycle: MultigridOptions {
                coarse: LinearOptions {
                    threads: 1,
                    ..linear
                },
                // V(1,1) with a forward sweep before and a backward one
                // after (symmetric as a whole): at 1025² 20 CG iterations on
                // the finest level and 8.2 s of solver time against
                // symmetric sweeps' 15 and 9.4 s (docs/solvers.md, "Newton
                // multigrid").
                smoother: Smoother::GaussSeidel,
                threads: linear.threads,
                ..MultigridOptions::default()
            },
        }),
        Method::DualAccelerated => SolverOptions::DualAccelerated(DualAcceleratedOptions {
            tol: solver.tol,
            max_iter,
            show_progress,
            initial_lambda: start.map(|s| s.lambda),
            linear,
            ..Default::default()
        }),
        Method::UzawaSplit => SolverOptions::UzawaSplit(UzawaSplitOptions {
            tol: solver.tol,
            max_iter,
            show_progress,
            linear,
            ..Default::default()
        }),
        Method::Uzawa => SolverOptions::Uzawa(UzawaOptions {
            step: uzawa_step(solver),
            step_form: solver.step_form.unwrap_or(StepForm::Mean),
            max_iter,
            tol: solver.tol,
            stop: solver.stop,
            thesis_tol: solver.thesis_tol,
            dual_norm: solver.dual_norm,
            show_progress,
            // Cold: a carried λ costs Uzawa iterations (its mesh-scale error
            // at the free boundary is the slowest mode; §8, measured).
            initial_lambda: None,
            linear,
        }),
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

/// Runs a scene on its one mesh (its `[adapt]` table is not read:
/// `run::run_scene` runs those) and writes `out` (HDF5, plus the `.xdmf`,
/// the `.msh` and the scene's plots beside it) in one [`OutputTransaction`]:
/// all of them or, on any error, none, and never over an input of the run.
pub fn run_uniform(scene: &Scene, out: &Path, show_progress: bool) -> Result<RunSummary> {
    let start = Instant::now();
    let (outputs, staged_out) = stage_run_outputs(scene, out)?;
    let msh = match &scene.mesh.file {
        None => outputs.stage(&out.with_extension("msh"))?,
        Some(_) => PathBuf::new(), // the scene's own mesh file: nothing written
    };
    // Each phase's end: the run's seconds so far and its peak RSS.
    let mut phase_ends: Vec<(String, AttrValue)> = Vec::new();
    let mut phase_end = |phase: &str| {
        let seconds = start.elapsed().as_secs_f64();
        phase_ends.push((
            format!("{PHASE_END_PREFIX}{phase}"),
            AttrValue::F64(seconds),
        ));
        if let Some(kb) = guards::peak_rss_kb() {
            phase_ends.push((
                format!("{PEAK_RSS_PREFIX}{phase}"),
                AttrValue::F64(kb as f64 / 1024.0),
            ));
        }
    };
    let hierarchy = scene_hierarchy(scene, &msh)?;
    let mesh = hierarchy.finest();
    phase_end("meshing");
    // The refined mesh's file (0.3 s at 1M vertices) is written beside
    // the assembly and the solve.
    let (solved, written) = beside(
        scene.solver.threads as usize,
        || {
            solve_on(
                scene,
                mesh,
                Start::Scene(Some(&hierarchy)),
                show_progress,
                &mut phase_end,
            )
        },
        || write_refined_msh(scene, &hierarchy, &msh),
    );
    let Solved {
        system,
        problem,
        report,
    } = solved?;
    written?;

    let (mut data, errors) = result_data(scene, system.as_ref(), &problem, &report)?;
    // The run's time so far, for tables built later from the file (`study --from-results`).
    data.solver_attrs.push((
        RUN_SECONDS.into(),
        AttrValue::F64(start.elapsed().as_secs_f64()),
    ));
    data.solver_attrs.extend(phase_ends);
    write_result(&staged_out, mesh, &data)?;
    write_plots(
        scene,
        &staged_out,
        system.as_ref(),
        &data,
        &report,
        errors.as_ref(),
    )?;
    outputs.commit()?;
    Ok(RunSummary::of_run(
        scene,
        system.as_ref(),
        &report,
        errors,
        &data,
        start,
        out,
    ))
}

/// How a solve on a mesh starts.
#[derive(Debug, Clone, Copy)]
pub enum Start<'a> {
    /// As the scene says: cold, nested (`solver.nested`), or by grid
    /// sequencing over the scene's hierarchy (`method = "multigrid"`: the
    /// hierarchy whose finest level is the mesh solved on).
    Scene(Option<&'a Hierarchy>),
    /// From coefficient vectors carried onto this mesh (`/dofs` names: an
    /// adaptive step's, from the last step's mesh); cold when they do not
    /// fit ([`warm_start`]).
    Carried(&'a [(String, Vec<f64>)]),
}

/// A scene's model solved on one mesh.
pub struct Solved<'m> {
    pub system: Box<dyn ModelSystem + 'm>,
    pub problem: ContactProblem,
    pub report: SolveReport,
}

/// The one solve of a scene on a mesh, for the run, its nested levels and
/// the adaptive steps: the model set up and its problem assembled
/// ([`assembled`]), the warm start of `start`, the scene's solver (without
/// an obstacle, one linear solve), a singular matrix named by the keys that
/// build it. `phase_end` is told "assembly" and "solve" as each ends.
pub fn solve_on<'m>(
    scene: &Scene,
    mesh: &'m Mesh,
    start: Start<'_>,
    show_progress: bool,
    phase_end: &mut dyn FnMut(&str),
) -> Result<Solved<'m>> {
    let hierarchy = match (scene.solver.method, start) {
        (Method::Multigrid, Start::Scene(Some(h))) if std::ptr::eq(h.finest(), mesh) => Some(h),
        (Method::Multigrid, _) => {
            return Err(scene.error(
                "solver.method",
                "the multigrid method solves on the hierarchy of mesh.refine, not on an adaptive step's or a nested level's mesh",
            ))
        }
        _ => None,
    };
    // The coarser levels (a third of the finest's work) are assembled
    // beside the finest when the scene gives the solver two threads.
    let (assembled_finest, levels) = match hierarchy {
        None => (assembled(scene, mesh), None),
        Some(h) => {
            let (finest, coarser) = beside(
                scene.solver.threads as usize,
                || assembled(scene, mesh),
                || multigrid_levels(scene, h),
            );
            (finest, Some(coarser))
        }
    };
    let (system, problem) = assembled_finest?;
    let levels = levels.transpose()?.map(LevelsHandle::new);
    phase_end("assembly");
    let warm = match start {
        Start::Scene(_) => nested_start(scene, system.as_ref(), &problem)?,
        Start::Carried(dofs) => warm_start(system.as_ref(), &problem, dofs)?,
    };
    let mut options = solver_options(&scene.solver, scene.model, warm, show_progress);
    if let SolverOptions::Multigrid(o) = &mut options {
        o.levels = levels;
    }
    let (problem, report) = crate::solvers::solve(problem, &options, &system.probes())
        .map_err(|e| guards::name_matrix_inputs(scene, e))?;
    phase_end("solve");
    Ok(Solved {
        system,
        problem,
        report,
    })
}

/// The problems of a hierarchy's coarser levels (the scene's model on each
/// mesh, without the exact solution's checks: their solutions are starts)
/// and the model's prolongations between the levels.
fn multigrid_levels(scene: &Scene, hierarchy: &Hierarchy) -> Result<MultigridLevels> {
    let mut coarse = scene.clone();
    coarse.output.errors = false;
    let finest = hierarchy.n_levels() - 1;
    let coarser = hierarchy.levels[..finest]
        .iter()
        .map(|mesh| Ok(assembled(&coarse, mesh)?.1))
        .collect::<Result<Vec<_>>>()?;
    let transfers = models::kind(scene.model).skeleton_transfers(hierarchy, scene)?;
    Ok(MultigridLevels {
        coarser,
        prolongations: transfers.prolongations,
        lifts: transfers.lifts,
        obstacles: transfers.obstacles,
    })
}

/// The scene's model set up on `mesh` and its contact problem assembled
/// and checked ([`assemble`]).
pub fn assembled<'m>(
    scene: &Scene,
    mesh: &'m Mesh,
) -> Result<(Box<dyn ModelSystem + 'm>, ContactProblem)> {
    let system = setup_model(scene, mesh)?;
    let problem = assemble(scene, mesh, system.as_ref())?;
    Ok((system, problem))
}

/// The model's contact problem, checked: finite, every multiplier acting
/// on a free unknown (`guards::check_assembled`); a symmetric A kept as
/// its lower triangle (`ContactProblem::store_lower_triangle`); its interior groups
/// dropped when the scene turns condensation off (`solver.condense`).
pub fn assemble(scene: &Scene, mesh: &Mesh, system: &dyn ModelSystem) -> Result<ContactProblem> {
    let mut problem = system.assemble()?;
    if !scene.solver.condense {
        problem.interior = None;
    }
    guards::check_assembled(scene, mesh, &problem)?;
    problem.store_lower_triangle();
    Ok(problem)
}

/// The scene's model set up on the mesh.
pub fn setup_model<'m>(scene: &Scene, mesh: &'m Mesh) -> Result<Box<dyn ModelSystem + 'm>> {
    models::kind(scene.model).setup(mesh, scene)
}

/// Nested iteration (`solver.nested`): the scene solved on the mesh with
/// n/2 (itself nested, down to n < 8) and its whole solution carried to
/// `system`'s mesh: every coefficient vector prolonged by interpolation
/// (`transfer::prolong_dofs`), x from the primal ones, λ from `lambda`. A
/// coarse level without contact (λ = 0) carries nothing: this level starts
/// cold (active-set: depth bisection), so the bisection runs on the
/// coarsest level that touches and PDAS finishes every finer one. None
/// when not asked for, at the coarsest level, or without contact.
fn nested_start(
    scene: &Scene,
    system: &dyn ModelSystem,
    problem: &ContactProblem,
) -> Result<Option<WarmStart>> {
    let (true, Some(n), Some(_)) = (scene.solver.nested, scene.mesh.n, &scene.obstacle) else {
        return Ok(None);
    };
    if n < 8 || n % 2 != 0 {
        return Ok(None);
    }
    let mut coarse = scene.clone();
    coarse.mesh.n = Some(n / 2);
    // A coarse level is a warm start: its errors against an exact solution
    // (evaluated at every point of a degree-10 rule) serve no one.
    coarse.output.errors = false;
    let coarse_mesh = scene_mesh_in_temp(&coarse)?;
    let solved = solve_on(
        &coarse,
        &coarse_mesh,
        Start::Scene(None),
        false,
        &mut |_| {},
    )?;
    if solved.report.lambda.iter().all(|&l| l <= 0.0) {
        return Ok(None);
    }
    let data = model_results(&coarse, &solved);
    warm_start(
        system,
        problem,
        &prolong_dofs(&data, &coarse_mesh, system.mesh()),
    )
}

/// The warm start of `problem` from coefficient vectors prolonged onto its
/// mesh (`/dofs` names): x from the model's unknowns, λ from `lambda`.
/// None (start cold) when `lambda` is missing or does not fit, e.g. a
/// multiplier space that does not prolong.
pub fn warm_start(
    system: &dyn ModelSystem,
    problem: &ContactProblem,
    dofs: &[(String, Vec<f64>)],
) -> Result<Option<WarmStart>> {
    let lambda = dofs
        .iter()
        .find(|(name, _)| name == "lambda")
        .map(|(_, l)| l.clone())
        .filter(|l| l.len() == problem.n_multipliers());
    let Some(lambda) = lambda else {
        return Ok(None);
    };
    let x = system.primal_from_dofs(dofs)?;
    Ok((x.len() == problem.n()).then_some(WarmStart { x, lambda }))
}

/// The `/solver` attributes `peak_rss_mb_<phase>` (in their order) as (phase, MB).
fn peak_rss_of(solver_attrs: &[(String, AttrValue)]) -> Vec<(String, f64)> {
    solver_attrs
        .iter()
        .filter_map(|(name, _)| {
            let phase = name.strip_prefix(PEAK_RSS_PREFIX)?;
            Some((phase.to_string(), numeric_attr(solver_attrs, name)?))
        })
        .collect()
}

/// A run's output transaction with its result (and companions) and the
/// scene's plots staged: staging checks each target now, before the run,
/// not after it. A shell's result has its 3D surface and a parameter-domain
/// XDMF. Returns the transaction and the staged result path.
pub fn stage_run_outputs(scene: &Scene, out: &Path) -> Result<(OutputTransaction, PathBuf)> {
    let dir = output_folder(out)?;
    let stem = out.file_stem().and_then(|s| s.to_str()).unwrap_or("result");
    let outputs = OutputTransaction::new(dir, stem, &scene.input_files())?;
    let staged_out = outputs.stage_result(out, models::kind(scene.model).has_surface())?;
    for kind in &scene.output.plots {
        outputs.stage(&plot_path(scene, out, *kind))?;
    }
    Ok((outputs, staged_out))
}

/// The model's results of a solve ([`ModelSystem::results`]).
pub fn model_results(scene: &Scene, solved: &Solved<'_>) -> ResultData {
    let Solved {
        system,
        problem,
        report,
    } = solved;
    results_on_solver_threads(scene, system.as_ref(), problem, report)
}

/// [`ModelSystem::results`], its products with A on the solver's threads.
pub fn results_on_solver_threads(
    scene: &Scene,
    system: &dyn ModelSystem,
    problem: &ContactProblem,
    report: &SolveReport,
) -> ResultData {
    system.results(problem, report, linear_options(&scene.solver).threads)
}

/// What a solve writes: the model's results, the scene text, the errors
/// against the exact solution (`output.errors`), the `/solver` group and,
/// for an adaptive scene or the "estimator" plot, the estimator. An exact
/// solution refused where the errors evaluate it is an error.
pub fn result_data(
    scene: &Scene,
    system: &dyn ModelSystem,
    problem: &ContactProblem,
    report: &SolveReport,
) -> Result<(ResultData, Option<ExactErrors>)> {
    let mut data = results_on_solver_threads(scene, system, problem, report);
    data.scene_text = scene.text.clone();
    let errors = if scene.output.errors {
        system.exact_errors(problem, report, linear_options(&scene.solver).threads)?
    } else {
        None
    };
    if let Some(e) = &errors {
        data.root_attrs.extend(e.attrs());
    }
    record_solver(&mut data, scene, report);
    if scene.adapt.is_some() || scene.output.plots.contains(&PlotKind::Estimator) {
        add_estimator(&mut data, system, problem, report);
    }
    Ok((data, errors))
}

/// The model's a posteriori indicators as the cell field `estimator` and
/// their total η = (Σ η_T²)^½ as the root attribute `estimator`; None (and
/// nothing added) when the model has no estimator.
fn add_estimator(
    data: &mut ResultData,
    system: &dyn ModelSystem,
    problem: &ContactProblem,
    report: &SolveReport,
) -> Option<f64> {
    let eta = system.estimator(problem, report)?;
    let total = eta.iter().map(|e| e * e).sum::<f64>().sqrt();
    data.fields.push(Field {
        name: "estimator".into(),
        values: eta,
        components: 1,
        location: Location::Cell,
    });
    data.root_attrs
        .push(("estimator".into(), AttrValue::F64(total)));
    Some(total)
}

/// Where the plot `kind` of a run goes: `FILE.<kind>.<png|svg>` beside `FILE.h5`.
fn plot_path(scene: &Scene, out: &Path, kind: PlotKind) -> PathBuf {
    let name = kind.name();
    out.with_extension(format!("{name}.{}", scene.output.plot_format.extension()))
}

/// The plots the scene asks for, beside the result file; nothing else is
/// drawn. The solver's history is drawn here, every other figure by the model.
pub fn write_plots(
    scene: &Scene,
    out: &Path,
    system: &dyn ModelSystem,
    data: &ResultData,
    report: &SolveReport,
    errors: Option<&ExactErrors>,
) -> Result<()> {
    let figure = FigureData { data, errors };
    for &kind in &scene.output.plots {
        let path = plot_path(scene, out, kind);
        let title = format!("{}: {} ({})", scene.name, kind.name(), scene.element.name());
        if kind != PlotKind::History {
            system.plot(kind, &path, &title, &figure)?;
        } else if !report.history.is_empty() {
            let mut columns = vec!["dual_step", "penetration", "complementarity", "kkt"];
            if report.history.column("gap_origin").is_some() {
                columns.push("gap_origin");
            }
            plot::plot_history(&path, &report.history, &columns, &title)?
        }
    }
    Ok(())
}

/// The `/solver` attributes and history of docs/formulation.md §5.
fn record_solver(data: &mut ResultData, scene: &Scene, report: &SolveReport) {
    let s = &scene.solver;
    let m = &report.measures;
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
        ("threads".into(), AttrValue::I64(s.threads)),
        (
            "stop".into(),
            AttrValue::Str(format!("{:?}", s.stop).to_lowercase()),
        ),
        (
            "dual_norm".into(),
            AttrValue::Str(format!("{:?}", s.dual_norm).to_lowercase()),
        ),
    ];
    if s.method == Method::ActiveSet {
        attrs.push((
            "cold_start".into(),
            AttrValue::Str(models::cold_start(s.cold_start, scene.model).name().into()),
        ));
    }
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
    if let Some(sp) = report.spectrum {
        attrs.push(("s_max_estimate".into(), AttrValue::F64(sp.s_max)));
        attrs.push(("s_min_ritz".into(), AttrValue::F64(sp.s_min)));
        attrs.push(("stability_bound".into(), AttrValue::F64(2.0 / sp.s_max)));
    }
    data.solver_attrs = attrs;
    data.history = report.history.columns.clone();
}
