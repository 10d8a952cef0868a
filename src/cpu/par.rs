//! Data-parallel loops for the CPU twins. Each index writes only its own outputs and reads
//! only inputs, exactly as one GPU thread does, so the result is bit-identical whatever the
//! number of threads (rayon splits the index range; it never changes what one index
//! computes or the order of any sum). The threads are those of the rayon pool the caller
//! runs in (`CpuStepper` installs its own pool of `--threads N`).

use rayon::prelude::*;

/// Indices per rayon task: enough work per task that scheduling costs little, few enough
/// that 2 to 64 cores all get work on meshes of a few thousand elements.
pub const MIN_INDICES_PER_TASK: usize = 128;

/// For every index i < n: `f(i, &mut out[K·i .. K·(i+1)])`.
pub fn for_each_chunk<const K: usize>(
    out: &mut [f32],
    n: usize,
    f: impl Fn(usize, &mut [f32]) + Sync + Send,
) {
    out[..K * n]
        .par_chunks_mut(K)
        .with_min_len(MIN_INDICES_PER_TASK)
        .enumerate()
        .for_each(|(i, chunk)| f(i, chunk));
}

/// For every index i < n: `f(i, &mut a[KA·i ..], &mut b[KB·i ..])` (two outputs per index).
pub fn for_each_chunk2<const KA: usize, const KB: usize>(
    a: &mut [f32],
    b: &mut [f32],
    n: usize,
    f: impl Fn(usize, &mut [f32], &mut [f32]) + Sync + Send,
) {
    a[..KA * n]
        .par_chunks_mut(KA)
        .zip(b[..KB * n].par_chunks_mut(KB))
        .with_min_len(MIN_INDICES_PER_TASK)
        .enumerate()
        .for_each(|(i, (x, y))| f(i, x, y));
}

/// Like [`for_each_chunk2`], returning the smallest `Some` any index returned (a flag such
/// as the lowest diverged vertex; min is order-independent, so this too is deterministic).
pub fn for_each_chunk2_min<const KA: usize, const KB: usize>(
    a: &mut [f32],
    b: &mut [f32],
    n: usize,
    f: impl Fn(usize, &mut [f32], &mut [f32]) -> Option<u32> + Sync + Send,
) -> Option<u32> {
    a[..KA * n]
        .par_chunks_mut(KA)
        .zip(b[..KB * n].par_chunks_mut(KB))
        .with_min_len(MIN_INDICES_PER_TASK)
        .enumerate()
        .filter_map(|(i, (x, y))| f(i, x, y))
        .min()
}

/// Flush denormal (subnormal) f32 results and inputs to zero on the calling thread, as GPUs
/// do. Without it, the first steps from rest, where forces and displacements are tiny,
/// run several times slower on x86 (every operation on a subnormal takes a microcode
/// assist). Set on every worker of the CPU backend's pool, so results stay identical for
/// any thread count. x86-64: MXCSR FTZ (bit 15) and DAZ (bit 6); aarch64: FPCR FZ (bit 24);
/// elsewhere a no-op.
pub fn flush_denormals_on_this_thread() {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: stmxcsr/ldmxcsr read and write only the SSE control register of this thread;
    // setting FTZ and DAZ changes rounding of subnormals only, which Rust permits.
    unsafe {
        let mut csr: u32 = 0;
        std::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack));
        csr |= (1 << 15) | (1 << 6);
        std::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack, readonly));
    }
    #[cfg(target_arch = "aarch64")]
    // SAFETY: reads and writes only this thread's floating-point control register.
    unsafe {
        let mut fpcr: u64;
        std::arch::asm!("mrs {}, fpcr", out(reg) fpcr, options(nomem, nostack));
        fpcr |= 1 << 24;
        std::arch::asm!("msr fpcr, {}", in(reg) fpcr, options(nomem, nostack));
    }
}
