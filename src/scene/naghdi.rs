//! The scene keys of model "naghdi": what the shell needs and what it
//! refuses (the membrane's keys).

use super::{
    BoundaryCondition, Chart, ContactMultiplier, ElementPair, Expression, Method, ObstacleShape,
    PlaneNormal, PlotKind, Scene,
};
use crate::error::Result;

impl Scene {
    /// What the shell model needs and cannot use.
    pub(super) fn validate_naghdi(&self) -> Result<()> {
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
}
