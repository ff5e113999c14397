//! Large sample buffers: on Linux the capacity of a buffer of many MiB is advised to use
//! transparent huge pages (`madvise(MADV_HUGEPAGE)`), so that its first touch costs one page
//! fault per 2 MiB instead of one per 4 KiB. A 3.24 M-sample axis is 26 MB: 6 300 faults of
//! small pages, each one a trip through the kernel (and, on a virtual machine, often the
//! hypervisor). Where the system has huge pages off, or the advice fails, nothing changes.

/// Smallest buffer worth advising: below a few huge pages the saving is nil.
const ADVISE_FROM_BYTES: usize = 8 << 20;

/// Size of a transparent huge page on x86-64 and most aarch64 kernels.
const HUGE_PAGE: usize = 2 << 20;

/// Advises the kernel to back the unused capacity of `buffer` with huge pages (Linux; a
/// no-op elsewhere and for small buffers). Call it right after reserving, before filling.
pub fn advise_huge_pages<T>(buffer: &mut Vec<T>) {
    let bytes = buffer.capacity().saturating_mul(std::mem::size_of::<T>());
    if bytes < ADVISE_FROM_BYTES {
        return;
    }
    #[cfg(target_os = "linux")]
    {
        let start = buffer.as_mut_ptr() as usize;
        // Only whole huge pages inside the allocation can be advised.
        let first = start.next_multiple_of(HUGE_PAGE);
        let end = (start + bytes) & !(HUGE_PAGE - 1);
        if end > first {
            // SAFETY: [first, end) lies inside the vector's own allocation (its capacity),
            // which stays alive across the call; MADV_HUGEPAGE changes only how the kernel
            // backs the pages, never their contents or the mapping's permissions.
            let _ = unsafe {
                libc::madvise(first as *mut libc::c_void, end - first, libc::MADV_HUGEPAGE)
            };
        }
    }
}
