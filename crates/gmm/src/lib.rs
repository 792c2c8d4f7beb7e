//! Gaussian mixture models fitted by EM (filled by the GMM/GMR issue).
#![warn(missing_docs)]
