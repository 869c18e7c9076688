//! Any-hit queries for small packets of coherent rays (up to four), such as the
//! shadow rays from one shading point to the corners of an area light.
//!
//! The packet walks the tree once: at each node every still-open ray runs the
//! same box test as a single ray would ([`entries`]), and a child is entered
//! with the set of rays whose own test hit it; a leaf is tested for each of those
//! rays with the same triangle test. A ray is answered "occluded" as soon as one
//! of its leaves has a hit. So each ray's answer is exactly what
//! [`Bvh::occluded`] gives for it alone (whether some triangle in a leaf its box
//! tests reach is hit): only the node visits are shared.

use super::Bvh;
use super::wide::{LEAF, LeafRay, Stack, W, WideRay, entries, leaf_range};
use crate::geometry::Ray;

/// See [`Bvh::occluded4`].
pub(super) fn occluded4(bvh: &Bvh, rays: &[Ray; 4], t_min: [f32; 4], t_max: [f32; 4], active: u32) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if bvh.avx_active() {
        // SAFETY: `avx_active` checked that this CPU has AVX.
        return unsafe { occluded4_avx(bvh, rays, t_min, t_max, active) };
    }
    occluded4_with::<false>(bvh, rays, t_min, t_max, active)
}

/// [`occluded4`] compiled for AVX.
///
/// # Safety
/// The CPU must support AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn occluded4_avx(bvh: &Bvh, rays: &[Ray; 4], t_min: [f32; 4], t_max: [f32; 4], active: u32) -> u32 {
    occluded4_with::<true>(bvh, rays, t_min, t_max, active)
}

/// [`occluded4`] with the AVX box test when `AVX` is set (see [`entries`]).
#[inline(always)]
fn occluded4_with<const AVX: bool>(
    bvh: &Bvh,
    rays: &[Ray; 4],
    t_min: [f32; 4],
    t_max: [f32; 4],
    active: u32,
) -> u32 {
    let active = active & 0xf;
    let wide = &bvh.wide[..];
    if wide.is_empty() || active == 0 {
        return 0;
    }
    let simd = !bvh.scalar_only;
    let wr = [0, 1, 2, 3].map(|j| WideRay::new(&rays[j]));
    let lr = [0, 1, 2, 3].map(|j| LeafRay::new(&rays[j], simd));
    let blocks = &bvh.blocks[..];
    let mut done = 0u32;
    let mut stack = Stack::<(u32, u32)>::new();
    let (mut current, mut open) = (0u32, active);
    loop {
        let node = &wide[current as usize];
        // child_rays[k]: the open rays whose box test hits child k.
        let mut child_rays = [0u32; W];
        let mut todo = open;
        while todo != 0 {
            let j = todo.trailing_zeros() as usize;
            todo &= todo - 1;
            let (_, mut mask) = entries::<AVX>(node, &wr[j], t_min[j], t_max[j], simd);
            while mask != 0 {
                let k = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                child_rays[k] |= 1 << j;
            }
        }
        let mut next: Option<(u32, u32)> = None;
        for (k, &rays_k) in child_rays.iter().enumerate() {
            let child = node.child[k];
            let mut todo = rays_k & !done;
            if todo == 0 {
                continue;
            }
            if child & LEAF == 0 {
                if next.is_none() {
                    next = Some((child, todo));
                } else {
                    stack.push((child, todo));
                }
                continue;
            }
            while todo != 0 {
                let j = todo.trailing_zeros() as usize;
                todo &= todo - 1;
                let (first, count) = leaf_range(child);
                if lr[j].hits(blocks, first, count, t_min[j], t_max[j]).mask != 0 {
                    done |= 1 << j;
                }
            }
            if done == active {
                return done;
            }
        }
        (current, open) = loop {
            match next.take().or_else(|| stack.pop()) {
                None => return done,
                Some((c, rays)) if rays & !done != 0 => break (c, rays & !done),
                Some(_) => {}
            }
        };
    }
}
