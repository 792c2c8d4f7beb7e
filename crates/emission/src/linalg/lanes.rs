//! Sums of lane-wise partial sums in a fixed order (so that a sum does not
//! depend on the SIMD width that computed its partial sums).

/// Pairwise sum of `L` partial sums, in a fixed order.
#[inline(always)]
pub fn reduce_lanes<const L: usize>(mut acc: [f64; L]) -> f64 {
    let mut w = L;
    while w > 1 {
        let h = w / 2;
        for l in 0..h {
            acc[l] += acc[l + h];
        }
        if w % 2 == 1 {
            acc[0] += acc[w - 1];
        }
        w = h;
    }
    acc[0]
}
