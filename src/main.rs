//! `obstacle`: the command line of the pipeline.

// The doc comments below are clap's help text, written for the terminal
// (`<scene name>`, `[adapt]`), not rustdoc markup.
#![allow(rustdoc::invalid_html_tags, rustdoc::broken_intra_doc_links)]

use clap::{Parser, Subcommand};
use obstacle_fem::bench::{run_bench, run_case, work_precision, BenchConfig};
use obstacle_fem::console::NOT_CONVERGED_STATUS;
use obstacle_fem::error::{Error, Result};
use obstacle_fem::mesh::Mesh;
use obstacle_fem::output::marker::FailureMarker;
use obstacle_fem::output::{read_result, summary, OutputTransaction};
use obstacle_fem::pipeline::scene_mesh;
use obstacle_fem::progress::progress_wanted;
use obstacle_fem::run::run_scene;
use obstacle_fem::scene::{command_line_overrides, Scene};
use obstacle_fem::study::{
    csv_table, history_csv, history_tables, markdown_table, reference_study, rows_from_results,
    run_study, write_convergence_plots, write_snakefile, write_work_precision, Study,
};
use obstacle_fem::{out, outln};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "obstacle",
    version,
    about = "Obstacle and shell contact problems: gmsh → FE + Uzawa → HDF5"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Mesh, assemble and solve a scene; write FILE.h5 (+ .xdmf, .msh beside it).
    ///
    /// Exit status: 0 converged (KKT measures within solver.tol) or stopped by
    /// the scene's own rule (stop = "thesis" met); 2 stopped by solver.max_iter
    /// before that (the result is written and records converged = false,
    /// stop_reason = "max_iter"); 1 an error. With --failure-marker, 0 whenever
    /// the run's outcome is recorded (result or marker).
    Solve {
        /// The scene file (TOML: docs/formulation.md, pipelines/scenes/ for examples).
        scene: PathBuf,
        /// Override a scene key, e.g. --set mesh.n=64 --set solver.alpha=0.9
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Result file (default: build/results/<scene name>.h5).
        #[arg(long)]
        out: Option<PathBuf>,
        /// No progress display.
        #[arg(long)]
        quiet: bool,
        /// For workflow engines: a numerical failure (divergence, singular
        /// matrix, ...) writes its message to this file (a marker: its first
        /// line says so) and exits 0, as does a run that did not converge;
        /// success removes an earlier marker. Refused before the run: the
        /// result or a file named after it, an input, an existing file that is
        /// no marker. Other errors still fail.
        #[arg(long, value_name = "FILE")]
        failure_marker: Option<PathBuf>,
    },
    /// Mesh a scene's geometry with gmsh (MSH 2.2) and validate the mesh.
    Mesh {
        /// The scene file (TOML: docs/formulation.md, pipelines/scenes/ for examples).
        scene: PathBuf,
        /// Override a scene key, e.g. --set mesh.n=64 --set solver.alpha=0.9 (repeatable)
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Mesh file (default: build/meshes/<scene name>.msh).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Print a summary of a result file.
    Info { file: PathBuf },
    /// Run a scene's FreeFEM twin (same .msh, same discrete problem, Uzawa) and
    /// write FILE.h5 (+ .xdmf) in the layout of `solve`.
    Freefem {
        /// The scene file (TOML: docs/formulation.md, pipelines/scenes/ for examples).
        scene: PathBuf,
        /// Override a scene key, e.g. --set mesh.n=64 --set solver.alpha=0.9 (repeatable)
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Result file (default: build/freefem/<scene name>.h5).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Exactly K Uzawa iterations, K ≥ 1 (default: the scene's thesis stop, or,
        /// for stop = "kkt", min(max_iter, 1000) iterations).
        #[arg(long, value_name = "K", value_parser = clap::value_parser!(u64).range(1..))]
        iterations: Option<u64>,
    },
    /// Compare two result files on the same mesh, field by field; exit 1 beyond tolerance.
    Compare {
        a: PathBuf,
        b: PathBuf,
        /// Tolerance on the relative max-norm and L² differences.
        #[arg(long, default_value_t = 1e-8)]
        rtol: f64,
        /// Only these fields/dof vectors, e.g. u,r,psi,lambda (default: all in both).
        #[arg(long, value_delimiter = ',')]
        fields: Option<Vec<String>>,
        /// Print compact rows `| LABEL | quantity | difference | tolerance |` instead of the table.
        #[arg(long, value_name = "LABEL")]
        row: Option<String>,
    },
    /// Run a study (a scene over a grid of overrides) and print its table.
    Study {
        study: PathBuf,
        /// Folder for the runs' result files, the CSV and the Markdown table.
        #[arg(long, default_value = "build/studies")]
        out_dir: PathBuf,
        #[arg(long)]
        quiet: bool,
        /// Runs at a time (they are independent); progress bars show only with 1.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..),
              conflicts_with_all = ["workflow", "from_results"])]
        jobs: u64,
        /// Solve nothing: write OUT_DIR/Snakefile, one rule per run, then the tables.
        #[arg(long, value_enum, conflicts_with = "from_results")]
        workflow: Option<Workflow>,
        /// Solve nothing: the tables and plots from the runs' result files (or failure markers).
        #[arg(long)]
        from_results: bool,
    },
    /// An [adapt] scene's loop beside uniform meshes n = 8…64 (`make adapt`):
    /// result files, a markdown table and the error curves in OUT_DIR.
    Adapt {
        /// The scene file (TOML: docs/formulation.md, pipelines/scenes/ for examples).
        scene: PathBuf,
        /// Override a scene key, e.g. --set mesh.n=64 --set solver.alpha=0.9 (repeatable)
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        #[arg(long, default_value = "build/adapt")]
        out_dir: PathBuf,
    },
    /// Run the hard cases (pipelines/scenes/hard/) and print their table.
    Hard {
        #[arg(default_value = "pipelines/scenes/hard")]
        dir: PathBuf,
        /// Override a key of one case: CASE:KEY=VALUE (e.g. mesh-large:mesh.n=96).
        #[arg(long = "set", value_name = "CASE:KEY=VALUE")]
        set: Vec<String>,
        #[arg(long, default_value = "build/hard")]
        out_dir: PathBuf,
    },
    /// Write a result's HTML page: scene as run, mesh, solver and KKT measures, key numbers, plots.
    Report {
        result: PathBuf,
        /// The page (default: RESULT.html beside the result).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Write the page linking every table, figure and result under BUILD/results and BUILD/studies.
    Index {
        #[arg(default_value = "build")]
        build: PathBuf,
        /// The page (default: BUILD/index.html).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Benchmarks and work–precision studies (`make bench`, `make scale`, `make study`).
    Bench {
        #[command(subcommand)]
        command: BenchCommand,
    },
}

/// The workflow engines `study --workflow` writes for.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum Workflow {
    Snakemake,
}

/// The `bench` subcommands.
#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// Run a benchmark configuration (pipelines/bench/*.toml): table, CSV, plots.
    Run {
        config: PathBuf,
        #[arg(long, default_value = "build/bench")]
        out_dir: PathBuf,
        /// Override the configuration's cap (seconds per run).
        #[arg(long)]
        cap: Option<f64>,
    },
    /// One benchmark case (run by `bench run` in a child process): prints one `BENCH …` line.
    Case {
        /// The scene file (TOML: docs/formulation.md, pipelines/scenes/ for examples).
        scene: PathBuf,
        /// Override a scene key, e.g. --set mesh.n=64 --set solver.alpha=0.9 (repeatable)
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Result file of the contact solve.
        #[arg(long)]
        out: PathBuf,
        /// Only the floor: factorise the system matrix without contact and solve once.
        #[arg(long)]
        linear: bool,
        /// Tolerances whose first iteration (and estimate when not reached) to report.
        #[arg(long, value_delimiter = ',')]
        tols: Vec<f64>,
    },
    /// Work–precision study: error against wall time (report, plots, CSV).
    Study {
        /// Studies whose runs carry errors against the exact solution (disk).
        #[arg(long = "exact")]
        exact: Vec<PathBuf>,
        /// Studies measured against `--reference` (shell).
        #[arg(long = "against")]
        against: Vec<PathBuf>,
        /// `[adapt]` scenes (membrane, exact solution): the adaptive loop beside
        /// uniform meshes, both pairs, H¹ error against dofs and wall time.
        #[arg(long = "adapt")]
        adapt: Vec<PathBuf>,
        /// A study with one run: the reference solution of the `--against` studies.
        #[arg(long)]
        reference: Option<PathBuf>,
        /// Fields of the reference comparison.
        #[arg(long, value_delimiter = ',', default_value = "u,r,psi,lambda")]
        fields: Vec<String>,
        #[arg(long, default_value = "build/study")]
        out_dir: PathBuf,
    },
}

/// Runs a `bench` subcommand.
fn bench(command: BenchCommand) -> Result<()> {
    match command {
        BenchCommand::Run {
            config,
            out_dir,
            cap,
        } => {
            let mut cfg = BenchConfig::load(&config)?;
            if let Some(c) = cap {
                cfg.cap_seconds = c;
            }
            run_bench(&cfg, &config, &out_dir).map(|_| ())
        }
        BenchCommand::Case {
            scene,
            set,
            out,
            linear,
            tols,
        } => {
            let line = run_case(&scene, &set, &out, linear, &tols)?;
            outln!("BENCH {line}");
            Ok(())
        }
        BenchCommand::Study {
            exact,
            against,
            adapt,
            reference,
            fields,
            out_dir,
        } => work_precision(
            &exact,
            &against,
            &adapt,
            reference.as_deref(),
            &fields,
            &out_dir,
        ),
    }
}

fn main() -> ExitCode {
    // Every Newton step allocates and frees factors of the same sizes.
    obstacle_fem::linalg::keep_freed_memory();
    // clap's usage errors would exit with 2, which means "not converged" here.
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return if e.exit_code() == 0 {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            };
        }
    };
    match run(cli.command) {
        Ok(Outcome::Done) => ExitCode::SUCCESS,
        Ok(Outcome::NotConverged) => ExitCode::from(NOT_CONVERGED_STATUS),
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// How a command that did not fail ends: its exit status.
enum Outcome {
    Done,
    /// A run stopped by `solver.max_iter` before the scene's stop rule was
    /// met; its result is written and says so.
    NotConverged,
}

/// `obstacle solve`. With a failure marker a numerical failure is recorded
/// there and a run that did not converge is recorded in its result: both
/// are outcomes for the workflow (exit 0), which tabulates them.
fn solve(
    scene: &Path,
    set: &[String],
    out: Option<PathBuf>,
    quiet: bool,
    failure_marker: Option<&Path>,
) -> Result<Outcome> {
    let scene = Scene::load(scene, &command_line_overrides(set))?;
    let out = out.unwrap_or_else(|| PathBuf::from(format!("build/results/{}.h5", scene.name)));
    // Checked before the run: a marker path that is not the command's own
    // is refused before meshing, not after a long solve.
    let marker = failure_marker
        .map(|m| FailureMarker::new(m, &out, &scene.input_files()))
        .transpose()?;
    let s = match (run_scene(&scene, &out, !quiet), &marker) {
        (Err(e @ Error::Numerical { .. }), Some(marker)) => {
            marker.write(&e.to_string())?;
            outln!("{}: failed: {e} → {}", scene.name, marker.path().display());
            return Ok(Outcome::Done);
        }
        (result, marker) => {
            let s = result?;
            if let Some(marker) = marker {
                marker.remove_stale()?;
            }
            s
        }
    };
    outln!(
        "{}: {} on {} triangles ({} dofs), {} iterations, stop: {}, converged: {}, KKT {:.3e}, {:.3}s → {}",
        s.scene,
        s.element,
        s.n_triangles,
        s.n_dofs,
        s.iterations,
        s.stop_reason,
        s.converged,
        s.measures.kkt,
        s.wall_seconds,
        out.display()
    );
    if let Some(e) = s.errors {
        outln!(
            "  errors vs exact: L² {:.4e}, H¹ {:.4e}; contact radius {:.5} (exact {:.5})",
            e.l2,
            e.h1,
            e.contact_radius,
            e.exact_contact_radius
        );
    }
    if !s.converged {
        eprintln!(
            "warning: not converged: relative KKT measure {:.3e} > tol {:.1e} after {} iterations (stop: {})",
            s.measures.kkt, scene.solver.tol, s.iterations, s.stop_reason
        );
    }
    Ok(if s.stopped_as_asked() || marker.is_some() {
        Outcome::Done
    } else {
        Outcome::NotConverged
    })
}

fn run(command: Command) -> Result<Outcome> {
    let done: Result<()> = match command {
        Command::Solve {
            scene,
            set,
            out,
            quiet,
            failure_marker,
        } => return solve(&scene, &set, out, quiet, failure_marker.as_deref()),
        Command::Mesh { scene, set, out } => {
            let scene = Scene::load(&scene, &command_line_overrides(&set))?;
            let out =
                out.unwrap_or_else(|| PathBuf::from(format!("build/meshes/{}.msh", scene.name)));
            let mesh = mesh_command(&scene, &out)?;
            outln!(
                "{}: {} vertices, {} triangles, {} edges, h = {:.4}",
                out.display(),
                mesh.n_vertices(),
                mesh.n_triangles(),
                mesh.n_edges(),
                mesh.h_max()
            );
            Ok(())
        }
        Command::Info { file } => {
            out!("{}", summary(&read_result(&file)?));
            // An adaptive result: every step read back, one table row each.
            let steps = obstacle_fem::output::read_steps(&file)?;
            if !steps.is_empty() {
                outln!("adaptive steps: {}", steps.len());
                out!(
                    "{}",
                    obstacle_fem::adapt::steps_table(&obstacle_fem::adapt::rows_of(&steps))
                );
            }
            Ok(())
        }
        Command::Freefem {
            scene,
            set,
            out,
            iterations,
        } => obstacle_fem::freefem::command(
            &Scene::load(&scene, &command_line_overrides(&set))?,
            out,
            iterations.map(|k| k as usize),
        ),
        Command::Compare {
            a,
            b,
            rtol,
            fields,
            row,
        } => {
            obstacle_fem::output::compare::command(&a, &b, rtol, fields.as_deref(), row.as_deref())
        }
        Command::Adapt {
            scene,
            set,
            out_dir,
        } => {
            let scene = Scene::load(&scene, &command_line_overrides(&set))?;
            std::fs::create_dir_all(&out_dir).map_err(|e| {
                obstacle_fem::Error::output(&out_dir, format!("cannot create the folder: {e}"))
            })?;
            out!(
                "{}",
                obstacle_fem::adapt::compare_command(&scene, &out_dir)?
            );
            Ok(())
        }
        Command::Hard { dir, set, out_dir } => obstacle_fem::hard::command(&dir, &out_dir, &set),
        Command::Bench { command } => bench(command),
        Command::Report { result, out } => {
            let page = obstacle_fem::report::report_command(&result, out.as_deref())?;
            outln!("report: {}", page.display());
            Ok(())
        }
        Command::Index { build, out } => {
            let page = obstacle_fem::report::index_command(&build, out.as_deref())?;
            outln!("index: {}", page.display());
            Ok(())
        }
        Command::Study {
            study,
            out_dir,
            quiet,
            jobs,
            workflow,
            from_results,
        } => {
            if let Some(Workflow::Snakemake) = workflow {
                let exe = std::env::current_exe().map_err(|e| {
                    Error::output("obstacle", format!("cannot find this program's path: {e}"))
                })?;
                let (snakefile, profile) = write_snakefile(&study, &out_dir, &exe)?;
                outln!(
                    "workflow: {} (run `snakemake -j N` in {}, or on Slurm `snakemake --profile slurm`: {})",
                    snakefile.display(),
                    out_dir.display(),
                    profile.display()
                );
                return Ok(Outcome::Done);
            }
            let rows = if from_results {
                rows_from_results(&study, &out_dir)?
            } else {
                run_study(&study, &out_dir, !quiet && progress_wanted(), jobs as usize)?
            };
            let spec = Study::load(&study)?;
            // The tables and plots appear together; the runs' files are each their own.
            let outputs =
                OutputTransaction::new(&out_dir, &spec.name, std::slice::from_ref(&study))?;
            let mut md = markdown_table(&spec, &rows);
            // Every table also as CSV (`STUDY.csv`, `STUDY.history.csv`,
            // `STUDY.reference.csv`): the index renders them.
            let mut csvs = vec![("csv", csv_table(&spec, &rows))];
            if let Some(h) = &spec.history {
                md.push_str(&history_tables(h, &rows));
                csvs.push(("history.csv", history_csv(h, &rows)));
            }
            let mut plots = Vec::new();
            if let Some(r) = &spec.reference {
                let reference = reference_study(&spec, r, &rows, &outputs)?;
                md.push_str(&reference.md);
                csvs.push(("reference.csv", reference.csv));
                plots.extend(reference.files);
            }
            if let Some(w) = &spec.work_precision {
                let (table, files) = write_work_precision(&spec, w, &rows, &outputs)?;
                md.push_str(&table);
                plots.extend(files);
            }
            if spec.convergence_plot {
                plots.extend(write_convergence_plots(&spec, &rows, &outputs)?);
            }
            let table = |ext: &str| outputs.stage(&out_dir.join(format!("{}.{ext}", spec.name)));
            write_text(&table("md")?, &md)?;
            for (ext, csv) in csvs
                .iter()
                .filter(|(ext, csv)| *ext == "csv" || !csv.is_empty())
            {
                write_text(&table(ext)?, csv)?;
            }
            outputs.commit()?;
            out!("{md}");
            for f in plots {
                outln!("plot: {}", f.display());
            }
            Ok(())
        }
    };
    done.map(|()| Outcome::Done)
}

/// `obstacle mesh`: the scene's mesh, validated, at `out` (a `.msh` that is
/// not an input of the scene), in one output transaction. A `mesh.file`
/// scene's mesh is validated and copied there.
fn mesh_command(scene: &Scene, out: &Path) -> Result<Mesh> {
    if out.extension().and_then(|e| e.to_str()) != Some("msh") {
        return Err(Error::output(out, "the mesh file name must end in .msh"));
    }
    let folder = out.parent().unwrap_or(Path::new(""));
    let stem = out.file_stem().and_then(|s| s.to_str()).unwrap_or("mesh");
    let outputs = OutputTransaction::new(folder, stem, &scene.input_files())?;
    let staged = outputs.stage(out)?;
    let mesh = scene_mesh(scene, &staged)?;
    if let Some(file) = &scene.mesh.file {
        let file = scene.resolve(file);
        std::fs::copy(&file, &staged)
            .map_err(|e| Error::output(out, format!("cannot copy {}: {e}", file.display())))?;
    }
    outputs.commit()?;
    Ok(mesh)
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    obstacle_fem::output::write_text_atomically(path, text)
}
