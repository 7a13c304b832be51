//! The scene: the one input of a run. A TOML file declares the domain and
//! mesh, the model, the elements, the data (load, obstacle), the solver and
//! the outputs; the solver assembles and runs only what it declares.
//!
//! Unknown keys are rejected; every value is range-checked; every error names
//! the file, the field (dotted path) and the reason. Any key can be
//! overridden from the command line (`--set solver.alpha=0.9`).

use crate::error::{Error, Result};
/// A number or an expression in x, y, r (src/expression.rs).
pub use crate::expression::Expression;
/// The solver vocabulary the scene's strings map onto (it belongs to solvers/).
pub use crate::solvers::{DualNorm, LinearMethod, StepForm, StopRule};
use serde::Deserialize;
use std::path::{Path, PathBuf};

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

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    /// gmsh geometry, relative to the scene file's folder (e.g. "../../meshes/disk.geo").
    pub geo: Option<String>,
    /// Structured subdivisions (disk: points per quarter circle; diamond: per side).
    pub n: Option<i64>,
    /// Unstructured target size (used when `n` is absent).
    pub h: Option<f64>,
    /// An existing MSH 2.2 file (relative to the scene file's folder) instead of meshing.
    pub file: Option<String>,
    /// Physical names of the boundary parts where the Dirichlet condition holds
    /// (default: the whole boundary).
    pub dirichlet: Option<Vec<String>>,
    /// The membrane's boundary values u = g_D on the Dirichlet parts (default 0).
    pub dirichlet_value: Option<Expression>,
    /// The memory a run may use, in GB (default: half of MemAvailable);
    /// a scene whose estimate is above it is refused (src/guards.rs).
    pub memory_limit_gb: Option<f64>,
    /// Numbers passed to gmsh as `-setnumber NAME VALUE` (e.g. the corners
    /// x0, x1, y0, y1 of meshes/rectangle.geo).
    #[serde(default)]
    pub parameters: std::collections::BTreeMap<String, f64>,
}

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

/// The midsurface chart φ: ω → R³, as declared in a scene (`kind = "..."`);
/// its geometry (jets, normals, curvature) is `models::naghdi::geometry`.
///
/// The presets (every variant but `parametric` and `graph`) have closed-form
/// first and second derivatives; `parametric` and `graph` take φ as
/// expressions in the mesh coordinates x, y and differentiate them exactly
/// ([`ChartExpressions`]). A preset and its parametric spelling give the same
/// geometry to round-off.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Chart {
    /// φ(x, y) = (x, y, (x² − y²)/r² + offset): the thesis hyperbolic
    /// paraboloid ("second test", r = 50√2, offset = 1.4). Gaussian curvature
    /// −4/r⁴ at the origin.
    HyperbolicParaboloid { r: f64, offset: f64 },
    /// φ(x, y) = (x, y, height): a flat plate at constant height.
    Plate { height: f64 },
    /// A circular cylinder of radius `radius` whose axis is the line
    /// {x = 0, z = height} parallel to e2, parametrised by arc length:
    ///
    ///   φ(x, y) = (R sin(x/R), y, height + R cos(x/R)),  R = radius.
    ///
    /// x is the arc length along the circular cross-section measured from the
    /// apex (0, y, height + R), y the coordinate along the axis; |a1| = |a2| = 1,
    /// a_αβ = δ_αβ, √a = 1 everywhere. The normal a3 = (sin(x/R), 0, cos(x/R))
    /// points away from the axis, so b_11 = −1/R, b_12 = b_22 = 0: mean
    /// curvature H = −1/(2R), Gaussian curvature 0. The chart is injective for
    /// |x| < πR; |x| < πR/2 is the upper half (a vault over the plane z = 0).
    Cylinder { radius: f64, height: f64 },
    /// A W^{2,∞} (C¹, not C²) chart: a flat plate for x ≤ 0 glued to a
    /// parabolic cylinder for x > 0,
    ///
    ///   φ(x, y) = (x, y, offset + max(x, 0)²/r²).
    ///
    /// φ and a_α are continuous across x = 0; ∂_11 φ jumps from 0 to
    /// (0, 0, 2/r²), so b_αβ and ∂_α a3 jump. Each side is evaluated exactly;
    /// exactly at x = 0 the left (flat) one-sided second derivative is used.
    CurvatureKink { r: f64, offset: f64 },
    /// A sphere of radius R centred at (0, 0, height), x the longitude and y
    /// the latitude (radians):
    ///
    ///   φ(x, y) = (R cos y cos x, R cos y sin x, height + R sin y).
    ///
    /// a3 = φ − centre over R points outward, √a = R² cos y: regular for
    /// |y| < π/2 (the poles are singular points of the chart).
    Sphere { radius: f64, height: f64 },
    /// A circular cone with its apex at (0, 0, height), opening upward with
    /// half-angle β (radians, 0 < β < π/2): x is the distance from the apex
    /// along a generator, y the angle about the axis:
    ///
    ///   φ(x, y) = (x sin β cos y, x sin β sin y, height + x cos β).
    ///
    /// a3 = (−cos β cos y, −cos β sin y, sin β) points into the cone (up);
    /// √a = x sin β: regular for x > 0 (the apex is singular).
    Cone { half_angle: f64, height: f64 },
    /// φ(x, y) = (X, Y, Z), three expressions in the mesh coordinates.
    Parametric(ParametricChart),
    /// φ(x, y) = (x, y, height), `height` an expression: a graph over the
    /// (x, y) plane.
    Graph(GraphChart),
}

/// φ = (X, Y, Z) as expressions with their exact first and second
/// derivatives, compiled once when the scene is read.
#[derive(Debug, Clone, PartialEq)]
pub struct ChartExpressions {
    /// X, Y, Z.
    pub phi: [Expression; 3],
    /// d\[i\]\[α\] = ∂_α φ_i.
    pub d: [[Expression; 2]; 3],
    /// dd\[i\] = (∂_xx φ_i, ∂_xy φ_i, ∂_yy φ_i).
    pub dd: [[Expression; 3]; 3],
}

impl ChartExpressions {
    /// Differentiates φ twice; `keys` name the components in errors.
    pub fn new(phi: [Expression; 3], keys: [&str; 3]) -> std::result::Result<Self, String> {
        use crate::expression::Variable::{X, Y};
        let mut d: Vec<[Expression; 2]> = Vec::new();
        let mut dd: Vec<[Expression; 3]> = Vec::new();
        for (component, key) in phi.iter().zip(keys) {
            let named =
                |r: std::result::Result<Expression, String>| r.map_err(|e| format!("{key}: {e}"));
            let dx = named(component.derivative(X))?;
            let dy = named(component.derivative(Y))?;
            let dxx = named(dx.derivative(X))?;
            let dxy = named(dx.derivative(Y))?;
            let dyy = named(dy.derivative(Y))?;
            d.push([dx, dy]);
            dd.push([dxx, dxy, dyy]);
        }
        Ok(ChartExpressions {
            phi,
            d: d.try_into().map_err(|_| "three components")?,
            dd: dd.try_into().map_err(|_| "three components")?,
        })
    }
}

/// `kind = "parametric"`: X, Y, Z.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(try_from = "ParametricSpec")]
pub struct ParametricChart(pub ChartExpressions);

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ParametricSpec {
    #[serde(rename = "X")]
    x: Expression,
    #[serde(rename = "Y")]
    y: Expression,
    #[serde(rename = "Z")]
    z: Expression,
}

impl TryFrom<ParametricSpec> for ParametricChart {
    type Error = String;
    fn try_from(s: ParametricSpec) -> std::result::Result<Self, String> {
        ChartExpressions::new([s.x, s.y, s.z], ["X", "Y", "Z"]).map(ParametricChart)
    }
}

/// `kind = "graph"`: height.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(try_from = "GraphSpec")]
pub struct GraphChart(pub ChartExpressions);

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct GraphSpec {
    height: Expression,
}

impl TryFrom<GraphSpec> for GraphChart {
    type Error = String;
    fn try_from(s: GraphSpec) -> std::result::Result<Self, String> {
        let coordinate = |t| Expression::parse(t).map_err(|e| e.to_string());
        let phi = [coordinate("x")?, coordinate("y")?, s.height];
        ChartExpressions::new(phi, ["x", "y", "height"]).map(GraphChart)
    }
}

impl Chart {
    /// `kind = "parametric"` with φ = (X, Y, Z) given as expression texts.
    pub fn parametric(texts: [&str; 3]) -> std::result::Result<Chart, String> {
        let [x, y, z] = texts.map(Expression::parse);
        ChartExpressions::new([x?, y?, z?], ["X", "Y", "Z"])
            .map(|e| Chart::Parametric(ParametricChart(e)))
    }

    /// The scene name of the variant (`kind = "..."`).
    pub fn kind(&self) -> &'static str {
        match self {
            Chart::HyperbolicParaboloid { .. } => "hyperbolic-paraboloid",
            Chart::Plate { .. } => "plate",
            Chart::Cylinder { .. } => "cylinder",
            Chart::CurvatureKink { .. } => "curvature-kink",
            Chart::Sphere { .. } => "sphere",
            Chart::Cone { .. } => "cone",
            Chart::Parametric(_) => "parametric",
            Chart::Graph(_) => "graph",
        }
    }

    /// The chart's expressions, for `parametric` and `graph`.
    pub fn expressions(&self) -> Option<&ChartExpressions> {
        match self {
            Chart::Parametric(ParametricChart(e)) | Chart::Graph(GraphChart(e)) => Some(e),
            _ => None,
        }
    }

    /// Range checks of the parameters; the error names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        let kind = self.kind();
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!(
                    "chart {kind}: {name} must be finite and > 0, got {v}"
                ))
            }
        };
        let finite = |name: &str, v: f64| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(format!("chart {kind}: {name} must be finite, got {v}"))
            }
        };
        match *self {
            Chart::HyperbolicParaboloid { r, offset } | Chart::CurvatureKink { r, offset } => {
                positive("r", r)?;
                finite("offset", offset)
            }
            Chart::Plate { height } => finite("height", height),
            Chart::Cylinder { radius, height } | Chart::Sphere { radius, height } => {
                positive("radius", radius)?;
                finite("height", height)
            }
            Chart::Cone { half_angle, height } => {
                if !(half_angle > 0.0 && half_angle < std::f64::consts::FRAC_PI_2) {
                    return Err(format!(
                        "chart cone: half_angle must lie in (0, π/2) (radians), got {half_angle}"
                    ));
                }
                finite("height", height)
            }
            Chart::Parametric(_) | Chart::Graph(_) => Ok(()),
        }
    }
}

/// The shell of model "naghdi": midsurface chart, material, the penalty ρ of
/// a_ρ, and the clamped boundary parts γ0.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShellSpec {
    pub chart: Chart,
    /// Young's modulus E.
    pub young: f64,
    /// Poisson's ratio ν ∈ [0, 1/2).
    pub poisson: f64,
    /// Thickness ε.
    pub thickness: f64,
    /// Penalty ρ ≥ 0 of a_ρ = a + ρ ∫ ∇(r·a3)·∇(s·a3) (ρ = 0: a_ρ is not
    /// coercive). Needed by `p1b-p0`; `p2b-psri` has tangent rotations and
    /// no penalty (a given ρ is recorded and unused).
    pub rho: Option<f64>,
    /// Physical names of the clamped parts γ0 (u = r = ψ = 0); default: all
    /// of ∂ω when no `[[shell.boundary]]` is given, none otherwise.
    pub clamped: Option<Vec<String>>,
    /// Conditions per boundary part and component; parts named nowhere are free.
    #[serde(default)]
    pub boundary: Vec<BoundarySpec>,
    /// Fields fixed at single mesh vertices (`[[shell.support]]`): e.g. the
    /// one vertical support that removes the rigid translation a model with
    /// symmetry planes leaves free (the pinched hemisphere).
    #[serde(default)]
    pub support: Vec<PointSupportSpec>,
}

/// `[[shell.support]]`: the fields `fix` (as in `condition = "fixed"`) are 0
/// at the mesh vertex `at`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointSupportSpec {
    pub at: [f64; 2],
    pub fix: Vec<String>,
}

/// The condition on one boundary part (`[[shell.boundary]]`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoundarySpec {
    /// Physical name of the boundary part.
    pub part: String,
    pub condition: BoundaryCondition,
    /// The normal of the symmetry plane or of the diaphragm's plane: e1, e2
    /// or e3 ("x", "y", "z"), or for a symmetry plane any vector [nx, ny, nz].
    pub normal: Option<PlaneNormal>,
    /// The fixed fields for `condition = "fixed"` (u1, u2, u3 and r1, r2, r3,
    /// psi or theta1, theta2 by element).
    pub fix: Option<Vec<String>>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BoundaryCondition {
    /// u = 0 and r = 0.
    Clamped,
    /// u = 0, rotations free (hard simple support).
    SimplySupported,
    /// Mirror symmetry about the plane with normal n: u·n = 0, r·n = 0.
    Symmetry,
    /// A rigid diaphragm in the plane with normal n: the two displacement
    /// components in that plane are 0; u·n and the rotations are free.
    Diaphragm,
    /// Nothing fixed (the default for parts named nowhere).
    Free,
    /// The fields listed in `fix` are 0.
    Fixed,
}

impl BoundaryCondition {
    pub fn name(self) -> &'static str {
        match self {
            BoundaryCondition::Clamped => "clamped",
            BoundaryCondition::SimplySupported => "simply-supported",
            BoundaryCondition::Symmetry => "symmetry",
            BoundaryCondition::Diaphragm => "diaphragm",
            BoundaryCondition::Free => "free",
            BoundaryCondition::Fixed => "fixed",
        }
    }
}

/// A plane's normal: a Cartesian axis, or any non-zero vector.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum PlaneNormal {
    Axis(Axis),
    Vector([f64; 3]),
}

impl PlaneNormal {
    /// The axis, also for a vector along one (whose conditions are then the
    /// axis' own, dof by dof).
    pub fn axis(self) -> Option<Axis> {
        match self {
            PlaneNormal::Axis(a) => Some(a),
            PlaneNormal::Vector(v) => {
                let along: Vec<usize> = (0..3).filter(|&c| v[c] != 0.0).collect();
                match along[..] {
                    [0] => Some(Axis::X),
                    [1] => Some(Axis::Y),
                    [2] => Some(Axis::Z),
                    _ => None,
                }
            }
        }
    }

    /// The unit normal.
    pub fn unit(self) -> [f64; 3] {
        let v = match self {
            PlaneNormal::Axis(a) => {
                let mut e = [0.0; 3];
                e[a.index()] = 1.0;
                e
            }
            PlaneNormal::Vector(v) => v,
        };
        let norm = v.iter().map(|c| c * c).sum::<f64>().sqrt();
        v.map(|c| c / norm)
    }
}

/// A Cartesian axis e1, e2, e3.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    pub fn index(self) -> usize {
        match self {
            Axis::X => 0,
            Axis::Y => 1,
            Axis::Z => 2,
        }
    }
}

impl ShellSpec {
    /// Range checks of E, ν and ε: the field and the reason.
    fn check_material(&self) -> std::result::Result<(), (&'static str, String)> {
        if !(self.young.is_finite() && self.young > 0.0) {
            let reason = format!(
                "Young's modulus E must be finite and > 0, got {}",
                self.young
            );
            return Err(("shell.young", reason));
        }
        if !(self.poisson.is_finite() && (0.0..0.5).contains(&self.poisson)) {
            let reason = format!(
                "Poisson's ratio ν must lie in [0, 1/2), got {}",
                self.poisson
            );
            return Err(("shell.poisson", reason));
        }
        if !(self.thickness.is_finite() && self.thickness > 0.0) {
            let reason = format!(
                "the thickness ε must be finite and > 0, got {}",
                self.thickness
            );
            return Err(("shell.thickness", reason));
        }
        Ok(())
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    pub shape: ObstacleShape,
    /// Paraboloid: φ(0, 0). Rigid plane: the plane z = height (default 0).
    /// Rigid surface: the body fills z < height(x, y) (an expression).
    pub height: Option<Expression>,
    /// k in φ = height − k (x² + y²) (paraboloid only).
    pub curvature: Option<f64>,
    /// Shape "expression" (membrane): u ≥ lower(x, y).
    pub lower: Option<Expression>,
    /// Shape "expression" (membrane), optional: u ≤ upper(x, y), the two-sided problem.
    pub upper: Option<Expression>,
    /// Shell only: the space of the contact multiplier λ (default: the element's,
    /// P0 for "p1b-p0", P1 for "p2b-psri"); the membrane's comes with `element`.
    pub multiplier: Option<ContactMultiplier>,
}

/// The space of the shell's contact multiplier (scene `obstacle.multiplier`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ContactMultiplier {
    /// One multiplier per triangle: the constraint on triangle means.
    P0,
    /// One multiplier per vertex: the constraint tested with the P1 hat functions.
    P1,
}

impl ContactMultiplier {
    pub fn name(self) -> &'static str {
        match self {
            ContactMultiplier::P0 => "p0",
            ContactMultiplier::P1 => "p1",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ObstacleShape {
    /// Membrane: φ(x, y) = height − curvature · (x² + y²).
    Paraboloid,
    /// Membrane: lower ≤ u (≤ upper) with expressions in x, y, r.
    Expression,
    /// Shell: the rigid half-space z < height below the shell (docs/formulation.md §2).
    RigidPlane,
    /// Shell: the rigid body z < height(x, y) below the shell (docs/formulation.md §2.1).
    RigidSurface,
}

impl ObstacleShape {
    pub fn name(self) -> &'static str {
        match self {
            ObstacleShape::Paraboloid => "paraboloid",
            ObstacleShape::Expression => "expression",
            ObstacleShape::RigidPlane => "rigid-plane",
            ObstacleShape::RigidSurface => "rigid-surface",
        }
    }
}

impl ObstacleSpec {
    /// The height when a number: φ(0, 0) or the plane's level (default 0);
    /// validation requires a number for the paraboloid and the plane.
    pub fn level(&self) -> f64 {
        self.height
            .as_ref()
            .and_then(Expression::as_constant)
            .unwrap_or(0.0)
    }

    /// The membrane's lower obstacle ψ₁(x): the paraboloid or `lower`.
    pub fn value(&self, x: [f64; 2]) -> f64 {
        match &self.lower {
            Some(lower) => lower.eval(x),
            None => self.level() - self.curvature.unwrap_or(0.0) * (x[0] * x[0] + x[1] * x[1]),
        }
    }
}

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
    /// "auto" made concrete for a model: the start with fewer Newton
    /// solves measured on its scenes (docs/work-precision.md, "The
    /// interior-point start"): the shell's grow with n under the depth
    /// bisection (7 … 61 at n = 16 … 512) and not under the interior point
    /// (8 … 17); the membrane disk takes 3–7 with the bisection, 11–12 from
    /// the interior point.
    pub fn for_model(self, model: Model) -> ColdStartSpec {
        match (self, model) {
            (ColdStartSpec::Auto, Model::Naghdi) => ColdStartSpec::InteriorPoint,
            (ColdStartSpec::Auto, Model::Membrane) => ColdStartSpec::DepthBisection,
            (spec, _) => spec,
        }
    }

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
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Uzawa => "uzawa",
            Method::UzawaSplit => "uzawa-split",
            Method::DualAccelerated => "dual-accelerated",
            Method::ActiveSet => "active-set",
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

/// `[adapt]`: solve → estimate → mark → remesh, until the estimator reaches
/// `target_error`, the next mesh would pass `max_dofs`, or `max_steps` solves.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AdaptSpec {
    pub marking: Marking,
    /// Dörfler's bulk parameter: the marked triangles carry ≥ θ of Σ η_T².
    pub theta: f64,
    /// Stop once η = (Σ η_T²)^½ ≤ target_error.
    pub target_error: Option<f64>,
    /// Stop before solving on a mesh with more than max_dofs unknowns.
    pub max_dofs: Option<i64>,
    /// At most this many solves (the first mesh included).
    pub max_steps: i64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Marking {
    /// Dörfler (bulk) marking with `theta`.
    Dorfler,
}

#[derive(Debug, Clone, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    /// Compute errors against the exact solution (disk with a paraboloid obstacle).
    #[serde(default)]
    pub errors: bool,
    /// Plots written beside the result file (`<stem>.<plot>.<format>`), only
    /// those listed: "u", "lambda", "gap", "contact", "history".
    #[serde(default)]
    pub plots: Vec<PlotKind>,
    #[serde(default)]
    pub plot_format: PlotFormat,
    /// Membrane: a known exact solution other than the disk's, for `errors`.
    pub exact: Option<ExactSpec>,
    /// Shell: a point of ω where the displacement is recorded (root
    /// attributes `probe_u1`, `probe_u2`, `probe_u3`), e.g. the point of a
    /// benchmark's reference deflection.
    pub probe: Option<[f64; 2]>,
}

/// An exact solution of a membrane scene (`[output.exact]`): errors of u in
/// L² and H¹ (∇u by central differences of `u`), of λ in L², and the contact radius.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExactSpec {
    pub u: Expression,
    pub lambda: Expression,
    /// The radius of the exact contact set (√(area/π) if it is not a disk).
    pub contact_radius: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PlotKind {
    /// Colour map and isolines of u (membrane).
    U,
    /// The shell displacement components.
    U1,
    U2,
    U3,
    /// The shell's contact constraint (u − ε/2 r)·e3 against Φ_h: colour map
    /// of the gap and profiles along the axes.
    Constraint,
    /// The multiplier λ.
    Lambda,
    /// The mean gap ḡ.
    Gap,
    /// The contact zone {λ > 0}, with the exact contact circle when known.
    Contact,
    /// Convergence history of the KKT measures and the dual step.
    History,
    /// The a posteriori indicator η_T per triangle (membrane).
    Estimator,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum PlotFormat {
    #[default]
    Png,
    Svg,
}

impl PlotKind {
    /// Every kind, in the order of the declaration (the report page's order).
    pub const ALL: [PlotKind; 10] = [
        PlotKind::U,
        PlotKind::U1,
        PlotKind::U2,
        PlotKind::U3,
        PlotKind::Constraint,
        PlotKind::Lambda,
        PlotKind::Gap,
        PlotKind::Contact,
        PlotKind::History,
        PlotKind::Estimator,
    ];

    /// The kind's name in scenes and in plot file names (`RESULT.<name>.png`).
    pub fn name(self) -> String {
        format!("{self:?}").to_lowercase()
    }

    /// Plots that only the shell can draw.
    pub fn shell_only(self) -> bool {
        matches!(
            self,
            PlotKind::U1 | PlotKind::U2 | PlotKind::U3 | PlotKind::Constraint
        )
    }
}

impl PlotFormat {
    pub fn extension(self) -> &'static str {
        match self {
            PlotFormat::Png => "png",
            PlotFormat::Svg => "svg",
        }
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
        let finite = |field: &str, v: f64| self.check_finite(field, v);
        let positive = |field: &str, v: f64| {
            finite(field, v)?;
            if v > 0.0 {
                Ok(())
            } else {
                Err(self.error(field, format!("must be > 0, got {v}")))
            }
        };
        crate::names::check_name(&self.name).map_err(|reason| self.error("name", reason))?;
        let m = &self.mesh;
        match (&m.file, &m.geo) {
            (Some(_), Some(_)) => {
                return Err(self.error("mesh", "give either `file` or `geo`, not both"))
            }
            (None, None) => {
                return Err(self.error(
                    "mesh",
                    "give `geo` (a gmsh .geo to mesh) or `file` (an MSH 2.2 mesh)",
                ))
            }
            (None, Some(_)) => {
                if m.n.is_none() && m.h.is_none() {
                    return Err(self.error(
                        "mesh",
                        "meshing a .geo needs `n` (structured) or `h` (target size)",
                    ));
                }
            }
            (Some(_), None) => {}
        }
        if let Some(n) = m.n {
            if !(1..=100_000).contains(&n) {
                return Err(self.error("mesh.n", format!("must be between 1 and 100000, got {n}")));
            }
        }
        if let Some(h) = m.h {
            positive("mesh.h", h)?;
        }
        if let Some(gb) = m.memory_limit_gb {
            positive("mesh.memory_limit_gb", gb)?;
        }
        for (name, value) in &m.parameters {
            let field = format!("mesh.parameters.{name}");
            finite(&field, *value)?;
            let ident = name.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
                && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
            if !ident || name == "n" || name == "h" {
                return Err(self.error(
                    &field,
                    "a gmsh parameter is a name of letters, digits and _ (not `n` or `h`: those are mesh.n, mesh.h)",
                ));
            }
        }
        if let Some(o) = &self.obstacle {
            let surface = matches!(o.shape, ObstacleShape::RigidSurface);
            match o.height.as_ref().map(|h| (h.as_constant(), h.text())) {
                Some((None, text)) if !surface => {
                    return Err(self.error(
                        "obstacle.height",
                        format!("shape \"{}\" takes a number, not \"{text}\" (an expression height is shape = \"rigid-surface\")", o.shape.name()),
                    ))
                }
                Some((Some(h), _)) => finite("obstacle.height", h)?,
                _ => {}
            }
            finite("obstacle.curvature", o.curvature.unwrap_or(0.0))?;
        }
        match self.model {
            Model::Membrane => self.validate_membrane()?,
            Model::Naghdi => self.validate_naghdi()?,
        }
        let s = &self.solver;
        if let Some(Alpha::Value(a)) = s.alpha {
            positive("solver.alpha", a)?;
        }
        if let Some(f) = s.alpha_factor {
            positive("solver.alpha_factor", f)?;
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
        tolerance("solver.thesis_tol", s.thesis_tol)?;
        if s.cold_start != ColdStartSpec::default() && s.method != Method::ActiveSet {
            return Err(self.error(
                "solver.cold_start",
                "the cold start is an option of the active-set method",
            ));
        }
        self.validate_adapt()?;
        Ok(())
    }

    /// `[adapt]`: ranges, and what the loop needs (the membrane, a gmsh mesh, contact).
    fn validate_adapt(&self) -> Result<()> {
        let Some(a) = &self.adapt else {
            return Ok(());
        };
        if !(a.theta.is_finite() && a.theta > 0.0 && a.theta <= 1.0) {
            return Err(self.error(
                "adapt.theta",
                format!("Dörfler's θ must lie in (0, 1], got {}", a.theta),
            ));
        }
        if let Some(t) = a.target_error {
            if !(t.is_finite() && t > 0.0) {
                return Err(self.error(
                    "adapt.target_error",
                    format!("must be a finite number > 0, got {t}"),
                ));
            }
        }
        if let Some(n) = a.max_dofs {
            if n < 1 {
                return Err(self.error("adapt.max_dofs", format!("must be ≥ 1, got {n}")));
            }
        }
        if !(1..=100).contains(&a.max_steps) {
            return Err(self.error(
                "adapt.max_steps",
                format!("must be between 1 and 100, got {}", a.max_steps),
            ));
        }
        if self.mesh.geo.is_none() {
            return Err(self.error(
                "adapt",
                "the adaptive loop remeshes with gmsh: give `mesh.geo` (taking `n` and `h`), not `mesh.file`",
            ));
        }
        if self.solver.nested {
            return Err(self.error(
                "adapt",
                "the adaptive loop warm-starts each step from the previous one; drop `solver.nested`",
            ));
        }
        Ok(())
    }

    /// What the membrane model needs and cannot use.
    fn validate_membrane(&self) -> Result<()> {
        let load = self
            .load
            .as_ref()
            .ok_or_else(|| self.error("load", "the membrane model needs `[load] g = ...`"))?;
        let g = load
            .g
            .as_ref()
            .ok_or_else(|| self.error("load.g", "the membrane model needs the source term g"))?;
        if let Some(g) = g.as_constant() {
            self.check_finite("load.g", g)?;
        }
        if let Some(v) = self
            .mesh
            .dirichlet_value
            .as_ref()
            .and_then(Expression::as_constant)
        {
            self.check_finite("mesh.dirichlet_value", v)?;
        }
        if load.f.is_some()
            || !load.edge.is_empty()
            || load.pressure.is_some()
            || !load.point.is_empty()
        {
            return Err(self.error(
                "load",
                "`f`, `pressure`, `point` and `edge` are shell loads; the membrane takes `g`",
            ));
        }
        if self.shell.is_some() {
            return Err(self.error("shell", "a [shell] table needs model = \"naghdi\""));
        }
        if self.element.is_p2b_shell() {
            return Err(self.error(
                "element",
                format!(
                    "\"{}\" is a shell element; the membrane takes \"p1b-p0\" or \"p2-p1\"",
                    self.element.name()
                ),
            ));
        }
        if let Some(o) = &self.obstacle {
            if o.multiplier.is_some() {
                return Err(self.error(
                    "obstacle.multiplier",
                    "a shell key: the membrane's multiplier space comes with `element` (\"p1b-p0\": P0, \"p2-p1\": P1)",
                ));
            }
            match o.shape {
                ObstacleShape::Paraboloid => {
                    if o.height.is_none() {
                        return Err(
                            self.error("obstacle.height", "the paraboloid needs φ(0,0) = height")
                        );
                    }
                    if o.lower.is_some() || o.upper.is_some() {
                        return Err(self.error(
                            "obstacle.lower",
                            "`lower` and `upper` go with shape = \"expression\"",
                        ));
                    }
                }
                ObstacleShape::Expression => {
                    if o.lower.is_none() {
                        return Err(self.error(
                            "obstacle.lower",
                            "shape = \"expression\" needs `lower = \"<expression in x, y, r>\"` (u ≥ lower)",
                        ));
                    }
                    if o.height.is_some() || o.curvature.is_some() {
                        return Err(self.error(
                            "obstacle.height",
                            "`height` and `curvature` belong to the paraboloid; shape = \"expression\" takes `lower` (and `upper`)",
                        ));
                    }
                }
                shape => {
                    return Err(self.error(
                        "obstacle.shape",
                        format!(
                        "the membrane takes shape = \"paraboloid\" or \"expression\", not \"{}\"",
                        shape.name()
                    ),
                    ))
                }
            }
        }
        if self.output.probe.is_some() {
            return Err(self.error("output.probe", "the probe records a shell's displacement"));
        }
        if let Some(exact) = &self.output.exact {
            self.check_finite("output.exact.contact_radius", exact.contact_radius)?;
            if !self.output.errors {
                return Err(self.error("output.exact", "an exact solution is for `errors = true`"));
            }
        }
        if let Some(k) = self.output.plots.iter().find(|k| k.shell_only()) {
            return Err(self.error(
                "output.plots",
                format!("{k:?} is a shell plot; the membrane has \"u\"").to_lowercase(),
            ));
        }
        Ok(())
    }

    /// What the shell model needs and cannot use.
    fn validate_naghdi(&self) -> Result<()> {
        let shell = self.shell.as_ref().ok_or_else(|| {
            self.error(
                "shell",
                "model = \"naghdi\" needs a [shell] table (chart, young, poisson, thickness, rho)",
            )
        })?;
        shell
            .chart
            .validate()
            .map_err(|reason| self.error("shell.chart", reason))?;
        shell
            .check_material()
            .map_err(|(field, reason)| self.error(field, reason))?;
        self.check_finite("shell.young", shell.young)?;
        self.check_finite("shell.thickness", shell.thickness)?;
        // The bending stiffness E ε³ scales K; it must be a number too.
        self.check_finite("shell.thickness", shell.young * shell.thickness.powi(3))
            .map_err(|_| {
                self.error(
                    "shell.thickness",
                    format!(
                        "the bending stiffness shell.young × shell.thickness³ = {:e} is outside [1e-100, 1e100]",
                        shell.young * shell.thickness.powi(3)
                    ),
                )
            })?;
        match (self.element, shell.rho) {
            (ElementPair::P1bP0, None) => {
                return Err(self.error(
                    "shell.rho",
                    "the thesis element (p1b-p0) needs the penalty ρ of a_ρ (the thesis takes 1e3)",
                ))
            }
            (ElementPair::P2P1, _) => return Err(self.error(
                "element",
                "the shell elements are \"p1b-p0\" (the thesis'), \"p2b-mitc\" (locking-free, recommended) and \"p2b-psri\"",
            )),
            _ => {}
        }
        if let Some(rho) = shell.rho {
            self.check_finite("shell.rho", rho)?;
            if rho < 0.0 {
                return Err(self.error("shell.rho", format!("the penalty must be ≥ 0, got {rho}")));
            }
            if rho == 0.0
                && self.element == ElementPair::P1bP0
                && self.solver.method == Method::UzawaSplit
                && !matches!(shell.chart, Chart::Plate { .. })
            {
                return Err(self.error(
                    "shell.rho",
                    "a_ρ is not coercive at ρ = 0 (thesis §5.3): the first splitting (method = \"uzawa-split\") factorises K_ρ alone and needs ρ > 0 (the thesis takes 1e3); the saddle-point methods (uzawa, active-set, dual-accelerated) accept ρ = 0",
                ));
            }
        }
        for (i, v) in self.output.probe.iter().flatten().enumerate() {
            self.check_finite(&format!("output.probe[{i}]"), *v)?;
        }
        for (i, b) in shell.boundary.iter().enumerate() {
            let field = format!("shell.boundary[{i}]");
            let needs_normal = matches!(
                b.condition,
                BoundaryCondition::Symmetry | BoundaryCondition::Diaphragm
            );
            if needs_normal != b.normal.is_some() {
                return Err(self.error(
                    &format!("{field}.normal"),
                    if needs_normal {
                        format!("`{}`: condition \"{}\" needs the plane's normal: normal = \"x\", \"y\", \"z\" or [nx, ny, nz]", b.part, b.condition.name())
                    } else {
                        format!("`{}`: only \"symmetry\" and \"diaphragm\" take a normal", b.part)
                    },
                ));
            }
            if let Some(PlaneNormal::Vector(v)) = b.normal {
                let norm = v.iter().map(|c| c * c).sum::<f64>().sqrt();
                if !v.iter().all(|c| c.is_finite()) || norm <= 1e-100 {
                    return Err(self.error(
                        &format!("{field}.normal"),
                        format!(
                            "`{}`: the normal must be a finite, non-zero vector, got {v:?}",
                            b.part
                        ),
                    ));
                }
                if b.condition == BoundaryCondition::Diaphragm
                    && b.normal.and_then(PlaneNormal::axis).is_none()
                {
                    return Err(self.error(
                        &format!("{field}.normal"),
                        format!("`{}`: a diaphragm's normal is \"x\", \"y\" or \"z\" (an oblique plane takes condition = \"symmetry\")", b.part),
                    ));
                }
            }
            if (b.condition == BoundaryCondition::Fixed) != b.fix.is_some() {
                return Err(self.error(
                    &format!("{field}.fix"),
                    format!(
                        "`{}`: `fix = [...]` goes with condition = \"fixed\" (and only with it)",
                        b.part
                    ),
                ));
            }
            if shell.clamped.as_ref().is_some_and(|c| c.contains(&b.part))
                || shell.boundary[..i].iter().any(|o| o.part == b.part)
            {
                return Err(self.error(
                    &format!("{field}.part"),
                    format!("`{}` has two conditions (shell.clamped and shell.boundary name each part once)", b.part),
                ));
            }
        }
        if self.mesh.dirichlet.is_some() {
            return Err(self.error(
                "mesh.dirichlet",
                "the shell names its clamped parts in `shell.clamped`",
            ));
        }
        if let Some(load) = &self.load {
            if load.g.is_some() {
                return Err(self.error(
                    "load.g",
                    "g is the membrane's source term; the shell takes f = [f1, f2, f3]",
                ));
            }
            for (i, v) in load.f.iter().flatten().enumerate() {
                if let Some(v) = v.as_constant() {
                    self.check_finite(&format!("load.f[{i}]"), v)?;
                }
            }
            if let Some(v) = load.pressure.as_ref().and_then(Expression::as_constant) {
                self.check_finite("load.pressure", v)?;
            }
            for (k, point) in load.point.iter().enumerate() {
                for (i, v) in point.at.iter().enumerate() {
                    self.check_finite(&format!("load.point[{k}].at[{i}]"), *v)?;
                }
                for (i, v) in point.force.iter().enumerate() {
                    self.check_finite(&format!("load.point[{k}].force[{i}]"), *v)?;
                }
            }
            for (e, edge) in load.edge.iter().enumerate() {
                for (i, v) in edge.traction.iter().chain(&edge.moment).enumerate() {
                    let name = if i < 3 { "traction" } else { "moment" };
                    if let Some(v) = v.as_constant() {
                        self.check_finite(&format!("load.edge[{e}].{name}[{}]", i % 3), v)?;
                    }
                }
                let clamped_by_default = shell.clamped.is_none() && shell.boundary.is_empty();
                if clamped_by_default
                    || shell
                        .clamped
                        .as_ref()
                        .is_some_and(|c| c.contains(&edge.part))
                {
                    return Err(self.error(
                        &format!("load.edge[{e}].part"),
                        format!(
                            "`{}` is clamped (shell.clamped, default: all of the boundary): tractions act on the free part γ1 only",
                            edge.part
                        ),
                    ));
                }
            }
        }
        if let Some(o) = &self.obstacle {
            let shell_shape = matches!(
                o.shape,
                ObstacleShape::RigidPlane | ObstacleShape::RigidSurface
            );
            if !shell_shape || o.curvature.is_some() || o.lower.is_some() || o.upper.is_some() {
                return Err(self.error(
                    "obstacle.shape",
                    "the shell's obstacle is shape = \"rigid-plane\" (optional height, a number) or \"rigid-surface\" (height = an expression in x, y, r)",
                ));
            }
            if o.shape == ObstacleShape::RigidSurface && o.height.is_none() {
                return Err(self.error(
                    "obstacle.height",
                    "shape = \"rigid-surface\" needs height = \"<expression in x, y, r>\" (the body fills z < height)",
                ));
            }
            if self.element.is_p2b_shell() && o.multiplier == Some(ContactMultiplier::P0) {
                return Err(self.error(
                    "obstacle.multiplier",
                    format!(
                        "\"{}\" has P1 contact multipliers only (multiplier = \"p1\"); \"p0\" goes with element = \"p1b-p0\"",
                        self.element.name()
                    ),
                ));
            }
        }
        if self.mesh.dirichlet_value.is_some() {
            return Err(self.error(
                "mesh.dirichlet_value",
                "boundary values are the membrane's; the shell fixes its parts at 0 (shell.boundary)",
            ));
        }
        if self.output.errors || self.output.exact.is_some() {
            return Err(self.error(
                "output.errors",
                "no exact solution is known for the shell; errors against a finer mesh come from a study",
            ));
        }
        if self.output.plots.contains(&PlotKind::U) {
            return Err(self.error(
                "output.plots",
                "the shell plots its components: \"u1\", \"u2\", \"u3\" (and \"constraint\")",
            ));
        }
        Ok(())
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
