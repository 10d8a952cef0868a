//! `[particles]`: the mesh-free layer. The tets of one region become the particle zone:
//! particles on a lattice of the given spacing fill it, embedded in the zone's tets, and the
//! particles near the tool become dynamic (see [`crate::particles`]).

use super::{positive, Bad};
use crate::error::Result;
use crate::mesh::TetMesh;
use serde::Deserialize;

/// `[particles]` as written in the scene file.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParticleSpec {
    /// The region id whose tets form the particle zone.
    pub region: Option<u32>,
    /// Lattice spacing Δx, m.
    pub spacing: Option<f64>,
    /// `"tlsph"` (default) or `"paper"`.
    pub model: Option<String>,
    /// Particles closer than this to the tool's surface become dynamic, m (required with
    /// activation `"tool"`; optional with `"all"`).
    pub activation_radius: Option<f64>,
    /// Kernel support radius in spacings (default 2.4).
    pub kernel_radius: Option<f64>,
    /// Hourglass-control coefficient α (Ganzenmüller 2015; default 0.1; 0 turns it off; at
    /// most `MAX_HOURGLASS`, 100).
    pub hourglass: Option<f64>,
    /// Deactivation happens beyond `hysteresis` × the activation radius (default 1.5, ≥ 1).
    pub hysteresis: Option<f64>,
    /// A particle stays dynamic at least this long after it last qualified, s (default 0.01).
    pub dwell: Option<f64>,
    /// A released particle blends back onto its host over this time, s (default 0.01).
    pub blend: Option<f64>,
    /// Steps between activation updates (default 10).
    pub activation_interval: Option<u32>,
    /// `"tool"` (default: particles near the tool are dynamic) or `"all"` (every particle is
    /// dynamic, the zone is purely mesh-free; for validation).
    pub activation: Option<String>,
    /// `"blend"` (default: the partition-of-unity energy blend of eq. 9–11) or `"exact"`
    /// (design 8 of `docs/hybrid_coupling.md`: full-energy tets plus each particle's
    /// Bregman remainder, zone-only vertices slaved to their particles; exact patch test).
    /// `"exact"` needs `model = "tlsph"`; under the tool the GPU backend runs each activation
    /// on a CPU twin of the stepper (README).
    pub coupling: Option<String>,
}

/// The most particles a scene may ask for (estimated from the zone volume and spacing).
pub const MAX_PARTICLES: f64 = 5.0e7;

/// The largest `particles.hourglass`. Above about this the penalty itself feeds the zig-zag
/// mode instead of damping it, whatever the time step: lv_touch with every particle dynamic
/// under the tool, 2,700 steps, ends with kinetic energy 1e-10 J at 30, 6e-9 J at 100 and
/// 1.4e-3 J at 200; at 1,000 it diverges at step ~470 even at 16 particle sub-steps.
pub const MAX_HOURGLASS: f64 = 100.0;

/// The particle models.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ParticleModel {
    /// Total-Lagrangian SPH with a Wendland C2 kernel, corrected gradients, the FEM's
    /// material law and hourglass control.
    #[default]
    Tlsph,
    /// The paper's eq. (8) Lennard-Jones-like kernel and eq. (13) acceleration.
    Paper,
}

impl ParticleModel {
    /// The scene-file name.
    pub fn name(self) -> &'static str {
        match self {
            ParticleModel::Tlsph => "tlsph",
            ParticleModel::Paper => "paper",
        }
    }

    /// The kernels' index (`ParticleParams::model`): 0 tlsph, 1 paper.
    pub fn index(self) -> u32 {
        match self {
            ParticleModel::Tlsph => 0,
            ParticleModel::Paper => 1,
        }
    }
}

/// Validated `[particles]` settings.
#[derive(Clone, Debug, PartialEq)]
pub struct ParticleSettings {
    /// Region id of the zone.
    pub region: u32,
    /// Lattice spacing Δx, m.
    pub spacing: f64,
    /// The particle model.
    pub model: ParticleModel,
    /// Activation radius from the tool's surface, m (0 when `all_active` left it out).
    pub activation_radius: f64,
    /// Kernel support radius in spacings.
    pub kernel_radius: f64,
    /// Hourglass coefficient α.
    pub hourglass: f64,
    /// Deactivation radius / activation radius.
    pub hysteresis: f64,
    /// Dwell time, s.
    pub dwell: f64,
    /// Blend-back time, s.
    pub blend: f64,
    /// Steps between activation updates.
    pub activation_interval: u32,
    /// Every particle dynamic, whatever the tool (`activation = "all"`).
    pub all_active: bool,
    /// Design 8's coupling (`coupling = "exact"`) instead of the energy blend.
    pub exact_coupling: bool,
}

/// Validate `[particles]` against the mesh: the region must exist.
pub(super) fn resolve_particles(
    spec: &ParticleSpec,
    mesh: &TetMesh,
    bad: &Bad,
) -> Result<ParticleSettings> {
    let region = spec.region.ok_or_else(|| {
        bad(
            "particles.region",
            "is required (a region id of the mesh)".into(),
        )
    })?;
    let zone_tets = mesh.regions.iter().filter(|&&r| r == region).count();
    if zone_tets == 0 {
        let mut regions: Vec<u32> = mesh.regions.clone();
        regions.sort_unstable();
        regions.dedup();
        return Err(bad(
            "particles.region",
            format!("no tet has region {region} (the mesh's regions: {regions:?})"),
        ));
    }
    let spacing = positive(
        bad,
        "particles.spacing",
        spec.spacing
            .ok_or_else(|| bad("particles.spacing", "is required (m)".into()))?,
        "m",
    )?;
    let zone_volume = zone_volume(mesh, region);
    let estimate = zone_volume / spacing.powi(3);
    if estimate > MAX_PARTICLES {
        return Err(bad(
            "particles.spacing",
            format!(
                "{} m would make about {estimate:.3e} particles in a zone of {zone_volume:.3e} m³ (limit {MAX_PARTICLES:.0e})",
                super::Num(spacing)
            ),
        ));
    }
    let name = spec.model.as_deref().unwrap_or("tlsph");
    let model = match name {
        "tlsph" => ParticleModel::Tlsph,
        "paper" => ParticleModel::Paper,
        other => {
            return Err(bad(
                "particles.model",
                format!("unknown particle model '{other}' (known: tlsph, paper)"),
            ))
        }
    };
    let all_active = match spec.activation.as_deref().unwrap_or("tool") {
        "tool" => false,
        "all" => true,
        other => {
            return Err(bad(
                "particles.activation",
                format!("must be \"tool\" or \"all\", got \"{other}\""),
            ))
        }
    };
    // With every particle dynamic no radius decides anything: optional (0 when left out).
    let activation_radius = match (spec.activation_radius, all_active) {
        (None, true) => 0.0,
        (r, _) => positive(
            bad,
            "particles.activation_radius",
            r.ok_or_else(|| {
                bad(
                    "particles.activation_radius",
                    "is required (m) with activation = \"tool\"".into(),
                )
            })?,
            "m",
        )?,
    };
    let kernel_radius = spec.kernel_radius.unwrap_or(2.4);
    // Below 4: at 4 the √16 shell sits on the support's edge (refused below).
    if !(kernel_radius.is_finite() && (1.5..4.0).contains(&kernel_radius)) {
        return Err(bad(
            "particles.kernel_radius",
            format!(
                "must be in [1.5, 4) spacings, got {}",
                super::Num(kernel_radius)
            ),
        ));
    }
    if let Some(k) = lattice_shell_on_support(kernel_radius) {
        return Err(bad(
            "particles.kernel_radius",
            format!(
                "{kernel_radius} puts the lattice's neighbours at √{k} spacings on the support's edge, where rounding decides on each device which of them count; use a value at least 0.1 % away from √{k} (e.g. {})",
                [(k as f64).sqrt() - 0.05, (k as f64).sqrt() + 0.05]
                    .iter()
                    .filter(|r| (1.5..4.0).contains(*r))
                    .map(|r| format!("{r:.2}"))
                    .collect::<Vec<_>>()
                    .join(" or ")
            ),
        ));
    }
    if spec.hourglass.is_some() && model == ParticleModel::Paper {
        return Err(bad(
            "particles.hourglass",
            "is not used by model \"paper\" (it is tlsph's hourglass control): remove it".into(),
        ));
    }
    let hourglass = spec.hourglass.unwrap_or(0.1);
    if !(hourglass.is_finite() && (0.0..=MAX_HOURGLASS).contains(&hourglass)) {
        return Err(bad(
            "particles.hourglass",
            format!(
                "must be in [0, {MAX_HOURGLASS}], got {} (a stiffer penalty drives the zig-zag mode it damps, at any time step)",
                super::Num(hourglass)
            ),
        ));
    }
    let hysteresis = super::at_least(
        bad,
        "particles.hysteresis",
        spec.hysteresis.unwrap_or(1.5),
        1.0,
        "",
    )?;
    let dwell = super::at_least(bad, "particles.dwell", spec.dwell.unwrap_or(0.01), 0.0, "s")?;
    let blend = super::at_least(bad, "particles.blend", spec.blend.unwrap_or(0.01), 0.0, "s")?;
    let activation_interval = spec.activation_interval.unwrap_or(10);
    if activation_interval == 0 {
        return Err(bad(
            "particles.activation_interval",
            "must be at least 1 step".into(),
        ));
    }
    let exact_coupling = match spec.coupling.as_deref().unwrap_or("blend") {
        "blend" => false,
        "exact" => true,
        other => {
            return Err(bad(
                "particles.coupling",
                format!("must be \"blend\" or \"exact\", got \"{other}\""),
            ))
        }
    };
    if exact_coupling && model != ParticleModel::Tlsph {
        return Err(bad(
            "particles.coupling",
            "\"exact\" needs particles.model = \"tlsph\" (the paper model has no strain energy)"
                .into(),
        ));
    }
    Ok(ParticleSettings {
        all_active,
        exact_coupling,
        region,
        spacing,
        model,
        activation_radius,
        kernel_radius,
        hourglass,
        hysteresis,
        dwell,
        blend,
        activation_interval,
    })
}

/// The lattice shell (k = i² + j² + l², neighbours at √k spacings) that lies within 0.1 % of
/// a support of `kernel_radius` spacings, if any: pairs there sit on the support's edge, where
/// f32 rounding of the rest positions (and a GPU's fused multiply-adds) decides which count.
fn lattice_shell_on_support(kernel_radius: f64) -> Option<u32> {
    let r2 = kernel_radius * kernel_radius;
    let k = r2.round() as u32;
    let is_shell =
        (0..=4u32).any(|i| (0..=4u32).any(|j| (0..=4u32).any(|l| i * i + j * j + l * l == k)));
    (is_shell && (kernel_radius - (k as f64).sqrt()).abs() <= 1e-3 * kernel_radius).then_some(k)
}

/// The volume of the tets of `region`, m³.
fn zone_volume(mesh: &TetMesh, region: u32) -> f64 {
    (0..mesh.n_tets())
        .filter(|&e| mesh.regions[e] == region)
        .map(|e| mesh.tet_volume(e))
        .sum()
}

/// About how many particles `settings` make in `mesh`: the zone's volume / spacing³ (the
/// lattice's count to within its surface cells).
pub fn estimated_count(mesh: &TetMesh, settings: &ParticleSettings) -> f64 {
    zone_volume(mesh, settings.region) / settings.spacing.powi(3)
}
