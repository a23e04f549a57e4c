//! The arithmetic of the vectorised flight kernel: one drone (`f32`) or a
//! group of [`LANES`] drones ([`Wide`]), lane by lane the same operations,
//! and the 3-vector products the cascade and the kernel share.

/// Drones integrated together by [`Flight::fly`]: one AVX-512 register of
/// `f32` (two of AVX2).
pub(crate) const LANES: usize = 16;

/// The arithmetic the flight kernel needs, for one drone (`f32`) or a
/// group of [`LANES`] ([`Wide`]), lane by lane the same operations.
pub(crate) trait Simd:
    Copy
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
    + std::ops::Neg<Output = Self>
{
    fn splat(x: f32) -> Self;
    fn sqrt(self) -> Self;
    fn min(self, o: Self) -> Self;
    fn max(self, o: Self) -> Self;
    /// Per lane: `a` where `self > o`, otherwise `b`.
    fn gt_select(self, o: Self, a: Self, b: Self) -> Self;
}

impl Simd for f32 {
    #[inline(always)]
    fn splat(x: f32) -> Self {
        x
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        f32::min(self, o)
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        f32::max(self, o)
    }
    #[inline(always)]
    fn gt_select(self, o: Self, a: Self, b: Self) -> Self {
        if self > o { a } else { b }
    }
}

/// [`LANES`] drones' values of one quantity; every operation is the `f32`
/// one lane by lane, which the compiler turns into vector instructions.
#[derive(Clone, Copy)]
pub(crate) struct Wide(pub(crate) [f32; LANES]);

macro_rules! wide_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl std::ops::$tr for Wide {
            type Output = Wide;
            #[inline(always)]
            fn $f(self, o: Wide) -> Wide {
                Wide(std::array::from_fn(|i| self.0[i] $op o.0[i]))
            }
        }
    };
}
wide_op!(Add, add, +);
wide_op!(Sub, sub, -);
wide_op!(Mul, mul, *);
wide_op!(Div, div, /);

impl std::ops::Neg for Wide {
    type Output = Wide;
    #[inline(always)]
    fn neg(self) -> Wide {
        Wide(self.0.map(|x| -x))
    }
}

impl Simd for Wide {
    #[inline(always)]
    fn splat(x: f32) -> Self {
        Wide([x; LANES])
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        Wide(self.0.map(f32::sqrt))
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        Wide(std::array::from_fn(|i| f32::min(self.0[i], o.0[i])))
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        Wide(std::array::from_fn(|i| f32::max(self.0[i], o.0[i])))
    }
    #[inline(always)]
    fn gt_select(self, o: Self, a: Self, b: Self) -> Self {
        Wide(std::array::from_fn(|i| if self.0[i] > o.0[i] { a.0[i] } else { b.0[i] }))
    }
}

#[inline(always)]
pub(crate) fn dot<T: Simd>(a: [T; 3], b: [T; 3]) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
pub(crate) fn cross<T: Simd>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// `v / |v|`, or `fallback` where `v` is zero.
#[inline(always)]
pub(crate) fn normalize_or<T: Simd>(v: [T; 3], fallback: [T; 3]) -> [T; 3] {
    let n2 = dot(v, v);
    let inv = T::splat(1.0) / n2.sqrt();
    let tiny = T::splat(f32::MIN_POSITIVE);
    std::array::from_fn(|k| n2.gt_select(tiny, v[k] * inv, fallback[k]))
}
