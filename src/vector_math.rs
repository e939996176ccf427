//! exp and ln as branch-free kernels written once over [`Lanes`], so that the scalar `f64` and
//! the AVX2 four-lane instantiations run the same IEEE operation sequence and return the same
//! bits. That is what keeps the values of the (scalar) Jacobian path equal to those of the
//! (vectorised) evaluator bit for bit.
//!
//! No FMA on purpose: a fused multiply–add rounds differently from a multiply then an add, and
//! the scalar path must run on any x86_64 (and aarch64) without it. The reductions and
//! polynomials: for exp, Cody–Waite reduction by ln 2 split in two and a degree-13 Taylor
//! polynomial (no division, no table); for ln, fdlibm's `__ieee754_log`
//! (exponent extraction, a Remez series in s = f/(2 + f)). tests/core/vector_math.rs checks both
//! against std over wide ranges (subnormals, edges, special values).

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;
use std::sync::OnceLock;

/// The operations the kernels and the evaluator need, on one or several f64 lanes.
pub(crate) trait Lanes: Copy {
    /// Number of lanes.
    const N: usize;
    /// Per-lane boolean.
    type Mask: Copy;
    fn splat(x: f64) -> Self;
    /// Loads the first N values of `x` (at least N long).
    fn load(x: &[f64]) -> Self;
    /// Stores into the first N values of `out`.
    fn store(self, out: &mut [f64]);
    fn add(self, o: Self) -> Self;
    fn sub(self, o: Self) -> Self;
    fn mul(self, o: Self) -> Self;
    fn div(self, o: Self) -> Self;
    fn abs(self) -> Self;
    fn gt(self, o: Self) -> Self::Mask;
    fn lt(self, o: Self) -> Self::Mask;
    fn ge(self, o: Self) -> Self::Mask;
    fn le(self, o: Self) -> Self::Mask;
    fn eq(self, o: Self) -> Self::Mask;
    /// `!=` as Rust has it: true where either side is NaN.
    fn ne(self, o: Self) -> Self::Mask;
    /// `!(self >= o)`: true where either side is NaN.
    fn nge(self, o: Self) -> Self::Mask;
    /// `a` where `m`, else `b`.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
    fn any(m: Self::Mask) -> bool;
    /// 1.0 where `m`, else 0.0.
    fn one_where(m: Self::Mask) -> Self;
    fn all(m: Self::Mask) -> bool;
    /// Bit j set where lane j of `m` is true.
    fn bits(m: Self::Mask) -> u32;
    /// 2^j for j integral in [-1022, 1023], given j + [`MAGIC`] (the integer sits in the low
    /// mantissa bits).
    fn pow2_from_magic(j_plus_magic: Self) -> Self;
    /// (exponent field as a float, significand scaled to [1, 2)) of a positive finite normal x.
    fn split_exponent(self) -> (Self, Self);
}

/// 1.5 · 2^52: adding it rounds to an integer (ties to even) and leaves that integer in the low
/// bits of the significand, with plain IEEE adds (no SSE4.1 round, no float→int conversion).
const MAGIC: f64 = 6755399441055744.0;
const TWO52: f64 = 4503599627370496.0;

const LN2_HI: f64 = f64::from_bits(0x3fe62e42fee00000); // ln 2 to 32 bits: k·LN2_HI exact
const LN2_LO: f64 = f64::from_bits(0x3dea39ef35793c76); // ln 2 − LN2_HI
/// Above ln(f64::MAX) exp overflows; below ln(2^-1075) it rounds to 0.
const EXP_HI: f64 = f64::from_bits(0x40862e42fefa39ef); // 709.782712893383973096
const EXP_LO: f64 = f64::from_bits(0xc0874910d52d3051); // -745.13321910194110842
const INV_LN2: f64 = std::f64::consts::LOG2_E;
/// 1/n! for n = 0..=13.
const INV_FACT: [f64; 14] = {
    let mut f = [1.0; 14];
    let mut n = 1;
    let mut fact = 1.0;
    while n < 14 {
        fact *= n as f64; // exact: 13! < 2^53
        f[n] = 1.0 / fact;
        n += 1;
    }
    f
};

const LG1: f64 = f64::from_bits(0x3fe5555555555593); // 6.666666666666735130e-01
const LG2: f64 = f64::from_bits(0x3fd999999997fa04); // 3.999999999940941908e-01
const LG3: f64 = f64::from_bits(0x3fd2492494229359); // 2.857142874366239149e-01
const LG4: f64 = f64::from_bits(0x3fcc71c51d8e78af); // 2.222219843214978396e-01
const LG5: f64 = f64::from_bits(0x3fc7466496cb03de); // 1.818357216161805012e-01
const LG6: f64 = f64::from_bits(0x3fc39a09d078c69f); // 1.531383769920937332e-01
const LG7: f64 = f64::from_bits(0x3fc2f112df3e5244); // 1.479819860511658591e-01
const SQRT2: f64 = std::f64::consts::SQRT_2;
/// 2^54, to bring subnormal arguments of ln into the normal range.
const TWO54: f64 = 18014398509481984.0;
const MIN_POSITIVE: f64 = f64::MIN_POSITIVE;

/// e^x, within 2 ulp (subnormal results within 2 ulp of 2^-1074); 0 below −745.13, +∞ above
/// 709.78, NaN for NaN.
#[inline(always)]
pub(crate) fn exp_lanes<V: Lanes>(x: V) -> V {
    let s = V::splat;
    // The model's arguments nearly always lie here (a normal result, no special value): one
    // exact scaling and no clean-up. Both ways give the same bits on these lanes (scaling by 2^k
    // in two exact halves equals scaling by 2^k when the result is normal).
    if V::all(x.abs().lt(s(708.0))) {
        let (y, k) = exp_reduced(x);
        return y.mul(V::pow2_from_magic(k.add(s(MAGIC))));
    }
    // Clamped so that k stays small; the out-of-range lanes are replaced at the end.
    let xc = V::select(
        x.lt(s(-746.0)),
        s(-746.0),
        V::select(x.gt(s(710.0)), s(710.0), x),
    );
    let (y, k) = exp_reduced(xc);
    // 2^k in two exact halves, so that subnormal results (k < −1022) round once, at the end.
    let k1 = k.mul(s(0.5)).add(s(MAGIC));
    let k2 = k.sub(k1.sub(s(MAGIC))).add(s(MAGIC));
    let e = y.mul(V::pow2_from_magic(k1)).mul(V::pow2_from_magic(k2));
    let e = V::select(x.lt(s(EXP_LO)), s(0.0), e);
    let e = V::select(x.gt(s(EXP_HI)), s(f64::INFINITY), e);
    V::select(x.ne(x), x, e)
}

/// x = k ln 2 + r with |r| ≤ ln2/2 (Cody–Waite, ln 2 split in two so that k·hi is exact):
/// (e^r, k), e^r = 1 + r + r²q(r) with q the Taylor polynomial to r¹³ (remainder below 5·10⁻¹⁸)
/// by Estrin's scheme. No division and no table: the divider bounded fdlibm's rational form and
/// gathers are slow on recent Intel microcode. The 2^k scaling is left to the caller, last, so
/// that no intermediate underflows.
#[inline(always)]
fn exp_reduced<V: Lanes>(x: V) -> (V, V) {
    let s = V::splat;
    let t = x.mul(s(INV_LN2)).add(s(MAGIC));
    let k = t.sub(s(MAGIC));
    let r = x.sub(k.mul(s(LN2_HI))).sub(k.mul(s(LN2_LO)));
    let r2 = r.mul(r);
    let r4 = r2.mul(r2);
    let r8 = r4.mul(r4);
    let pair = |a: usize| s(INV_FACT[a]).add(r.mul(s(INV_FACT[a + 1])));
    let b0 = pair(2).add(r2.mul(pair(4)));
    let b1 = pair(6).add(r2.mul(pair(8)));
    let b2 = pair(10).add(r2.mul(pair(12)));
    let q = b0.add(r4.mul(b1)).add(r8.mul(b2));
    (s(1.0).add(r.add(r2.mul(q))), k)
}

/// ln x, within 1 ulp; −∞ at ±0, NaN below 0 and for NaN, +∞ at +∞, exact on subnormals.
#[inline(always)]
pub(crate) fn ln_lanes<V: Lanes>(x: V) -> V {
    let s = V::splat;
    // Positive normal finite lanes only (the model's |τ| > 0): no rescaling, no clean-up; the
    // same bits as the general way below on these lanes.
    if V::all(x.ge(s(MIN_POSITIVE))) && V::all(x.le(s(f64::MAX))) {
        return ln_normal(x, None);
    }
    let tiny = x.lt(s(MIN_POSITIVE));
    let xs = V::select(tiny, x.mul(s(TWO54)), x);
    let l = ln_normal(xs, Some(V::select(tiny, s(54.0), s(0.0))));
    let l = V::select(x.eq(s(f64::INFINITY)), x, l);
    let l = V::select(x.eq(s(0.0)), s(f64::NEG_INFINITY), l);
    V::select(x.nge(s(0.0)), s(f64::NAN), l)
}

/// fdlibm's ln of a positive normal x (divided by 2^`scaled` when given, for subnormals brought
/// up by 2^54): x = 2^k m, √½ < m ≤ √2, ln m = 2 atanh(s) with s = f/(2 + f), f = m − 1.
#[inline(always)]
fn ln_normal<V: Lanes>(x: V, scaled: Option<V>) -> V {
    let s = V::splat;
    let (e_field, m) = x.split_exponent();
    // m > √2 is a coin flip from sample to sample: arithmetic on 0/1, not a select, so that the
    // scalar code cannot become a mispredicted branch (m·1 and m·½ are exact either way).
    let big = V::one_where(m.gt(s(SQRT2)));
    let m = m.mul(s(1.0).sub(s(0.5).mul(big)));
    let mut dk = e_field.sub(s(1023.0));
    if let Some(sc) = scaled {
        dk = dk.sub(sc);
    }
    let dk = dk.add(big);
    let f = m.sub(s(1.0));
    let sv = f.div(s(2.0).add(f));
    let z = sv.mul(sv);
    let w = z.mul(z);
    let t1 = w.mul(s(LG2).add(w.mul(s(LG4).add(w.mul(s(LG6))))));
    let t2 = z.mul(s(LG1).add(w.mul(s(LG3).add(w.mul(s(LG5).add(w.mul(s(LG7))))))));
    let r = t2.add(t1);
    let hfsq = s(0.5).mul(f).mul(f);
    dk.mul(s(LN2_HI))
        .sub(hfsq.sub(sv.mul(hfsq.add(r)).add(dk.mul(s(LN2_LO)))).sub(f))
}

/// e^x (the kernel every model exponential goes through).
#[inline(always)]
pub fn exp(x: f64) -> f64 {
    exp_lanes(x)
}

/// ln x (the kernel every model logarithm goes through).
#[inline(always)]
pub fn ln(x: f64) -> f64 {
    ln_lanes(x)
}

/// Whether the four-lane AVX2 path is used: detected once at run time; `COARTIC_SCALAR=1` in the
/// environment forces the scalar path (for comparisons and benchmarks).
pub fn simd_enabled() -> bool {
    static ENABLED: OnceLock<bool> = OnceLock::new();
    *ENABLED.get_or_init(|| {
        if std::env::var_os("COARTIC_SCALAR").is_some_and(|v| !v.is_empty() && v != "0") {
            return false;
        }
        #[cfg(target_arch = "x86_64")]
        {
            is_x86_feature_detected!("avx2")
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            false
        }
    })
}

/// e^x of every element, in place, four at a time where AVX2 is available (same bits as [`exp`]).
pub fn exp_in_place(x: &mut [f64]) {
    map_in_place(x, exp, Kernel::Exp)
}

/// ln x of every element, in place, four at a time where AVX2 is available (same bits as [`ln`]).
pub fn ln_in_place(x: &mut [f64]) {
    map_in_place(x, ln, Kernel::Ln)
}

#[derive(Clone, Copy)]
enum Kernel {
    Exp,
    Ln,
}

#[inline(always)]
fn map_in_place(x: &mut [f64], scalar: impl Fn(f64) -> f64, kernel: Kernel) {
    #[cfg(target_arch = "x86_64")]
    if simd_enabled() {
        // SAFETY: AVX2 was detected at run time.
        unsafe { map_avx2(x, kernel) };
        return;
    }
    let _ = kernel;
    x.iter_mut().for_each(|v| *v = scalar(*v));
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn map_avx2(x: &mut [f64], kernel: Kernel) {
    let apply = |v: F64x4| match kernel {
        Kernel::Exp => exp_lanes(v),
        Kernel::Ln => ln_lanes(v),
    };
    let mut chunks = x.chunks_exact_mut(4);
    for c in &mut chunks {
        apply(F64x4::load(c)).store(c);
    }
    let rest = chunks.into_remainder();
    if !rest.is_empty() {
        let mut t = [1.0; 4];
        t[..rest.len()].copy_from_slice(rest);
        apply(F64x4::load(&t)).store(&mut t);
        let n = rest.len();
        rest.copy_from_slice(&t[..n]);
    }
}

impl Lanes for f64 {
    const N: usize = 1;
    type Mask = bool;
    #[inline(always)]
    fn splat(x: f64) -> Self {
        x
    }
    #[inline(always)]
    fn load(x: &[f64]) -> Self {
        x[0]
    }
    #[inline(always)]
    fn store(self, out: &mut [f64]) {
        out[0] = self;
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        self + o
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        self - o
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        self * o
    }
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        self / o
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f64::abs(self)
    }
    #[inline(always)]
    fn gt(self, o: Self) -> bool {
        self > o
    }
    #[inline(always)]
    fn lt(self, o: Self) -> bool {
        self < o
    }
    #[inline(always)]
    fn ge(self, o: Self) -> bool {
        self >= o
    }
    #[inline(always)]
    fn le(self, o: Self) -> bool {
        self <= o
    }
    #[inline(always)]
    fn eq(self, o: Self) -> bool {
        self == o
    }
    #[inline(always)]
    fn ne(self, o: Self) -> bool {
        self != o
    }
    #[inline(always)]
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // the NaN-true negation is the point
    fn nge(self, o: Self) -> bool {
        !(self >= o)
    }
    #[inline(always)]
    fn select(m: bool, a: Self, b: Self) -> Self {
        // By masks, not a branch: some conditions (ln's m > √2) are data-dependent coin flips.
        let mask = (m as u64).wrapping_neg();
        f64::from_bits((a.to_bits() & mask) | (b.to_bits() & !mask))
    }
    #[inline(always)]
    fn any(m: bool) -> bool {
        m
    }
    #[inline(always)]
    fn one_where(m: bool) -> Self {
        m as u8 as f64
    }
    #[inline(always)]
    fn all(m: bool) -> bool {
        m
    }
    #[inline(always)]
    fn bits(m: bool) -> u32 {
        m as u32
    }
    #[inline(always)]
    fn pow2_from_magic(j: Self) -> Self {
        let int = j.to_bits().wrapping_sub(MAGIC.to_bits());
        f64::from_bits(int.wrapping_add(1023) << 52)
    }
    #[inline(always)]
    fn split_exponent(self) -> (Self, Self) {
        let b = self.to_bits();
        let e = f64::from_bits(TWO52.to_bits() | (b >> 52)) - TWO52;
        let m = f64::from_bits((b & 0x000f_ffff_ffff_ffff) | 0x3ff0_0000_0000_0000);
        (e, m)
    }
}

/// Four f64 lanes in one AVX register. Only constructed inside `#[target_feature(enable =
/// "avx2")]` functions entered after run-time detection; every method is inlined into them.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(crate) struct F64x4(__m256d);

#[cfg(target_arch = "x86_64")]
impl Lanes for F64x4 {
    const N: usize = 4;
    type Mask = __m256d;
    // SAFETY (every method): AVX2 is available wherever an F64x4 exists (see the type's doc);
    // loads and stores go through slices of at least 4 elements (checked).
    #[inline(always)]
    fn splat(x: f64) -> Self {
        unsafe { F64x4(_mm256_set1_pd(x)) }
    }
    #[inline(always)]
    fn load(x: &[f64]) -> Self {
        assert!(x.len() >= 4);
        unsafe { F64x4(_mm256_loadu_pd(x.as_ptr())) }
    }
    #[inline(always)]
    fn store(self, out: &mut [f64]) {
        assert!(out.len() >= 4);
        unsafe { _mm256_storeu_pd(out.as_mut_ptr(), self.0) }
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        unsafe { F64x4(_mm256_add_pd(self.0, o.0)) }
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        unsafe { F64x4(_mm256_sub_pd(self.0, o.0)) }
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        unsafe { F64x4(_mm256_mul_pd(self.0, o.0)) }
    }
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        unsafe { F64x4(_mm256_div_pd(self.0, o.0)) }
    }
    #[inline(always)]
    fn abs(self) -> Self {
        unsafe { F64x4(_mm256_andnot_pd(_mm256_set1_pd(-0.0), self.0)) }
    }
    #[inline(always)]
    fn gt(self, o: Self) -> __m256d {
        unsafe { _mm256_cmp_pd::<_CMP_GT_OQ>(self.0, o.0) }
    }
    #[inline(always)]
    fn lt(self, o: Self) -> __m256d {
        unsafe { _mm256_cmp_pd::<_CMP_LT_OQ>(self.0, o.0) }
    }
    #[inline(always)]
    fn ge(self, o: Self) -> __m256d {
        unsafe { _mm256_cmp_pd::<_CMP_GE_OQ>(self.0, o.0) }
    }
    #[inline(always)]
    fn le(self, o: Self) -> __m256d {
        unsafe { _mm256_cmp_pd::<_CMP_LE_OQ>(self.0, o.0) }
    }
    #[inline(always)]
    fn eq(self, o: Self) -> __m256d {
        unsafe { _mm256_cmp_pd::<_CMP_EQ_OQ>(self.0, o.0) }
    }
    #[inline(always)]
    fn ne(self, o: Self) -> __m256d {
        unsafe { _mm256_cmp_pd::<_CMP_NEQ_UQ>(self.0, o.0) }
    }
    #[inline(always)]
    fn nge(self, o: Self) -> __m256d {
        unsafe { _mm256_cmp_pd::<_CMP_NGE_UQ>(self.0, o.0) }
    }
    #[inline(always)]
    fn select(m: __m256d, a: Self, b: Self) -> Self {
        unsafe { F64x4(_mm256_blendv_pd(b.0, a.0, m)) }
    }
    #[inline(always)]
    fn any(m: __m256d) -> bool {
        unsafe { _mm256_movemask_pd(m) != 0 }
    }
    #[inline(always)]
    fn one_where(m: __m256d) -> Self {
        unsafe { F64x4(_mm256_and_pd(m, _mm256_set1_pd(1.0))) }
    }
    #[inline(always)]
    fn all(m: __m256d) -> bool {
        unsafe { _mm256_movemask_pd(m) == 0b1111 }
    }
    #[inline(always)]
    fn bits(m: __m256d) -> u32 {
        unsafe { _mm256_movemask_pd(m) as u32 }
    }
    #[inline(always)]
    fn pow2_from_magic(j: Self) -> Self {
        unsafe {
            let b = _mm256_castpd_si256(j.0);
            let off = _mm256_set1_epi64x(1023i64.wrapping_sub(MAGIC.to_bits() as i64));
            F64x4(_mm256_castsi256_pd(_mm256_slli_epi64::<52>(
                _mm256_add_epi64(b, off),
            )))
        }
    }
    #[inline(always)]
    fn split_exponent(self) -> (Self, Self) {
        unsafe {
            let b = _mm256_castpd_si256(self.0);
            let two52 = _mm256_set1_pd(TWO52);
            let e = _mm256_sub_pd(
                _mm256_castsi256_pd(_mm256_or_si256(
                    _mm256_castpd_si256(two52),
                    _mm256_srli_epi64::<52>(b),
                )),
                two52,
            );
            let m = _mm256_or_si256(
                _mm256_and_si256(b, _mm256_set1_epi64x(0x000f_ffff_ffff_ffff)),
                _mm256_set1_epi64x(0x3ff0_0000_0000_0000),
            );
            (F64x4(e), F64x4(_mm256_castsi256_pd(m)))
        }
    }
}
