//! `[output]`: plots, probes, errors against an exact solution.

use super::Expression;
use serde::Deserialize;

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
