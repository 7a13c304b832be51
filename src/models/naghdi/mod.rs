//! The Naghdi shell in Cartesian form (Blouza–Le Dret, docs/formulation.md §2): midsurface
//! geometry, material, obstacle function ([`geometry`]); the forms a_ρ, b, c,
//! L and the discrete Problem 9 as an algebraic problem ([`forms`], with the
//! tied membrane and shear strains of `p2b-mitc` in [`forms::tied_strains`]); the model
//! as the pipeline runs it ([`system`]); its residual a posteriori estimator ([`estimator`]).

pub mod estimator;
pub mod forms;
pub mod geometry;
pub mod system;

use super::{FreefemTwin, ModelKind, ModelSystem};
use crate::error::Result;
use crate::mesh::Mesh;
use crate::scene::{ColdStartSpec, ElementPair, Scene};

/// The shell model as the stages around it see it ([`ModelKind`]).
pub struct Naghdi;

/// Bytes per unknown of a whole shell run (assembly, factorisation,
/// iteration, output) with the whole matrix factorised (`solver.condense =
/// false`; docs/work-precision.md, "Scale" and "Scale after condensation"):
/// active set, p1b-p0, n = 128, 378,631 unknowns, 1796 MB (4.7 KB each);
/// n = 256, 1,510,919, 7408 MB (4.9 KB).
const BYTES_PER_UNKNOWN: f64 = 5.0e3;

/// The same, condensed (the default), since the symmetric matrices are
/// stored and condensed by their lower triangle (docs/work-precision.md,
/// "Lower-triangle storage"): n = 64, 95,111 unknowns, 265 MB (2.8 KB);
/// n = 128, 1069 MB (2.8 KB); n = 256, 4778 MB (3.2 KB); n = 512, ≈ 6.03M,
/// 20157 MB (3.3 KB).
const CONDENSED_BYTES_PER_UNKNOWN: f64 = 3.6e3;

impl ModelKind for Naghdi {
    fn setup<'m>(&self, mesh: &'m Mesh, scene: &Scene) -> Result<Box<dyn ModelSystem + 'm>> {
        Ok(Box::new(system::NaghdiSystem::setup(mesh, scene)?))
    }

    fn unknowns_per_triangle(&self, element: ElementPair) -> f64 {
        match element {
            // 7 P1⊕B3 blocks and P0.
            ElementPair::P1bP0 => 11.5,
            // 5 P2⊕B3 blocks (V + E + T each) and P1; and the P2–P1 fallback.
            _ => 15.5,
        }
    }

    fn bytes_per_unknown(&self, condensed: bool) -> f64 {
        if condensed {
            CONDENSED_BYTES_PER_UNKNOWN
        } else {
            BYTES_PER_UNKNOWN
        }
    }

    fn matrix_inputs(&self) -> (&'static str, &'static str) {
        (
            "shell",
            "shell.young, shell.thickness, shell.rho, shell.chart and the mesh coordinates",
        )
    }

    fn load_inputs(&self) -> (&'static str, &'static str) {
        ("load", "load.f, load.edge")
    }

    fn has_surface(&self) -> bool {
        true
    }

    /// The interior point: the shell's Newton solves grow with n under the
    /// depth bisection (7 … 61 at n = 16 … 512) and not under the interior
    /// point (8 … 17).
    fn auto_cold_start(&self) -> ColdStartSpec {
        ColdStartSpec::InteriorPoint
    }

    /// `p2b-psri` has its own script; `p2b-mitc` has none (the thesis
    /// element's script refuses it).
    fn freefem_twin(&self, element: ElementPair) -> Option<FreefemTwin> {
        Some(match element {
            ElementPair::P2bPsri => FreefemTwin::ShellPsri,
            _ => FreefemTwin::ShellThesis,
        })
    }
}
