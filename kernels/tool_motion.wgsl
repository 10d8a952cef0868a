// Stage: the tool's centre for this step of the batch. Step k (0-based) of a batch of
// `steps` steps puts the tool at start + (end - start) k / steps; the batch's last state (after
// its last step) has the tool at `to`. One thread. CPU twin: src/cpu/tool_motion.rs.
#import tool

@group(0) @binding(0) var<uniform> tool_input: ToolInput;
@group(0) @binding(1) var<storage, read_write> tool_state: ToolState;

@compute @workgroup_size(1)
fn tool_motion() {
    let k = tool_state.step;
    tool_state.position = tool_at_step(tool_input, k);
    tool_state.step = k + 1u;
}
