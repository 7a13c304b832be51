//! Geometric multigrid on nested meshes: what the levels of a
//! [`crate::mesh::Hierarchy`] give the algebraic V-cycle
//! (`linalg::Multigrid`, `linalg::pcg`, which know no meshes).
//!
//! - [`transfer`]: P1 prolongations between the levels on the free
//!   (non-Dirichlet) vertices, what boundary values add to them, and the P1
//!   stiffness and load of a level, Dirichlet vertices eliminated as the
//!   membrane does;
//! - [`p2`]: P2 prolongations, and those of systems of P2⊕B3 fields (the
//!   shell's; coarser levels P2 alone).
//!
//! The obstacle problem on these levels is `solvers::multigrid_newton`
//! (Newton multigrid; the P1⊕B3 bubbles condensed there). Not built:
//! `solver.linear = "multigrid"` (the seam's analysis sees no hierarchy).

pub mod p2;
pub mod transfer;

pub use crate::linalg::{
    pcg, CgReport, CycleReport, Multigrid, MultigridOptions, Smoother, SweepOrder, SweptLevel,
};
pub use p2::{p2_prolongation, FieldLevel, P2FieldLevels};
pub use transfer::{p1_load, p1_prolongation, p1_stiffness, P1Levels};
