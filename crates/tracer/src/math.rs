//! Platform-independent transcendental functions.
//!
//! `f32::sin`, `powf` and friends call the platform's libm, whose last bits differ
//! between C libraries and versions. Everything that can influence a pixel goes
//! through these wrappers around the pure-Rust `libm` crate instead, so a slave
//! on any machine computes the same bytes. (`sqrt` is correctly rounded by IEEE 754
//! and needs no wrapper.)

/// Sine, computed identically on every platform.
#[inline]
pub fn sin(x: f32) -> f32 {
    libm::sinf(x)
}

/// Cosine, computed identically on every platform.
#[inline]
pub fn cos(x: f32) -> f32 {
    libm::cosf(x)
}

/// Tangent, computed identically on every platform.
#[inline]
pub fn tan(x: f32) -> f32 {
    libm::tanf(x)
}

/// `x` raised to `y`, computed identically on every platform.
#[inline]
pub fn powf(x: f32, y: f32) -> f32 {
    libm::powf(x, y)
}

/// Base-2 logarithm, computed identically on every platform.
#[inline]
pub fn log2(x: f32) -> f32 {
    libm::log2f(x)
}

/// Arc-cosine, computed identically on every platform.
#[inline]
pub fn acos(x: f32) -> f32 {
    libm::acosf(x)
}

/// Arc-tangent of `y / x`, computed identically on every platform.
#[inline]
pub fn atan2(y: f32, x: f32) -> f32 {
    libm::atan2f(y, x)
}
