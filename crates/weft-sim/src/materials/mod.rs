//! Cloth materials.
