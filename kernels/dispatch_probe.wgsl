// Indirect-dispatch probe (used by the tests of the kernel layer; no simulation stage).
//   dispatch_probe_args   one thread: counts the nonzero words of probe_input and writes
//                DispatchIndirectArgs (count, 1, 1) to probe_dispatch
//   dispatch_probe_hits   dispatched indirectly with those arguments: the first thread of each
//                workgroup adds 1 to probe_hit_counts[workgroup], every thread adds 1 to
//                probe_thread_counts[workgroup]
// CPU twin: src/cpu/dispatch_probe.rs.

@group(0) @binding(0) var<storage, read> probe_input: array<u32>;
@group(0) @binding(1) var<storage, read_write> probe_dispatch: array<u32>;
@group(0) @binding(2) var<storage, read_write> probe_hit_counts: array<u32>;
@group(0) @binding(3) var<storage, read_write> probe_thread_counts: array<atomic<u32>>;

@compute @workgroup_size(1)
fn dispatch_probe_args() {
    var count = 0u;
    for (var i = 0u; i < arrayLength(&probe_input); i++) {
        if probe_input[i] != 0u {
            count += 1u;
        }
    }
    probe_dispatch[0] = count;
    probe_dispatch[1] = 1u;
    probe_dispatch[2] = 1u;
}

@compute @workgroup_size(64)
fn dispatch_probe_hits(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let w = wid.x;
    if w >= arrayLength(&probe_hit_counts) {
        return;
    }
    if lid == 0u {
        probe_hit_counts[w] = probe_hit_counts[w] + 1u;
    }
    atomicAdd(&probe_thread_counts[w], 1u);
}
