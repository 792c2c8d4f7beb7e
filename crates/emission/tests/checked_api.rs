//! Public per-frame entry points check their arguments instead of panicking
//! or silently reading the wrong values.

use phasekit_emission::{CovarianceType, EmissionError, Gaussian, Shape};

#[test]
fn log_density_one_refuses_wrong_state_length_and_values() {
    let g = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 2,
            dim: 3,
        },
    )
    .unwrap();
    let want = -1.5 * (2.0 * std::f64::consts::PI).ln();
    assert!((g.log_density_one(1, &[0.0; 3]).unwrap() - want).abs() < 1e-12);
    assert!(matches!(
        g.log_density_one(2, &[0.0; 3]),
        Err(EmissionError::InvalidParameter { name: "state", .. })
    ));
    for bad in [&[0.0; 2][..], &[0.0; 4]] {
        assert!(matches!(
            g.log_density_one(0, bad),
            Err(EmissionError::DimensionMismatch { expected: 3, .. })
        ));
    }
    for v in [f64::NAN, f64::INFINITY] {
        assert!(matches!(
            g.log_density_one(0, &[0.0, v, 0.0]),
            Err(EmissionError::InvalidValue { column: 1, .. })
        ));
    }
}
