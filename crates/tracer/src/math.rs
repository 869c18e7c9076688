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

/// Arc-cosine by the polynomial of Abramowitz & Stegun 4.4.46 (absolute
/// error ≤ 2·10⁻⁸ in exact arithmetic; a few f32 roundings here), in plain
/// multiplications and additions, so identical on every platform; a
/// fraction of [`acos`]'s cost. `x` is clamped to `[−1, 1]`.
#[inline]
pub fn acos_poly(x: f32) -> f32 {
    let x = x.clamp(-1.0, 1.0);
    let a = x.abs();
    let p = std::f32::consts::FRAC_PI_2
        + a * (-0.214_598_8
            + a * (0.088_978_99
                + a * (-0.050_174_3
                    + a * (0.030_891_88 + a * (-0.017_088_126 + a * (0.006_670_09 + a * -0.001_262_491))))));
    let r = (1.0 - a).sqrt() * p;
    if x < 0.0 { std::f32::consts::PI - r } else { r }
}

/// [`acos_poly`] of four numbers at once: the same operations lane by lane,
/// so the same bits for finite inputs.
#[inline]
pub fn acos_poly4(x: glam::Vec4) -> glam::Vec4 {
    use glam::Vec4;
    let x = x.clamp(Vec4::splat(-1.0), Vec4::ONE);
    let a = x.abs();
    let c = |v: f32| Vec4::splat(v);
    let p = c(std::f32::consts::FRAC_PI_2)
        + a * (c(-0.214_598_8)
            + a * (c(0.088_978_99)
                + a * (c(-0.050_174_3)
                    + a * (c(0.030_891_88)
                        + a * (c(-0.017_088_126) + a * (c(0.006_670_09) + a * c(-0.001_262_491)))))));
    let r = (Vec4::ONE - a).sqrt() * p;
    Vec4::select(x.cmplt(Vec4::ZERO), c(std::f32::consts::PI) - r, r)
}

/// Arc-tangent of `y / x`, computed identically on every platform.
#[inline]
pub fn atan2(y: f32, x: f32) -> f32 {
    libm::atan2f(y, x)
}

/// Sine in double precision, computed identically on every platform.
#[inline]
pub fn sin_f64(x: f64) -> f64 {
    libm::sin(x)
}

/// Arc-cosine in double precision, computed identically on every platform.
#[inline]
pub fn acos_f64(x: f64) -> f64 {
    libm::acos(x)
}

#[cfg(test)]
mod tests {
    #[test]
    fn acos_poly_matches_acos() {
        let mut worst = 0.0f32;
        for i in 0..=20_000 {
            let x = -1.0 + i as f32 / 10_000.0;
            worst = worst.max((super::acos_poly(x) - super::acos(x)).abs());
        }
        assert!(worst < 1e-6, "{worst}");
        assert_eq!(super::acos_poly(2.0), super::acos_poly(1.0));
    }

    #[test]
    fn acos_poly4_is_acos_poly_in_every_lane() {
        for i in 0..=5_000 {
            let x = -1.25 + i as f32 / 2_000.0;
            let xs = [x, -x, x * 0.5, 1.0 - x.abs()];
            let got = super::acos_poly4(glam::Vec4::from_array(xs)).to_array();
            for (g, x) in got.iter().zip(xs) {
                assert_eq!(g.to_bits(), super::acos_poly(x).to_bits(), "acos_poly4({x})");
            }
        }
    }
}
