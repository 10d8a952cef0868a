//! Shared by the examples: press a scene's tool along its path and hold it.

use palpate::stepper::{BatchInput, Stepper};
use palpate::Scene;

/// Move the scene's tool along its path to `hold_time` in batches of 10 steps, then hold it
/// there for one batch; where it is held.
pub fn press(
    stepper: &mut dyn Stepper,
    scene: &Scene,
    dt: f64,
    hold_time: f64,
) -> palpate::error::Result<Option<glam::DVec3>> {
    let tool = scene.tool.as_ref();
    let batch = 10u32;
    let mut t = 0.0;
    let mut from = tool.map(|t| t.position_at(0.0));
    while t < hold_time {
        let to = tool.map(|tl| tl.position_at((t + batch as f64 * dt).min(hold_time)));
        stepper.submit(
            batch,
            &BatchInput {
                tool: from.zip(to),
                tool_slice: None,
            },
        )?;
        stepper.wait()?;
        from = to;
        t += batch as f64 * dt;
    }
    // One batch holding the tool still: the profile replays the last batch's move past its
    // end (the step count runs on), which for a moving tool would carry it on along the path.
    stepper.submit(
        batch,
        &BatchInput {
            tool: from.zip(from),
            tool_slice: None,
        },
    )?;
    stepper.wait()?;
    Ok(from)
}
