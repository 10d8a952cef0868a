//! The tool and its contact with the tissue surface: the surface data the contact stages
//! run over, the per-run and per-batch uniforms (mirrored in `kernels/shared/tool.wgsl`),
//! the layout of the per-batch tool report, and the contact's effect on the stable step.
//!
//! Contact is a penalty on each boundary vertex i inside the sphere (centre c, radius R):
//! with r = |x_i − c|, penetration d = R − r > 0 and normal n = (x_i − c)/r,
//!
//!   f_i = A_i (k d − b min(0, (v_i − v_c)·n)) n,
//!
//! k the penalty per unit area (Pa/m), b the damping per unit area (Pa·s/m, acting only
//! while the surface approaches the tool), A_i the vertex's share of the rest surface area
//! (a third of each incident boundary triangle). The force on the tool is F = −Σ f_i; its
//! derivative with respect to the tool position with the tissue held (the "frozen"
//! stiffness) is K = Σ k A_i [(R/r)(I − n nᵀ) − I].

use crate::mesh::TetMesh;
use crate::scene::Tool;
use bytemuck::{Pod, Zeroable};
use glam::DVec3;

/// Marks a vertex that is not on the boundary surface in `surface_index`.
pub const NOT_ON_SURFACE: u32 = u32::MAX;

/// Number of floats in the per-batch tool report (see [`report`]).
pub const REPORT_LEN: usize = 16;

/// Slots of the tool report written by `tool_force` (`tool_report` buffer).
pub mod report {
    /// Force the tissue exerts on the tool, N (3 floats).
    pub const FORCE: usize = 0;
    /// Frozen-tissue stiffness ∂F/∂c, N/m, 9 floats column-major.
    pub const STIFFNESS: usize = 3;
    /// Largest penetration, m.
    pub const MAX_PENETRATION: usize = 12;
    /// Number of surface vertices in contact.
    pub const CONTACTS: usize = 13;
    /// Rest surface area in contact, m².
    pub const AREA: usize = 14;
}

/// Per-run tool constants (WGSL `ToolParams`), 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ToolParams {
    /// Sphere radius R, m.
    pub radius: f32,
    /// Penalty per unit area k, Pa/m.
    pub stiffness: f32,
    /// Damping per unit area b, Pa·s/m.
    pub damping: f32,
    /// Number of surface vertices.
    pub n_surface: u32,
    /// Number of particles (their contact forces count in the tool's report).
    pub n_particles: u32,
    /// Padding.
    pub _pad: [u32; 3],
}

/// Per-batch tool input (WGSL `ToolInput`), 32 bytes: the tool moves linearly from `start`
/// to `end` over the batch's `steps` steps (step k of the batch, 0-based, computes its
/// forces with the tool at start + (end − start)·k/steps; the batch ends with it at `end`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ToolInput {
    /// Centre at the batch start, m.
    pub start: [f32; 3],
    /// Steps in the batch.
    pub steps: u32,
    /// Centre at the batch end, m.
    pub end: [f32; 3],
    /// Padding to 16-byte alignment.
    pub _pad: u32,
}

/// The tool's position during a batch (WGSL `ToolState`), 16 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ToolState {
    /// Centre after the last `tool_motion`, m.
    pub position: [f32; 3],
    /// Steps of the batch done.
    pub step: u32,
}

/// The tool and the boundary surface it touches.
#[derive(Clone, Debug)]
pub struct ToolModel {
    /// The scene's tool.
    pub tool: Tool,
    /// Boundary vertices, ascending.
    pub surface_vertices: Vec<u32>,
    /// Each surface vertex's share of the rest boundary area, m².
    pub surface_area: Vec<f32>,
    /// Per vertex: its index in `surface_vertices`, or [`NOT_ON_SURFACE`].
    pub surface_index: Vec<u32>,
}

impl ToolModel {
    /// Surface data of `mesh` for `tool`.
    pub fn new(mesh: &TetMesh, tool: Tool) -> ToolModel {
        let faces = mesh.boundary_faces();
        let mut area = vec![0.0f64; mesh.n_vertices()];
        for f in &faces {
            let [a, b, c] = f.map(|v| mesh.positions[v as usize]);
            let share = 0.5 * (b - a).cross(c - a).length() / 3.0;
            for &v in f {
                area[v as usize] += share;
            }
        }
        let surface_vertices = mesh.boundary_vertices();
        let mut surface_index = vec![NOT_ON_SURFACE; mesh.n_vertices()];
        for (s, &v) in surface_vertices.iter().enumerate() {
            surface_index[v as usize] = s as u32;
        }
        let surface_area = surface_vertices
            .iter()
            .map(|&v| area[v as usize] as f32)
            .collect();
        ToolModel {
            tool,
            surface_vertices,
            surface_area,
            surface_index,
        }
    }

    /// The per-run uniform.
    pub fn params(&self) -> ToolParams {
        ToolParams {
            radius: self.tool.radius as f32,
            stiffness: self.tool.stiffness as f32,
            damping: self.tool.damping as f32,
            n_surface: self.surface_vertices.len() as u32,
            n_particles: 0,
            _pad: [0; 3],
        }
    }

    /// The largest stable step of the contact springs alone: per surface vertex of mass m,
    /// ω² = k A/m and ζ = b A/(2 m ω), dt = (2/ω)(sqrt(1 + ζ²) − ζ); the minimum over
    /// free vertices (∞ when none).
    pub fn contact_dt_bound(&self, mass: &[f32], inv_mass: &[f32]) -> f64 {
        self.spring_dt_bound(self.tool.damping, mass, inv_mass)
    }

    /// [`ToolModel::contact_dt_bound`] with contact damping `b` per unit area.
    pub fn spring_dt_bound(&self, b: f64, mass: &[f32], inv_mass: &[f32]) -> f64 {
        let k = self.tool.stiffness;
        self.surface_vertices
            .iter()
            .zip(&self.surface_area)
            .filter(|(&v, _)| inv_mass[v as usize] > 0.0)
            .map(|(&v, &a)| {
                let m = mass[v as usize] as f64;
                let omega = (k * a as f64 / m).sqrt();
                let zeta = b * a as f64 / (2.0 * m * omega);
                2.0 / omega * crate::timestep::damped_step_factor(zeta)
            })
            .fold(f64::INFINITY, f64::min)
    }
}

/// The tool input for a batch that moves the tool from `from` to `to` in `steps` steps.
pub fn batch_input(from: DVec3, to: DVec3, steps: u32) -> ToolInput {
    ToolInput {
        start: from.as_vec3().to_array(),
        steps,
        end: to.as_vec3().to_array(),
        _pad: 0,
    }
}
