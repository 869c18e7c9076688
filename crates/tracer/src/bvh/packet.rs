//! Any-hit queries for packets of up to four coherent rays, such as the shadow
//! rays from one shading point to the corners of an area light: the eight-ray
//! packet query (see `packet8`) with four lanes left empty, so each ray's
//! answer is exactly what [`Bvh::occluded`] gives for it alone.

use super::Bvh;
use super::packet8::{LANES, occluded8};
use crate::geometry::Ray;

/// See [`Bvh::occluded4`].
pub(super) fn occluded4(bvh: &Bvh, rays: &[Ray; 4], t_min: [f32; 4], t_max: [f32; 4], active: u32) -> u32 {
    let active = (active & 0xf) as u8;
    // Lanes 4..8 are inactive (the packet query ignores what they hold).
    let r: [Ray; LANES] = std::array::from_fn(|j| rays[j % 4]);
    let t0: [f32; LANES] = std::array::from_fn(|j| t_min[j % 4]);
    let t1: [f32; LANES] = std::array::from_fn(|j| t_max[j % 4]);
    u32::from(occluded8(bvh, &r, t0, t1, active))
}
