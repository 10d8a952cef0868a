// Linear thread index for 1-D work dispatched as a 2-D grid of workgroups (x up to 65535),
// so that meshes of more than 65535 * workgroup_size elements can be covered.
fn linear_index(gid: vec3<u32>, nwg: vec3<u32>, workgroup_size: u32) -> u32 {
    return gid.y * nwg.x * workgroup_size + gid.x;
}

// True when every component is finite: the exponent bits are not all ones.
// (WGSL lets compilers assume no NaN/Inf, so `x != x` is not a reliable test.)
fn finite3(v: vec3<f32>) -> bool {
    let e = bitcast<vec3<u32>>(v) & vec3<u32>(0x7f800000u);
    return all(e != vec3<u32>(0x7f800000u));
}

// The flat index of this workgroup in a 2-D grid of workgroups. Kernels that give each item
// LANES threads (const ITEMS_PER_WORKGROUP, reflected by the host for its dispatches) take item
// workgroup_index * ITEMS_PER_WORKGROUP + local % ITEMS_PER_WORKGROUP, lane local /
// ITEMS_PER_WORKGROUP: the lanes of an item sit in different subgroups, and the items of a
// subgroup are consecutive, as with one thread per item.
fn workgroup_index(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.y * nwg.x + wid.x;
}
