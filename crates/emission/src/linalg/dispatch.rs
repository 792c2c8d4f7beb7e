//! Which instruction set the kernels run with, chosen once at run time.
//!
//! Every kernel of this crate (and the recursions of `phasekit-hmm`) is plain
//! Rust written so that every SIMD lane does exactly the arithmetic of the
//! scalar form: `+`, `−`, `×`, `÷` and [`f64::mul_add`] are correctly rounded
//! in IEEE 754 on every target, Rust never contracts `a·b + c` into a fused
//! multiply-add on its own, and the summation orders are fixed by the code,
//! not by the vector width (the Gaussian's full/tied kernels follow the same
//! rule over explicit vector types, `gaussian/simd.rs`, and take their level
//! from [`simd_level`]). [`dispatch`] compiles such code once more for
//! AVX2 + FMA and once for AVX-512 and runs the best build the CPU has, so
//! the results are the same bits on every CPU and at every [`SimdLevel`]
//! (tested by forcing each level with [`with_simd_level`]).
//!
//! What this does not cover: `f64::ln` and `f64::exp` outside
//! [`super::exp_in_place`] come from the platform's math library, whose last
//! bit may differ between libraries (glibc, musl, Apple's libm).

use std::sync::atomic::{AtomicU8, Ordering};

/// Instruction sets the kernels are compiled for, in increasing order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum SimdLevel {
    /// Whatever the compilation target guarantees (SSE2 on x86-64, NEON on aarch64).
    Portable,
    /// x86-64 with AVX2 and FMA (Haswell, Zen and later).
    Avx2Fma,
    /// x86-64 with AVX-512 F, VL and DQ (and AVX2, FMA).
    Avx512,
}

impl SimdLevel {
    fn code(self) -> u8 {
        match self {
            SimdLevel::Portable => 1,
            SimdLevel::Avx2Fma => 2,
            SimdLevel::Avx512 => 3,
        }
    }

    fn from_code(c: u8) -> Self {
        match c {
            3 => SimdLevel::Avx512,
            2 => SimdLevel::Avx2Fma,
            _ => SimdLevel::Portable,
        }
    }
}

/// The best level the CPU supports (0 = not detected yet).
static DETECTED: AtomicU8 = AtomicU8::new(0);
/// An upper bound set by [`with_simd_level`] (0 = none).
static CAP: AtomicU8 = AtomicU8::new(0);

fn detect() -> SimdLevel {
    #[cfg(target_arch = "x86_64")]
    {
        let v3 = std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma");
        let v4 = v3
            && std::is_x86_feature_detected!("avx512f")
            && std::is_x86_feature_detected!("avx512vl")
            && std::is_x86_feature_detected!("avx512dq");
        if v4 {
            return SimdLevel::Avx512;
        }
        if v3 {
            return SimdLevel::Avx2Fma;
        }
    }
    SimdLevel::Portable
}

/// The level of the CPU, capped by the environment variable `PHASEKIT_SIMD`
/// (`portable`, `avx2` or `avx512`; read once), so that one machine can check
/// that every build gives the same numbers (an unknown value caps nothing).
fn detect_capped() -> SimdLevel {
    let cap = match std::env::var("PHASEKIT_SIMD").as_deref() {
        Ok("portable") => SimdLevel::Portable,
        Ok("avx2") => SimdLevel::Avx2Fma,
        _ => SimdLevel::Avx512,
    };
    detect().min(cap)
}

/// The level the CPU supports (detected once, capped by `PHASEKIT_SIMD`),
/// lowered by [`with_simd_level`].
#[inline]
pub fn simd_level() -> SimdLevel {
    let mut d = DETECTED.load(Ordering::Relaxed);
    if d == 0 {
        d = detect_capped().code();
        DETECTED.store(d, Ordering::Relaxed);
    }
    let cap = CAP.load(Ordering::Relaxed);
    if cap != 0 && cap < d {
        d = cap;
    }
    SimdLevel::from_code(d)
}

/// Runs `f` with the kernels capped at `level` (never above what the CPU
/// has), for tests and benchmarks that check that every level gives the same
/// bits. The cap is process-wide: other threads running meanwhile use it too
/// (which changes no result, only the speed).
#[doc(hidden)]
pub fn with_simd_level<R>(level: SimdLevel, f: impl FnOnce() -> R) -> R {
    struct Restore(u8);
    impl Drop for Restore {
        fn drop(&mut self) {
            CAP.store(self.0, Ordering::Relaxed);
        }
    }
    let _restore = Restore(CAP.swap(level.code(), Ordering::Relaxed));
    f()
}

/// Runs `f` compiled for the best instruction set of the CPU
/// ([`simd_level`]), or as it is.
///
/// `f` and everything hot that it calls must be inlined into the clone for
/// the instruction set to apply: write the closure `#[inline(always)] || …`
/// and mark its helpers `#[inline(always)]` (generic code is inlined too).
/// A helper that is not inlined runs in its portable build, which gives the
/// same results, only more slowly.
#[inline(always)]
pub fn dispatch<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    match simd_level() {
        // SAFETY: `simd_level` returns `Avx512` only when the CPU reported
        // AVX-512 F, VL, DQ, AVX2 and FMA, and `Avx2Fma` only when it reported
        // AVX2 and FMA: the instructions the clones may use exist.
        SimdLevel::Avx512 => return unsafe { x86::avx512(f) },
        // SAFETY: as above.
        SimdLevel::Avx2Fma => return unsafe { x86::avx2_fma(f) },
        SimdLevel::Portable => {}
    }
    f()
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    /// `f` compiled with AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub fn avx2_fma<R>(f: impl FnOnce() -> R) -> R {
        f()
    }

    /// `f` compiled with AVX-512 (F, VL, DQ), AVX2 and FMA.
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,avx2,fma")]
    pub fn avx512<R>(f: impl FnOnce() -> R) -> R {
        f()
    }
}
