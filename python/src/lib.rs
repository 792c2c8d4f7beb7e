//! `phasekit._core`: the compiled core of the `phasekit` Python package.
//!
//! The Rust side is deliberately thin. It turns NumPy arrays into phasekit's
//! validated views (borrowed, no copy, when the array is C-contiguous
//! float64; the Python layer converts anything else once), calls phasekit with
//! the GIL released, and hands NumPy arrays back. Everything that mirrors
//! hmmlearn's and scikit-learn's conventions (parameter letters, priors,
//! attribute shapes, random initialisation) lives in the Python package, so
//! that it can be read next to the library it mirrors.
//!
//! Every call into phasekit's API is in one place per estimator:
//! `hmm` (the HMMs and their E-step statistics), `gmm` (the mixture),
//! `gmr` (regression), `interaction` (the command's pipeline and model
//! files, through `phasekit_cli`) and `stats` (mergeable statistics and
//! their compact serialisation). A rename in phasekit's API is followed there.

use pyo3::prelude::*;

mod arrays;
mod gmm;
mod gmr;
mod hmm;
mod interaction;
mod stats;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<arrays::Sequences>()?;
    m.add_class::<hmm::HmmCore>()?;
    m.add_class::<stats::Statistics>()?;
    m.add_class::<gmm::GmmCore>()?;
    m.add_function(wrap_pyfunction!(gmm::kmeans, m)?)?;
    m.add_class::<gmr::GmrCore>()?;
    m.add_class::<gmr::OnlineGmr>()?;
    m.add_class::<interaction::InteractionCore>()?;
    m.add_class::<interaction::OnlineInteraction>()?;
    m.add_function(wrap_pyfunction!(interaction::read_table, m)?)?;
    m.add_function(wrap_pyfunction!(interaction::load_action, m)?)?;
    m.add_function(wrap_pyfunction!(interaction::load_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(interaction::default_options, m)?)?;
    m.add_function(wrap_pyfunction!(interaction::load_training, m)?)?;
    Ok(())
}
