//! Eight f64 lanes for the hand-vectorised Allan kernels (the OADEV/TOTDEV sweep and the
//! MDEV/TDEV window sums): one small trait ([`Lanes`]) with portable, AVX2 + FMA and
//! AVX-512F implementations, and [`run_on`], which runs a [`LaneJob`] on the lanes of a
//! [`SweepPath`] inside a `#[target_feature]` function so that the lane methods inline.
//! Every operation is the correctly rounded IEEE one per lane (shuffles only move values),
//! so every path gives the same bits. Why intrinsics and not the auto-vectoriser or a
//! crate: see the module docs of [`super::sweep`] and [`super::modified`].

use super::sweep::SweepPath;

/// Lanes per vector.
pub(super) const LANES: usize = 8;

/// A job that runs on the lanes of any path (see [`run_on`]). Its `run` (and the kernel it
/// calls) must be `#[inline(always)]`: only code inlined into [`run_on`]'s `#[target_feature]`
/// wrappers is compiled with their instruction sets, so the lane methods inline there.
pub(super) trait LaneJob {
    type Output;
    /// Safety: `V`'s instructions must be available.
    unsafe fn run<V: Lanes>(self) -> Self::Output;
}

/// Runs `job` on the lanes of `path` (the portable ones if the CPU lacks its features).
pub(super) fn run_on<J: LaneJob>(path: SweepPath, job: J) -> J::Output {
    #[cfg(target_arch = "x86_64")]
    {
        let best = SweepPath::detected();
        if path == SweepPath::Avx512 && best == SweepPath::Avx512 {
            // SAFETY: the CPU has AVX-512F, AVX2 and FMA (detected just above).
            return unsafe { with_avx512(job) };
        }
        if path == SweepPath::Avx2 && best != SweepPath::Portable {
            // SAFETY: the CPU has AVX2 and FMA (detected just above).
            return unsafe { with_avx2(job) };
        }
    }
    let _ = path;
    // SAFETY: the portable lanes need no CPU feature.
    unsafe { job.run::<Portable>() }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn with_avx2<J: LaneJob>(job: J) -> J::Output {
    job.run::<x86::Avx2>()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
unsafe fn with_avx512<J: LaneJob>(job: J) -> J::Output {
    job.run::<x86::Avx512>()
}

/// Eight f64 lanes. Every method is `unsafe` because the SIMD implementations need their
/// CPU features; each operation is the correctly rounded IEEE one per lane (and the
/// shuffles of [`Lanes::exclusive_scan`] only move values), so all implementations give
/// the same bits.
pub(super) trait Lanes: Copy {
    /// Vectors a kernel may keep per row of a register-carried walk: as many as leave
    /// the three rows, their accumulators and temporaries in registers (AVX-512: 32
    /// registers of one vector each; AVX2: 16 of half a vector; portable SSE2: 16 of a
    /// quarter).
    const WALK: usize;
    unsafe fn zero() -> Self;
    unsafe fn splat(v: f64) -> Self;
    /// Loads eight values from `p` (unaligned).
    unsafe fn load(p: *const f64) -> Self;
    /// Stores the eight values at `p` (unaligned).
    unsafe fn store(self, p: *mut f64);
    unsafe fn add(self, other: Self) -> Self;
    unsafe fn sub(self, other: Self) -> Self;
    unsafe fn mul(self, other: Self) -> Self;
    /// acc + self², rounded once (one fused multiply-add; `f64::mul_add` per lane on the
    /// portable path, so every path gives the same bits).
    unsafe fn square_add(self, acc: Self) -> Self;
    /// self − 2·b, rounded once (2b is exact, so this is also the rounding of the
    /// subtraction: one fused multiply-add on the SIMD paths).
    unsafe fn minus_twice(self, b: Self) -> Self;
    /// e[l] = Σ_{i<l} d[i] (the last lane of d unused): the lanes shifted up by one, then
    /// three steps s[l] += s[l − k] for k = 1, 2, 4 (a zero added where l < k).
    unsafe fn exclusive_scan(self) -> Self;
    unsafe fn to_array(self) -> [f64; LANES];
}

/// Portable lanes (the compiler vectorises them for the baseline target).
#[derive(Clone, Copy)]
pub(super) struct Portable(pub(super) [f64; LANES]);

impl Portable {
    /// The lanes shifted up by `k`, zeros below.
    #[inline(always)]
    fn shifted(self, k: usize) -> [f64; LANES] {
        std::array::from_fn(|l| if l >= k { self.0[l - k] } else { 0.0 })
    }
}

impl Lanes for Portable {
    const WALK: usize = 1;
    #[inline(always)]
    unsafe fn zero() -> Self {
        Portable([0.0; LANES])
    }
    #[inline(always)]
    unsafe fn splat(v: f64) -> Self {
        Portable([v; LANES])
    }
    #[inline(always)]
    unsafe fn load(p: *const f64) -> Self {
        Portable(p.cast::<[f64; LANES]>().read_unaligned())
    }
    #[inline(always)]
    unsafe fn store(self, p: *mut f64) {
        p.cast::<[f64; LANES]>().write_unaligned(self.0)
    }
    #[inline(always)]
    unsafe fn add(self, o: Self) -> Self {
        Portable(std::array::from_fn(|l| self.0[l] + o.0[l]))
    }
    #[inline(always)]
    unsafe fn sub(self, o: Self) -> Self {
        Portable(std::array::from_fn(|l| self.0[l] - o.0[l]))
    }
    #[inline(always)]
    unsafe fn mul(self, o: Self) -> Self {
        Portable(std::array::from_fn(|l| self.0[l] * o.0[l]))
    }
    #[inline(always)]
    unsafe fn square_add(self, acc: Self) -> Self {
        Portable(std::array::from_fn(|l| {
            self.0[l].mul_add(self.0[l], acc.0[l])
        }))
    }
    #[inline(always)]
    unsafe fn minus_twice(self, b: Self) -> Self {
        Portable(std::array::from_fn(|l| self.0[l] - 2.0 * b.0[l]))
    }
    #[inline(always)]
    unsafe fn exclusive_scan(self) -> Self {
        let mut s = Portable(self.shifted(1));
        for k in [1, 2, 4] {
            s = s.add(Portable(s.shifted(k)));
        }
        s
    }
    #[inline(always)]
    unsafe fn to_array(self) -> [f64; LANES] {
        self.0
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    //! AVX2 and AVX-512 lanes. The methods carry their target features, so they inline
    //! into the `#[target_feature]` functions that run the jobs with them.
    use super::{Lanes, LANES};
    use std::arch::x86_64::*;

    /// Two 256-bit halves.
    #[derive(Clone, Copy)]
    pub(super) struct Avx2(__m256d, __m256d);

    impl Avx2 {
        /// Both halves shifted up by one lane across the pair, a zero in lane 0.
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        fn shifted1(self) -> Self {
            let zero = _mm256_setzero_pd();
            // [0, lo0, lo1, lo2]
            let lo =
                _mm256_blend_pd::<0b0001>(_mm256_permute4x64_pd::<0b10_01_00_00>(self.0), zero);
            // [lo2, lo3, hi0, hi1] → [lo3, hi0, hi1, hi2]
            let mid = _mm256_permute2f128_pd::<0x21>(self.0, self.1);
            Avx2(lo, _mm256_shuffle_pd::<0b0101>(mid, self.1))
        }
        /// Shifted up by two lanes, zeros below.
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        fn shifted2(self) -> Self {
            Avx2(
                _mm256_permute2f128_pd::<0x08>(self.0, self.0),
                _mm256_permute2f128_pd::<0x21>(self.0, self.1),
            )
        }
    }

    impl Lanes for Avx2 {
        const WALK: usize = 2;
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn zero() -> Self {
            Avx2(_mm256_setzero_pd(), _mm256_setzero_pd())
        }
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn splat(v: f64) -> Self {
            Avx2(_mm256_set1_pd(v), _mm256_set1_pd(v))
        }
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn load(p: *const f64) -> Self {
            Avx2(_mm256_loadu_pd(p), _mm256_loadu_pd(p.add(4)))
        }
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn store(self, p: *mut f64) {
            _mm256_storeu_pd(p, self.0);
            _mm256_storeu_pd(p.add(4), self.1);
        }
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn add(self, o: Self) -> Self {
            Avx2(_mm256_add_pd(self.0, o.0), _mm256_add_pd(self.1, o.1))
        }
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn sub(self, o: Self) -> Self {
            Avx2(_mm256_sub_pd(self.0, o.0), _mm256_sub_pd(self.1, o.1))
        }
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn mul(self, o: Self) -> Self {
            Avx2(_mm256_mul_pd(self.0, o.0), _mm256_mul_pd(self.1, o.1))
        }
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn square_add(self, acc: Self) -> Self {
            Avx2(
                _mm256_fmadd_pd(self.0, self.0, acc.0),
                _mm256_fmadd_pd(self.1, self.1, acc.1),
            )
        }
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn minus_twice(self, b: Self) -> Self {
            let two = _mm256_set1_pd(2.0);
            Avx2(
                _mm256_fnmadd_pd(two, b.0, self.0),
                _mm256_fnmadd_pd(two, b.1, self.1),
            )
        }
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn exclusive_scan(self) -> Self {
            let s = self.shifted1();
            let s = s.add(s.shifted1());
            let s = s.add(s.shifted2());
            // Shifted by four: zeros below, the low half above.
            s.add(Avx2(_mm256_setzero_pd(), s.0))
        }
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn to_array(self) -> [f64; LANES] {
            let mut out = [0.0; LANES];
            _mm256_storeu_pd(out.as_mut_ptr(), self.0);
            _mm256_storeu_pd(out.as_mut_ptr().add(4), self.1);
            out
        }
    }

    /// One 512-bit register.
    #[derive(Clone, Copy)]
    pub(super) struct Avx512(__m512d);

    impl Avx512 {
        /// Shifted up by `K` lanes, zeros below (`S` = 8 − K).
        #[inline]
        #[target_feature(enable = "avx512f")]
        fn shifted<const S: i32>(self) -> Self {
            let zero = _mm512_setzero_si512();
            Avx512(_mm512_castsi512_pd(_mm512_alignr_epi64::<S>(
                _mm512_castpd_si512(self.0),
                zero,
            )))
        }
    }

    impl Lanes for Avx512 {
        const WALK: usize = 4;
        #[inline]
        #[target_feature(enable = "avx512f")]
        unsafe fn zero() -> Self {
            Avx512(_mm512_setzero_pd())
        }
        #[inline]
        #[target_feature(enable = "avx512f")]
        unsafe fn splat(v: f64) -> Self {
            Avx512(_mm512_set1_pd(v))
        }
        #[inline]
        #[target_feature(enable = "avx512f")]
        unsafe fn load(p: *const f64) -> Self {
            Avx512(_mm512_loadu_pd(p))
        }
        #[inline]
        #[target_feature(enable = "avx512f")]
        unsafe fn store(self, p: *mut f64) {
            _mm512_storeu_pd(p, self.0)
        }
        #[inline]
        #[target_feature(enable = "avx512f")]
        unsafe fn add(self, o: Self) -> Self {
            Avx512(_mm512_add_pd(self.0, o.0))
        }
        #[inline]
        #[target_feature(enable = "avx512f")]
        unsafe fn sub(self, o: Self) -> Self {
            Avx512(_mm512_sub_pd(self.0, o.0))
        }
        #[inline]
        #[target_feature(enable = "avx512f")]
        unsafe fn mul(self, o: Self) -> Self {
            Avx512(_mm512_mul_pd(self.0, o.0))
        }
        #[inline]
        #[target_feature(enable = "avx512f")]
        unsafe fn square_add(self, acc: Self) -> Self {
            Avx512(_mm512_fmadd_pd(self.0, self.0, acc.0))
        }
        #[inline]
        #[target_feature(enable = "avx512f")]
        unsafe fn minus_twice(self, b: Self) -> Self {
            Avx512(_mm512_fnmadd_pd(_mm512_set1_pd(2.0), b.0, self.0))
        }
        #[inline]
        #[target_feature(enable = "avx512f")]
        unsafe fn exclusive_scan(self) -> Self {
            let s = self.shifted::<7>();
            let s = s.add(s.shifted::<7>());
            let s = s.add(s.shifted::<6>());
            s.add(s.shifted::<4>())
        }
        #[inline]
        #[target_feature(enable = "avx512f")]
        unsafe fn to_array(self) -> [f64; LANES] {
            let mut out = [0.0; LANES];
            _mm512_storeu_pd(out.as_mut_ptr(), self.0);
            out
        }
    }
}
