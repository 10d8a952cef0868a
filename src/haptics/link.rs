//! The two latest-value slots between the servo and the physics thread, bundled per side.
//!
//! | slot | written by | read by |
//! |---|---|---|
//! | [`ToolCommand`] | servo, every tick | physics, at each batch start |
//! | [`LocalModel`] | physics, after each batch | servo, every tick |

use super::model::{LocalModel, LoopClock, ToolCommand};
use super::slot::{LatestValue, Publisher, Reader};

/// Reader handles each slot allows (the servo or physics thread, plus a few observers such
/// as a viewer).
pub const MAX_READERS: usize = 4;

/// The servo thread's end: publishes tool commands, reads the local model.
pub struct ServoLink {
    /// The tool command slot (written by the servo).
    pub tool: Publisher<ToolCommand>,
    /// The local model slot (read by the servo).
    pub model: Reader<LocalModel>,
    /// The shared clock.
    pub clock: LoopClock,
}

/// The physics thread's end: reads tool commands, publishes the local model.
pub struct PhysicsLink {
    tool: Reader<ToolCommand>,
    model: Publisher<LocalModel>,
    clock: LoopClock,
}

/// A pair of connected ends sharing `clock`.
pub fn link(clock: LoopClock) -> (ServoLink, PhysicsLink) {
    let (tool_pub, tool_reader) = LatestValue::<ToolCommand>::channel(MAX_READERS);
    let (model_pub, model_reader) = LatestValue::<LocalModel>::channel(MAX_READERS);
    (
        ServoLink {
            tool: tool_pub,
            model: model_reader,
            clock,
        },
        PhysicsLink {
            tool: tool_reader,
            model: model_pub,
            clock,
        },
    )
}

impl PhysicsLink {
    /// The newest tool command and its sequence number (0: the servo has not ticked yet, the
    /// command is the default at the origin).
    pub fn tool(&mut self) -> (ToolCommand, u64) {
        self.tool.read()
    }

    /// Publish the model computed from a tool command; set `model.stamp` to that command's
    /// `stamp` so the servo sees the round-trip age. Returns its sequence number.
    pub fn publish(&mut self, model: LocalModel) -> u64 {
        self.model.publish(model)
    }

    /// The shared clock (seconds).
    pub fn clock(&self) -> LoopClock {
        self.clock
    }

    /// Another reader of the tool slot (a viewer, a logger), if handles remain.
    pub fn tool_reader(&self) -> Option<Reader<ToolCommand>> {
        self.tool.try_clone()
    }

    /// A reader of the model slot (a viewer, a logger), if handles remain.
    pub fn model_reader(&self) -> Option<Reader<LocalModel>> {
        self.model.reader()
    }
}
