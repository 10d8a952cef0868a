//! CPU twin of `kernels/tool_motion.wgsl`: the tool's centre for step k of a batch,
//! start + (end − start)·k/steps.

use crate::contact::{ToolInput, ToolState};
use glam::Vec3;

/// One thread: place the tool for the next step of the batch and count the step.
pub fn tool_motion(tool_input: &ToolInput, tool_state: &mut ToolState) {
    let k = tool_state.step;
    tool_state.position = tool_at_step(tool_input, k).to_array();
    tool_state.step = k + 1;
}

/// The tool's centre at step k of the move, start + (end − start)·k/steps (twin of
/// `tool_at_step` in `kernels/shared/tool.wgsl`).
pub fn tool_at_step(tool_input: &ToolInput, k: u32) -> Vec3 {
    let s = k as f32 / tool_input.steps.max(1) as f32;
    let (from, to) = (
        Vec3::from_array(tool_input.start),
        Vec3::from_array(tool_input.end),
    );
    from + (to - from) * s
}
