//! Models: each turns a scene and a mesh into an algebraic
//! [`ContactProblem`](crate::solvers::ContactProblem) using the shared FE
//! machinery, and turns the solver's answer back into fields.

pub mod exact;
pub mod membrane;
pub mod naghdi;
