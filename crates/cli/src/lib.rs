//! Library side of the `phasekit` command: reading demonstrations, building
//! features, and the paper-compatible evaluation protocol.

#![warn(missing_docs)]

pub mod data;
pub mod experiment;
