//! `[solver]`: the method and its parameters (Uzawa's step, tolerances,
//! stop rule, cold start, nested iteration, threads, linear solver).

use super::{DualNorm, LinearMethod, Scene, StepForm, StopRule};
use crate::error::Result;
use serde::Deserialize;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSpec {
    pub method: Method,
    /// Dual step: a positive number, or "auto" (Lanczos estimate of s_max).
    #[serde(default)]
    pub alpha: Option<Alpha>,
    /// Uzawa's α as a multiple of the stability bound 2/s_max (Lanczos
    /// estimate), instead of `alpha`: 0.5 is safe, above 1 diverges.
    #[serde(default)]
    pub alpha_factor: Option<f64>,
    #[serde(default)]
    pub step_form: Option<StepForm>,
    #[serde(default = "default_max_iter")]
    pub max_iter: i64,
    /// Tolerance on the relative KKT measures (docs/formulation.md §4).
    #[serde(default = "default_tol")]
    pub tol: f64,
    /// Which criterion stops the iteration; both are always recorded.
    #[serde(default)]
    pub stop: StopRule,
    /// The thesis criterion ‖λ^{k+1} − λ^k‖ < thesis_tol.
    #[serde(default = "default_thesis_tol")]
    pub thesis_tol: f64,
    /// The norm of the thesis criterion.
    #[serde(default)]
    pub dual_norm: DualNorm,
    /// Nested iteration: start from the solution (x and λ) on the mesh with
    /// n/2 (recursively, down to n < 8), for methods that take a warm start
    /// (active-set, dual-accelerated). Needs a structured mesh (`mesh.n`).
    #[serde(default)]
    pub nested: bool,
    /// Active set from a cold start: "depth-bisection" (probe nested sets
    /// inside the free solution's penetration zone, then PDAS),
    /// "interior-point" (interior-point steps until the contact set shows,
    /// then PDAS), "plain" PDAS, or "auto": interior-point for the shell,
    /// depth-bisection for the membrane (src/solvers/active_set/).
    #[serde(default)]
    pub cold_start: ColdStartSpec,
    /// Static condensation of element-interior unknowns (bubbles) in every
    /// factorisation (src/linalg/condensed.rs); false factorises the whole
    /// matrix (the old floor, for benchmarks). Same results to round-off.
    #[serde(default = "default_condense")]
    pub condense: bool,
    /// Threads of the supernodal LDLᵀ factorisations: 1 faer's sequential
    /// one; 2 (the default) or more two threads on the elimination tree
    /// (src/linalg/tree_ldlt.rs). Solves stay sequential. Same results to
    /// round-off (docs/work-precision.md, "Two threads on the elimination tree").
    /// With `method = "multigrid"`, 2 or more assemble the coarser levels
    /// beside the finest and set the finest up beside the coarser levels'
    /// solves (the same results).
    #[serde(default = "default_threads")]
    pub threads: i64,
    /// The linear solver of every method's systems: "direct" (the sparse
    /// factorisations of src/linalg/ behind the seam of
    /// src/linalg/linear_solver.rs).
    #[serde(default)]
    pub linear: LinearMethod,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum ColdStartSpec {
    #[default]
    Auto,
    DepthBisection,
    InteriorPoint,
    Plain,
}

impl ColdStartSpec {
    pub fn name(self) -> &'static str {
        match self {
            ColdStartSpec::Auto => "auto",
            ColdStartSpec::DepthBisection => "depth-bisection",
            ColdStartSpec::InteriorPoint => "interior-point",
            ColdStartSpec::Plain => "plain",
        }
    }
}

fn default_max_iter() -> i64 {
    100_000
}
fn default_tol() -> f64 {
    1e-8
}
fn default_condense() -> bool {
    true
}
fn default_threads() -> i64 {
    2
}
fn default_thesis_tol() -> f64 {
    1e-5
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The thesis' Uzawa iteration (Algorithm 1, "second splitting", docs/formulation.md §3).
    Uzawa,
    /// The thesis' Ch. 4 "first splitting": Richardson on ψ and λ.
    UzawaSplit,
    /// FISTA with restart on the dual problem, one solve per iteration.
    DualAccelerated,
    /// Primal–dual active set (semismooth Newton): the exact discrete solution
    /// in few linear solves.
    ActiveSet,
    /// Newton multigrid with grid sequencing on the meshes of `mesh.refine`
    /// (the P1⊕B3–P0 membrane; src/solvers/multigrid_newton.rs).
    Multigrid,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Uzawa => "uzawa",
            Method::UzawaSplit => "uzawa-split",
            Method::DualAccelerated => "dual-accelerated",
            Method::ActiveSet => "active-set",
            Method::Multigrid => "multigrid",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Alpha {
    Value(f64),
    Keyword(AlphaKeyword),
}

/// A number or "auto"; anything else gets one message saying so (serde's
/// untagged enums say "did not match any variant of untagged enum Alpha").
impl<'de> Deserialize<'de> for Alpha {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct AlphaVisitor;
        impl serde::de::Visitor<'_> for AlphaVisitor {
            type Value = Alpha;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(ALPHA_EXPECTED)
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> std::result::Result<Alpha, E> {
                Ok(Alpha::Value(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> std::result::Result<Alpha, E> {
                Ok(Alpha::Value(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> std::result::Result<Alpha, E> {
                Ok(Alpha::Value(v as f64))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> std::result::Result<Alpha, E> {
                match v {
                    "auto" => Ok(Alpha::Keyword(AlphaKeyword::Auto)),
                    _ => Err(E::custom(format!("{ALPHA_EXPECTED}, got \"{v}\""))),
                }
            }
        }
        d.deserialize_any(AlphaVisitor)
    }
}

const ALPHA_EXPECTED: &str = "must be a positive number or \"auto\"";

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AlphaKeyword {
    Auto,
}

impl Scene {
    /// Ranges, and the options each method takes.
    pub(super) fn validate_solver(&self) -> Result<()> {
        let s = &self.solver;
        if let Some(Alpha::Value(a)) = s.alpha {
            self.check_positive("solver.alpha", a)?;
        }
        if let Some(f) = s.alpha_factor {
            self.check_positive("solver.alpha_factor", f)?;
            if f > 100.0 {
                return Err(self.error(
                    "solver.alpha_factor",
                    format!("a multiple of the stability bound 2/s_max must be ≤ 100, got {f}"),
                ));
            }
            if s.alpha.is_some() {
                return Err(self.error(
                    "solver.alpha_factor",
                    "give either `alpha` or `alpha_factor` (α = factor × 2/s_max), not both",
                ));
            }
            if s.method != Method::Uzawa {
                return Err(self.error(
                    "solver.alpha_factor",
                    format!(
                        "only Uzawa takes a fixed step, not method = \"{}\"",
                        s.method.name()
                    ),
                ));
            }
        }
        if self.obstacle.is_some() && s.method == Method::Uzawa {
            if s.alpha.is_none() && s.alpha_factor.is_none() {
                return Err(self.error(
                    "solver.alpha",
                    "Uzawa needs a step: a number > 0, \"auto\", or alpha_factor = a multiple of 2/s_max",
                ));
            }
            if s.step_form.is_none() {
                return Err(self.error(
                    "solver.step_form",
                    "name the dual step form: \"mean\" or \"integral\" (docs/formulation.md §3)",
                ));
            }
        }
        if !(1..=64).contains(&s.threads) {
            return Err(self.error(
                "solver.threads",
                format!("must be between 1 and 64, got {}", s.threads),
            ));
        }
        if !(1..=100_000_000).contains(&s.max_iter) {
            return Err(self.error(
                "solver.max_iter",
                format!("must be between 1 and 1e8, got {}", s.max_iter),
            ));
        }
        // Tolerances are compared, never multiplied: any positive number.
        let tolerance = |field: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(self.error(field, format!("must be a finite number > 0, got {v}")))
            }
        };
        tolerance("solver.tol", s.tol)?;
        if s.nested {
            if !matches!(s.method, Method::ActiveSet | Method::DualAccelerated) {
                return Err(self.error(
                    "solver.nested",
                    "nested iteration warm-starts active-set or dual-accelerated only",
                ));
            }
            if self.obstacle.as_ref().is_some_and(|o| o.upper.is_some()) {
                return Err(self.error(
                    "solver.nested",
                    "nested iteration carries a one-sided multiplier; the two-sided problem starts cold",
                ));
            }
            if self.mesh.n.is_none() || self.mesh.geo.is_none() {
                return Err(self.error(
                    "solver.nested",
                    "nested iteration needs a structured gmsh mesh (`mesh.geo` with `mesh.n`)",
                ));
            }
        }
        if s.method == Method::Multigrid {
            if self.model != super::Model::Membrane || self.element != super::ElementPair::P1bP0 {
                return Err(self.error(
                    "solver.method",
                    format!(
                        "the multigrid method solves the membrane with element = \"p1b-p0\" (its constraint rows act through the bubbles it condenses), not model = \"{}\" with element = \"{}\"",
                        self.model.name(),
                        self.element.name()
                    ),
                ));
            }
            if self.mesh.refine < 1 {
                return Err(self.error(
                    "solver.method",
                    "the multigrid method needs a hierarchy: set mesh.refine ≥ 1 (the scene's mesh refined that many times; e.g. mesh.n = 4 with mesh.refine = 8 on meshes/rectangle.geo gives 1025² vertices)",
                ));
            }
        }
        tolerance("solver.thesis_tol", s.thesis_tol)?;
        if s.cold_start != ColdStartSpec::default() && s.method != Method::ActiveSet {
            return Err(self.error(
                "solver.cold_start",
                "the cold start is an option of the active-set method",
            ));
        }
        Ok(())
    }
}
