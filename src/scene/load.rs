//! `[load]`: the membrane's source term g; the shell's force f, pressure,
//! point and edge loads.

use super::Expression;
use serde::Deserialize;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadSpec {
    /// Source term g(x, y) of −Δu = g (membrane): a number or an expression.
    pub g: Option<Expression>,
    /// Force per unit area f = (f1, f2, f3) (shell), each a number or an
    /// expression: L(V) ∋ ∫ f·v √a dx.
    pub f: Option<[Expression; 3]>,
    /// Tractions N and moments M on parts γ1 of the boundary (shell).
    #[serde(default)]
    pub edge: Vec<EdgeLoadSpec>,
    /// Pressure p(x, y) on the shell: force per unit area p·a3 along the unit
    /// normal a3 = a1×a2/|a1×a2| (p > 0 pushes the shell along a3; on the
    /// sphere preset, whose a3 points outward, an internal pressure):
    /// L(V) ∋ ∫ p a3·v √a dx.
    pub pressure: Option<Expression>,
    /// Concentrated forces at points of ω (shell): L(V) ∋ F·v(x₀).
    #[serde(default)]
    pub point: Vec<PointLoadSpec>,
}

/// A concentrated force `force` = (F1, F2, F3) at the parameter point `at`
/// (`[[load.point]]`): exact at a vertex of the mesh, refused outside ω.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointLoadSpec {
    pub at: [f64; 2],
    pub force: [f64; 3],
}

/// A traction N and a moment M per unit length on one named boundary part
/// γ1, each component a number or an expression in x, y:
/// L(V) ∋ ∫_γ1 (N·v + M·s) ℓ dσ, ℓ = |a_α ς^α| the length element of the chart.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EdgeLoadSpec {
    /// Physical name of the boundary part (must not be clamped).
    pub part: String,
    #[serde(default = "zero_vector")]
    pub traction: [Expression; 3],
    #[serde(default = "zero_vector")]
    pub moment: [Expression; 3],
}

fn zero_vector() -> [Expression; 3] {
    std::array::from_fn(|_| Expression::constant(0.0))
}
