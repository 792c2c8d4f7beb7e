//! Helpers of the kernels' tests.

/// Distance in units in the last place between two doubles (ordered bit
/// patterns; 0 for the same bits, and for `0.0` against `-0.0`).
pub(crate) fn ulps(a: f64, b: f64) -> u64 {
    if a == b || a.to_bits() == b.to_bits() {
        return 0;
    }
    let key = |v: f64| {
        let b = v.to_bits() as i64;
        if b < 0 {
            i64::MIN - b
        } else {
            b
        }
    };
    key(a).abs_diff(key(b))
}
