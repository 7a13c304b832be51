//! obstacle-fem: finite elements and Uzawa-type solvers for obstacle and
//! shell contact problems.
//!
//! The pipeline, one module a stage: [`scene`] (the one input) → [`gmsh`] /
//! [`mesh`] → [`space`] (FE spaces, DOF maps) → [`assembly`] (forms as plain
//! functions) → [`models`] (membrane, Naghdi shell) build an algebraic contact problem
//! → [`solvers`] (know nothing about the models) → [`output`] (HDF5 + XDMF).
//! [`pipeline`] runs these steps for one scene ([`run`] picks it or the
//! adaptive loop); [`study`] runs many, and
//! [`transfer`] measures a run against a finer one; [`adapt`] loops a scene
//! over meshes refined where its a posteriori estimator is large.

// FE kernels index several arrays with the same local index; iterator
// chains would hide that, so index loops are kept.
#![allow(clippy::needless_range_loop)]

pub mod adapt;
pub mod assembly;
pub mod bench;
pub mod console;
pub mod error;
pub mod expression;
pub mod freefem;
pub mod gmsh;
pub mod guards;
pub mod hard;
pub mod linalg;
pub mod mesh;
pub mod models;
pub mod multigrid;
pub mod names;
pub mod numbers;
pub mod output;
pub mod pipeline;
pub mod plot;
pub mod progress;
pub mod quadrature;
pub mod report;
pub mod run;
pub mod scene;
pub mod solvers;
pub mod space;
pub mod study;
pub mod subprocess;
pub mod transfer;

pub use error::{Error, Result};
