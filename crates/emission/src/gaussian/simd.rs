//! The lanes the Gaussian's kernels are written in, and which instruction
//! set runs them.
//!
//! Every kernel of [`super::kernels`] is written once, generic over a
//! [`Lanes`] type (a vector of `W` doubles), and compiled three times: with
//! AVX-512 (`W = 8`), with AVX2 and FMA (`W = 4`), and portably (`W = 4`,
//! plain `f64` arithmetic and [`f64::mul_add`], which is correctly rounded on
//! every target, in hardware or in software). Each lane of each operation is
//! one IEEE-754 operation on one value — no horizontal sums, no
//! reassociation, no flush-to-zero — and a kernel's lanes never exchange
//! values, so the three builds give the same bits, whatever the CPU: the
//! vector width only decides how many values are computed at once, never how
//! any of them is computed.
//!
//! The instruction set is the crate's [`crate::linalg::simd_level`] (detected
//! once per process, capped by the environment variable `PHASEKIT_SIMD` or by
//! [`crate::linalg::with_simd_level`]), so that one switch checks every
//! kernel of the workspace on one machine.

/// A vector of [`Lanes::W`] doubles and the lane-wise operations the kernels
/// use. Every operation is the IEEE-754 operation on each lane.
///
/// # Safety
/// Implementations for an instruction set may only be used when the CPU
/// supports it (the kernels are instantiated inside `#[target_feature]`
/// functions that are called after detection). Loads and stores read or
/// write exactly the lanes they are given (`W`, or `n` for the partial forms).
pub(super) unsafe trait Lanes: Copy {
    /// Number of lanes.
    const W: usize;
    /// All lanes `0.0`.
    unsafe fn zero() -> Self;
    /// All lanes `v`.
    unsafe fn splat(v: f64) -> Self;
    /// Lanes `p[0..W]`.
    unsafe fn load(p: *const f64) -> Self;
    /// Lanes `p[0..n]` and zeros (`n ≤ W`); nothing beyond `p[n − 1]` is read.
    unsafe fn load_partial(p: *const f64, n: usize) -> Self;
    /// Stores all lanes to `p[0..W]`.
    unsafe fn store(self, p: *mut f64);
    /// Stores lanes `0..n` to `p[0..n]` (`n ≤ W`); nothing else is written.
    unsafe fn store_partial(self, p: *mut f64, n: usize);
    /// `a + b`.
    unsafe fn add(a: Self, b: Self) -> Self;
    /// `a − b`.
    unsafe fn sub(a: Self, b: Self) -> Self;
    /// `a · b`.
    unsafe fn mul(a: Self, b: Self) -> Self;
    /// `a · b + c`, rounded once (fused multiply-add).
    unsafe fn fma(a: Self, b: Self, c: Self) -> Self;
    /// `if x < m { x } else { m }` (so `m` is kept on ties of `±0`).
    unsafe fn min(x: Self, m: Self) -> Self;
    /// `if x > m { x } else { m }`.
    unsafe fn max(x: Self, m: Self) -> Self;
    /// Bit `l` set where lane `l` is a weight that counts in the statistics
    /// ([`super::kernels::counts`]: `|w| ≥` [`super::kernels::NEGLIGIBLE_WEIGHT`]
    /// or NaN), compared as the bits of `|w|`: for non-negative doubles
    /// their order as integers is their order as numbers, and every NaN lies
    /// above `+∞`.
    unsafe fn counts_mask(self) -> u32;
}

/// The bits of `|w|`, of [`super::kernels::NEGLIGIBLE_WEIGHT`], and the mask
/// that clears the sign (see [`Lanes::counts_mask`]).
const ABS_BITS: u64 = !(1 << 63);
const NEGLIGIBLE_BITS: u64 = super::kernels::NEGLIGIBLE_WEIGHT.to_bits();

/// The portable build: four `f64` lanes, plain arithmetic and
/// [`f64::mul_add`] (vectorised by the compiler where the target allows).
#[derive(Clone, Copy)]
pub(super) struct Portable([f64; 4]);

// SAFETY: plain Rust arithmetic, valid on every CPU; the pointer accesses
// touch exactly the documented lanes.
unsafe impl Lanes for Portable {
    const W: usize = 4;
    #[inline(always)]
    unsafe fn zero() -> Self {
        Portable([0.0; 4])
    }
    #[inline(always)]
    unsafe fn splat(v: f64) -> Self {
        Portable([v; 4])
    }
    #[inline(always)]
    unsafe fn load(p: *const f64) -> Self {
        Portable(std::ptr::read_unaligned(p as *const [f64; 4]))
    }
    #[inline(always)]
    unsafe fn load_partial(p: *const f64, n: usize) -> Self {
        let mut v = [0.0; 4];
        for (l, x) in v.iter_mut().enumerate().take(n) {
            *x = *p.add(l);
        }
        Portable(v)
    }
    #[inline(always)]
    unsafe fn store(self, p: *mut f64) {
        std::ptr::write_unaligned(p as *mut [f64; 4], self.0)
    }
    #[inline(always)]
    unsafe fn store_partial(self, p: *mut f64, n: usize) {
        for (l, x) in self.0.iter().enumerate().take(n) {
            *p.add(l) = *x;
        }
    }
    #[inline(always)]
    unsafe fn add(a: Self, b: Self) -> Self {
        Portable(std::array::from_fn(|l| a.0[l] + b.0[l]))
    }
    #[inline(always)]
    unsafe fn sub(a: Self, b: Self) -> Self {
        Portable(std::array::from_fn(|l| a.0[l] - b.0[l]))
    }
    #[inline(always)]
    unsafe fn mul(a: Self, b: Self) -> Self {
        Portable(std::array::from_fn(|l| a.0[l] * b.0[l]))
    }
    #[inline(always)]
    unsafe fn fma(a: Self, b: Self, c: Self) -> Self {
        Portable(std::array::from_fn(|l| a.0[l].mul_add(b.0[l], c.0[l])))
    }
    #[inline(always)]
    unsafe fn min(x: Self, m: Self) -> Self {
        Portable(std::array::from_fn(|l| {
            if x.0[l] < m.0[l] {
                x.0[l]
            } else {
                m.0[l]
            }
        }))
    }
    #[inline(always)]
    unsafe fn max(x: Self, m: Self) -> Self {
        Portable(std::array::from_fn(|l| {
            if x.0[l] > m.0[l] {
                x.0[l]
            } else {
                m.0[l]
            }
        }))
    }
    #[inline(always)]
    unsafe fn counts_mask(self) -> u32 {
        self.0.iter().enumerate().fold(0, |m, (l, w)| {
            m | (((w.to_bits() & ABS_BITS) >= NEGLIGIBLE_BITS) as u32) << l
        })
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) use x86::{Avx2, Avx512};

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{Lanes, ABS_BITS, NEGLIGIBLE_BITS};
    use std::arch::x86_64::*;

    /// Four lanes in an AVX2 register (`vfmadd…pd ymm` for [`Lanes::fma`]).
    #[derive(Clone, Copy)]
    pub(in crate::gaussian) struct Avx2(__m256d);

    /// `_mm256_maskload_pd` masks: lanes `0..n` for `n = 0..=4`.
    const MASK4: [[i64; 4]; 5] = [
        [0, 0, 0, 0],
        [-1, 0, 0, 0],
        [-1, -1, 0, 0],
        [-1, -1, -1, 0],
        [-1, -1, -1, -1],
    ];

    // SAFETY: used only inside functions compiled with `avx2,fma` that are
    // called after run-time detection of both; masked loads and stores touch
    // only the lanes of the mask.
    unsafe impl Lanes for Avx2 {
        const W: usize = 4;
        #[inline(always)]
        unsafe fn zero() -> Self {
            Avx2(_mm256_setzero_pd())
        }
        #[inline(always)]
        unsafe fn splat(v: f64) -> Self {
            Avx2(_mm256_set1_pd(v))
        }
        #[inline(always)]
        unsafe fn load(p: *const f64) -> Self {
            Avx2(_mm256_loadu_pd(p))
        }
        #[inline(always)]
        unsafe fn load_partial(p: *const f64, n: usize) -> Self {
            let m = _mm256_loadu_si256(MASK4[n].as_ptr() as *const __m256i);
            Avx2(_mm256_maskload_pd(p, m))
        }
        #[inline(always)]
        unsafe fn store(self, p: *mut f64) {
            _mm256_storeu_pd(p, self.0)
        }
        #[inline(always)]
        unsafe fn store_partial(self, p: *mut f64, n: usize) {
            let m = _mm256_loadu_si256(MASK4[n].as_ptr() as *const __m256i);
            _mm256_maskstore_pd(p, m, self.0)
        }
        #[inline(always)]
        unsafe fn add(a: Self, b: Self) -> Self {
            Avx2(_mm256_add_pd(a.0, b.0))
        }
        #[inline(always)]
        unsafe fn sub(a: Self, b: Self) -> Self {
            Avx2(_mm256_sub_pd(a.0, b.0))
        }
        #[inline(always)]
        unsafe fn mul(a: Self, b: Self) -> Self {
            Avx2(_mm256_mul_pd(a.0, b.0))
        }
        #[inline(always)]
        unsafe fn fma(a: Self, b: Self, c: Self) -> Self {
            Avx2(_mm256_fmadd_pd(a.0, b.0, c.0))
        }
        #[inline(always)]
        unsafe fn min(x: Self, m: Self) -> Self {
            // MINPD: `first < second ? first : second`.
            Avx2(_mm256_min_pd(x.0, m.0))
        }
        #[inline(always)]
        unsafe fn max(x: Self, m: Self) -> Self {
            Avx2(_mm256_max_pd(x.0, m.0))
        }
        #[inline(always)]
        unsafe fn counts_mask(self) -> u32 {
            // No unsigned 64-bit comparison in AVX2; the bits of `|w|` are
            // below 2⁶³, so the signed `abs > NEGLIGIBLE − 1` is the same.
            let abs = _mm256_and_si256(
                _mm256_castpd_si256(self.0),
                _mm256_set1_epi64x(ABS_BITS as i64),
            );
            let on = _mm256_cmpgt_epi64(abs, _mm256_set1_epi64x(NEGLIGIBLE_BITS as i64 - 1));
            _mm256_movemask_pd(_mm256_castsi256_pd(on)) as u32
        }
    }

    /// Eight lanes in an AVX-512 register.
    #[derive(Clone, Copy)]
    pub(in crate::gaussian) struct Avx512(__m512d);

    #[inline(always)]
    fn mask8(n: usize) -> __mmask8 {
        ((1u32 << n) - 1) as __mmask8
    }

    // SAFETY: used only inside functions compiled with `avx512f` that are
    // called after run-time detection; masked loads and stores touch only the
    // lanes of the mask (masked-off lanes do not fault).
    unsafe impl Lanes for Avx512 {
        const W: usize = 8;
        #[inline(always)]
        unsafe fn zero() -> Self {
            Avx512(_mm512_setzero_pd())
        }
        #[inline(always)]
        unsafe fn splat(v: f64) -> Self {
            Avx512(_mm512_set1_pd(v))
        }
        #[inline(always)]
        unsafe fn load(p: *const f64) -> Self {
            Avx512(_mm512_loadu_pd(p))
        }
        #[inline(always)]
        unsafe fn load_partial(p: *const f64, n: usize) -> Self {
            Avx512(_mm512_maskz_loadu_pd(mask8(n), p))
        }
        #[inline(always)]
        unsafe fn store(self, p: *mut f64) {
            _mm512_storeu_pd(p, self.0)
        }
        #[inline(always)]
        unsafe fn store_partial(self, p: *mut f64, n: usize) {
            _mm512_mask_storeu_pd(p, mask8(n), self.0)
        }
        #[inline(always)]
        unsafe fn add(a: Self, b: Self) -> Self {
            Avx512(_mm512_add_pd(a.0, b.0))
        }
        #[inline(always)]
        unsafe fn sub(a: Self, b: Self) -> Self {
            Avx512(_mm512_sub_pd(a.0, b.0))
        }
        #[inline(always)]
        unsafe fn mul(a: Self, b: Self) -> Self {
            Avx512(_mm512_mul_pd(a.0, b.0))
        }
        #[inline(always)]
        unsafe fn fma(a: Self, b: Self, c: Self) -> Self {
            Avx512(_mm512_fmadd_pd(a.0, b.0, c.0))
        }
        #[inline(always)]
        unsafe fn min(x: Self, m: Self) -> Self {
            Avx512(_mm512_min_pd(x.0, m.0))
        }
        #[inline(always)]
        unsafe fn max(x: Self, m: Self) -> Self {
            Avx512(_mm512_max_pd(x.0, m.0))
        }
        #[inline(always)]
        unsafe fn counts_mask(self) -> u32 {
            let abs = _mm512_and_si512(
                _mm512_castpd_si512(self.0),
                _mm512_set1_epi64(ABS_BITS as i64),
            );
            _mm512_cmpge_epu64_mask(abs, _mm512_set1_epi64(NEGLIGIBLE_BITS as i64)) as u32
        }
    }
}

/// The instruction sets the kernels are built for, in increasing order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub(super) enum Isa {
    /// Plain Rust ([`Portable`]): every CPU.
    Portable,
    /// AVX2 and FMA ([`Avx2`]).
    Avx2,
    /// AVX-512F ([`Avx512`]).
    Avx512,
}

impl Isa {
    /// The instruction sets this CPU supports, portable first.
    pub(super) fn available() -> Vec<Isa> {
        let mut v = vec![Isa::Portable];
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
                v.push(Isa::Avx2);
                if std::is_x86_feature_detected!("avx512f") {
                    v.push(Isa::Avx512);
                }
            }
        }
        v
    }
}

/// The instruction set the kernels use: [`crate::linalg::simd_level`]
/// (AVX-512 there needs F, VL and DQ; these kernels use only F).
#[inline]
pub(super) fn isa() -> Isa {
    use crate::linalg::{simd_level, SimdLevel};
    match simd_level() {
        SimdLevel::Portable => Isa::Portable,
        SimdLevel::Avx2Fma => Isa::Avx2,
        SimdLevel::Avx512 => Isa::Avx512,
    }
}
