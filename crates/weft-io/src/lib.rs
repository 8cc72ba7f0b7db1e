//! # weft-io — file formats
