//! Midsurface geometry of the Cartesian Naghdi shell (docs/formulation.md §2, thesis Ch. 1–2).
//!
//! A [`Chart`] φ: ω ⊂ R² → R³ maps the reference domain onto the midsurface.
//! [`Chart::at`] evaluates, at one point x = (x, y) of ω, everything the
//! Blouza–Le Dret formulation needs, collected in a [`SurfacePoint`]:
//!
//! * the covariant basis a_α = ∂_α φ, the unit normal a3 = a1×a2/|a1×a2| and
//!   the area element √a = |a1×a2|;
//! * the metric a_αβ = a_α·a_β, its inverse a^αβ and the contravariant basis
//!   a^α = a^αβ a_β (a^α·a_β = δ^α_β);
//! * the curvature b_αβ = a3·∂_β a_α (symmetric) and the exact derivatives of the
//!   normal, ∂_α a3 = −b_αβ a^β (Weingarten), computed from the exact second
//!   derivatives of φ — no finite differences.
//!
//! [`Material`] holds E, ν, ε and the elasticity tensor a^αβρσ;
//! [`obstacle_function`] is Φ = (ε/2 a3 − φ)·e3 (the rigid plane fills z < 0).
//!
//! Index convention: α = 0, 1 in code stands for α = 1, 2 in the formulas.

use nalgebra::{Matrix2, Vector3};
use serde::Deserialize;

/// The chart is declared by the scene (its variants and their range checks
/// are scene data); its geometry is implemented here.
pub use crate::scene::Chart;
use crate::scene::{ChartExpressions, GraphChart, ParametricChart};

/// A chart is singular at a point where |a1×a2| falls below this.
pub const SINGULAR_TOL: f64 = 1e-12;

/// φ with its exact first and second derivatives at one point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Jet {
    /// φ(x).
    pub phi: Vector3<f64>,
    /// d\[α\] = ∂_α φ = a_α.
    pub d: [Vector3<f64>; 2],
    /// dd\[α\]\[β\] = ∂_α ∂_β φ = ∂_β a_α (symmetric in α, β).
    pub dd: [[Vector3<f64>; 2]; 2],
}

/// Everything the shell model needs at one point x ∈ ω.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    /// The reference point x = (x, y) ∈ ω.
    pub x: [f64; 2],
    /// Position φ(x) on the midsurface.
    pub phi: Vector3<f64>,
    /// a1 = ∂_1 φ.
    pub a1: Vector3<f64>,
    /// a2 = ∂_2 φ.
    pub a2: Vector3<f64>,
    /// Unit normal a3 = a1×a2/|a1×a2|.
    pub a3: Vector3<f64>,
    /// Area element √a = |a1×a2| (= √det(a_αβ)).
    pub sqrt_a: f64,
    /// Covariant metric a_αβ = a_α·a_β.
    pub a_cov: Matrix2<f64>,
    /// Contravariant metric a^αβ = (a_αβ)⁻¹.
    pub a_contra: Matrix2<f64>,
    /// Contravariant basis a^α = a^αβ a_β (tangent, a^α·a_β = δ^α_β).
    pub a_contra_basis: [Vector3<f64>; 2],
    /// Covariant curvature tensor b_αβ = a3·∂_β a_α (symmetric).
    pub b_cov: Matrix2<f64>,
    /// d_a3\[α\] = ∂_α a3 = −b_αβ a^β (exact, tangent to the surface).
    pub d_a3: [Vector3<f64>; 2],
    /// d_a\[α\]\[β\] = ∂_β a_α = ∂_α∂_β φ (symmetric in α, β).
    pub d_a: [[Vector3<f64>; 2]; 2],
}

impl Chart {
    /// φ and its exact first and second derivatives at x.
    pub fn jet(&self, x: [f64; 2]) -> Jet {
        let [x1, x2] = x;
        let zero = Vector3::zeros();
        match *self {
            Chart::Parametric(ParametricChart(ref e)) | Chart::Graph(GraphChart(ref e)) => {
                expression_jet(e, x)
            }
            Chart::Sphere { radius, height } => {
                let (sx, cx) = x1.sin_cos();
                let (sy, cy) = x2.sin_cos();
                let r = radius;
                Jet {
                    phi: Vector3::new(r * cy * cx, r * cy * sx, height + r * sy),
                    d: [
                        Vector3::new(-r * cy * sx, r * cy * cx, 0.0),
                        Vector3::new(-r * sy * cx, -r * sy * sx, r * cy),
                    ],
                    dd: [
                        [
                            Vector3::new(-r * cy * cx, -r * cy * sx, 0.0),
                            Vector3::new(r * sy * sx, -r * sy * cx, 0.0),
                        ],
                        [
                            Vector3::new(r * sy * sx, -r * sy * cx, 0.0),
                            Vector3::new(-r * cy * cx, -r * cy * sx, -r * sy),
                        ],
                    ],
                }
            }
            Chart::Cone { half_angle, height } => {
                let (sb, cb) = half_angle.sin_cos();
                let (sy, cy) = x2.sin_cos();
                let tangent_turn = Vector3::new(-sb * sy, sb * cy, 0.0);
                Jet {
                    phi: Vector3::new(x1 * sb * cy, x1 * sb * sy, height + x1 * cb),
                    d: [Vector3::new(sb * cy, sb * sy, cb), x1 * tangent_turn],
                    dd: [
                        [zero, tangent_turn],
                        [
                            tangent_turn,
                            Vector3::new(-x1 * sb * cy, -x1 * sb * sy, 0.0),
                        ],
                    ],
                }
            }
            Chart::HyperbolicParaboloid { r, offset } => {
                let r2 = r * r;
                Jet {
                    phi: Vector3::new(x1, x2, (x1 * x1 - x2 * x2) / r2 + offset),
                    d: [
                        Vector3::new(1.0, 0.0, 2.0 * x1 / r2),
                        Vector3::new(0.0, 1.0, -2.0 * x2 / r2),
                    ],
                    dd: [
                        [Vector3::new(0.0, 0.0, 2.0 / r2), zero],
                        [zero, Vector3::new(0.0, 0.0, -2.0 / r2)],
                    ],
                }
            }
            Chart::Plate { height } => Jet {
                phi: Vector3::new(x1, x2, height),
                d: [Vector3::x(), Vector3::y()],
                dd: [[zero; 2]; 2],
            },
            Chart::Cylinder { radius, height } => {
                let (s, c) = (x1 / radius).sin_cos();
                Jet {
                    phi: Vector3::new(radius * s, x2, height + radius * c),
                    d: [Vector3::new(c, 0.0, -s), Vector3::y()],
                    dd: [
                        [Vector3::new(-s / radius, 0.0, -c / radius), zero],
                        [zero, zero],
                    ],
                }
            }
            Chart::CurvatureKink { r, offset } => {
                let r2 = r * r;
                if x1 > 0.0 {
                    Jet {
                        phi: Vector3::new(x1, x2, offset + x1 * x1 / r2),
                        d: [Vector3::new(1.0, 0.0, 2.0 * x1 / r2), Vector3::y()],
                        dd: [[Vector3::new(0.0, 0.0, 2.0 / r2), zero], [zero, zero]],
                    }
                } else {
                    Jet {
                        phi: Vector3::new(x1, x2, offset),
                        d: [Vector3::x(), Vector3::y()],
                        dd: [[zero; 2]; 2],
                    }
                }
            }
        }
    }

    /// The full local geometry at x (see [`SurfacePoint`]).
    pub fn at(&self, x: [f64; 2]) -> SurfacePoint {
        SurfacePoint::from_jet(x, &self.jet(x))
    }

    /// The first point where the chart is singular, |a1×a2| < [`SINGULAR_TOL`]
    /// (or not a number), with that value; `Ok(())` if it is regular at all.
    pub fn check_regular(
        &self,
        points: impl Iterator<Item = [f64; 2]>,
    ) -> Result<(), ([f64; 2], f64)> {
        for x in points {
            let jet = self.jet(x);
            let [a1, a2] = jet.d;
            let sqrt_a = a1.cross(&a2).norm();
            let finite = jet
                .phi
                .iter()
                .chain(jet.dd.iter().flatten().flatten())
                .all(|v| v.is_finite());
            if !finite || sqrt_a.is_nan() || sqrt_a < SINGULAR_TOL {
                return Err((x, if finite { sqrt_a } else { f64::NAN }));
            }
        }
        Ok(())
    }
}

/// φ's jet from its expressions and their exact derivatives.
fn expression_jet(e: &ChartExpressions, x: [f64; 2]) -> Jet {
    let v = |f: &crate::scene::Expression| f.eval(x);
    let column = |f: &dyn Fn(usize) -> f64| Vector3::new(f(0), f(1), f(2));
    let d: [Vector3<f64>; 2] = std::array::from_fn(|al| column(&|i| v(&e.d[i][al])));
    let second = |k: usize| column(&|i| v(&e.dd[i][k]));
    let mixed = second(1);
    Jet {
        phi: column(&|i| v(&e.phi[i])),
        d,
        dd: [[second(0), mixed], [mixed, second(2)]],
    }
}

impl SurfacePoint {
    /// The geometry at x from φ's jet there (any chart).
    pub fn from_jet(x: [f64; 2], jet: &Jet) -> SurfacePoint {
        let [a1, a2] = jet.d;
        let n = a1.cross(&a2);
        let sqrt_a = n.norm();
        let a3 = n / sqrt_a;
        let a_cov = Matrix2::new(a1.dot(&a1), a1.dot(&a2), a2.dot(&a1), a2.dot(&a2));
        let det = a_cov[(0, 0)] * a_cov[(1, 1)] - a_cov[(0, 1)] * a_cov[(1, 0)];
        let a_contra = Matrix2::new(
            a_cov[(1, 1)] / det,
            -a_cov[(0, 1)] / det,
            -a_cov[(1, 0)] / det,
            a_cov[(0, 0)] / det,
        );
        let a = [a1, a2];
        let a_contra_basis: [Vector3<f64>; 2] =
            std::array::from_fn(|al| a_contra[(al, 0)] * a[0] + a_contra[(al, 1)] * a[1]);
        // b_αβ = a3·∂_β a_α; symmetrised against rounding (∂_1∂_2 φ = ∂_2∂_1 φ).
        let mut b_cov = Matrix2::zeros();
        for al in 0..2 {
            for be in 0..2 {
                b_cov[(al, be)] = 0.5 * (a3.dot(&jet.dd[al][be]) + a3.dot(&jet.dd[be][al]));
            }
        }
        // Weingarten: ∂_α a3 = −b_αβ a^β.
        let d_a3: [Vector3<f64>; 2] = std::array::from_fn(|al| {
            -(b_cov[(al, 0)] * a_contra_basis[0] + b_cov[(al, 1)] * a_contra_basis[1])
        });
        SurfacePoint {
            x,
            phi: jet.phi,
            a1,
            a2,
            a3,
            sqrt_a,
            a_cov,
            a_contra,
            a_contra_basis,
            b_cov,
            d_a3,
            d_a: jet.dd,
        }
    }

    /// a_α (α = 0, 1).
    pub fn a(&self, alpha: usize) -> &Vector3<f64> {
        match alpha {
            0 => &self.a1,
            1 => &self.a2,
            _ => panic!("surface index α must be 0 or 1, got {alpha}"),
        }
    }

    /// Mean curvature H = ½ a^αβ b_αβ (sign: with respect to a3).
    pub fn mean_curvature(&self) -> f64 {
        0.5 * self.a_contra.component_mul(&self.b_cov).sum()
    }

    /// Gaussian curvature K = det(b_αβ)/det(a_αβ).
    pub fn gaussian_curvature(&self) -> f64 {
        self.b_cov.determinant() / self.a_cov.determinant()
    }
}

/// The obstacle function Φ = (ε/2 a3 − φ)·e3 of docs/formulation.md §2 (the rigid plane fills
/// z < 0): the constraint is (u − ε/2 r)·e3 ≥ Φ, and Φ ≤ 0 (thesis (2.2))
/// says the lower face of the undeformed shell lies above the plane.
pub fn obstacle_function(p: &SurfacePoint, thickness: f64) -> f64 {
    0.5 * thickness * p.a3.z - p.phi.z
}

/// Homogeneous isotropic material and thickness of the shell.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// Young's modulus E > 0.
    pub young: f64,
    /// Poisson's ratio ν ∈ [0, 1/2).
    pub poisson: f64,
    /// Thickness ε > 0.
    pub thickness: f64,
}

impl Material {
    /// The material of a scene's shell (ranges checked when the scene was read).
    pub fn of(shell: &crate::scene::ShellSpec) -> Material {
        Material {
            young: shell.young,
            poisson: shell.poisson,
            thickness: shell.thickness,
        }
    }

    /// Shear modulus μ = E/(2(1+ν)).
    pub fn shear_modulus(&self) -> f64 {
        self.young / (2.0 * (1.0 + self.poisson))
    }

    /// Plane-stress Lamé coefficient λ̄ = Eν/(1−ν²) = 2λμ/(λ+2μ).
    pub fn plane_stress_lambda(&self) -> f64 {
        self.young * self.poisson / (1.0 - self.poisson * self.poisson)
    }

    /// The elasticity tensor, indexed `[α][β][ρ][σ]`:
    ///
    ///   a^αβρσ = E/(2(1+ν)) (a^αρ a^βσ + a^ασ a^βρ) + Eν/(1−ν²) a^αβ a^ρσ.
    pub fn elasticity(&self, a_contra: &Matrix2<f64>) -> [[[[f64; 2]; 2]; 2]; 2] {
        let mu = self.shear_modulus();
        let lambda = self.plane_stress_lambda();
        let a = |i: usize, j: usize| a_contra[(i, j)];
        std::array::from_fn(|al| {
            std::array::from_fn(|be| {
                std::array::from_fn(|rh| {
                    std::array::from_fn(|si| {
                        mu * (a(al, rh) * a(be, si) + a(al, si) * a(be, rh))
                            + lambda * a(al, be) * a(rh, si)
                    })
                })
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const R_THESIS: f64 = 50.0 * std::f64::consts::SQRT_2;

    fn hypar_thesis() -> Chart {
        Chart::HyperbolicParaboloid {
            r: R_THESIS,
            offset: 1.4,
        }
    }

    /// Every chart variant, with strongly and weakly curved parameters.
    fn all_charts() -> Vec<Chart> {
        vec![
            hypar_thesis(),
            Chart::HyperbolicParaboloid {
                r: 1.7,
                offset: -0.3,
            },
            Chart::Plate { height: 2.0 },
            Chart::Cylinder {
                radius: 3.0,
                height: 0.5,
            },
            Chart::Cylinder {
                radius: 40.0,
                height: 1.0,
            },
            Chart::CurvatureKink {
                r: 1.3,
                offset: 0.2,
            },
            Chart::Sphere {
                radius: 4.0,
                height: 1.0,
            },
            Chart::Cone {
                half_angle: 0.4,
                height: 0.3,
            },
            Chart::parametric(["x + 0.1*y^2", "y*(1 + 0.2*x)", "sin(x)*cos(y)"]).unwrap(),
        ]
    }

    /// Sample points, none within 1e-3 of x = 0 (the kink line).
    fn sample_points() -> Vec<[f64; 2]> {
        let mut pts = Vec::new();
        for &x in &[-2.3, -0.7, 0.31, 1.1, 2.9] {
            for &y in &[-1.9, -0.2, 0.0, 0.8, 2.2] {
                pts.push([x, y]);
            }
        }
        pts
    }

    fn approx(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    fn phi_closed_form(x: f64, y: f64) -> f64 {
        let r2 = R_THESIS * R_THESIS;
        0.4 * r2 / (4.0 * (x * x + y * y) + r2 * r2).sqrt() - (x * x - y * y) / r2 - 1.4
    }

    #[test]
    fn flat_plate() {
        let chart = Chart::Plate { height: 1.5 };
        chart.validate().unwrap();
        for x in sample_points() {
            let p = chart.at(x);
            assert_eq!(p.a3, Vector3::z());
            assert_eq!(p.sqrt_a, 1.0);
            assert_eq!(p.b_cov, Matrix2::zeros());
            assert_eq!(p.d_a3, [Vector3::zeros(); 2]);
            assert_eq!(p.a_cov, Matrix2::identity());
            assert_eq!(p.a_contra, Matrix2::identity());
            assert_eq!(p.phi, Vector3::new(x[0], x[1], 1.5));
            assert_eq!(obstacle_function(&p, 0.8), 0.4 - 1.5);
        }
    }

    #[test]
    fn hypar_obstacle_closed_form() {
        let chart = hypar_thesis();
        let eps = 0.8;
        let origin = obstacle_function(&chart.at([0.0, 0.0]), eps);
        assert!(approx(origin, -1.0, 1e-12), "Φ(0,0) = {origin}");
        let pts = [
            [0.0, 0.0],
            [10.0, -3.0],
            [-25.0, 40.0],
            [R_THESIS, 0.0],
            [0.0, R_THESIS],
            [0.0, -R_THESIS],
            [-R_THESIS / 2.0, R_THESIS / 2.0],
            [33.3, 12.5],
        ];
        for x in pts {
            let p = chart.at(x);
            let phi = obstacle_function(&p, eps);
            let exact = phi_closed_form(x[0], x[1]);
            assert!(
                approx(phi, exact, 1e-12),
                "Φ{x:?} = {phi}, closed form {exact}"
            );
            // Φ = 0.4 a3_z − φ_z directly.
            assert!(approx(phi, 0.4 * p.a3.z - p.phi.z, 1e-15));
            assert!(phi <= 0.0, "Φ{x:?} = {phi} > 0 (thesis (2.2))");
        }
        for y in [R_THESIS, -R_THESIS] {
            let phi = obstacle_function(&chart.at([0.0, y]), eps);
            println!("hypar: Φ(0, {y:+.6}) = {phi:.6e}");
            assert!(phi < 0.0 && phi > -1e-3, "Φ(0, {y}) = {phi}");
        }
    }

    #[test]
    fn frame_identities_all_charts() {
        for chart in all_charts() {
            chart.validate().unwrap();
            for x in sample_points() {
                let p = chart.at(x);
                let tag = format!("{chart:?} at {x:?}");
                assert!(
                    approx(p.a3.norm(), 1.0, 1e-14),
                    "{tag}: |a3| = {}",
                    p.a3.norm()
                );
                assert!(p.a3.dot(&p.a1).abs() < 1e-14, "{tag}: a3·a1");
                assert!(p.a3.dot(&p.a2).abs() < 1e-14, "{tag}: a3·a2");
                assert!(
                    approx(p.sqrt_a, p.a_cov.determinant().sqrt(), 1e-13),
                    "{tag}: √a"
                );
                let id = p.a_contra * p.a_cov;
                assert!(
                    (id - Matrix2::identity()).abs().max() < 1e-13,
                    "{tag}: a^αβ a_βγ = {id}"
                );
                for al in 0..2 {
                    for be in 0..2 {
                        let d = p.a_contra_basis[al].dot(p.a(be));
                        let delta = if al == be { 1.0 } else { 0.0 };
                        assert!(approx(d, delta, 1e-13), "{tag}: a^{al}·a_{be} = {d}");
                        assert_eq!(p.b_cov[(al, be)], p.b_cov[(be, al)], "{tag}: b symmetric");
                        // b_αβ = −∂_α a3·a_β as well.
                        assert!(
                            approx(p.b_cov[(al, be)], -p.d_a3[al].dot(p.a(be)), 1e-13),
                            "{tag}: b_αβ = −∂_α a3·a_β"
                        );
                    }
                    assert!(p.d_a3[al].dot(&p.a3).abs() < 1e-14, "{tag}: ∂_α a3 tangent");
                }
                // Jet consistency: a1, a2 are the finite-difference derivatives of φ.
                let h = 1e-5;
                for al in 0..2 {
                    let (mut xp, mut xm) = (x, x);
                    xp[al] += h;
                    xm[al] -= h;
                    let fd = (chart.at(xp).phi - chart.at(xm).phi) / (2.0 * h);
                    let err = (fd - p.a(al)).norm();
                    assert!(
                        err <= 1e-6 * p.a(al).norm(),
                        "{tag}: a_{al} vs FD of φ: {err}"
                    );
                }
            }
        }
    }

    #[test]
    fn d_a3_matches_finite_differences() {
        let h = 1e-5;
        let mut worst: f64 = 0.0;
        for chart in all_charts() {
            for x in sample_points() {
                let p = chart.at(x);
                for al in 0..2 {
                    let (mut xp, mut xm) = (x, x);
                    xp[al] += h;
                    xm[al] -= h;
                    let fd = (chart.at(xp).a3 - chart.at(xm).a3) / (2.0 * h);
                    let exact = p.d_a3[al];
                    let err = (fd - exact).norm();
                    if exact.norm() > 0.0 {
                        worst = worst.max(err / exact.norm());
                    }
                    assert!(
                        err <= 1e-6 * exact.norm() + 1e-10, // FD round-off ~ ε/h
                        "{chart:?} at {x:?}: ∂_{al} a3 = {exact:?}, FD {fd:?}, error {err:e}"
                    );
                }
            }
        }
        println!("worst relative error of ∂_α a3 against centred FD (h = 1e-5): {worst:e}");
    }

    #[test]
    fn cylinder_curvatures() {
        for radius in [0.5, 3.0, 40.0] {
            let chart = Chart::Cylinder {
                radius,
                height: 1.0,
            };
            chart.validate().unwrap();
            for x in sample_points() {
                let p = chart.at(x);
                let h = p.mean_curvature();
                assert!(approx(h.abs(), 1.0 / (2.0 * radius), 1e-12), "H = {h}");
                assert!(
                    approx(h, -1.0 / (2.0 * radius), 1e-12),
                    "H = {h} (a3 outward)"
                );
                let k = p.gaussian_curvature();
                assert!(k.abs() <= 1e-12, "K = {k}");
                assert!(approx(p.sqrt_a, 1.0, 1e-14));
                // A genuine cylinder: distance to the axis {x = 0, z = height} is the radius.
                let dist = (p.phi.x.powi(2) + (p.phi.z - 1.0).powi(2)).sqrt();
                assert!(
                    approx(dist, radius, 1e-12 * radius),
                    "distance to the axis {dist}"
                );
                // a3 is the outward radial direction.
                let radial = Vector3::new(p.phi.x, 0.0, p.phi.z - 1.0) / radius;
                assert!((p.a3 - radial).norm() < 1e-12);
            }
            let apex = chart.at([0.0, 0.7]);
            assert!((apex.a3 - Vector3::z()).norm() < 1e-15);
            assert!(approx(apex.phi.z, 1.0 + radius, 1e-15));
        }
    }

    #[test]
    fn hypar_gaussian_curvature_at_origin() {
        for r in [R_THESIS, 1.7, 10.0] {
            let chart = Chart::HyperbolicParaboloid { r, offset: 1.4 };
            let p = chart.at([0.0, 0.0]);
            let k = p.gaussian_curvature();
            let exact = -4.0 / r.powi(4);
            assert!(
                approx(k, exact, 1e-12 * exact.abs()),
                "K(0) = {k}, expected {exact}"
            );
            assert!(
                p.mean_curvature().abs() < 1e-15,
                "the origin is a saddle, H = 0"
            );
            assert_eq!(p.a3, Vector3::z());
            let q = chart.at([0.6, -1.1]);
            let s = 4.0 * (0.36 + 1.21);
            let k = q.gaussian_curvature();
            // (z_xx z_yy − z_xy²)/(1 + |∇z|²)² with z_xx = −z_yy = 2/r².
            let graph = -(4.0 / r.powi(4)) / (1.0 + s / r.powi(4)).powi(2);
            assert!(
                approx(k, graph, 1e-12 * graph.abs()),
                "K = {k}, graph formula {graph}"
            );
        }
    }

    #[test]
    fn curvature_kink_is_c1_not_c2() {
        let r = 1.3;
        let chart = Chart::CurvatureKink { r, offset: 0.2 };
        chart.validate().unwrap();
        for y in [-1.0, 0.0, 0.4] {
            let left = chart.jet([-1e-9, y]);
            let right = chart.jet([1e-9, y]);
            // Second derivatives jump: ∂_11 φ·e3 = 0 on the left, 2/r² on the right.
            assert_eq!(left.dd[0][0].z, 0.0);
            assert!(approx(right.dd[0][0].z, 2.0 / (r * r), 1e-15));
            let pl = chart.at([-1e-9, y]);
            let pr = chart.at([1e-9, y]);
            assert!(approx(
                pr.b_cov[(0, 0)] - pl.b_cov[(0, 0)],
                2.0 / (r * r),
                1e-12
            ));
            assert!((pr.d_a3[0] - pl.d_a3[0]).norm() > 1.0 / (r * r));
            // φ and a_α are continuous: the jumps vanish with the distance.
            for delta in [1e-3, 1e-6, 1e-9] {
                let l = chart.at([-delta, y]);
                let rr = chart.at([delta, y]);
                assert!((rr.phi - l.phi).norm() <= 3.0 * delta);
                assert!((rr.a1 - l.a1).norm() <= 2.0 * delta / (r * r) + 1e-15);
                assert!((rr.a2 - l.a2).norm() <= 1e-15);
                assert!((rr.a3 - l.a3).norm() <= 2.0 * delta / (r * r) + 1e-15);
            }
            // At x = 0 itself the two one-sided first-order data agree exactly.
            let zero = chart.at([0.0, y]);
            assert_eq!(zero.phi, Vector3::new(0.0, y, 0.2));
            assert_eq!(zero.a1, Vector3::x());
            assert_eq!(zero.a3, Vector3::z());
        }
    }

    /// The presets' closed forms against their parametric spelling, whose
    /// derivatives are the expression tree's exact ones: jets equal to
    /// round-off at points off the kink line.
    #[test]
    fn presets_equal_their_parametric_spelling() {
        let cases: [(Chart, [&str; 3]); 7] = [
            (hypar_thesis(), ["x", "y", "(x^2 - y^2)/5000 + 1.4"]),
            (
                Chart::HyperbolicParaboloid {
                    r: 1.7,
                    offset: -0.3,
                },
                ["x", "y", "(x^2 - y^2)/1.7^2 - 0.3"],
            ),
            (Chart::Plate { height: 2.0 }, ["x", "y", "2"]),
            (
                Chart::Cylinder {
                    radius: 3.0,
                    height: 0.5,
                },
                ["3*sin(x/3)", "y", "0.5 + 3*cos(x/3)"],
            ),
            (
                Chart::CurvatureKink {
                    r: 1.3,
                    offset: 0.2,
                },
                ["x", "y", "0.2 + max(x, 0)^2/1.3^2"],
            ),
            (
                Chart::Sphere {
                    radius: 10.0,
                    height: -7.0,
                },
                ["10*cos(y)*cos(x)", "10*cos(y)*sin(x)", "-7 + 10*sin(y)"],
            ),
            (
                Chart::Cone {
                    half_angle: 0.6,
                    height: 1.5,
                },
                ["x*sin(0.6)*cos(y)", "x*sin(0.6)*sin(y)", "1.5 + x*cos(0.6)"],
            ),
        ];
        for (preset, texts) in cases {
            let spelled = Chart::parametric(texts).unwrap();
            for x in sample_points() {
                // The sphere's chart is regular for |latitude| < π/2 only.
                let x = [x[0], x[1] * 0.5];
                let (a, b) = (preset.jet(x), spelled.jet(x));
                let scale = 1.0 + a.phi.norm();
                let worst = (a.phi - b.phi)
                    .norm()
                    .max((0..2).map(|k| (a.d[k] - b.d[k]).norm()).fold(0.0, f64::max))
                    .max(
                        (0..4)
                            .map(|k| (a.dd[k / 2][k % 2] - b.dd[k / 2][k % 2]).norm())
                            .fold(0.0, f64::max),
                    );
                assert!(
                    worst < 1e-12 * scale,
                    "{} at {x:?}: {worst:e}",
                    preset.kind()
                );
                let (p, q) = (preset.at(x), spelled.at(x));
                assert!((p.a3 - q.a3).norm() < 1e-13 && (p.b_cov - q.b_cov).norm() < 1e-12 * scale);
            }
        }
        // The sphere's normal points outward, the cone's into it.
        let sphere = Chart::Sphere {
            radius: 2.0,
            height: 0.0,
        }
        .at([0.3, 0.4]);
        assert!((sphere.a3 - sphere.phi / 2.0).norm() < 1e-14);
        let cone = Chart::Cone {
            half_angle: 0.6,
            height: 0.0,
        }
        .at([1.0, 0.0]);
        assert!((cone.a3 - Vector3::new(-0.6f64.cos(), 0.0, 0.6f64.sin())).norm() < 1e-14);
    }

    #[test]
    fn check_regular_reports_singular_points() {
        let pts = sample_points();
        for chart in all_charts() {
            assert_eq!(chart.check_regular(pts.iter().copied()), Ok(()));
        }
        // A NaN point gives a NaN area element: reported, first one only.
        let chart = hypar_thesis();
        let bad = [[0.0, 0.0], [f64::NAN, 1.0], [f64::INFINITY, 2.0]];
        let (x, sqrt_a) = chart.check_regular(bad.iter().copied()).unwrap_err();
        assert!(x[0].is_nan() && x[1] == 1.0);
        assert!(sqrt_a.is_nan());
    }

    #[test]
    fn chart_validate() {
        for chart in all_charts() {
            assert_eq!(chart.validate(), Ok(()));
        }
        let cases = [
            (
                Chart::Cylinder {
                    radius: 0.0,
                    height: 1.0,
                },
                "radius",
            ),
            (
                Chart::Cylinder {
                    radius: 1.0,
                    height: f64::NAN,
                },
                "height",
            ),
            (
                Chart::HyperbolicParaboloid {
                    r: -1.0,
                    offset: 1.4,
                },
                "r must",
            ),
            (
                Chart::HyperbolicParaboloid {
                    r: 1.0,
                    offset: f64::INFINITY,
                },
                "offset",
            ),
            (
                Chart::CurvatureKink {
                    r: f64::NAN,
                    offset: 0.0,
                },
                "r must",
            ),
            (Chart::Plate { height: f64::NAN }, "height"),
        ];
        for (chart, field) in cases {
            let err = chart.validate().unwrap_err();
            assert!(err.contains(field), "{err}");
            assert!(err.contains(chart.kind()), "{err}");
        }
    }

    #[test]
    fn chart_from_toml() {
        #[derive(Deserialize)]
        struct Doc {
            chart: Chart,
            material: Material,
        }
        let doc: Doc = toml::from_str(
            "[chart]\nkind = \"hyperbolic-paraboloid\"\nr = 70.71067811865476\noffset = 1.4\n\
             [material]\nyoung = 2.85e4\npoisson = 0.4\nthickness = 0.8\n",
        )
        .unwrap();
        assert_eq!(
            doc.chart,
            Chart::HyperbolicParaboloid {
                r: 70.71067811865476,
                offset: 1.4
            }
        );
        assert_eq!(doc.material.young, 2.85e4);
        let c: Chart = toml::from_str("kind = \"cylinder\"\nradius = 2.0\nheight = 3.0\n").unwrap();
        assert_eq!(
            c,
            Chart::Cylinder {
                radius: 2.0,
                height: 3.0
            }
        );
        let c: Chart =
            toml::from_str("kind = \"curvature-kink\"\nr = 2.0\noffset = 3.0\n").unwrap();
        assert_eq!(
            c,
            Chart::CurvatureKink {
                r: 2.0,
                offset: 3.0
            }
        );
        let c: Chart = toml::from_str("kind = \"plate\"\nheight = 3.0\n").unwrap();
        assert_eq!(c, Chart::Plate { height: 3.0 });
        assert!(toml::from_str::<Chart>("kind = \"plate\"\nheight = 3.0\nr = 1.0\n").is_err());
        assert!(toml::from_str::<Chart>("kind = \"sphere\"\nradius = 3.0\n").is_err());
        assert!(toml::from_str::<Chart>("kind = \"cylinder\"\nradius = 3.0\n").is_err());
    }

    #[test]
    fn elasticity_tensor() {
        let mat = Material {
            young: 2.85e4,
            poisson: 0.4,
            thickness: 0.8,
        };
        let (e, nu) = (mat.young, mat.poisson);
        // Plate: a^αβ = δ, plane-stress values.
        let c = mat.elasticity(&Matrix2::identity());
        let tol = 1e-12 * e;
        assert!(approx(c[0][0][0][0], e / (1.0 - nu * nu), tol));
        assert!(approx(c[1][1][1][1], e / (1.0 - nu * nu), tol));
        assert!(approx(c[0][0][1][1], e * nu / (1.0 - nu * nu), tol));
        assert!(approx(c[1][1][0][0], e * nu / (1.0 - nu * nu), tol));
        assert!(approx(c[0][1][0][1], e / (2.0 * (1.0 + nu)), tol));
        assert!(approx(c[0][1][1][0], e / (2.0 * (1.0 + nu)), tol));
        assert_eq!(c[0][0][0][1], 0.0);
        assert_eq!(c[0][1][1][1], 0.0);
        // Symmetries on a curved metric.
        for chart in all_charts() {
            let p = chart.at([0.9, -1.3]);
            let c = mat.elasticity(&p.a_contra);
            for al in 0..2 {
                for be in 0..2 {
                    for rh in 0..2 {
                        for si in 0..2 {
                            let v = c[al][be][rh][si];
                            assert_eq!(v, c[be][al][rh][si], "αβρσ = βαρσ");
                            assert_eq!(v, c[al][be][si][rh], "αβρσ = αβσρ");
                            assert!(approx(v, c[rh][si][al][be], 1e-12 * e), "αβρσ = ρσαβ");
                        }
                    }
                }
            }
        }
    }
}
