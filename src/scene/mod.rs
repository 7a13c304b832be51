//! The scene: the one input of a run. A TOML file declares the domain and
//! mesh, the model, the elements, the data (load, obstacle), the solver and
//! the outputs; the solver assembles and runs only what it declares.
//!
//! Unknown keys are rejected; every value is range-checked; every error names
//! the file, the field (dotted path) and the reason. Any key can be
//! overridden from the command line (`--set solver.alpha=0.9`).
//!
//! Each table is a submodule with its own range checks (`mesh`, `load`,
//! `shell`, `obstacle`, `solver`, `output`, `adapt`); what each model takes
//! and refuses of the others' keys is `membrane` and `naghdi`. This module
//! holds the [`Scene`], its loading (TOML, `--set` overrides) and the order
//! of the checks ([`Scene::error`] names the field of every message).

use crate::error::{Error, Result};
/// A number or an expression in x, y, r (src/expression.rs).
pub use crate::expression::Expression;
/// The solver vocabulary the scene's strings map onto (it belongs to solvers/).
pub use crate::solvers::{DualNorm, LinearMethod, StepForm, StopRule};
use serde::Deserialize;
use std::path::{Path, PathBuf};

mod adapt;
mod load;
mod membrane;
mod mesh;
mod naghdi;
mod obstacle;
mod output;
mod shell;
mod solver;

pub use adapt::{AdaptSpec, Marking};
pub use load::{EdgeLoadSpec, LoadSpec, PointLoadSpec};
pub use mesh::MeshSpec;
pub use obstacle::{ContactMultiplier, ObstacleShape, ObstacleSpec};
pub use output::{ExactSpec, OutputSpec, PlotFormat, PlotKind};
pub use shell::{
    Axis, BoundaryCondition, BoundarySpec, Chart, ChartExpressions, GraphChart, ParametricChart,
    PlaneNormal, PointSupportSpec, ShellSpec,
};
pub use solver::{Alpha, AlphaKeyword, ColdStartSpec, Method, SolverSpec};

/// The largest magnitude of a scene number (and the inverse, the smallest
/// non-zero one): see `Scene::check_finite`.
pub use crate::expression::MAGNITUDE_LIMIT;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// A short name, used for default output names.
    pub name: String,
    pub model: Model,
    /// The element pair (primal – multiplier).
    pub element: ElementPair,
    pub mesh: MeshSpec,
    pub load: Option<LoadSpec>,
    /// The shell's chart, material, penalty and clamped parts (model "naghdi").
    pub shell: Option<ShellSpec>,
    /// No `[obstacle]` table: no contact, one linear solve.
    pub obstacle: Option<ObstacleSpec>,
    pub solver: SolverSpec,
    #[serde(default)]
    pub output: OutputSpec,
    /// `[adapt]`: the adaptive loop (docs/formulation.md §8); None: one solve.
    pub adapt: Option<AdaptSpec>,
    /// The scene file (for messages and relative paths).
    #[serde(skip)]
    pub source: PathBuf,
    /// The scene as run (file text with the overrides applied), stored in results.
    #[serde(skip)]
    pub text: String,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Model {
    /// −Δu = g, u = 0 on the boundary, u ≥ φ (docs/formulation.md §1).
    Membrane,
    /// The Cartesian Naghdi shell, optionally in contact with a rigid plane (docs/formulation.md §2).
    Naghdi,
}

impl Model {
    pub fn name(self) -> &'static str {
        match self {
            Model::Membrane => "membrane",
            Model::Naghdi => "naghdi",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub enum ElementPair {
    /// P1⊕B3 for u, P0 for λ (constraint on triangle means).
    #[serde(rename = "p1b-p0")]
    P1bP0,
    /// P2 for u, P1 for λ (constraint tested with P1 hats).
    #[serde(rename = "p2-p1")]
    P2P1,
    /// Shell only, the locking-free element: P2⊕B3 displacements and tangent
    /// rotations r = θ^β a_β, partial selective reduced integration of the
    /// membrane and shear energies; P1 contact multipliers.
    #[serde(rename = "p2b-psri")]
    P2bPsri,
    /// Shell only, recommended: the spaces and contact of `p2b-psri`, the
    /// membrane strain tied to Regge and the shear strain to Nédélec
    /// elements, every energy fully integrated.
    #[serde(rename = "p2b-mitc")]
    P2bMitc,
}

impl ElementPair {
    pub fn name(self) -> &'static str {
        match self {
            ElementPair::P1bP0 => "p1b-p0",
            ElementPair::P2P1 => "p2-p1",
            ElementPair::P2bPsri => "p2b-psri",
            ElementPair::P2bMitc => "p2b-mitc",
        }
    }

    /// The locking-free shell elements (tangent rotations, P1 multipliers).
    pub fn is_p2b_shell(self) -> bool {
        matches!(self, ElementPair::P2bPsri | ElementPair::P2bMitc)
    }
}

impl Scene {
    /// Reads a scene file, applies `--set key=value` overrides, validates.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Scene> {
        Scene::from_text(&read_text(path)?, path, overrides)
    }

    /// Parses scene text (`path` is used for messages and relative paths).
    pub fn from_text(text: &str, path: &Path, overrides: &[String]) -> Result<Scene> {
        let err = |field: &str, reason: String| Error::Scene {
            file: path.to_path_buf(),
            field: field.to_string(),
            reason,
        };
        let mut table = parse_toml(text, path)?;
        for o in overrides {
            apply_override(&mut table, o).map_err(|(field, reason)| err(&field, reason))?;
        }
        let value = toml::Value::Table(table.clone());
        let mut scene: Scene = serde_path_to_error::deserialize(value).map_err(|e| {
            let field = e.path().to_string();
            // toml appends "in `field`" lines: the field is named already.
            let reason = e.into_inner().to_string();
            let reason: Vec<&str> = reason.lines().filter(|l| !l.starts_with("in `")).collect();
            let mut reason = reason.join(" ").trim().to_string();
            let membrane = table.get("model").and_then(|m| m.as_str()) == Some("membrane");
            if field.starts_with("load.f") && membrane {
                reason.push_str(
                    " (`load.f` is the shell's force vector [f1, f2, f3]; a membrane's load is `load.g`, a number or an expression)",
                );
            }
            err(if field == "." { "(top level)" } else { &field }, reason)
        })?;
        scene.source = path.to_path_buf();
        scene.text = if overrides.is_empty() {
            text.to_string()
        } else {
            format!(
                "# overrides: {}\n{}",
                overrides.join(" "),
                toml::to_string(&table).unwrap_or_else(|_| text.to_string())
            )
        };
        scene.validate()?;
        Ok(scene)
    }

    /// An error in this scene's `field` (dotted key), naming its file.
    pub fn error(&self, field: &str, reason: impl Into<String>) -> Error {
        Error::Scene {
            file: self.source.clone(),
            field: field.to_string(),
            reason: reason.into(),
        }
    }

    /// Range checks that the types cannot express.
    fn validate(&self) -> Result<()> {
        crate::names::check_name(&self.name).map_err(|reason| self.error("name", reason))?;
        self.validate_mesh()?;
        self.validate_obstacle()?;
        match self.model {
            Model::Membrane => self.validate_membrane()?,
            Model::Naghdi => self.validate_naghdi()?,
        }
        self.validate_solver()?;
        self.validate_adapt()
    }

    /// Finite, and 0 or of a magnitude within [1/MAGNITUDE_LIMIT,
    /// MAGNITUDE_LIMIT]: assembly and the solvers multiply a few data values
    /// (E ε³, g × area, squares in norms), which must stay within f64.
    fn check_finite(&self, field: &str, v: f64) -> Result<()> {
        if !v.is_finite() {
            return Err(self.error(field, format!("must be a finite number, got {v}")));
        }
        if v != 0.0 && !(1.0 / MAGNITUDE_LIMIT..=MAGNITUDE_LIMIT).contains(&v.abs()) {
            return Err(self.error(
                field,
                format!("|{v:e}| is outside [1e-100, 1e100] (or 0): products of such numbers overflow f64"),
            ));
        }
        Ok(())
    }

    /// [`Scene::check_finite`], and > 0.
    fn check_positive(&self, field: &str, v: f64) -> Result<()> {
        self.check_finite(field, v)?;
        if v > 0.0 {
            Ok(())
        } else {
            Err(self.error(field, format!("must be > 0, got {v}")))
        }
    }

    /// The files a run reads (the scene, its `.geo` or mesh file): no
    /// output may replace them.
    pub fn input_files(&self) -> Vec<PathBuf> {
        let mut files = vec![self.source.clone()];
        files.extend(
            [&self.mesh.geo, &self.mesh.file]
                .into_iter()
                .flatten()
                .map(|f| self.resolve(f)),
        );
        files
    }

    /// A path of the scene, relative to the scene file's folder.
    pub fn resolve(&self, relative: &str) -> PathBuf {
        let p = Path::new(relative);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.source.parent().unwrap_or(Path::new(".")).join(p)
        }
    }
}

/// The text of a scene, study or benchmark file.
fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| Error::SceneFile {
        file: path.to_path_buf(),
        reason: format!("cannot read the file: {e}"),
    })
}

/// The TOML table of a file's text; a syntax error keeps TOML's message
/// with its lines, so the caret stands under the offending character.
fn parse_toml(text: &str, path: &Path) -> Result<toml::Table> {
    text.parse().map_err(|e: toml::de::Error| Error::SceneFile {
        file: path.to_path_buf(),
        reason: format!("not valid TOML:\n{}", e.to_string().trim_end()),
    })
}

/// Reads a TOML file into `T` (a study or benchmark description): errors
/// name the file, the dotted field and the reason, like a scene's.
pub fn read_toml_file<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let err = |field: &str, reason: String| Error::Scene {
        file: path.to_path_buf(),
        field: field.into(),
        reason,
    };
    let table = parse_toml(&read_text(path)?, path)?;
    serde_path_to_error::deserialize(toml::Value::Table(table))
        .map_err(|e| err(&e.path().to_string(), e.into_inner().to_string()))
}

/// Applies `a.b.c=value` to a TOML table. The value is parsed as TOML
/// (numbers, booleans, arrays, quoted strings); a bare word is taken as a string.
/// `--set` overrides as typed on the command line: a relative `mesh.file`
/// or `mesh.geo` there names a file from where the command runs (inside a
/// scene or a study it is relative to that file's folder), so it is made
/// absolute, and so recorded in the result.
pub fn command_line_overrides(sets: &[String]) -> Vec<String> {
    sets.iter().map(|s| command_line_path(s)).collect()
}

fn command_line_path(assignment: &str) -> String {
    let Some((key, raw)) = assignment.split_once('=') else {
        return assignment.to_string();
    };
    let unquoted = raw.trim().trim_matches('"');
    if !matches!(key.trim(), "mesh.file" | "mesh.geo") || Path::new(unquoted).is_absolute() {
        return assignment.to_string();
    }
    match std::env::current_dir() {
        Ok(cwd) => {
            let path = cwd.join(unquoted).display().to_string();
            format!("{}={}", key.trim(), toml::Value::String(path))
        }
        Err(_) => assignment.to_string(),
    }
}

fn apply_override(
    table: &mut toml::Table,
    assignment: &str,
) -> std::result::Result<(), (String, String)> {
    let (key, raw) = assignment.split_once('=').ok_or_else(|| {
        (
            assignment.to_string(),
            "an override is KEY=VALUE, e.g. solver.alpha=0.9".to_string(),
        )
    })?;
    let key = key.trim();
    let raw = raw.trim();
    let parts: Vec<&str> = key.split('.').collect();
    if parts.iter().any(|p| p.is_empty()) {
        return Err((key.to_string(), "empty key segment in override".into()));
    }
    let value = match format!("v = {raw}").parse::<toml::Table>() {
        Ok(mut t) => t.remove("v").expect("parsed one key"),
        Err(_) => toml::Value::String(raw.to_string()),
    };
    // A mesh given one way replaces the others: a file replaces the .geo and
    // its sizes, a .geo the file, a structured n the target size h and back.
    let replaced: &[&str] = match key {
        "mesh.file" => &["geo", "n", "h", "parameters"],
        "mesh.geo" => &["file"],
        "mesh.n" => &["file", "h"],
        "mesh.h" => &["file", "n"],
        _ => &[],
    };
    if let Some(toml::Value::Table(mesh)) = table.get_mut("mesh") {
        for k in replaced {
            mesh.remove(*k);
        }
    }
    let mut node = table;
    for (i, part) in parts.iter().enumerate() {
        if i + 1 == parts.len() {
            node.insert(part.to_string(), value);
            return Ok(());
        }
        let entry = node
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        node = match entry {
            toml::Value::Table(t) => t,
            _ => {
                return Err((
                    parts[..=i].join("."),
                    "is not a table, cannot set a key inside it".into(),
                ))
            }
        };
    }
    unreachable!("the loop returns at the last segment")
}

#[cfg(test)]
mod tests {
    use super::*;

    const DISK: &str = r#"
name = "t"
model = "membrane"
element = "p1b-p0"
[mesh]
geo = "disk.geo"
n = 8
[load]
g = -4.0
[obstacle]
shape = "paraboloid"
height = 0.3
curvature = 1.0
[solver]
method = "uzawa"
alpha = 11.0
step_form = "mean"
"#;

    fn parse(extra: &[&str]) -> Result<Scene> {
        let o: Vec<String> = extra.iter().map(|s| s.to_string()).collect();
        Scene::from_text(DISK, Path::new("s.toml"), &o)
    }

    fn message(r: Result<Scene>) -> String {
        r.expect_err("should be rejected").to_string()
    }

    #[test]
    fn parses_and_overrides() {
        let s = parse(&[
            "mesh.n=32",
            "solver.alpha=0.9",
            "element=p2-p1",
            "solver.alpha=\"auto\"",
        ])
        .unwrap();
        assert_eq!(s.mesh.n, Some(32));
        assert_eq!(s.element, ElementPair::P2P1);
        assert_eq!(s.solver.alpha, Some(Alpha::Keyword(AlphaKeyword::Auto)));
        assert!(s.text.contains("overrides"));
        assert_eq!(s.solver.tol, 1e-8);
    }

    #[test]
    fn a_mesh_given_one_way_replaces_the_others() {
        // DISK names a .geo with n = 8.
        let s = parse(&["mesh.file=\"m.msh\""]).unwrap();
        assert_eq!(s.mesh.file.as_deref(), Some("m.msh"));
        assert_eq!(
            (s.mesh.geo.as_deref(), s.mesh.n, s.mesh.h),
            (None, None, None)
        );
        assert!(!s.text.contains("geo =") && s.text.contains("file = \"m.msh\""));
        let s = parse(&["mesh.file=\"m.msh\"", "mesh.geo=\"d.geo\"", "mesh.h=0.2"]).unwrap();
        assert_eq!(
            (s.mesh.file.as_deref(), s.mesh.geo.as_deref()),
            (None, Some("d.geo"))
        );
        assert_eq!((s.mesh.n, s.mesh.h), (None, Some(0.2)));
        let s = parse(&["mesh.h=0.2", "mesh.n=4"]).unwrap();
        assert_eq!((s.mesh.n, s.mesh.h), (Some(4), None));
        // On the command line a relative mesh path is the working folder's.
        let cwd = std::env::current_dir().unwrap();
        let sets = command_line_overrides(&["mesh.file=m.msh".into(), "mesh.n=3".into()]);
        assert_eq!(
            sets[0],
            format!("mesh.file=\"{}\"", cwd.join("m.msh").display())
        );
        assert_eq!(sets[1], "mesh.n=3");
        let abs = command_line_overrides(&["mesh.geo=\"/x/d.geo\"".into()]);
        assert_eq!(abs[0], "mesh.geo=\"/x/d.geo\"");
    }

    #[test]
    fn errors_name_file_field_and_reason() {
        let m = message(parse(&["solver.alpah=1"]));
        assert!(
            m.contains("s.toml") && m.contains("solver") && m.contains("alpah"),
            "{m}"
        );
        let m = message(parse(&["solver.alpha=-1"]));
        assert!(m.contains("solver.alpha") && m.contains("> 0"), "{m}");
        let m = message(parse(&["solver.alpha=nan"]));
        assert!(m.contains("solver.alpha") && m.contains("finite"), "{m}");
        let m = message(parse(&["element=p3"]));
        assert!(m.contains("element") && m.contains("p3"), "{m}");
        let m = message(parse(&["mesh.n=0"]));
        assert!(m.contains("mesh.n"), "{m}");
        let m = message(parse(&["solver.tol=inf"]));
        assert!(m.contains("solver.tol"), "{m}");
        let m = message(parse(&["mesh"]));
        assert!(m.contains("KEY=VALUE"), "{m}");
        let m = message(Scene::from_text("name = [", Path::new("bad.toml"), &[]));
        assert!(
            m.contains("bad.toml") && m.contains("not valid TOML") && m.contains("column 9"),
            "{m}"
        );
    }
}
