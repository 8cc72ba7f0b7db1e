//! # weft-sim — the ACM engine

pub mod materials;
