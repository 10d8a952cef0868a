// Exclusive prefix sum of n u32 values in place, in three dispatches (blocks of 256):
// scan_local scans each block and writes its total to scan_blocks[block]; scan_totals (one
// workgroup) scans the block totals and writes the grand total to scan_blocks[n_blocks];
// scan_apply adds each block's offset. Exact (integers), so the result is the same on every
// device. Bound to different arrays through binding aliases (neighbour counts, flags, ...).
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

var<workgroup> lanes: array<u32, 256>;

// Hillis-Steele inclusive scan of `lanes` within the workgroup.
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

@compute @workgroup_size(256)
fn scan_local(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) l: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
) {
    let i = linear_index(gid, nwg, WORKGROUP);
    var v = 0u;
    if i < scan_params.n {
        v = scan_data[i];
    }
    lanes[l] = v;
    scan_lanes(l);
    if i < scan_params.n {
        scan_data[i] = lanes[l] - v;
    }
    if l == WORKGROUP - 1u {
        scan_blocks[wid.y * nwg.x + wid.x] = lanes[l];
    }
}

@compute @workgroup_size(256)
fn scan_totals(@builtin(local_invocation_index) l: u32) {
    let n_blocks = (scan_params.n + WORKGROUP - 1u) / WORKGROUP;
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
        scan_data[i] += scan_blocks[i / WORKGROUP];
    }
}
