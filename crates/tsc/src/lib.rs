//! Transition state clustering (filled by the TSC issue).
#![warn(missing_docs)]
