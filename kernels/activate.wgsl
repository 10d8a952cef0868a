// Stage (every `activation_interval` steps): which particles are dynamic, which carry SPH
// stress (set S) and which receive SPH force (set F), the tets' energy weights and the
// vertices' lumped masses. Entry points, in order:
//   activate                  per particle: the mode state machine (below); raises
//                             activation_gate[0] when a particle became or stopped being
//                             dynamic (the sets' marks of the last update stay until then)
//   activate_gate             one thread: the gated passes' indirect arguments, each pass's
//                             full grid (activation_full_args) when the gate is raised, else no
//                             workgroup; lowers the gate, keeps its verdict in
//                             activation_gate[1] for the relump and counts full / skipped
//   activate_clear_sets       (gated) per particle: clears IN_S and IN_F
//   activate_stress_set       (gated) per dynamic particle: marks itself and its neighbours IN_S
//   activate_force_set        (gated) per particle in S: marks itself and its neighbours IN_F
//   [compact.wgsl and scan.wgsl: the lists, gated]
//   activate_tet_weights      (gated) per tet: 1 - phi_e, phi_e = (its particles in S)/(its
//                             particles)
//   activate_relump           per vertex: mass = core + sum w_i m_p over non-dynamic hosted
//                             particles; velocity keeps the momentum of released particles;
//                             vertices with no mass left take their dynamic particles'
//                             velocity field at their rest place (kinematic_velocity); the
//                             short list of its force-set embedded particles' slots for
//                             gather_coupled (coupled_slots from its CSR offset, coupled_count);
//                             after a skipped update only the vertices with no mass
//                             (NODE_MASSLESS) are relumped: every other product is a function
//                             of which particles are dynamic, and a vertex with mass keeps its
//                             velocity exactly when no particle was released (a fixed one is at
//                             rest: integrate keeps it there)
// Everything the gated passes write (the marks, lists, counts, dispatch arguments and tet
// weights) depends only on which particles are dynamic, so skipping them when no particle
// changed is the full update bit for bit. The host raises the gate after it writes any buffer
// (restore, write_state, write_f32), and the gate starts raised.
// Mode machine (a particle at distance d from the tool's surface; PINNED never moves):
//   embedded or blending, d < activation radius -> DYNAMIC at its embedded position and
//     velocity (its momentum leaves the host vertices exactly);
//   dynamic, d < release radius (activation x hysteresis) -> stays, dwell timer reset (-1:
//     near at the last check);
//   dynamic, farther for `dwell` s (counted from the first check that finds it far, so at
//     least that long) -> BLENDING with offset u_p - embed(u) that fades to zero
//     over `blend` s (no jump), then embedded. The blend clock of a particle in F advances
//     every sub-step in `follow` (a smooth fade where the SPH sees it); of any other, here,
//     by the interval.
// The IN_S/IN_F marks are integer atomic ORs, so the result is the same in any order.
// CPU twin: src/cpu/activate.rs.
#import params
#import index
#import tool
#import particles

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<uniform> particle_params: ParticleParams;
@group(0) @binding(2) var<uniform> tool_params: ToolParams;
@group(0) @binding(3) var<storage, read> tool_state: ToolState;
@group(0) @binding(4) var<storage, read> particle_rest: array<f32>;
@group(0) @binding(5) var<storage, read> particle_host: array<u32>;
@group(0) @binding(6) var<storage, read> particle_weights: array<f32>;
@group(0) @binding(7) var<storage, read> tets: array<vec4<u32>>;
@group(0) @binding(8) var<storage, read_write> displacements: array<f32>;
@group(0) @binding(9) var<storage, read_write> velocities: array<f32>;
@group(0) @binding(10) var<storage, read_write> particle_displacements: array<f32>;
@group(0) @binding(11) var<storage, read_write> particle_velocities: array<f32>;
@group(0) @binding(12) var<storage, read_write> particle_mode: array<atomic<u32>>;
@group(0) @binding(13) var<storage, read_write> particle_timer: array<f32>;
@group(0) @binding(14) var<storage, read_write> particle_offset: array<f32>;
@group(0) @binding(15) var<storage, read> neighbour_offsets: array<u32>;
@group(0) @binding(16) var<storage, read> neighbours: array<u32>;
@group(0) @binding(17) var<storage, read> particle_tet_offsets: array<u32>;
@group(0) @binding(18) var<storage, read_write> tet_weight: array<f32>;
@group(0) @binding(19) var<storage, read> particle_slot_offsets: array<u32>;
@group(0) @binding(20) var<storage, read> particle_slots: array<u32>;
@group(0) @binding(21) var<storage, read> particle_core_mass: array<f32>;
@group(0) @binding(22) var<storage, read> node_fixed: array<u32>;
@group(0) @binding(23) var<storage, read_write> mass: array<f32>;
@group(0) @binding(24) var<storage, read_write> inv_mass: array<f32>;
@group(0) @binding(25) var<storage, read_write> node_flags: array<u32>;
@group(0) @binding(26) var<storage, read> incidence_offsets: array<u32>;
@group(0) @binding(27) var<storage, read> incidence: array<u32>;
@group(0) @binding(28) var<storage, read_write> contact_weight: array<f32>;
@group(0) @binding(29) var<storage, read_write> coupled_slots: array<u32>;
@group(0) @binding(30) var<storage, read_write> coupled_count: array<u32>;
@group(0) @binding(31) var<storage, read_write> coupled_valid: array<u32>;
@group(0) @binding(32) var<storage, read> rest_positions: array<f32>;
// [0] raised (1) by a change, [1] the last verdict, [2] full updates, [3] skipped ones.
@group(0) @binding(33) var<storage, read_write> activation_gate: array<atomic<u32>>;
// Per gated pass, its DispatchIndirectArgs over its whole domain (written once by the host).
@group(0) @binding(34) var<storage, read> activation_full_args: array<u32>;
// Per gated pass, the DispatchIndirectArgs it is launched with.
@group(0) @binding(35) var<storage, read_write> activation_args: array<u32>;

// Pipeline constant: the scene has a tool (else only activation = "all" runs particles).
override TOOL: bool = false;

const WORKGROUP: u32 = 64u;
// Cleared by the mode machine at every update (IN_S and IN_F by activate_clear_sets, when the
// dynamic set changed).
const PER_UPDATE: u32 = MODE_NEAR | MODE_ACTIVATED | MODE_RELEASED;
const SETS: u32 = MODE_IN_S | MODE_IN_F;

fn node_u(i: u32) -> vec3<f32> {
    return vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
}

fn node_v(i: u32) -> vec3<f32> {
    return vec3<f32>(velocities[3u * i], velocities[3u * i + 1u], velocities[3u * i + 2u]);
}

fn particle_u(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_displacements[3u * p], particle_displacements[3u * p + 1u], particle_displacements[3u * p + 2u]);
}

fn particle_v(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_velocities[3u * p], particle_velocities[3u * p + 1u], particle_velocities[3u * p + 2u]);
}

fn particle_x0(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_rest[3u * p], particle_rest[3u * p + 1u], particle_rest[3u * p + 2u]);
}

fn weight(p: u32, c: u32) -> f32 {
    return particle_weights[4u * p + c];
}

// Embedded displacement of particle p: sum w_i u_i over its host's corners.
fn embed_u(p: u32) -> vec3<f32> {
    let t = tets[particle_host[p]];
    return node_u(t.x) * weight(p, 0u) + node_u(t.y) * weight(p, 1u) + node_u(t.z) * weight(p, 2u) + node_u(t.w) * weight(p, 3u);
}

// Embedded velocity of particle p: sum w_i v_i.
fn embed_v(p: u32) -> vec3<f32> {
    let t = tets[particle_host[p]];
    return node_v(t.x) * weight(p, 0u) + node_v(t.y) * weight(p, 1u) + node_v(t.z) * weight(p, 2u) + node_v(t.w) * weight(p, 3u);
}

@compute @workgroup_size(64)
fn activate(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = linear_index(gid, nwg, WORKGROUP);
    if p >= particle_params.n_particles {
        return;
    }
    let last = atomicLoad(&particle_mode[p]);
    // In F since the last update: `follow` advanced its blend clock every sub-step.
    let followed = (last & MODE_IN_F) != 0u;
    var mode = last & ~PER_UPDATE;
    if (mode & MODE_PINNED) != 0u {
        atomicStore(&particle_mode[p], mode);
        return;
    }
    let pp = particle_params;
    var timer = particle_timer[p];
    var offset = vec3<f32>(particle_offset[3u * p], particle_offset[3u * p + 1u], particle_offset[3u * p + 2u]);
    let ue = embed_u(p);
    var blend = 0.0;
    if (mode & MODE_BLENDING) != 0u {
        blend = max(0.0, 1.0 - timer / max(pp.blend, 1e-30));
    }
    var u = ue + offset * blend;
    if (mode & MODE_DYNAMIC) != 0u {
        u = particle_u(p);
    }
    var qualifies = pp.all_active != 0u;
    var keep = qualifies;
    if TOOL && !qualifies {
        let d = length(particle_x0(p) + u - tool_state.position) - tool_params.radius;
        qualifies = d < pp.activation_radius;
        keep = d < pp.release_radius;
    }
    if (mode & MODE_DYNAMIC) != 0u {
        if keep {
            timer = -1.0;
        } else {
            // The dwell clock starts at the first check that finds it far (it may have left
            // just before) and counts the intervals after it.
            timer = select(timer + pp.interval, 0.0, timer < 0.0);
            if timer >= pp.dwell {
                offset = u - ue;
                mode = (mode & ~MODE_DYNAMIC) | MODE_BLENDING | MODE_RELEASED;
                timer = 0.0;
                atomicStore(&activation_gate[0], 1u);
            }
        }
    } else if qualifies {
        let ve = embed_v(p);
        particle_displacements[3u * p] = u.x;
        particle_displacements[3u * p + 1u] = u.y;
        particle_displacements[3u * p + 2u] = u.z;
        particle_velocities[3u * p] = ve.x;
        particle_velocities[3u * p + 1u] = ve.y;
        particle_velocities[3u * p + 2u] = ve.z;
        mode = (mode & ~MODE_BLENDING) | MODE_DYNAMIC | MODE_ACTIVATED;
        timer = -1.0;
        atomicStore(&activation_gate[0], 1u);
        offset = vec3<f32>(0.0);
    } else if (mode & MODE_BLENDING) != 0u {
        if !followed {
            timer += pp.interval;
        }
        if timer >= pp.blend {
            mode = mode & ~MODE_BLENDING;
            offset = vec3<f32>(0.0);
        }
    }
    particle_timer[p] = timer;
    particle_offset[3u * p] = offset.x;
    particle_offset[3u * p + 1u] = offset.y;
    particle_offset[3u * p + 2u] = offset.z;
    atomicStore(&particle_mode[p], mode);
}

@compute @workgroup_size(1)
fn activate_gate() {
    let raised = atomicLoad(&activation_gate[0]);
    let n = arrayLength(&activation_full_args) / 3u;
    for (var k = 0u; k < n; k++) {
        if raised != 0u {
            activation_args[3u * k] = activation_full_args[3u * k];
            activation_args[3u * k + 1u] = activation_full_args[3u * k + 1u];
            activation_args[3u * k + 2u] = activation_full_args[3u * k + 2u];
        } else {
            activation_args[3u * k] = 0u;
            activation_args[3u * k + 1u] = 1u;
            activation_args[3u * k + 2u] = 1u;
        }
    }
    atomicStore(&activation_gate[0], 0u);
    atomicStore(&activation_gate[1], raised);
    if raised != 0u {
        atomicAdd(&activation_gate[2], 1u);
    } else {
        atomicAdd(&activation_gate[3], 1u);
    }
}

@compute @workgroup_size(64)
fn activate_clear_sets(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = linear_index(gid, nwg, WORKGROUP);
    if p >= particle_params.n_particles {
        return;
    }
    atomicAnd(&particle_mode[p], ~SETS);
}

@compute @workgroup_size(64)
fn activate_stress_set(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = linear_index(gid, nwg, WORKGROUP);
    if p >= particle_params.n_particles {
        return;
    }
    if (atomicLoad(&particle_mode[p]) & MODE_DYNAMIC) == 0u {
        return;
    }
    atomicOr(&particle_mode[p], MODE_IN_S);
    for (var k = neighbour_offsets[p]; k < neighbour_offsets[p + 1u]; k++) {
        atomicOr(&particle_mode[neighbours[k]], MODE_IN_S);
    }
}

@compute @workgroup_size(64)
fn activate_force_set(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = linear_index(gid, nwg, WORKGROUP);
    if p >= particle_params.n_particles {
        return;
    }
    if (atomicLoad(&particle_mode[p]) & MODE_IN_S) == 0u {
        return;
    }
    atomicOr(&particle_mode[p], MODE_IN_F);
    for (var k = neighbour_offsets[p]; k < neighbour_offsets[p + 1u]; k++) {
        atomicOr(&particle_mode[neighbours[k]], MODE_IN_F);
    }
}

@compute @workgroup_size(64)
fn activate_tet_weights(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = linear_index(gid, nwg, WORKGROUP);
    if e >= params.n_tets {
        return;
    }
    let first = particle_tet_offsets[e];
    let last = particle_tet_offsets[e + 1u];
    var in_s = 0u;
    for (var p = first; p < last; p++) {
        if (atomicLoad(&particle_mode[p]) & MODE_IN_S) != 0u {
            in_s += 1u;
        }
    }
    var w = 1.0;
    if last > first {
        w = 1.0 - f32(in_s) / f32(last - first);
    }
    tet_weight[e] = w;
}

// A vertex with no mass left moves with its dynamic particles: the weighted linear least-squares
// fit v(d) = a + G d of their velocities over their rest offsets d = (X_p - X_i)/spacing,
// weights b = w m_p, at d = 0: G = Cov(v, d) Cov(d, d)^-1, a = mean(v) - G mean(d). Exact for a
// rigid or affine velocity field; the mean where the offsets do not span three dimensions
// (tr Cov(d, d) <= 1e-4 tr E[d d^T] or det Cov(d, d) <= 1e-3 (trace/3)^3), zero without
// particles. CPU twin: KinematicFit.
fn kinematic_velocity(b: f32, bd: vec3<f32>, bv: vec3<f32>, bdd: mat3x3<f32>, bvd: mat3x3<f32>) -> vec3<f32> {
    if !(b > 0.0) {
        return vec3<f32>(0.0);
    }
    let inv_b = 1.0 / b;
    let d_mean = bd * inv_b;
    let v_mean = bv * inv_b;
    let cov_dd = bdd * inv_b - mat3x3<f32>(d_mean * d_mean.x, d_mean * d_mean.y, d_mean * d_mean.z);
    let cov_vd = bvd * inv_b - mat3x3<f32>(v_mean * d_mean.x, v_mean * d_mean.y, v_mean * d_mean.z);
    let c0 = cov_dd[0];
    let c1 = cov_dd[1];
    let c2 = cov_dd[2];
    let t0 = cross(c1, c2);
    let t1 = cross(c2, c0);
    let t2 = cross(c0, c1);
    let det = dot(c2, t2);
    let trace = (c0.x + c1.y + c2.z) / 3.0;
    // The spread must stand above the rounding of E[d d^T] - mean(d) mean(d)^T.
    let second_moment = (bdd[0].x + bdd[1].y + bdd[2].z) * inv_b / 3.0;
    if !(trace > 1e-4 * second_moment && det > 1e-3 * trace * trace * trace) {
        return v_mean;
    }
    let inv = transpose(mat3x3<f32>(t0, t1, t2)) * (1.0 / det);
    return v_mean - cov_vd * (inv * d_mean);
}

@compute @workgroup_size(64)
fn activate_relump(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg, WORKGROUP);
    if i >= params.n_vertices {
        return;
    }
    // A skipped update: only a vertex with no mass has anything new (its particles' velocity).
    if atomicLoad(&activation_gate[1]) == 0u && (node_flags[i] & NODE_MASSLESS) == 0u {
        return;
    }
    let mp = particle_params.mass;
    var m = particle_core_mass[i];
    var m_released = 0.0;
    var p_released = vec3<f32>(0.0);
    // Kinematic fit sums (see kinematic_velocity): sum b, b d, b v, b d d^T, b v d^T.
    var b_sum = 0.0;
    var bd_sum = vec3<f32>(0.0);
    var bv_sum = vec3<f32>(0.0);
    var bdd_sum = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    var bvd_sum = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    let x_i = vec3<f32>(rest_positions[3u * i], rest_positions[3u * i + 1u], rest_positions[3u * i + 2u]);
    var coupled = false;
    var released = false;
    let first = particle_slot_offsets[i];
    var listed = 0u;
    for (var k = first; k < particle_slot_offsets[i + 1u]; k++) {
        let slot = particle_slots[k];
        let p = slot / 4u;
        let w = particle_weights[slot];
        let mode = atomicLoad(&particle_mode[p]);
        if (mode & MODE_DYNAMIC) == 0u {
            m += w * mp;
            if (mode & MODE_RELEASED) != 0u {
                released = true;
                m_released += w * mp;
                p_released += particle_v(p) * (w * mp);
            }
            if (mode & MODE_IN_F) != 0u {
                coupled = true;
                coupled_slots[first + listed] = slot;
                listed += 1u;
            }
        } else {
            let beta = w * mp;
            let d = (particle_x0(p) - x_i) / particle_params.spacing;
            let vp = particle_v(p);
            b_sum += beta;
            bd_sum += d * beta;
            bv_sum += vp * beta;
            let bd = d * beta;
            bdd_sum += mat3x3<f32>(d * bd.x, d * bd.y, d * bd.z);
            bvd_sum += mat3x3<f32>(vp * bd.x, vp * bd.y, vp * bd.z);
        }
    }
    coupled_count[i] = listed;
    coupled_valid[0] = 1u;
    mass[i] = m;
    var v = node_v(i);
    var w_inv = 0.0;
    if node_fixed[i] != 0u {
        v = vec3<f32>(0.0);
    } else if m > 0.0 {
        w_inv = 1.0 / m;
        // Without released particles v stays exactly (v (m - 0)/m would round it).
        if released {
            v = (v * (m - m_released) + p_released) / m;
        }
    } else {
        // No mass left: the vertex is carried (kinematically) by its dynamic particles.
        w_inv = -1.0;
        v = kinematic_velocity(b_sum, bd_sum, bv_sum, bdd_sum, bvd_sum);
    }
    inv_mass[i] = w_inv;
    velocities[3u * i] = v.x;
    velocities[3u * i + 1u] = v.y;
    velocities[3u * i + 2u] = v.z;
    var flags = 0u;
    if coupled {
        flags = NODE_COUPLED;
    }
    if w_inv < 0.0 {
        flags |= NODE_MASSLESS;
    }
    node_flags[i] = flags;
    var cw = 1.0;
    for (var k = incidence_offsets[i]; k < incidence_offsets[i + 1u]; k++) {
        cw = min(cw, tet_weight[incidence[k] / 4u]);
    }
    contact_weight[i] = cw;
}
