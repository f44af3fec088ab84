//! glibc `malloc` tuning for tensor workloads.
//!
//! glibc serves every allocation above its mmap threshold (128 KiB, raised dynamically up to
//! 32 MiB) with fresh anonymous pages and hands them back to the kernel on `free`. A CNN training
//! step on the ndarray backend allocates and frees thousands of tensors of tens of MB, so nearly
//! every op page-faults its output in again: an FPFDCNN train step took ~1.1 M page faults, and
//! page clearing + fault handling was ~10 % of its profile on the project's VMs. Raising the
//! mmap and trim thresholds to 1 GiB lets freed tensors be reused from the heap instead
//! (~200 K faults, about 30 % less CPU time for the same step). The cost is that freed memory
//! stays mapped in the process, up to its peak use.
//!
//! That was not enough where several threads allocate: glibc gives a thread that finds the
//! main arena busy an arena of its own, carved from mmap'd heaps of at most 64 MiB, and the
//! thresholds did not keep those from faulting pages in again (the ndarray SDFCNN train step
//! on a 2-core Intel VM: 16 % of a `perf` profile clearing fresh pages). One arena for the
//! whole process (`M_ARENA_MAX` = 1) took that step's system time from 2.3-4.8 s to 1.2-1.6 s
//! over six steps; flex's step and `slam`'s frames/s did not move (`lab/notes/cpu-speed.md`,
//! 2026-12-07).
//!
//! Binaries that run the networks call [`tune_for_tensors`] first, before they start
//! threads. An explicit `MALLOC_MMAP_THRESHOLD_`, `MALLOC_TRIM_THRESHOLD_` or
//! `GLIBC_TUNABLES` in the environment wins (nothing is changed), and so does an explicit
//! `MALLOC_ARENA_MAX` (the thresholds are still raised). Other C libraries and platforms
//! are left alone.

/// The mmap and trim threshold set by [`tune_for_tensors`]: 1 GiB.
pub(crate) const THRESHOLD: usize = 1 << 30;

/// Raises glibc's mmap and trim thresholds to `THRESHOLD` and keeps one arena, unless the
/// environment already configures them (see the module docs). Returns whether the
/// thresholds were set.
pub fn tune_for_tensors() -> bool {
    let set = |v: &str| std::env::var_os(v).is_some();
    let configured = [
        "MALLOC_MMAP_THRESHOLD_",
        "MALLOC_TRIM_THRESHOLD_",
        "GLIBC_TUNABLES",
    ]
    .iter()
    .any(|v| set(v));
    if configured {
        return false;
    }
    if !set("MALLOC_ARENA_MAX") {
        one_arena();
    }
    set_thresholds()
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn set_thresholds() -> bool {
    let value = libc::c_int::try_from(THRESHOLD).expect("1 GiB fits in a C int");
    // SAFETY: mallopt only updates glibc's allocator parameters; it is called with valid
    // parameter numbers and values, and takes the allocator's own lock.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, value) == 1
            && libc::mallopt(libc::M_TRIM_THRESHOLD, value) == 1
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn set_thresholds() -> bool {
    false
}

/// One malloc arena for the whole process; whether glibc accepted it.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn one_arena() -> bool {
    // SAFETY: as in `set_thresholds`.
    unsafe { libc::mallopt(libc::M_ARENA_MAX, 1) == 1 }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn one_arena() -> bool {
    false
}

#[cfg(test)]
mod tests {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[test]
    fn glibc_accepts_the_thresholds() {
        // Only the return value is checked: the tuning stays in effect for the test process,
        // which is harmless.
        assert!(super::set_thresholds());
        assert!(super::one_arena());
    }
}
