//! Memory placement for large scenes: a global allocator that backs big
//! allocations with transparent huge pages.
//!
//! A ray walking a 1.6M-triangle BVH touches about 100 MB of nodes and
//! triangle blocks in no predictable order. With 4 KiB pages nearly every node
//! it loads is also a TLB miss (the second-level TLB covers a few MiB), and the
//! page walk itself misses the caches. Linux can back memory with 2 MiB pages
//! instead, but on most distributions only where a program asks for it
//! (`/sys/kernel/mm/transparent_hugepage/enabled` = `madvise`) — which is what
//! Embree does for its BVH. [`HugePages`] asks for it: on Linux, blocks of at
//! least [`HugePages::MIN_BYTES`] are mapped directly, 2 MiB aligned, and
//! advised with `madvise(MADV_HUGEPAGE)` before they are first touched.
//! Everything else goes to the allocator it wraps: the system's
//! ([`HugePages::SYSTEM`]) or another ([`HugePages::over`]; the `isin` binary
//! wraps mimalloc, whose per-thread heaps take the cluster's buffers freed on
//! another thread than the one that made them without a lock).
//!
//! Large blocks grow with `mremap`, which moves their pages instead of
//! copying them: a vector that doubles its way up to 100 MB is not written
//! twice, and the process never holds the old and the new copy at once.
//!
//! The advice is a hint: where the kernel refuses it (or on other systems)
//! memory simply stays in small pages. It changes no value the tracer
//! computes, only where the bytes live.
//!
//! **Opting out.** With the kernel's default `defrag` setting (`madvise`), a
//! fault in an advised block compacts memory on the spot when no free 2 MiB
//! page is at hand: on a long-running machine with fragmented memory, loading
//! a large scene can then stall for a fraction of a second. Setting the
//! environment variable `ISIN_HUGE_PAGES=0` (or `off`) leaves the advice out;
//! large blocks are still mapped on their own and grown without copies.
//!
//! Binaries opt in with
//!
//! ```ignore
//! #[global_allocator]
//! static ALLOC: isin_tracer::memory::HugePages = isin_tracer::memory::HugePages::SYSTEM;
//! ```

use std::alloc::{GlobalAlloc, Layout, System};

/// An allocator for small blocks (`A`, the system's by default), with huge
/// pages for large ones (see the module docs).
#[derive(Clone, Copy, Debug, Default)]
pub struct HugePages<A = System> {
    small: A,
}

impl HugePages {
    /// Smallest block that is mapped on its own and advised. Below this the
    /// alignment's slack (up to 2 MiB of address space) is not worth it.
    pub const MIN_BYTES: usize = 4 << 20;

    /// Small blocks from the system allocator.
    pub const SYSTEM: Self = Self::over(System);
}

impl<A> HugePages<A> {
    /// Small blocks from `small`.
    pub const fn over(small: A) -> Self {
        Self { small }
    }
}

/// Whether `layout` is served by [`large`] rather than the system allocator.
#[inline]
fn is_large(layout: &Layout) -> bool {
    cfg!(target_os = "linux") && layout.size() >= HugePages::MIN_BYTES && layout.align() <= large::ALIGN
}

/// Whether large blocks are advised, given the value of `ISIN_HUGE_PAGES`
/// (if set): yes unless it is `0`, `off`, `no` or `false` (any case).
#[cfg_attr(not(target_os = "linux"), allow(dead_code))]
fn advice_wanted_for(value: Option<&[u8]>) -> bool {
    let off = |v: &[u8]| [&b"0"[..], b"off", b"no", b"false"].iter().any(|o| v.eq_ignore_ascii_case(o));
    !value.is_some_and(|v| off(v.trim_ascii()))
}

#[cfg(target_os = "linux")]
mod large {
    //! Huge-page-aligned anonymous mappings. Every function returns null on
    //! failure and leaves existing mappings as they were.

    use std::ptr::null_mut;

    /// Alignment of every large block: one transparent huge page on x86_64
    /// and most aarch64 kernels.
    pub(super) const ALIGN: usize = 2 << 20;

    /// Bytes mapped for a block of `size` bytes (whole pages).
    pub(super) fn mapped_len(size: usize) -> usize {
        const PAGE: usize = 4096;
        size.div_ceil(PAGE) * PAGE
    }

    /// Asks for huge pages on `[p, p + len)` (a hint: failure is harmless),
    /// unless the environment opts out (see the module docs).
    unsafe fn advise(p: *mut u8, len: usize) {
        if !advice_wanted() {
            return;
        }
        // SAFETY: the caller owns the page-aligned mapping `[p, p + len)`;
        // MADV_HUGEPAGE changes how it is backed, never its contents.
        unsafe { libc::madvise(p.cast(), len, libc::MADV_HUGEPAGE) };
    }

    /// `ISIN_HUGE_PAGES`, read once. Through `getenv`, which does not
    /// allocate: this runs inside the allocator.
    fn advice_wanted() -> bool {
        use std::sync::atomic::{AtomicU8, Ordering};
        // 0: not read yet; 1: advise; 2: do not.
        static STATE: AtomicU8 = AtomicU8::new(0);
        match STATE.load(Ordering::Relaxed) {
            1 => true,
            2 => false,
            _ => {
                // SAFETY: the name is a NUL-terminated string; a non-null
                // result points to the variable's NUL-terminated value, read
                // at once. (Like every `getenv`, it must not race a `setenv`;
                // the tracer's binaries never set variables.)
                let wanted = unsafe {
                    let v = libc::getenv(c"ISIN_HUGE_PAGES".as_ptr());
                    super::advice_wanted_for((!v.is_null()).then(|| std::ffi::CStr::from_ptr(v).to_bytes()))
                };
                STATE.store(if wanted { 1 } else { 2 }, Ordering::Relaxed);
                wanted
            }
        }
    }

    /// A fresh, zeroed, advised mapping of `len` bytes (whole pages) at an
    /// [`ALIGN`]-aligned address.
    pub(super) unsafe fn map(len: usize) -> *mut u8 {
        let Some(total) = len.checked_add(ALIGN) else { return null_mut() };
        // SAFETY: an anonymous private mapping at an address of the kernel's
        // choosing touches no existing memory.
        let p = unsafe {
            libc::mmap(
                null_mut(),
                total,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                -1,
                0,
            )
        };
        if p == libc::MAP_FAILED {
            return null_mut();
        }
        let start = p as usize;
        let head = start.next_multiple_of(ALIGN) - start;
        let tail = total - head - len;
        // SAFETY: both ranges lie inside the mapping just made, which nothing
        // else knows of; what stays is `[start + head, start + head + len)`.
        unsafe {
            let base = p.cast::<u8>();
            if head > 0 {
                libc::munmap(base.cast(), head);
            }
            if tail > 0 {
                libc::munmap(base.add(head + len).cast(), tail);
            }
            let block = base.add(head);
            advise(block, len);
            block
        }
    }

    /// Unmaps a block made by [`map`] or [`remap`] with this length.
    pub(super) unsafe fn unmap(p: *mut u8, len: usize) {
        // SAFETY: the caller passes a whole block it owns.
        unsafe { libc::munmap(p.cast(), len) };
    }

    /// The block `p` of `old` bytes resized to `new` bytes (both whole
    /// pages), its contents kept: shrunk or grown in place where the address
    /// space allows, otherwise its pages moved (not copied) to a fresh
    /// aligned address. Null on failure, with `p` untouched.
    pub(super) unsafe fn remap(p: *mut u8, old: usize, new: usize) -> *mut u8 {
        // SAFETY (all calls): `p` is a whole block of `old` bytes that the
        // caller owns; the target of a move is a fresh mapping of `new`
        // bytes made here, which MREMAP_FIXED replaces.
        unsafe {
            if new <= old {
                if new < old {
                    libc::munmap(p.add(new).cast(), old - new);
                }
                return p;
            }
            if libc::mremap(p.cast(), old, new, 0) != libc::MAP_FAILED {
                advise(p, new);
                return p;
            }
            let target = map(new);
            if target.is_null() {
                return null_mut();
            }
            let flags = libc::MREMAP_MAYMOVE | libc::MREMAP_FIXED;
            if libc::mremap(p.cast(), old, new, flags, target.cast::<libc::c_void>()) == libc::MAP_FAILED {
                unmap(target, new);
                return null_mut();
            }
            advise(target, new);
            target
        }
    }
}

#[cfg(not(target_os = "linux"))]
mod large {
    //! Never used: [`super::is_large`] is false off Linux.

    pub(super) const ALIGN: usize = 1;

    pub(super) fn mapped_len(size: usize) -> usize {
        size
    }

    pub(super) unsafe fn map(_len: usize) -> *mut u8 {
        std::ptr::null_mut()
    }

    pub(super) unsafe fn unmap(_p: *mut u8, _len: usize) {}

    pub(super) unsafe fn remap(_p: *mut u8, _old: usize, _new: usize) -> *mut u8 {
        std::ptr::null_mut()
    }
}

// SAFETY: a block is large exactly when `is_large` holds for its layout (a
// pure function of the layout `GlobalAlloc` hands back with the block), and
// then it is a mapping of `mapped_len(size)` bytes aligned to at least its
// layout's alignment; every other block comes from and goes back to
// `self.small` with its own layout. Mappings are zeroed by the kernel.
unsafe impl<A: GlobalAlloc> GlobalAlloc for HugePages<A> {
    #[inline]
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if is_large(&layout) {
            // SAFETY: a fresh mapping.
            return unsafe { large::map(large::mapped_len(layout.size())) };
        }
        // SAFETY: forwarded contract (`layout` has a non-zero size).
        unsafe { self.small.alloc(layout) }
    }

    #[inline]
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if is_large(&layout) {
            // SAFETY: a fresh mapping, zeroed by the kernel.
            return unsafe { large::map(large::mapped_len(layout.size())) };
        }
        // SAFETY: forwarded contract.
        unsafe { self.small.alloc_zeroed(layout) }
    }

    #[inline]
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `alloc` with this `layout` (see the impl's
        // safety comment for where that put it).
        unsafe {
            if is_large(&layout) {
                large::unmap(ptr, large::mapped_len(layout.size()));
            } else {
                self.small.dealloc(ptr, layout);
            }
        }
    }

    #[inline]
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY (all branches): `ptr` came from `alloc` with `layout`;
        // `new_size` is non-zero and valid for `layout.align()` (the caller's
        // contract). A moved block gets the first `min(old, new)` bytes.
        unsafe {
            let new_layout = Layout::from_size_align_unchecked(new_size, layout.align());
            match (is_large(&layout), is_large(&new_layout)) {
                (false, false) => self.small.realloc(ptr, layout, new_size),
                (true, true) => {
                    large::remap(ptr, large::mapped_len(layout.size()), large::mapped_len(new_size))
                }
                _ => {
                    let p = self.alloc(new_layout);
                    if !p.is_null() {
                        std::ptr::copy_nonoverlapping(ptr, p, layout.size().min(new_size));
                        self.dealloc(ptr, layout);
                    }
                    p
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fills `len` bytes at `p` with a pattern keyed by `seed`.
    unsafe fn fill(p: *mut u8, len: usize, seed: u8) {
        for i in (0..len).step_by(4093) {
            // SAFETY: the caller owns `len` bytes at `p`.
            unsafe { p.add(i).write(seed.wrapping_add(i as u8)) };
        }
    }

    /// Whether `fill(p, len, seed)`'s pattern is there.
    unsafe fn holds(p: *const u8, len: usize, seed: u8) -> bool {
        // SAFETY: the caller owns `len` bytes at `p`.
        (0..len).step_by(4093).all(|i| unsafe { p.add(i).read() } == seed.wrapping_add(i as u8))
    }

    #[test]
    fn the_environment_switches_the_advice_off() {
        assert!(advice_wanted_for(None));
        for on in [&b"1"[..], b"on", b"yes", b"", b"always"] {
            assert!(advice_wanted_for(Some(on)), "{on:?}");
        }
        for off in [&b"0"[..], b"off", b"OFF", b" no ", b"False"] {
            assert!(!advice_wanted_for(Some(off)), "{off:?}");
        }
    }

    #[test]
    fn blocks_keep_their_contents_through_every_kind_of_resize() {
        let a = HugePages::SYSTEM;
        let min = HugePages::MIN_BYTES;
        // SAFETY: non-zero sizes; every block is resized and freed with the
        // layout it has at that moment.
        unsafe {
            let small = Layout::from_size_align(1000, 8).unwrap();
            let s = a.alloc(small);
            assert!(!s.is_null());
            fill(s, 1000, 1);
            // Small → large: a fresh mapping, huge-page aligned.
            let mut size = min + 12_345;
            let mut p = a.realloc(s, small, size);
            assert!(!p.is_null());
            assert!(cfg!(not(target_os = "linux")) || p as usize % large::ALIGN == 0);
            assert!(holds(p, 1000, 1));
            fill(p, size, 2);
            // Large → larger, several times (in place or moved), and a
            // block mapped right after it to force a move.
            let blocker_layout = Layout::from_size_align(min, 8).unwrap();
            let blocker = a.alloc(blocker_layout);
            assert!(!blocker.is_null());
            for _ in 0..3 {
                let next = size * 2 + 777;
                p = a.realloc(p, Layout::from_size_align(size, 8).unwrap(), next);
                assert!(!p.is_null());
                assert!(cfg!(not(target_os = "linux")) || p as usize % large::ALIGN == 0);
                assert!(holds(p, size, 2), "contents moved with the block");
                size = next;
                fill(p, size, 2);
            }
            a.dealloc(blocker, blocker_layout);
            // Large → smaller large, then → small.
            let shrunk = min + 1;
            p = a.realloc(p, Layout::from_size_align(size, 8).unwrap(), shrunk);
            assert!(holds(p, shrunk, 2));
            p = a.realloc(p, Layout::from_size_align(shrunk, 8).unwrap(), 500);
            assert!(holds(p, 500, 2));
            a.dealloc(p, Layout::from_size_align(500, 8).unwrap());

            let large = Layout::from_size_align(min * 3, 64).unwrap();
            let z = a.alloc_zeroed(large);
            assert!(!z.is_null());
            assert!(std::slice::from_raw_parts(z, large.size()).iter().all(|&b| b == 0));
            a.dealloc(z, large);
        }
    }
}
