//! The adaptive loop of a scene's `[adapt]` table (docs/formulation.md §8):
//! solve → estimate → mark (Dörfler) → remesh → solve again, warm-started
//! from the previous step's solution carried to the new mesh.
//!
//! Remeshing is gmsh on the scene's `.geo` with a background size field
//! (`-bgm`, a `.pos` view of target sizes at the vertices): the pipeline's own
//! mesher, curved boundaries resolved by gmsh, the same mesh quality as the
//! uniform runs. Why gmsh and not bisection: docs/formulation.md §8.
//! Every step (mesh, fields, dofs, estimator, errors, time) goes into one
//! result file, `/steps/NNN`, with the last step at the root.

use crate::error::{Error, Result};
use crate::gmsh::run_gmsh_sized;
use crate::mesh::Mesh;
use crate::output::transaction::RemoveOnSignal;
use crate::output::{numeric_attr, write_adaptive_result, AttrValue, ResultData};
use crate::pipeline::{
    result_data, run_uniform, scene_mesh, setup_model, solve_on, stage_run_outputs, write_plots,
    RunSummary, Solved, Start,
};
use crate::scene::{AdaptSpec, Scene};
use crate::transfer::prolong_dofs;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

/// One step of the loop, as the summary and `make adapt` report it.
#[derive(Debug, Clone)]
pub struct StepRow {
    pub n_dofs: usize,
    pub n_triangles: usize,
    /// η = (Σ η_T²)^½.
    pub estimator: f64,
    /// ‖∇(u − u_h)‖ when the exact solution is known.
    pub error_h1: Option<f64>,
    /// Wall time since the loop started, at the end of this step's estimate
    /// (meshing, transfer, assembly, solve, estimate of all steps so far).
    pub seconds: f64,
    /// The step's values of [`STEP_QUANTITIES`] it has (the shell's u3 min,
    /// contact area, ∫λ, strain energy): what converges under refinement
    /// when no exact solution is known.
    pub quantities: Vec<(&'static str, f64)>,
}

/// Root attributes tabulated per step when every step has them, with their
/// column titles.
pub const STEP_QUANTITIES: [(&str, &str); 4] = [
    ("u3_min", "u3 min"),
    ("contact_area", "contact area"),
    ("contact_force", "∫λ"),
    ("strain_energy", "strain energy"),
];

impl StepRow {
    /// The row of one step's result: its root attributes (as written, or
    /// read back) and its triangle count.
    pub fn of_step(attrs: &[(String, AttrValue)], n_triangles: usize) -> StepRow {
        let attr = |n: &str| numeric_attr(attrs, n);
        StepRow {
            n_dofs: attr("n_dofs").unwrap_or(0.0) as usize,
            n_triangles,
            estimator: attr("estimator").unwrap_or(f64::NAN),
            error_h1: attr("error_h1_u"),
            seconds: attr("adapt_seconds").unwrap_or(f64::NAN),
            quantities: STEP_QUANTITIES
                .iter()
                .filter_map(|&(name, _)| attr(name).map(|v| (name, v)))
                .collect(),
        }
    }

    /// η / ‖∇(u − u_h)‖.
    pub fn effectivity(&self) -> Option<f64> {
        self.error_h1.map(|e| self.estimator / e)
    }
}

/// Why the loop stopped (root attribute `adapt_stop`).
fn stop_reason(
    spec: &AdaptSpec,
    step: usize,
    estimator: f64,
    next_dofs: Option<usize>,
) -> Option<String> {
    if let Some(target) = spec.target_error {
        if estimator <= target {
            return Some(format!("target_error: η = {estimator:.4e} ≤ {target:e}"));
        }
    }
    if step + 1 >= spec.max_steps as usize {
        return Some(format!("max_steps: {} solves", spec.max_steps));
    }
    match (next_dofs, spec.max_dofs) {
        (Some(n), Some(max)) if n as i64 > max => {
            Some(format!("max_dofs: the next mesh has {n} unknowns > {max}"))
        }
        _ => None,
    }
}

/// Dörfler marking: the fewest triangles, largest η_T first, whose Σ η_T²
/// reaches θ Σ η_T².
pub fn dorfler(eta: &[f64], theta: f64) -> Vec<bool> {
    let mut order: Vec<usize> = (0..eta.len()).collect();
    order.sort_by(|&a, &b| eta[b].total_cmp(&eta[a]).then(a.cmp(&b)));
    let total: f64 = eta.iter().map(|e| e * e).sum();
    let mut marked = vec![false; eta.len()];
    let mut sum = 0.0;
    for t in order {
        if sum >= theta * total {
            break;
        }
        marked[t] = true;
        sum += eta[t] * eta[t];
    }
    marked
}

/// Target mesh sizes at the vertices: each triangle asks for its mean edge
/// length, halved when marked; a vertex takes the smallest request around it.
pub fn target_sizes(mesh: &Mesh, marked: &[bool]) -> Vec<f64> {
    let mut size = vec![f64::INFINITY; mesh.n_vertices()];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let mean = mesh.triangle_edges[t]
            .iter()
            .map(|&e| mesh.edge_length(e))
            .sum::<f64>()
            / 3.0;
        let h = if marked[t] { 0.5 * mean } else { mean };
        for &v in tri {
            size[v] = size[v].min(h);
        }
    }
    size
}

/// The sizes as a gmsh post-processing view (`ST` scalar triangles), the
/// background mesh of the next meshing.
fn background_view(mesh: &Mesh, size: &[f64]) -> String {
    let mut s = String::from("View \"size\" {\n");
    for tri in &mesh.triangles {
        let [a, b, c] = tri.map(|v| mesh.vertices[v]);
        let _ = writeln!(
            s,
            "ST({},{},0,{},{},0,{},{},0){{{},{},{}}};",
            a[0], a[1], b[0], b[1], c[0], c[1], size[tri[0]], size[tri[1]], size[tri[2]]
        );
    }
    s.push_str("};\n");
    s
}

/// The next mesh: gmsh on the scene's `.geo` in its unstructured mode
/// (`n = 0`, `h` = the current largest edge, so the background sizes rule).
fn remesh(scene: &Scene, mesh: &Mesh, marked: &[bool], dir: &Path, step: usize) -> Result<Mesh> {
    let geo = scene.resolve(
        scene
            .mesh
            .geo
            .as_deref()
            .expect("validated: adapt needs geo"),
    );
    let pos = dir.join(format!("size-{step:03}.pos"));
    let view = background_view(mesh, &target_sizes(mesh, marked));
    std::fs::write(&pos, view)
        .map_err(|e| Error::output(&pos, format!("cannot write the size field: {e}")))?;
    let mut params = vec![("n".to_string(), 0.0), ("h".to_string(), mesh.h_max())];
    params.extend(scene.mesh.parameters.iter().map(|(k, v)| (k.clone(), *v)));
    let msh = dir.join(format!("step-{step:03}.msh"));
    run_gmsh_sized(&geo, &msh, &params, &pos)?;
    let mut next = Mesh::read_msh(&msh).map_err(|e| match e {
        Error::Mesh { reason, .. } => Error::mesh(
            &geo,
            format!("the mesh gmsh made for adaptive step {step}: {reason}"),
        ),
        other => other,
    })?;
    next.source = geo;
    Ok(next)
}

/// Runs the adaptive loop of `scene` and writes every step into `out`
/// (one [`crate::output::OutputTransaction`]: the file, its XDMF, the plots
/// of the last step). The summary is the last step's, with the whole loop's
/// wall time.
pub fn run_adaptive(scene: &Scene, out: &Path) -> Result<(RunSummary, Vec<StepRow>)> {
    let start = Instant::now();
    let spec = scene.adapt.as_ref().expect("run_adaptive needs [adapt]");
    let (outputs, staged_out) = stage_run_outputs(scene, out)?;
    let meshes = tempfile::tempdir().map_err(|e| {
        Error::output(
            std::env::temp_dir(),
            format!("cannot create a temporary folder: {e}"),
        )
    })?;
    let _on_signal = RemoveOnSignal::new(meshes.path());

    let mut mesh = scene_mesh(scene, &meshes.path().join("step-000.msh"))?;
    // Meshing and transfer time of the step about to be solved.
    let mut mesh_seconds = start.elapsed().as_secs_f64();
    let mut steps: Vec<(Mesh, ResultData)> = Vec::new();
    let mut rows: Vec<StepRow> = Vec::new();
    let mut carried: Vec<(String, Vec<f64>)> = Vec::new();
    loop {
        let k = steps.len();
        let Solved {
            system,
            problem,
            report,
        } = solve_on(scene, &mesh, Start::Carried(&carried), false, &mut |_| {})?;
        let (mut data, errors) = result_data(scene, system.as_ref(), &problem, &report)?;
        let estimator = numeric_attr(&data.root_attrs, "estimator").ok_or_else(|| {
            scene.error(
                "adapt",
                format!("the {} model has no estimator", scene.model.name()),
            )
        })?;
        let seconds = start.elapsed().as_secs_f64();
        data.root_attrs.extend([
            ("adapt_step".to_string(), AttrValue::I64(k as i64)),
            ("adapt_seconds".to_string(), AttrValue::F64(seconds)),
            (
                "adapt_mesh_seconds".to_string(),
                AttrValue::F64(mesh_seconds),
            ),
        ]);
        rows.push(StepRow::of_step(&data.root_attrs, mesh.n_triangles()));
        // Stop, or remesh where the estimator is large.
        let mut stop = stop_reason(spec, k, estimator, None);
        let next = match stop {
            Some(_) => None,
            None => {
                let meshing = Instant::now();
                let eta = &data.fields.iter().find(|f| f.name == "estimator");
                let eta = &eta.expect("add_estimator wrote it").values;
                let next = remesh(
                    scene,
                    &mesh,
                    &dorfler(eta, spec.theta),
                    meshes.path(),
                    k + 1,
                )?;
                // The model's own count (membrane: u; shell: every field and λ).
                let next_dofs = setup_model(scene, &next)?.n_dofs();
                stop = stop_reason(spec, k, estimator, Some(next_dofs));
                mesh_seconds = meshing.elapsed().as_secs_f64();
                stop.is_none().then_some(next)
            }
        };
        if let Some(reason) = &stop {
            data.root_attrs
                .push(("adapt_stop".into(), AttrValue::Str(reason.clone())));
            data.root_attrs
                .push(("adapt_steps".into(), AttrValue::I64(k as i64 + 1)));
            write_plots(
                scene,
                &staged_out,
                system.as_ref(),
                &data,
                &report,
                errors.as_ref(),
            )?;
            let summary =
                RunSummary::of_run(scene, system.as_ref(), &report, errors, &data, start, out);
            drop(system);
            steps.push((mesh, data));
            let refs: Vec<(&Mesh, &ResultData)> = steps.iter().map(|(m, d)| (m, d)).collect();
            write_adaptive_result(&staged_out, &refs)?;
            outputs.commit()?;
            return Ok((summary, rows));
        }
        drop(system);
        let next = next.expect("no stop: a next mesh");
        let previous = (mesh, data);
        let transfer = Instant::now();
        carried = prolong_dofs(&previous.1, &previous.0, &next);
        mesh_seconds += transfer.elapsed().as_secs_f64();
        steps.push(previous);
        mesh = next;
    }
}

/// The steps as a markdown table (dofs, triangles, η, error, effectivity,
/// seconds, then each of [`STEP_QUANTITIES`] that every step has, to six
/// digits: the change between steps is the measure of convergence).
pub fn steps_table(rows: &[StepRow]) -> String {
    let value = |r: &StepRow, name: &str| r.quantities.iter().find(|q| q.0 == name).map(|q| q.1);
    let shown: Vec<(&str, &str)> = STEP_QUANTITIES
        .into_iter()
        .filter(|(name, _)| !rows.is_empty() && rows.iter().all(|r| value(r, name).is_some()))
        .collect();
    let mut s =
        String::from("| step | dofs | triangles | estimator η | H¹ error | η / error | seconds |");
    for (_, title) in &shown {
        let _ = write!(s, " {title} |");
    }
    s.push_str("\n|---:|---:|---:|---:|---:|---:|---:|");
    s.push_str(&"---:|".repeat(shown.len()));
    s.push('\n');
    for (k, r) in rows.iter().enumerate() {
        let opt = |v: Option<f64>, p: usize| v.map_or("–".to_string(), |v| format!("{v:.p$e}"));
        let _ = write!(
            s,
            "| {k} | {} | {} | {:.3e} | {} | {} | {:.2} |",
            r.n_dofs,
            r.n_triangles,
            r.estimator,
            opt(r.error_h1, 3),
            r.effectivity().map_or("–".into(), |e| format!("{e:.2}")),
            r.seconds
        );
        for (name, _) in &shown {
            let v = value(r, name).expect("shown: every step has it");
            let _ = write!(s, " {} |", crate::numbers::meaningful(v, 6));
        }
        s.push('\n');
    }
    s
}

/// The step rows of an adaptive result read back (`obstacle info`).
pub fn rows_of(steps: &[crate::output::ResultFile]) -> Vec<StepRow> {
    steps
        .iter()
        .map(|f| StepRow::of_step(&f.data.root_attrs, f.triangles.len()))
        .collect()
}

/// The uniform levels `make adapt` compares against (structured disk meshes, `mesh.n`).
pub const UNIFORM_LEVELS: [i64; 4] = [8, 16, 32, 64];

/// The fitted rates leave out the coarse, pre-asymptotic meshes.
const RATE_MIN_DOFS: f64 = 1000.0;

/// One run of a comparison curve: dofs, H¹ error and wall time.
pub type CurvePoint = (f64, f64, f64);

/// The scene's adaptive loop and its uniform levels [`UNIFORM_LEVELS`], both
/// with errors against the exact solution: result files `LABEL.h5` (every
/// step) and `LABEL-uniform-N.h5` in `out_dir`, LABEL = `NAME-ELEMENT`.
/// Returns the adaptive steps and the uniform points (time: the whole run,
/// meshing included; the adaptive one with remeshing and transfer).
pub fn compare_runs(scene: &Scene, out_dir: &Path) -> Result<(Vec<StepRow>, Vec<CurvePoint>)> {
    if scene.adapt.is_none() || !scene.output.errors {
        return Err(scene.error(
            "adapt",
            "`obstacle adapt` compares an [adapt] scene with `output.errors = true` against uniform meshes",
        ));
    }
    let label = compare_label(scene);
    let (_, rows) = run_adaptive(scene, &out_dir.join(format!("{label}.h5")))?;
    let mut uniform: Vec<CurvePoint> = Vec::new();
    for n in UNIFORM_LEVELS {
        let mut level = scene.clone();
        level.adapt = None;
        level.mesh.n = Some(n);
        level.mesh.h = None;
        level.output.plots.clear();
        let s = run_uniform(
            &level,
            &out_dir.join(format!("{label}-uniform-{n}.h5")),
            false,
        )?;
        let error = s.errors.map_or(f64::NAN, |e| e.h1);
        uniform.push((s.n_dofs as f64, error, s.wall_seconds));
    }
    Ok((rows, uniform))
}

/// `NAME-ELEMENT`: the file names of one comparison.
fn compare_label(scene: &Scene) -> String {
    format!("{}-{}", scene.name, scene.element.name())
}

/// The adaptive steps as curve points (dofs, H¹ error, seconds).
pub fn adaptive_points(rows: &[StepRow]) -> Vec<CurvePoint> {
    rows.iter()
        .map(|r| (r.n_dofs as f64, r.error_h1.unwrap_or(f64::NAN), r.seconds))
        .collect()
}

/// `obstacle adapt SCENE`: [`compare_runs`], then in `out_dir`
/// `NAME-ELEMENT.md` (both tables, and dofs and seconds to the finest
/// uniform error) and the curves `NAME-ELEMENT.dofs.png` (error against
/// dofs) and `NAME-ELEMENT.time.png` (against wall time, meshing and
/// transfer included). Returns the markdown text.
pub fn compare_command(scene: &Scene, out_dir: &Path) -> Result<String> {
    let (rows, uniform) = compare_runs(scene, out_dir)?;
    let label = compare_label(scene);
    let adaptive = adaptive_points(&rows);
    let title = format!(
        "{}: adaptive vs uniform ({})",
        scene.name,
        scene.element.name()
    );
    let series = |pick: fn(&CurvePoint) -> (f64, f64)| {
        vec![
            ("adaptive".to_string(), adaptive.iter().map(pick).collect()),
            ("uniform".to_string(), uniform.iter().map(pick).collect()),
        ]
    };
    crate::plot::plot_convergence(
        &out_dir.join(format!("{label}.dofs.png")),
        &series(|p| (p.0, p.1)),
        "dofs",
        "H¹ error",
        &title,
        &[-0.5, -1.0],
    )?;
    crate::plot::plot_convergence(
        &out_dir.join(format!("{label}.time.png")),
        &series(|p| (p.2, p.1)),
        "wall seconds (meshing and transfer included)",
        "H¹ error",
        &title,
        &[],
    )?;
    let markdown = compare_markdown(&label, &rows, &uniform);
    crate::output::write_text_atomically(&out_dir.join(format!("{label}.md")), &markdown)?;
    Ok(markdown)
}

/// The comparison's markdown: both tables and the cost of the finest uniform error.
pub fn compare_markdown(label: &str, rows: &[StepRow], uniform: &[CurvePoint]) -> String {
    let mut s = format!(
        "## {label}: adaptive\n\n{}\n## {label}: uniform\n\n",
        steps_table(rows)
    );
    s.push_str("| n | dofs | H¹ error | seconds |\n|---:|---:|---:|---:|\n");
    for (n, (dofs, error, seconds)) in UNIFORM_LEVELS.iter().zip(uniform) {
        let _ = writeln!(s, "| {n} | {dofs} | {error:.3e} | {seconds:.2} |");
    }
    let (n, (dofs, error, seconds)) = (
        UNIFORM_LEVELS[UNIFORM_LEVELS.len() - 1],
        uniform[uniform.len() - 1],
    );
    let reached = rows
        .iter()
        .enumerate()
        .find(|(_, r)| r.error_h1.is_some_and(|e| e <= error));
    let rate = |pts: &[CurvePoint]| {
        let asymptotic: Vec<(f64, f64)> = pts
            .iter()
            .filter(|p| p.0 >= RATE_MIN_DOFS)
            .map(|p| (p.0, p.1))
            .collect();
        crate::plot::loglog_slope(&asymptotic).map_or("–".into(), |r| format!("{r:.2}"))
    };
    let _ = writeln!(
        s,
        "\nFitted rates in dofs N (H¹ error ~ N^s, least squares over the points with N ≥ {RATE_MIN_DOFS}): uniform s = {}, adaptive s = {}.",
        rate(uniform),
        rate(&adaptive_points(rows))
    );
    let _ = writeln!(s);
    match reached {
        Some((k, r)) => {
            let _ = writeln!(
                s,
                "Uniform n = {n}: H¹ error {error:.3e} with {dofs} dofs in {seconds:.2} s. Adaptive: ≤ that error at step {k} with {} dofs ({:.2}× the uniform dofs) after {:.2} s in all ({:.2}× the uniform time).",
                r.n_dofs,
                r.n_dofs as f64 / dofs,
                r.seconds,
                r.seconds / seconds
            );
        }
        None => {
            let _ = writeln!(
                s,
                "Uniform n = {n}: H¹ error {error:.3e} with {dofs} dofs in {seconds:.2} s. The adaptive loop stopped before reaching it (best {:.3e} with {} dofs).",
                rows.last().and_then(|r| r.error_h1).unwrap_or(f64::NAN),
                rows.last().map_or(0, |r| r.n_dofs)
            );
        }
    }
    s
}
