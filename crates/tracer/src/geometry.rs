//! Rays and axis-aligned bounding boxes.

use glam::Vec3;

/// A ray `origin + t * dir`. `dir` need not be normalised, but every ray the
/// integrator creates has a unit direction so that `t` is a distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Start point.
    pub origin: Vec3,
    /// Direction.
    pub dir: Vec3,
}

impl Ray {
    /// A ray from `origin` along `dir`.
    #[inline]
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Self { origin, dir }
    }

    /// The point at parameter `t`.
    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// An axis-aligned bounding box. The empty box has `min = +inf`, `max = -inf`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: Vec3,
    /// Upper corner.
    pub max: Vec3,
}

impl Default for Aabb {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Aabb {
    /// The box that contains nothing; the identity for [`Aabb::union`].
    pub const EMPTY: Aabb = Aabb { min: Vec3::INFINITY, max: Vec3::NEG_INFINITY };

    /// The smallest box containing `p`.
    #[inline]
    pub fn from_point(p: Vec3) -> Self {
        Self { min: p, max: p }
    }

    /// Grows the box to contain `p`.
    #[inline]
    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// The smallest box containing both.
    #[inline]
    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb { min: self.min.min(o.min), max: self.max.max(o.max) }
    }

    /// True when the box contains nothing.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    /// Edge lengths (zero for the empty box).
    #[inline]
    pub fn extent(&self) -> Vec3 {
        if self.is_empty() { Vec3::ZERO } else { self.max - self.min }
    }

    /// Half the surface area (zero for the empty box).
    #[inline]
    pub fn half_area(&self) -> f32 {
        let e = self.extent();
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    /// Centre point.
    #[inline]
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Surface area (zero for the empty box).
    #[inline]
    pub fn area(&self) -> f32 {
        let e = self.extent();
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }

    /// Length of the diagonal.
    #[inline]
    pub fn diagonal(&self) -> f32 {
        self.extent().length()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn union_and_area() {
        let mut b = Aabb::EMPTY;
        assert!(b.is_empty());
        assert_eq!(b.area(), 0.0);
        b.grow(Vec3::ZERO);
        b.grow(Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(b.area(), 2.0 * (2.0 + 6.0 + 3.0));
        assert_eq!(b.center(), Vec3::new(0.5, 1.0, 1.5));
        let c = b.union(&Aabb::from_point(Vec3::splat(-1.0)));
        assert_eq!(c.min, Vec3::splat(-1.0));
    }
}
