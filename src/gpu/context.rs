//! The wgpu context: instance, adapter choice, device with the adapter's own limits, and
//! capture of asynchronous wgpu errors so they surface as [`PalpateError::Gpu`].
//!
//! Adapter choice: a hardware GPU first (discrete, integrated, virtual), then a software one
//! (Vulkan lavapipe, llvmpipe through GL). `PALPATE_BACKEND` (`vulkan`, `gl`, `metal`,
//! `dx12`, `all`) limits the backends, among those the build has (Vulkan and GL;
//! `Cargo.toml`'s wgpu features); `PALPATE_ADAPTER` picks an adapter whose name contains the
//! given text.

use crate::error::{PalpateError, Result};
use std::sync::{Arc, Mutex};

/// A headless device and queue. A clone shares the device, the queue and the error sink.
#[derive(Clone)]
pub struct GpuContext {
    /// The chosen adapter.
    pub adapter: wgpu::Adapter,
    /// Its description.
    pub info: wgpu::AdapterInfo,
    /// The device, created with the adapter's full limits.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The device's limits (= the adapter's).
    pub limits: wgpu::Limits,
    errors: Arc<Mutex<Vec<CapturedError>>>,
}

/// An uncaptured wgpu error: its first line and the thread whose call raised it.
#[derive(Debug)]
struct CapturedError {
    message: String,
    thread: std::thread::ThreadId,
    thread_name: Option<String>,
}

/// Backends named by `PALPATE_BACKEND` (default: all compiled in); one this build lacks (the
/// crate compiles wgpu's Vulkan and GL backends only, `Cargo.toml`) is an error naming those
/// it has.
pub fn backends_from_env() -> Result<wgpu::Backends> {
    backends_named(std::env::var("PALPATE_BACKEND").ok().as_deref())
}

/// [`backends_from_env`] for the value `name`.
fn backends_named(name: Option<&str>) -> Result<wgpu::Backends> {
    let wanted = match name {
        None | Some("") | Some("all") => return Ok(wgpu::Backends::all()),
        Some("vulkan") => wgpu::Backends::VULKAN,
        Some("gl") => wgpu::Backends::GL,
        Some("metal") => wgpu::Backends::METAL,
        Some("dx12") => wgpu::Backends::DX12,
        Some(other) => {
            return Err(PalpateError::Usage(format!(
                "PALPATE_BACKEND='{other}' is not one of vulkan, gl, metal, dx12, all"
            )))
        }
    };
    let built = wgpu::Instance::enabled_backend_features();
    if !built.contains(wanted) {
        return Err(PalpateError::Usage(format!(
            "PALPATE_BACKEND='{}': this build of palpate has no {} backend (it has {}; the wgpu features in Cargo.toml choose them)",
            name.unwrap_or_default(),
            backend_names(wanted),
            match backend_names(built) {
                b if b.is_empty() => "none".to_string(),
                b => b,
            }
        )));
    }
    Ok(wanted)
}

/// The process's one wgpu instance for `backends`, made on first use and shared by every
/// context after (an instance is a handle: clones share it). On an NVIDIA H200 (driver
/// 580.159.04, 2026-11-27) a test binary whose 8 threads each made their own instance and
/// device hung in 6 of 10 runs and in none of 8 on one thread; drivers are known to hang
/// when instances are enumerated or torn down from several threads at once (the same
/// pattern on NVIDIA GB10, paiml/aprender#2063), so one instance per process, and devices
/// opened one at a time ([`DEVICE_OPEN`]).
fn instance(backends: wgpu::Backends) -> wgpu::Instance {
    static INSTANCES: Mutex<Vec<(wgpu::Backends, wgpu::Instance)>> = Mutex::new(Vec::new());
    let mut made = INSTANCES
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    if let Some((_, i)) = made.iter().find(|(b, _)| *b == backends) {
        return i.clone();
    }
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = backends;
    desc.flags = instance_flags(cfg!(windows));
    let i = wgpu::Instance::new(desc);
    made.push((backends, i.clone()));
    i
}

/// The instance's flags: wgpu's defaults for the build, without `VALIDATION_INDIRECT_CALL`
/// unless `d3d12` (a target that may pick Direct3D 12, where `@builtin(num_workgroups)`
/// reads 0 in an indirect dispatch without it), then the `WGPU_*` environment variables
/// (`WGPU_VALIDATION_INDIRECT_CALL=1` turns it back on).
///
/// That validation, on by default in release builds, puts a one-workgroup compute pass and
/// its barriers before every indirect dispatch, to clamp arguments a kernel wrote. Every
/// particle stage is dispatched indirectly (several a step, and the activation's gated
/// passes), and every argument they read is valid by construction: `compact_args` splits
/// its grid at 65,535 workgroups (the smallest per-dimension limit an adapter may have),
/// `activate_gate` copies grids made with the device's own limit
/// (`kernel::grid_for`) or writes (0, 1, 1), and the buffers start at (0, 1, 1) or zero.
pub fn instance_flags(d3d12: bool) -> wgpu::InstanceFlags {
    without_indirect_validation(wgpu::InstanceFlags::default(), d3d12).with_env()
}

/// `flags` without `VALIDATION_INDIRECT_CALL` unless `d3d12` ([`instance_flags`]).
fn without_indirect_validation(flags: wgpu::InstanceFlags, d3d12: bool) -> wgpu::InstanceFlags {
    let mut flags = flags;
    if !d3d12 {
        flags.remove(wgpu::InstanceFlags::VALIDATION_INDIRECT_CALL);
    }
    flags
}

/// Held while a device is opened: one at a time in the process (see [`instance`]).
static DEVICE_OPEN: Mutex<()> = Mutex::new(());

/// Rank for adapter preference: lower is better.
fn rank(info: &wgpu::AdapterInfo) -> (u8, u8) {
    let kind = match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    };
    let backend = match info.backend {
        wgpu::Backend::Vulkan | wgpu::Backend::Metal | wgpu::Backend::Dx12 => 0,
        _ => 1,
    };
    (kind, backend)
}

/// Every adapter that can run compute shaders, best first. Without `PALPATE_BACKEND`, the
/// native backends (Vulkan; Metal and DX12 where a build has them) are tried first and GL
/// only when they offer none.
pub fn list_adapters() -> Result<Vec<wgpu::Adapter>> {
    let from_env = std::env::var("PALPATE_BACKEND").is_ok_and(|v| !v.is_empty());
    let backends = backends_from_env()?;
    let mut adapters = enumerate(backends - wgpu::Backends::GL);
    if adapters.is_empty() || (from_env && backends.contains(wgpu::Backends::GL)) {
        adapters.extend(enumerate(wgpu::Backends::GL & backends));
    }
    adapters.sort_by_key(|a| rank(&a.get_info()));
    Ok(adapters)
}

fn enumerate(backends: wgpu::Backends) -> Vec<wgpu::Adapter> {
    if backends.is_empty() {
        return Vec::new();
    }
    let inst = instance(backends);
    pollster::block_on(inst.enumerate_adapters(backends))
        .into_iter()
        .filter(|a| {
            a.get_downlevel_capabilities()
                .flags
                .contains(wgpu::DownlevelFlags::COMPUTE_SHADERS)
        })
        .collect()
}

/// The adapters `PALPATE_ADAPTER` allows (all of [`list_adapters`] when it is unset or
/// empty: those whose name contains its text, case-insensitively), in the same order.
pub fn allowed_adapters() -> Result<Vec<wgpu::Adapter>> {
    let mut adapters = list_adapters()?;
    if let Some(want) = adapter_filter() {
        adapters.retain(|a| {
            a.get_info()
                .name
                .to_lowercase()
                .contains(&want.to_lowercase())
        });
    }
    Ok(adapters)
}

/// `backends` as the names a user reads ("Vulkan, GL, Metal, DX12, WebGPU").
fn backend_names(backends: wgpu::Backends) -> String {
    [
        (wgpu::Backends::VULKAN, "Vulkan"),
        (wgpu::Backends::GL, "GL"),
        (wgpu::Backends::METAL, "Metal"),
        (wgpu::Backends::DX12, "DX12"),
        (wgpu::Backends::BROWSER_WEBGPU, "WebGPU"),
    ]
    .iter()
    .filter(|(b, _)| backends.contains(*b))
    .map(|(_, name)| *name)
    .collect::<Vec<_>>()
    .join(", ")
}

/// The text of `PALPATE_ADAPTER`, when set and not empty.
pub fn adapter_filter() -> Option<String> {
    std::env::var("PALPATE_ADAPTER")
        .ok()
        .filter(|a| !a.is_empty())
}

impl GpuContext {
    /// Pick an adapter (see module docs) and open a device with its full limits.
    pub fn new() -> Result<GpuContext> {
        let adapters = allowed_adapters()?;
        if let (None, Some(want)) = (adapters.first(), adapter_filter()) {
            // Adapters there may be, but none with that name: say which there are.
            let found = list_adapters()
                .map(|all| {
                    all.iter()
                        .map(|a| a.get_info().name)
                        .collect::<Vec<_>>()
                        .join(", ")
                })
                .ok()
                .filter(|names| !names.is_empty())
                .unwrap_or_else(|| "none".into());
            return Err(PalpateError::Usage(format!(
                "PALPATE_ADAPTER='{want}' matches no GPU adapter (found: {found}); give a part of one of those names, unset it, or run with --backend cpu"
            )));
        }
        let adapter = adapters
            .into_iter()
            .next()
            .ok_or_else(|| PalpateError::NoAdapter {
                detail: format!(
                    "backends {}",
                    backend_names(backends_from_env().unwrap_or(wgpu::Backends::all()))
                ),
            })?;
        GpuContext::from_adapter(adapter)
    }

    /// Open a device with the full limits of `adapter`.
    pub fn from_adapter(adapter: wgpu::Adapter) -> Result<GpuContext> {
        let info = adapter.get_info();
        let limits = adapter.limits();
        let opening = DEVICE_OPEN
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        let opened = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("palpate"),
            // Timestamp queries, where the adapter has them, for per-stage GPU timings.
            required_features: adapter.features() & wgpu::Features::TIMESTAMP_QUERY,
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }));
        drop(opening);
        let (device, queue) = opened.map_err(|e| {
            PalpateError::Gpu(format!("cannot open device on '{}': {e}", info.name))
        })?;
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut v) = sink.lock() {
                let here = std::thread::current();
                v.push(CapturedError {
                    message: one_line(&e),
                    thread: here.id(),
                    thread_name: here.name().map(str::to_string),
                });
            }
        }));
        Ok(GpuContext {
            adapter,
            info,
            device,
            queue,
            limits,
            errors,
        })
    }

    /// One line naming the adapter and backend.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        )
    }

    /// Return the first wgpu error this thread raised since its last check, if any (and drop
    /// this thread's others); other threads' errors stay for them to find. With none of its
    /// own, the thread reports (and takes) the oldest error of another thread, naming it, so
    /// that an error raised where nobody checks again (the polling thread for an error found
    /// while polling, a thread that has finished) is still reported once.
    pub fn check_errors(&self) -> Result<()> {
        let mut v = self
            .errors
            .lock()
            .map_err(|_| PalpateError::Gpu("error sink poisoned".into()))?;
        let me = std::thread::current().id();
        if let Some(i) = v.iter().position(|e| e.thread == me) {
            let e = v.remove(i);
            v.retain(|e| e.thread != me);
            return Err(PalpateError::Gpu(e.message));
        }
        if v.is_empty() {
            return Ok(());
        }
        let e = v.remove(0);
        Err(PalpateError::Gpu(format!(
            "{} (raised on thread '{}')",
            e.message,
            e.thread_name.as_deref().unwrap_or("unnamed")
        )))
    }

    /// Run `make` (device calls that create objects) inside this thread's own validation,
    /// internal and out-of-memory error scopes and return its result, or the first error it raised, prefixed
    /// with `what`. Scopes are per thread in wgpu, so another thread's pending errors are
    /// neither taken nor blamed here.
    pub fn scoped<T>(&self, what: &str, make: impl FnOnce() -> T) -> Result<T> {
        let memory = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let internal = self.device.push_error_scope(wgpu::ErrorFilter::Internal);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let made = make();
        let validation = pollster::block_on(validation.pop());
        let internal = pollster::block_on(internal.pop());
        let memory = pollster::block_on(memory.pop());
        match validation.or(internal).or(memory) {
            Some(e) => Err(PalpateError::Gpu(format!("{what}: {}", one_line(&e)))),
            None => Ok(made),
        }
    }

    /// Wait for all submitted work.
    pub fn wait(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| PalpateError::Gpu(format!("poll: {e}")))?;
        self.check_errors()
    }

    /// Copy `size` bytes of a MAP_READ buffer to the host (waits for the GPU).
    pub fn read_mapped(&self, buffer: &wgpu::Buffer, size: u64) -> Result<Vec<u8>> {
        let slice = buffer.slice(..size);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|_| PalpateError::Gpu("map callback never ran".into()))?
            .map_err(|e| PalpateError::Gpu(format!("map: {e}")))?;
        let data = slice
            .get_mapped_range()
            .map_err(|e| PalpateError::Gpu(format!("mapped range: {e}")))?
            .to_vec();
        buffer.unmap();
        Ok(data)
    }
}

/// A wgpu error on one line: its lines trimmed and joined with ": ", without the "Caused
/// by:" headings (wgpu's Display puts the kind on the first line and the call, label and
/// reason on the next ones).
fn one_line(e: &wgpu::Error) -> String {
    e.to_string()
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && *l != "Caused by:")
        .collect::<Vec<_>>()
        .join(": ")
}

#[cfg(test)]
mod tests {
    use super::{backends_named, without_indirect_validation};
    use wgpu::InstanceFlags as F;

    /// A backend the build lacks is refused with the ones it has, not left to find nothing.
    #[test]
    fn a_backend_missing_from_the_build_is_an_error_naming_those_it_has() {
        assert_eq!(backends_named(None).unwrap(), wgpu::Backends::all());
        // What this target builds (Vulkan and GL on Linux and Windows; on Apple targets wgpu
        // builds them only with its vulkan-portability and angle features).
        let built = wgpu::Instance::enabled_backend_features();
        for (name, b) in [
            ("vulkan", wgpu::Backends::VULKAN),
            ("gl", wgpu::Backends::GL),
            ("metal", wgpu::Backends::METAL),
            ("dx12", wgpu::Backends::DX12),
        ] {
            match backends_named(Some(name)) {
                Ok(got) => assert!(built.contains(b) && got == b),
                Err(e) => {
                    let text = e.to_string();
                    assert!(!built.contains(b), "{text}");
                    assert!(text.contains("has no"), "{text}");
                }
            }
        }
        #[cfg(target_os = "linux")]
        assert!(backends_named(Some("dx12"))
            .unwrap_err()
            .to_string()
            .contains("it has Vulkan, GL"));
        assert!(backends_named(Some("cuda")).is_err());
    }

    /// The indirect-call validation goes, except where Direct3D 12 may be picked; the other
    /// flags of the build stay.
    #[test]
    fn indirect_validation_stays_only_where_d3d12_needs_it() {
        let all = F::debugging();
        let off = without_indirect_validation(all, false);
        assert!(!off.contains(F::VALIDATION_INDIRECT_CALL));
        assert!(off.contains(F::DEBUG | F::VALIDATION));
        assert_eq!(without_indirect_validation(all, true), all);
        let release = F::VALIDATION_INDIRECT_CALL;
        assert_eq!(without_indirect_validation(release, false), F::empty());
    }
}
