//! Gaussian mixture regression (filled by the GMM/GMR issue).
#![warn(missing_docs)]
