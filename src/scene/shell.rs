//! `[shell]` (model "naghdi"): the chart φ (presets and expressions), the
//! material, the penalty ρ, the clamped parts and the boundary conditions
//! per part.

use super::Expression;
use serde::Deserialize;

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
    pub(super) fn check_material(&self) -> std::result::Result<(), (&'static str, String)> {
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
