//! CPU twin of `kernels/dispatch_probe.wgsl`, the indirect-dispatch probe: `dispatch_probe_args`
//! writes the dispatch arguments (count of nonzero inputs, 1, 1) and `dispatch_probe_hits`, run with
//! those arguments, records one hit and 64 threads per workgroup it ran.

/// Threads per workgroup of `dispatch_probe_hits`.
pub const WORKGROUP: u32 = 64;

/// `probe_dispatch = (#{i : probe_input[i] ≠ 0}, 1, 1)`.
pub fn dispatch_probe_args(probe_input: &[u32], probe_dispatch: &mut [u32]) {
    probe_dispatch[0] = probe_input.iter().filter(|&&x| x != 0).count() as u32;
    probe_dispatch[1] = 1;
    probe_dispatch[2] = 1;
}

/// For each of the `probe_dispatch[0]` workgroups w (within the arrays): one hit and
/// [`WORKGROUP`] threads.
pub fn dispatch_probe_hits(
    probe_dispatch: &[u32],
    probe_hit_counts: &mut [u32],
    probe_thread_counts: &mut [u32],
) {
    let groups =
        probe_dispatch[0] as usize * probe_dispatch[1] as usize * probe_dispatch[2] as usize;
    for w in 0..groups.min(probe_hit_counts.len()) {
        probe_hit_counts[w] += 1;
        probe_thread_counts[w] += WORKGROUP;
    }
}
