//! Geometric multigrid on nested meshes (issue 45): the linear core.
//!
//! - [`transfer`]: P1 prolongations between the levels of a
//!   [`crate::mesh::Hierarchy`] on the free (non-Dirichlet) vertices, and the
//!   P1 stiffness and load of a level, Dirichlet vertices eliminated as the
//!   membrane does;
//! - [`vcycle`]: [`Multigrid`], the V-cycle of an SPD matrix given the
//!   prolongations (Galerkin coarse operators, Gauss–Seidel or damped
//!   Jacobi, the coarsest level by the direct solver through the seam), as
//!   a solver ([`Multigrid::solve`]) and a preconditioner
//!   ([`Multigrid::precondition`]);
//! - [`pcg`]: conjugate gradients with such a preconditioner;
//! - [`p2`]: P2 prolongations, and those of systems of P2⊕B3 fields (the
//!   shell's; coarser levels P2 alone).
//!
//! The V-cycle and PCG know no meshes: they need the matrix and the
//! prolongations only. Both run on one thread.
//!
//! Not yet here (issue 45): the obstacle (a multigrid method for the
//! inequality, or the active set with these solves inside), the P1⊕B3
//! element's bubbles (condensed to P1 first), `solver.linear = "multigrid"`.

pub mod p2;
pub mod pcg;
pub mod transfer;
pub mod vcycle;

pub use p2::{p2_prolongation, FieldLevel, P2FieldLevels};
pub use pcg::{pcg, CgReport};
pub use transfer::{p1_load, p1_prolongation, p1_stiffness, P1Levels};
pub use vcycle::{CycleReport, Multigrid, MultigridOptions, Smoother, SweepOrder};
