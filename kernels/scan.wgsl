// Exclusive prefix sum of n u32 values in place, in three dispatches over runs of RUN = 64
// values: scan_local (one thread per run, dispatched over ceil(n / RUN) threads) scans its run
// serially and writes the run's total to scan_blocks[run], with no workgroup memory and no
// barrier; scan_totals (one workgroup) scans the run totals and writes the grand total to
// scan_blocks[n_runs]; scan_apply (one thread per value) adds each run's offset. (A
// Hillis-Steele scan of 256-value blocks took 3.2 ms per 27,752 values on lavapipe, where a
// workgroup with barriers costs ~80 us; this takes a fraction.) Exact (integers), so the
// result is the same on every device. Bound to different arrays through binding aliases
// (neighbour counts, flags, ...).
// CPU twin: src/cpu/scan.rs.
#import index

struct ScanParams {
    n: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> scan_params: ScanParams;
@group(0) @binding(1) var<storage, read_write> scan_data: array<u32>;
@group(0) @binding(2) var<storage, read_write> scan_blocks: array<u32>;

const WORKGROUP: u32 = 256u;
// Values per scan_local thread (one run), as `cpu::scan::SCAN_BLOCK`.
const RUN: u32 = 64u;
// scan_local's workgroup size.
const LOCAL_WORKGROUP: u32 = 64u;

var<workgroup> lanes: array<u32, 256>;

// Hillis-Steele inclusive scan of `lanes` within the workgroup (scan_totals only). A variant
// with 4 barriers (16 threads scanning 16 lanes each) made scan_totals slower on lavapipe.
fn scan_lanes(l: u32) {
    for (var s = 1u; s < WORKGROUP; s = s * 2u) {
        workgroupBarrier();
        var v = lanes[l];
        if l >= s {
            v += lanes[l - s];
        }
        workgroupBarrier();
        lanes[l] = v;
    }
    workgroupBarrier();
}

@compute @workgroup_size(LOCAL_WORKGROUP)
fn scan_local(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let run = linear_index(gid, nwg, LOCAL_WORKGROUP);
    let n = scan_params.n;
    let first = run * RUN;
    if first >= n {
        return;
    }
    let end = min(first + RUN, n);
    var t = 0u;
    for (var i = first; i < end; i++) {
        let v = scan_data[i];
        scan_data[i] = t;
        t += v;
    }
    scan_blocks[run] = t;
}

@compute @workgroup_size(256)
fn scan_totals(@builtin(local_invocation_index) l: u32) {
    let n_blocks = (scan_params.n + RUN - 1u) / RUN;
    var carry = 0u;
    for (var base = 0u; base < n_blocks; base += WORKGROUP) {
        var v = 0u;
        if base + l < n_blocks {
            v = scan_blocks[base + l];
        }
        lanes[l] = v;
        scan_lanes(l);
        if base + l < n_blocks {
            scan_blocks[base + l] = carry + lanes[l] - v;
        }
        carry += lanes[WORKGROUP - 1u];
        workgroupBarrier();
    }
    if l == 0u {
        scan_blocks[n_blocks] = carry;
    }
}

@compute @workgroup_size(256)
fn scan_apply(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let i = linear_index(gid, nwg, WORKGROUP);
    if i < scan_params.n {
        scan_data[i] += scan_blocks[i / RUN];
    }
}
