//! Memory for frame-sized buffers. Every stereo frame allocates and frees several
//! buffers of 1–4 MB (camera frames, rectified views, disparity, depth, the point cloud).
//! glibc serves blocks that large with a fresh `mmap` each time and returns them on free,
//! so every frame pays a page fault per 4 KiB on first touch, and every free flushes the
//! other cores' TLBs: 2.4 ms of a 14.6 ms stereo frame at 640×480. Raising the two
//! thresholds keeps freed blocks in the heap for the next frame.

/// Blocks up to this size come from the heap, not their own `mmap`.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const MMAP_THRESHOLD: i32 = 64 << 20;
/// Free memory at the top of the heap up to this much is kept, not returned.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const TRIM_THRESHOLD: i32 = 128 << 20;

/// Tells glibc's allocator to keep frame-sized blocks (see the module documentation);
/// other C libraries are left as they are.
pub fn keep_frame_buffers() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[allow(unsafe_code)]
    // SAFETY: `mallopt` only sets allocator parameters; it is called before any thread
    // starts, with parameters and values glibc documents.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD);
        libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD);
    }
}
