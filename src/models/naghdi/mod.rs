//! The Naghdi shell in Cartesian form (Blouza–Le Dret, docs/formulation.md §2): midsurface
//! geometry, material, obstacle function ([`geometry`]); the forms a_ρ, b, c,
//! L and the discrete Problem 9 as an algebraic problem ([`forms`], with the
//! tied membrane and shear strains of `p2b-mitc` in [`forms::tied_strains`]); the model
//! as the pipeline runs it ([`system`]); its residual a posteriori estimator ([`estimator`]).

pub mod estimator;
pub mod forms;
pub mod geometry;
pub mod system;
