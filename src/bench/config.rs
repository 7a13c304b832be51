//! The benchmark configuration (`pipelines/bench/*.toml`): problems, mesh
//! levels, methods, tolerances, the cap.

use crate::error::{Error, Result};
use crate::scene::read_toml_file;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;

/// A benchmark configuration (`pipelines/bench/*.toml`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchConfig {
    pub name: String,
    /// Seconds per run for the iterative methods (Uzawa, …).
    pub cap_seconds: f64,
    /// Tolerances of the relative KKT measure, loosest first.
    pub tolerances: Vec<f64>,
    pub method: Vec<BenchMethod>,
    pub problem: Vec<BenchProblem>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchMethod {
    pub label: String,
    /// Overrides selecting the method, e.g. ["solver.method=active-set"].
    pub set: Vec<String>,
    /// This method's cap (default: the configuration's).
    pub cap_seconds: Option<f64>,
    /// Cost of one iteration in floors: "solve" (one solve with the fixed
    /// factorisation) or "factor" (a refactorisation, active-set).
    #[serde(default = "default_cost")]
    pub iteration_cost: String,
    /// Once capped at a level, report the finer levels as `>cap` without
    /// running them (default true).
    #[serde(default = "default_true")]
    pub skip_after_cap: bool,
    /// Cap relative to another method measured before at the same level:
    /// cap = factor × its time to `tol` (e.g. 1000 × active-set to 1e-6), so
    /// a capped run proves "at least factor× slower" directly.
    pub cap_relative: Option<CapRelative>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CapRelative {
    pub method: String,
    pub factor: f64,
    pub tol: f64,
}

fn default_true() -> bool {
    true
}

fn default_cost() -> String {
    "solve".into()
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchProblem {
    pub label: String,
    /// Scene file, relative to the configuration file.
    pub scene: String,
    /// Overrides for every run of this problem.
    #[serde(default)]
    pub set: Vec<String>,
    /// The level key (default "mesh.n") and its values.
    #[serde(default = "default_key")]
    pub key: String,
    pub levels: Vec<toml::Value>,
    /// Extra overrides per method label, e.g. uzawa = ["solver.alpha=0.01"].
    #[serde(default)]
    pub method_set: BTreeMap<String, Vec<String>>,
    /// Methods run on this problem (default: all).
    pub methods: Option<Vec<String>>,
    /// Levels per method label (default: all levels). The others get no
    /// row, unless the method was capped at a coarser level: then they are
    /// "not run" with the cap as their lower bound, like every level after
    /// a capped one.
    #[serde(default)]
    pub method_levels: BTreeMap<String, Vec<toml::Value>>,
}

fn default_key() -> String {
    "mesh.n".into()
}

impl BenchConfig {
    pub fn load(path: &Path) -> Result<BenchConfig> {
        let err = |field: &str, reason: String| Error::Scene {
            file: path.to_path_buf(),
            field: field.into(),
            reason,
        };
        let cfg: BenchConfig = read_toml_file(path)?;
        if cfg.tolerances.is_empty()
            || cfg
                .tolerances
                .iter()
                .any(|t| t.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater))
        {
            return Err(err("tolerances", "at least one, all > 0".into()));
        }
        if cfg.cap_seconds.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return Err(err("cap_seconds", "must be > 0".into()));
        }
        // Each of these becomes part of a file name.
        crate::names::check_name(&cfg.name).map_err(|reason| err("name", reason))?;
        for p in &cfg.problem {
            crate::names::check_name(&p.label)
                .map_err(|reason| err("problem.label", format!("`{}` {reason}", p.label)))?;
        }
        for m in &cfg.method {
            crate::names::check_name(&m.label)
                .map_err(|reason| err("method.label", format!("`{}` {reason}", m.label)))?;
            if m.iteration_cost != "solve" && m.iteration_cost != "factor" {
                return Err(err(
                    "method.iteration_cost",
                    format!("`{}`: \"solve\" or \"factor\"", m.iteration_cost),
                ));
            }
        }
        Ok(cfg)
    }
}
