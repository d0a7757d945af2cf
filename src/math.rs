//! Elementary functions that give the same bits on every machine.
//!
//! `f64::sin` and its kin call the system's C library, whose results can
//! differ in the last bit between CPUs (glibc picks FMA or plain builds of
//! them at run time) and between library versions. These come from the
//! pure-Rust `libm` crate instead: plain IEEE-754 operations, which every
//! CPU rounds alike and Rust never fuses. Every computation that reaches an
//! artifact or a picture calls them (a test scans the sources for the
//! standard methods). `sqrt`, `powi`, `abs`, `floor` and the like stay the
//! standard ones: they are exact or use no library.

/// A float type with the elementary functions of `libm`.
pub(crate) trait Real: Copy {
    fn sin(self) -> Self;
    fn cos(self) -> Self;
    fn tan(self) -> Self;
    fn asin(self) -> Self;
    fn atan2(self, x: Self) -> Self;
    fn exp(self) -> Self;
    fn exp2(self) -> Self;
    fn ln(self) -> Self;
    fn log2(self) -> Self;
    fn log10(self) -> Self;
    fn powf(self, e: Self) -> Self;
    fn hypot(self, y: Self) -> Self;
    fn sin_cos(self) -> (Self, Self);
}

macro_rules! real {
    ($t:ty, $sin:ident, $cos:ident, $tan:ident, $asin:ident, $atan2:ident,
     $exp:ident, $exp2:ident, $ln:ident, $log2:ident, $log10:ident, $pow:ident, $hypot:ident, $sincos:ident) => {
        impl Real for $t {
            fn sin(self) -> Self {
                libm::$sin(self)
            }
            fn cos(self) -> Self {
                libm::$cos(self)
            }
            fn tan(self) -> Self {
                libm::$tan(self)
            }
            fn asin(self) -> Self {
                libm::$asin(self)
            }
            fn atan2(self, x: Self) -> Self {
                libm::$atan2(self, x)
            }
            fn exp(self) -> Self {
                libm::$exp(self)
            }
            fn exp2(self) -> Self {
                libm::$exp2(self)
            }
            fn ln(self) -> Self {
                libm::$ln(self)
            }
            fn log2(self) -> Self {
                libm::$log2(self)
            }
            fn log10(self) -> Self {
                libm::$log10(self)
            }
            fn powf(self, e: Self) -> Self {
                libm::$pow(self, e)
            }
            fn hypot(self, y: Self) -> Self {
                libm::$hypot(self, y)
            }
            fn sin_cos(self) -> (Self, Self) {
                libm::$sincos(self)
            }
        }
    };
}

real!(f64, sin, cos, tan, asin, atan2, exp, exp2, log, log2, log10, pow, hypot, sincos);
real!(f32, sinf, cosf, tanf, asinf, atan2f, expf, exp2f, logf, log2f, log10f, powf, hypotf, sincosf);

/// sin x.
#[inline]
pub(crate) fn sin<T: Real>(x: T) -> T {
    x.sin()
}
/// cos x.
#[inline]
pub(crate) fn cos<T: Real>(x: T) -> T {
    x.cos()
}
/// tan x.
#[inline]
pub(crate) fn tan<T: Real>(x: T) -> T {
    x.tan()
}
/// arcsin x.
#[inline]
pub(crate) fn asin<T: Real>(x: T) -> T {
    x.asin()
}
/// The angle of (x, y), as `y.atan2(x)`.
#[inline]
pub(crate) fn atan2<T: Real>(y: T, x: T) -> T {
    y.atan2(x)
}
/// eˣ.
#[inline]
pub(crate) fn exp<T: Real>(x: T) -> T {
    x.exp()
}
/// 2ˣ.
#[inline]
pub(crate) fn exp2<T: Real>(x: T) -> T {
    x.exp2()
}
/// The natural logarithm.
#[inline]
pub(crate) fn ln<T: Real>(x: T) -> T {
    x.ln()
}
/// log₂ x.
#[inline]
pub(crate) fn log2<T: Real>(x: T) -> T {
    x.log2()
}
/// log₁₀ x.
#[inline]
pub(crate) fn log10<T: Real>(x: T) -> T {
    x.log10()
}
/// xᵉ.
#[inline]
pub(crate) fn powf<T: Real>(x: T, e: T) -> T {
    x.powf(e)
}
/// √(x² + y²) without undue overflow.
#[inline]
pub(crate) fn hypot<T: Real>(x: T, y: T) -> T {
    x.hypot(y)
}
/// (sin x, cos x).
#[inline]
pub(crate) fn sin_cos<T: Real>(x: T) -> (T, T) {
    x.sin_cos()
}

#[cfg(test)]
mod tests;
