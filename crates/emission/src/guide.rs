//! # Writing an emission
//!
//! (filled in below)
