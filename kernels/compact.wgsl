// Stage part (every activation update): the lists the particle kernels run over, compacted
// in ascending particle order (deterministic), with their counts and the indirect dispatch
// arguments the particle kernels are launched with.
//   compact_mark     per particle (and one past the end): 0/1 marks of the dynamic set D,
//                    the stress set S and the force set F
//   [a prefix sum over each mark array]
//   compact_scatter  per particle: its slot in each list it belongs to
//   compact_args     one thread: particle_counts = (|D|, |S|, |F|, 0) and four
//                    DispatchIndirectArgs (64 items per workgroup) for D, S, F and the
//                    larger of S and the tool's surface vertices (the grid of the fused
//                    contact + sph_stress dispatch, contact.wgsl; no CPU twin: no CPU stage
//                    dispatches, and the GPU sets it to the surface's alone before the first)
// CPU twin: src/cpu/compact.rs.
#import index
#import particles

@group(0) @binding(0) var<uniform> particle_params: ParticleParams;
@group(0) @binding(1) var<storage, read> particle_mode: array<u32>;
@group(0) @binding(2) var<storage, read_write> dynamic_scan: array<u32>;
@group(0) @binding(3) var<storage, read_write> stress_scan: array<u32>;
@group(0) @binding(4) var<storage, read_write> force_scan: array<u32>;
@group(0) @binding(5) var<storage, read_write> dynamic_list: array<u32>;
@group(0) @binding(6) var<storage, read_write> stress_list: array<u32>;
@group(0) @binding(7) var<storage, read_write> force_list: array<u32>;
@group(0) @binding(8) var<storage, read_write> particle_counts: array<u32>;
@group(0) @binding(9) var<storage, read_write> particle_dispatch: array<u32>;

const WORKGROUP: u32 = 64u;
// Workgroups per dimension every adapter allows (WebGPU's default limit).
const MAX_GROUPS: u32 = 65535u;

fn bit(p: u32, b: u32) -> u32 {
    if p < particle_params.n_particles && (particle_mode[p] & b) != 0u {
        return 1u;
    }
    return 0u;
}

@compute @workgroup_size(64)
fn compact_mark(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = linear_index(gid, nwg, WORKGROUP);
    if p > particle_params.n_particles {
        return;
    }
    dynamic_scan[p] = bit(p, MODE_DYNAMIC);
    stress_scan[p] = bit(p, MODE_IN_S);
    force_scan[p] = bit(p, MODE_IN_F);
}

@compute @workgroup_size(64)
fn compact_scatter(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = linear_index(gid, nwg, WORKGROUP);
    if p >= particle_params.n_particles {
        return;
    }
    let mode = particle_mode[p];
    if (mode & MODE_DYNAMIC) != 0u {
        dynamic_list[dynamic_scan[p]] = p;
    }
    if (mode & MODE_IN_S) != 0u {
        stress_list[stress_scan[p]] = p;
    }
    if (mode & MODE_IN_F) != 0u {
        force_list[force_scan[p]] = p;
    }
}

fn write_args(k: u32, count: u32) {
    let groups = (count + WORKGROUP - 1u) / WORKGROUP;
    var x = groups;
    var y = 1u;
    if groups > MAX_GROUPS {
        x = MAX_GROUPS;
        y = (groups + MAX_GROUPS - 1u) / MAX_GROUPS;
    }
    particle_dispatch[3u * k] = x;
    particle_dispatch[3u * k + 1u] = y;
    particle_dispatch[3u * k + 2u] = 1u;
}

@compute @workgroup_size(1)
fn compact_args() {
    let n = particle_params.n_particles;
    let counts = vec3<u32>(dynamic_scan[n], stress_scan[n], force_scan[n]);
    particle_counts[0] = counts.x;
    particle_counts[1] = counts.y;
    particle_counts[2] = counts.z;
    particle_counts[3] = 0u;
    write_args(0u, counts.x);
    write_args(1u, counts.y);
    write_args(2u, counts.z);
    write_args(3u, max(counts.y, particle_params.n_surface));
}
