//! Memory placement for large scenes: a global allocator that backs big
//! allocations with transparent huge pages.
//!
//! A ray walking a 1.6M-triangle BVH touches about 100 MB of nodes and
//! triangle blocks in no predictable order. With 4 KiB pages nearly every node
//! it loads is also a TLB miss (the second-level TLB covers a few MiB), and the
//! page walk itself misses the caches. Linux can back memory with 2 MiB pages
//! instead, but on most distributions only where a program asks for it
//! (`/sys/kernel/mm/transparent_hugepage/enabled` = `madvise`) — which is what
//! Embree does for its BVH. [`HugePages`] asks for it: allocations of at least
//! [`HugePages::MIN_BYTES`] are aligned to 2 MiB and advised with
//! `madvise(MADV_HUGEPAGE)` before they are first touched; everything else
//! goes straight to the system allocator.
//!
//! The advice is a hint: where the kernel refuses it (or on other systems)
//! memory simply stays in small pages. It changes no value the tracer
//! computes, only where the bytes live. Binaries opt in with
//!
//! ```ignore
//! #[global_allocator]
//! static ALLOC: isin_tracer::memory::HugePages = isin_tracer::memory::HugePages;
//! ```

use std::alloc::{GlobalAlloc, Layout, System};

/// Size of a transparent huge page on x86_64 and most aarch64 kernels.
const HUGE_PAGE: usize = 2 << 20;

/// The system allocator, with huge-page advice on large blocks (see the module docs).
#[derive(Clone, Copy, Debug, Default)]
pub struct HugePages;

impl HugePages {
    /// Smallest allocation that is aligned to a huge page and advised. Below
    /// this the alignment's slack (up to 2 MiB of address space) is not worth it.
    pub const MIN_BYTES: usize = 4 << 20;

    /// The layout actually requested from the system for `layout`.
    #[inline]
    fn system_layout(layout: Layout) -> Layout {
        if layout.size() >= Self::MIN_BYTES && layout.align() < HUGE_PAGE {
            // A power of two at least the old alignment, and the size is far
            // below `isize::MAX - HUGE_PAGE` for any allocation that succeeds.
            Layout::from_size_align(layout.size(), HUGE_PAGE).unwrap_or(layout)
        } else {
            layout
        }
    }
}

/// Advises the kernel to back `[ptr, ptr + len)` with huge pages. Called
/// before the block is first written, so its page faults allocate huge pages.
fn advise(ptr: *mut u8, len: usize) {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: `ptr` starts a live allocation of at least `len` bytes that
        // we own; MADV_HUGEPAGE only changes how the kernel backs those pages
        // (never their contents). `ptr` is 2 MiB aligned, hence page aligned,
        // as madvise requires. A failure (e.g. THP compiled out) is harmless.
        unsafe {
            libc::madvise(ptr.cast(), len, libc::MADV_HUGEPAGE);
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (ptr, len);
}

// SAFETY: every block comes from `System` with `system_layout(layout)` and is
// returned to it with the same layout (a pure function of the caller's layout,
// which `GlobalAlloc` guarantees is the one it allocated with); `advise` never
// changes memory contents.
unsafe impl GlobalAlloc for HugePages {
    #[inline]
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let sys = Self::system_layout(layout);
        // SAFETY: forwarded contract: `layout` (hence `sys`) has a non-zero size.
        let p = unsafe { System.alloc(sys) };
        if sys != layout && !p.is_null() {
            advise(p, layout.size());
        }
        p
    }

    #[inline]
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let sys = Self::system_layout(layout);
        if sys == layout {
            // SAFETY: forwarded contract.
            return unsafe { System.alloc_zeroed(layout) };
        }
        // Advise first, then zero: zeroing is the first touch.
        // SAFETY: forwarded contract; `p` holds `layout.size()` writable bytes.
        unsafe {
            let p = self.alloc(layout);
            if !p.is_null() {
                std::ptr::write_bytes(p, 0, layout.size());
            }
            p
        }
    }

    #[inline]
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `alloc` with this `layout`, i.e. from
        // `System` with `system_layout(layout)`.
        unsafe { System.dealloc(ptr, Self::system_layout(layout)) }
    }

    #[inline]
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY (both branches): `ptr` came from `alloc` with `layout`;
        // `new_size` is non-zero and valid for `layout.align()` (the caller's
        // contract).
        unsafe {
            let new_layout = Layout::from_size_align_unchecked(new_size, layout.align());
            if Self::system_layout(layout) == layout && Self::system_layout(new_layout) == new_layout {
                return System.realloc(ptr, layout, new_size);
            }
            // Crossing into (or staying in) huge-page territory: a fresh,
            // advised block and a copy.
            let p = self.alloc(new_layout);
            if !p.is_null() {
                std::ptr::copy_nonoverlapping(ptr, p, layout.size().min(new_size));
                self.dealloc(ptr, layout);
            }
            p
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn large_blocks_are_huge_page_aligned_and_keep_their_contents() {
        let a = HugePages;
        let small = Layout::from_size_align(1000, 8).unwrap();
        let large = Layout::from_size_align(HugePages::MIN_BYTES + 12_345, 64).unwrap();
        // SAFETY: non-zero sizes; every block is freed with its own layout.
        unsafe {
            let s = a.alloc(small);
            assert!(!s.is_null());
            std::ptr::write_bytes(s, 7, small.size());
            // Growing a small block past the threshold moves it to an aligned one.
            let g = a.realloc(s, small, large.size());
            assert!(!g.is_null());
            assert_eq!(g as usize % HUGE_PAGE, 0);
            assert!(std::slice::from_raw_parts(g, small.size()).iter().all(|&b| b == 7));
            let grown = Layout::from_size_align(large.size(), small.align()).unwrap();
            // Shrinking back keeps the prefix too.
            let s2 = a.realloc(g, grown, 500);
            assert!(std::slice::from_raw_parts(s2, 500).iter().all(|&b| b == 7));
            a.dealloc(s2, Layout::from_size_align(500, 8).unwrap());

            let z = a.alloc_zeroed(large);
            assert!(!z.is_null());
            assert_eq!(z as usize % HUGE_PAGE, 0);
            assert!(std::slice::from_raw_parts(z, large.size()).iter().all(|&b| b == 0));
            a.dealloc(z, large);
        }
    }
}
