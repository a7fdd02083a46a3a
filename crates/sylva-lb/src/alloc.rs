//! Large zeroed buffers aligned for the kernel and backed by transparent huge pages where the
//! kernel allows them.
//!
//! A step sweeps two 160 MB states at 128³. Alignment to 64 bytes (2 MiB for large buffers)
//! keeps each row's runs on cache-line boundaries when `nz` is a multiple of 16, so the
//! kernel's 8-wide loads never split a line. Linux backs regions marked `MADV_HUGEPAGE` with
//! 2 MiB pages when `transparent_hugepage` is `madvise` (the common default), which spares the
//! TLB; the buffers are marked before their first touch.

use std::alloc::{alloc, alloc_zeroed, dealloc, handle_alloc_error, Layout};
use std::ops::{Deref, DerefMut};
use std::ptr::NonNull;

const HUGE: usize = 2 << 20;

/// A zeroed, aligned, fixed-length `f32` buffer.
pub struct AlignedBuf {
    ptr: NonNull<f32>,
    len: usize,
    layout: Layout,
}

// SAFETY: AlignedBuf owns its allocation exactly like a Vec<f32>.
unsafe impl Send for AlignedBuf {}
unsafe impl Sync for AlignedBuf {}

impl AlignedBuf {
    pub fn zeroed(len: usize) -> AlignedBuf {
        let bytes = (len * 4).max(4);
        let align = if bytes >= HUGE { HUGE } else { 64 };
        let layout = Layout::from_size_align(bytes, align).expect("buffer size fits a Layout");
        // The allocator zeroes an over-aligned block by writing it, which would fault it in
        // as 4 KiB pages before any advice (89,600 faults per 128³ solve; docs/PERFORMANCE.md,
        // "Huge pages for the LB state"). So a huge block is marked first and zeroed after,
        // and its first touch faults 2 MiB pages.
        let huge = align == HUGE;
        // SAFETY: the layout has non-zero size.
        let raw = unsafe {
            if huge {
                alloc(layout)
            } else {
                alloc_zeroed(layout)
            }
        };
        let Some(ptr) = NonNull::new(raw as *mut f32) else {
            handle_alloc_error(layout)
        };
        if huge {
            advise_huge(raw, bytes);
            // SAFETY: `raw` is valid for `bytes` bytes; zero bytes are 0.0 as f32.
            unsafe { std::ptr::write_bytes(raw, 0, bytes) };
        }
        AlignedBuf { ptr, len, layout }
    }
}

impl Deref for AlignedBuf {
    type Target = [f32];
    fn deref(&self) -> &[f32] {
        // SAFETY: ptr is valid for len initialised (zeroed) floats for the buffer's lifetime.
        unsafe { std::slice::from_raw_parts(self.ptr.as_ptr(), self.len) }
    }
}

impl DerefMut for AlignedBuf {
    fn deref_mut(&mut self) -> &mut [f32] {
        // SAFETY: as in deref, and &mut self guarantees exclusive access.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.as_ptr(), self.len) }
    }
}

impl Drop for AlignedBuf {
    fn drop(&mut self) {
        // SAFETY: allocated in `zeroed` with this layout.
        unsafe { dealloc(self.ptr.as_ptr() as *mut u8, self.layout) }
    }
}

#[cfg(target_os = "linux")]
fn advise_huge(ptr: *mut u8, bytes: usize) {
    let start = (ptr as usize).div_ceil(HUGE) * HUGE;
    let end = (ptr as usize + bytes) / HUGE * HUGE;
    if end > start {
        // SAFETY: the range lies inside the allocation; madvise only changes how the kernel
        // backs it, and a failure (e.g. THP disabled) leaves ordinary pages.
        unsafe {
            libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_HUGEPAGE);
        }
    }
}

#[cfg(not(target_os = "linux"))]
fn advise_huge(_ptr: *mut u8, _bytes: usize) {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zeroed_aligned_and_writable() {
        for len in [0, 1, 17, (3 << 20) + 5] {
            let mut v = AlignedBuf::zeroed(len);
            assert_eq!(v.len(), len);
            assert_eq!(v.as_ptr() as usize % 64, 0);
            assert!(v.iter().all(|&x| x == 0.0));
            if len > 0 {
                v[len - 1] = 2.0;
                assert_eq!(v[len - 1], 2.0);
            }
        }
    }
}
