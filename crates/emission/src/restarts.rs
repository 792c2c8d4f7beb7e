//! The best of several runs of EM, shared by Baum-Welch (`phasekit-hmm`), the
//! HSMM's EM (`phasekit-hsmm`) and the mixture's EM (`phasekit-gmm`), so that
//! the three keep the same rule: run `r = 0, 1, …` in order, keep the run
//! whose final objective is the highest (the first of equal ones), report the
//! final objective of every run and the error of the first that failed.

/// What [`best_of_restarts`] found.
#[derive(Debug)]
#[non_exhaustive]
pub struct Restarts<T, E> {
    /// The kept run and its index: the highest final objective, the first
    /// of equal ones (the first successful run is kept whatever its
    /// objective; a NaN objective never replaces a kept run).
    pub best: Option<(T, usize)>,
    /// The final objective of every run (`None` for a run that failed), in
    /// run order.
    pub finals: Vec<Option<f64>>,
    /// The error of the first run that failed.
    pub first_error: Option<E>,
}

/// Runs `run(r)` for `r` in `0..n`, in order, and keeps the run with the
/// highest `objective` (see [`Restarts`]).
pub fn best_of_restarts<T, E>(
    n: usize,
    mut run: impl FnMut(usize) -> Result<T, E>,
    objective: impl Fn(&T) -> f64,
) -> Restarts<T, E> {
    let mut best: Option<(T, usize, f64)> = None;
    let mut finals = Vec::with_capacity(n);
    let mut first_error = None;
    for r in 0..n {
        match run(r) {
            Ok(fitted) => {
                let obj = objective(&fitted);
                finals.push(Some(obj));
                if best.as_ref().is_none_or(|(_, _, b)| obj > *b) {
                    best = Some((fitted, r, obj));
                }
            }
            Err(e) => {
                finals.push(None);
                first_error.get_or_insert(e);
            }
        }
    }
    Restarts {
        best: best.map(|(fitted, r, _)| (fitted, r)),
        finals,
        first_error,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_first_highest_and_reports_every_run() {
        let objectives = [Ok(1.0), Err("a"), Ok(3.0), Ok(f64::NAN), Ok(3.0), Err("b")];
        let out = best_of_restarts(objectives.len(), |r| objectives[r], |&o| o);
        let (best, r) = out.best.unwrap();
        assert_eq!((best, r), (3.0, 2));
        assert_eq!(out.first_error, Some("a"));
        let finals: Vec<_> = out.finals.iter().map(|f| f.map(f64::to_bits)).collect();
        let expected: Vec<_> = [Some(1.0), None, Some(3.0), Some(f64::NAN), Some(3.0), None]
            .iter()
            .map(|f| f.map(f64::to_bits))
            .collect();
        assert_eq!(finals, expected);
    }

    #[test]
    fn a_kept_nan_is_not_replaced_and_no_run_is_an_error() {
        // The first run is kept before any comparison; NaN then compares false.
        let out = best_of_restarts(2, |r| Ok::<f64, ()>([f64::NAN, 5.0][r]), |&o| o);
        assert_eq!(out.best.unwrap().1, 0);
        let none = best_of_restarts(2, |_| Err::<f64, _>(7), |&o| o);
        assert!(none.best.is_none() && none.first_error == Some(7));
    }
}
