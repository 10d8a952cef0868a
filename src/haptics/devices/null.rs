//! `null`: a device held still at the origin (the tool home). Forces go nowhere.

use crate::haptics::device::{DeviceReading, DeviceSpec, HapticDevice};
use crate::haptics::model::ForceCommand;

/// A device at rest at the origin, always fresh; useful to time the loop.
#[derive(Clone, Debug)]
pub struct NullDevice {
    spec: DeviceSpec,
    /// The last force sent, N (for tests).
    pub last_command: ForceCommand,
}

impl NullDevice {
    /// A null device with `spec`.
    pub fn new(spec: DeviceSpec) -> Self {
        NullDevice {
            spec,
            last_command: ForceCommand::default(),
        }
    }
}

impl HapticDevice for NullDevice {
    fn spec(&self) -> DeviceSpec {
        self.spec
    }
    fn describe(&self) -> String {
        "null".into()
    }
    fn read(&mut self, _now: f64) -> DeviceReading {
        DeviceReading {
            fresh: true,
            ..Default::default()
        }
    }
    fn send(&mut self, _now: f64, command: &ForceCommand) {
        self.last_command = *command;
    }
}
