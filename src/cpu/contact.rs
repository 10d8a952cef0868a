//! CPU twin of `kernels/contact.wgsl` and of the shared `contact_force` in
//! `kernels/shared/tool.wgsl`: per surface vertex, the penalty force of the tool (see
//! [`crate::contact`] for the formula).

use super::{load3, store3};
use crate::contact::{ToolInput, ToolParams, ToolState};
use crate::params::StepParams;
use glam::Vec3;

/// The contact of one surface point with the tool (twin of WGSL `Contact`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Contact {
    /// Force on the surface point, N.
    pub force: Vec3,
    /// Unit normal from the tool centre to the point (zero without contact).
    pub normal: Vec3,
    /// Distance from the tool centre, m.
    pub distance: f32,
    /// Penetration R − distance (0 without contact), m.
    pub penetration: f32,
}

/// f = A (k d − b min(0, (v − v_c)·n)) n for d = R − |x − c| > 0 (twin of WGSL
/// `contact_force`).
pub fn contact_force(p: &ToolParams, x: Vec3, v: Vec3, c: Vec3, vc: Vec3, area: f32) -> Contact {
    let y = x - c;
    let r = y.length();
    let mut out = Contact {
        distance: r,
        ..Default::default()
    };
    let d = p.radius - r;
    if d > 0.0 && r > 0.0 {
        let n = y / r;
        let approach = 0.0f32.min((v - vc).dot(n));
        out.force = n * (area * (p.stiffness * d - p.damping * approach));
        out.normal = n;
        out.penetration = d;
    }
    out
}

/// Where the tool is once the batch's steps are done (twin of `tool_batch_end` in
/// `kernels/shared/tool.wgsl`): `end` after the whole move, else the move's position at
/// `state.step`, start + (end − start)·step/steps, as `tool_motion` places it.
pub fn tool_batch_end(tool_input: &ToolInput, state: &crate::contact::ToolState) -> Vec3 {
    if state.step >= tool_input.steps {
        return Vec3::from_array(tool_input.end);
    }
    super::tool_motion::tool_at_step(tool_input, state.step)
}

/// The tool's velocity during a batch, (to − from)/(steps·dt).
pub fn tool_velocity(params: &StepParams, tool_input: &ToolInput) -> Vec3 {
    (Vec3::from_array(tool_input.end) - Vec3::from_array(tool_input.start))
        / (tool_input.steps.max(1) as f32 * params.dt)
}

/// Per surface vertex s: `contact_forces[s]` = the tool's penalty force on vertex
/// `surface_vertices[s]` at x = X + u (its area scaled by `contact_weight`, the `PARTICLES`
/// variant).
#[allow(clippy::too_many_arguments)]
pub fn contact(
    params: &StepParams,
    tool_params: &ToolParams,
    tool_input: &ToolInput,
    tool_state: &ToolState,
    surface_vertices: &[u32],
    surface_area: &[f32],
    rest_positions: &[f32],
    displacements: &[f32],
    velocities: &[f32],
    contact_forces: &mut [f32],
    contact_weight: Option<&[f32]>,
) {
    let vc = tool_velocity(params, tool_input);
    let c = Vec3::from_array(tool_state.position);
    super::par::for_each_chunk::<3>(contact_forces, tool_params.n_surface as usize, |s, out| {
        let i = surface_vertices[s] as usize;
        let x = load3(rest_positions, i) + load3(displacements, i);
        let v = load3(velocities, i);
        let area = surface_area[s] * contact_weight.map_or(1.0, |w| w[i]);
        let f = contact_force(tool_params, x, v, c, vc, area);
        store3(out, 0, f.force);
    });
}
