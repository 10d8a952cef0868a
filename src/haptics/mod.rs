//! Haptic interaction on the CPU side: devices, the 1 kHz servo thread, the virtual
//! coupling, force shaping, the passivity observer, and the lock-free hand-off to the
//! physics thread (DESIGN §7). Nothing here touches wgpu.
//!
//! ```text
//! device ──pose──► servo thread (1 kHz, absolute deadlines)          physics thread
//!                   proxy = coupling(local model, pose) ──ToolCommand slot──► tool input
//!                   force = shape(coupling force) ──► device    ◄──LocalModel slot── after each batch
//! ```
//!
//! A haptic session, as `palpate haptic` runs it:
//!
//! ```no_run
//! use palpate::haptics::{self, DeviceSpec, LocalModel, LoopClock, ServoConfig};
//! # fn main() -> palpate::Result<()> {
//! let spec = DeviceSpec::by_name("touch")?;
//! let device = haptics::DeviceArg::parse("null")?.open(spec)?;
//! let (servo_end, mut physics) = haptics::link(LoopClock::new());
//! let servo = haptics::spawn_servo(device, servo_end, ServoConfig::new(spec).with_duration(2.0))?;
//! while !servo.is_finished() {
//!     let (tool, _seq) = physics.tool();     // place the simulated tool at home + tool.position
//!     // … run a batch, read back the tool force f0 and stiffness K …
//!     physics.publish(LocalModel { proxy: tool.position, stamp: tool.stamp, ..Default::default() });
//! #   std::thread::sleep(std::time::Duration::from_millis(1));
//! }
//! let report = servo.join()?;
//! report.log.write_csv(std::path::Path::new("out/haptic.csv"))?;
//! println!("{}", serde_json::to_string(&report.stats).unwrap());
//! # Ok(()) }
//! ```
//!
//! Frames and units: positions are metres in the device frame relative to the tool's home
//! (the physics side adds the scene's home), forces newtons (the force the tissue exerts on
//! the tool; the device applies the same to the hand), times seconds on the [`LoopClock`].

pub mod coupling;
pub mod device;
pub mod devices;
pub mod link;
pub mod log;
pub mod model;
pub mod observer;
pub mod pose_gate;
pub mod protocol;
pub mod servo;
pub mod shaping;
pub mod slot;

pub use device::{DeviceReading, DeviceSpec, DeviceStats, HapticDevice, VelocityEstimator};
pub use devices::{open_device, DeviceArg, NullDevice, ScriptedDevice, Trajectory, UdpDevice};
pub use link::{link, PhysicsLink, ServoLink};
pub use log::{TickLog, TickRecord};
pub use model::{ForceCommand, LocalModel, LoopClock, ToolCommand};
pub use servo::{
    run_servo, spawn_servo, RenderMode, ServoConfig, ServoCore, ServoHandle, ServoReport,
    ServoStats,
};
pub use slot::{LatestValue, Publisher, Reader};
