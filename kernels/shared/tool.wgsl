// The tool (a rigid sphere) and its contact with the surface. Mirrors src/contact.rs
// (a test checks sizes and offsets against naga's layout of these structs).
struct ToolParams {
    radius: f32,          // m
    stiffness: f32,       // penalty per unit area, Pa/m
    damping: f32,         // damping per unit area, Pa s/m
    n_surface: u32,       // surface vertices
    n_particles: u32,     // particles (their contacts count too), 0 without particles
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// Per batch: the tool moves linearly from `start` to `end` over `steps` steps.
struct ToolInput {
    start: vec3<f32>,     // m
    steps: u32,
    end: vec3<f32>,       // m
    _pad: u32,
}

// The tool's position after the last tool_motion, and the steps of the batch done.
struct ToolState {
    position: vec3<f32>,  // m
    step: u32,
}

// Where the tool is once the batch's steps are done (tool_motion counted them in
// state.step): `end` after the whole move; after a slice of it (a diverged batch replayed one
// step at a time), the move's position at that step, as tool_motion would place it.
fn tool_batch_end(input: ToolInput, state: ToolState) -> vec3<f32> {
    if state.step >= input.steps {
        return input.end;
    }
    return tool_at_step(input, state.step);
}

// The tool's centre at step k of the move: start + (end - start) k / steps.
fn tool_at_step(input: ToolInput, k: u32) -> vec3<f32> {
    return input.start + (input.end - input.start) * (f32(k) / f32(max(input.steps, 1u)));
}

const NOT_ON_SURFACE: u32 = 0xffffffffu;

// Slots of the 16-float tool report (src/contact.rs `report`).
const REPORT_FORCE: u32 = 0u;
const REPORT_STIFFNESS: u32 = 3u;
const REPORT_MAX_PENETRATION: u32 = 12u;
const REPORT_CONTACTS: u32 = 13u;
const REPORT_AREA: u32 = 14u;

// Penalty force on a surface point at x (velocity v) from the tool at c (velocity vc), and
// whether it touches: f = A (k d - b min(0, (v - vc).n)) n, d = R - |x - c|, n = (x - c)/|x - c|.
struct Contact {
    force: vec3<f32>,
    normal: vec3<f32>,
    distance: f32,
    penetration: f32,
}

fn contact_force(p: ToolParams, x: vec3<f32>, v: vec3<f32>, c: vec3<f32>, vc: vec3<f32>, area: f32) -> Contact {
    let y = x - c;
    let r = length(y);
    var out = Contact(vec3<f32>(0.0), vec3<f32>(0.0), r, 0.0);
    let d = p.radius - r;
    if d > 0.0 && r > 0.0 {
        let n = y / r;
        let approach = min(0.0, dot(v - vc, n));
        out.force = n * (area * (p.stiffness * d - p.damping * approach));
        out.normal = n;
        out.penetration = d;
    }
    return out;
}
