//! The Naghdi shell in Cartesian form (Blouza–Le Dret, SPEC §2): midsurface geometry, material, obstacle function.

pub mod geometry;
