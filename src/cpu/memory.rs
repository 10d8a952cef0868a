//! What a mesh and the CPU backend's particle layer will take of the machine's memory,
//! checked before they are built: a resolution or spacing fine enough to make tens of
//! millions of tets or particles otherwise runs minutes of setup and then aborts on a failed
//! allocation (exit 134, with nothing written).
//!
//! Measured (2026-11-28, the 2-core VM, peak resident memory of the `lv` generator at
//! resolution 20 and 30, 0.77 M and 2.59 M tets): `palpate mesh` 215 and 197 bytes per tet,
//! `palpate run --steps 1` 410 and 380 on the CPU backend and 670 and 560 on the GPU backend
//! through the software adapter (whose "GPU" buffers are host memory), which
//! [`MESH_BYTES_PER_TET`] and [`RUN_BYTES_PER_TET`] round up.
//!
//! Measured (2026-11-28, the 2-core VM; `palpate run --backend cpu --steps 1`, peak resident
//! memory of 989,740 particles on a 768-tet LV): 1.07 GB at kernel_radius 1.95 (26
//! neighbours), 1.96 GB at 2.4 (56) and 5.43 GB at 3.5 (178): about 330 bytes per particle
//! plus 29 per neighbour slot (lists, pair table, transposes, checkpoint), which
//! [`BYTES_PER_PARTICLE`] and [`BYTES_PER_NEIGHBOUR`] round up.

use crate::error::{PalpateError, Result};
use crate::scene::ParticleSettings;

/// Bytes per particle besides its neighbour slots (measured 330, see the module docs).
pub const BYTES_PER_PARTICLE: f64 = 400.0;

/// Bytes per neighbour slot (measured 29).
pub const BYTES_PER_NEIGHBOUR: f64 = 35.0;

/// Bytes per tet to generate (or read) and validate a mesh (measured ≤ 215).
pub const MESH_BYTES_PER_TET: f64 = 250.0;

/// Bytes per tet to build and step the model, the mesh included: the GPU backend's figure on
/// a software adapter (measured ≤ 670; the CPU backend ≤ 410). Checked once the mesh is in
/// memory, against [`RUN_BYTES_PER_TET`] − [`MESH_BYTES_PER_TET`].
pub const RUN_BYTES_PER_TET: f64 = 750.0;

/// Lattice neighbours within `kernel_radius` spacings of a particle of a full cubic lattice
/// (26 at 1.95, 56 at 2.4): the particles' average slot count, a little over it at a surface.
pub fn lattice_neighbours(kernel_radius: f64) -> u64 {
    let reach = kernel_radius.floor() as i64;
    let mut n = 0;
    for i in -reach..=reach {
        for j in -reach..=reach {
            for k in -reach..=reach {
                let r2 = (i * i + j * j + k * k) as f64;
                if r2 > 0.0 && r2 < kernel_radius * kernel_radius {
                    n += 1;
                }
            }
        }
    }
    n
}

/// Estimated bytes the CPU backend holds for `n` particles of `settings`:
/// n (BYTES_PER_PARTICLE + BYTES_PER_NEIGHBOUR · neighbours(kernel_radius)).
pub fn particle_bytes(n: f64, settings: &ParticleSettings) -> f64 {
    let slots = lattice_neighbours(settings.kernel_radius) as f64;
    n * (BYTES_PER_PARTICLE + BYTES_PER_NEIGHBOUR * slots)
}

/// Environment variable that sets the memory palpate may plan to use, bytes, in place of
/// the machine's `MemAvailable` (for a shared machine, or a test of these checks).
pub const MEMORY_ENV: &str = "PALPATE_MEMORY_BYTES";

/// The memory [`MEMORY_ENV`] plans for, bytes: None where it is unset or empty; a one-line
/// error naming it where it is not a finite number ≥ 1 (read by every command at its start).
pub fn memory_from_env() -> Result<Option<f64>> {
    let Ok(text) = std::env::var(MEMORY_ENV) else {
        return Ok(None);
    };
    let text = text.trim();
    if text.is_empty() {
        return Ok(None);
    }
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 1.0 => Ok(Some(v)),
        _ => Err(PalpateError::Usage(format!(
            "{MEMORY_ENV} = {:?} is not a number of bytes ≥ 1 (e.g. 8e9)",
            crate::input::excerpt(text)
        ))),
    }
}

/// The memory palpate may plan to use, bytes: [`MEMORY_ENV`] where it is set, else
/// `MemAvailable` of `/proc/meminfo` (None where neither can be read).
pub fn available_memory() -> Option<f64> {
    if let Ok(Some(v)) = memory_from_env() {
        return Some(v);
    }
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024.0)
}

/// "this machine has 3.2 GB available", or "PALPATE_MEMORY_BYTES plans for 50.0 MB" where
/// the figure came from [`MEMORY_ENV`].
fn available_text(available: f64) -> String {
    match memory_from_env() {
        Ok(Some(_)) => format!("{MEMORY_ENV} plans for {}", bytes_text(available)),
        _ => format!("this machine has {} available", bytes_text(available)),
    }
}

/// Bytes as GB from 1 GB up, MB from 1 MB, kB from 1 kB, else bytes (a small figure in a
/// large unit reads "0.0 GB").
pub fn bytes_text(bytes: f64) -> String {
    if bytes >= 1e9 {
        format!("{:.1} GB", bytes / 1e9)
    } else if bytes >= 1e6 {
        format!("{:.1} MB", bytes / 1e6)
    } else if bytes >= 1e3 {
        format!("{:.1} kB", bytes / 1e3)
    } else {
        // Whole bytes, rounded down (PALPATE_MEMORY_BYTES = 1.5 plans for 1, not "2 bytes").
        format!("{:.0} bytes", bytes.floor())
    }
}

/// Refuse `n` particles of `settings` (`about`: n is the scene's estimate, zone volume /
/// spacing³, before they are sampled) that the CPU backend could not hold in `available`
/// bytes, naming `particles.spacing` of `origin` (the scene), with the figures.
pub fn check_particles_fit(
    n: f64,
    about: bool,
    settings: &ParticleSettings,
    available: f64,
    origin: &str,
) -> Result<()> {
    let need = particle_bytes(n, settings);
    if need <= available {
        return Ok(());
    }
    Err(PalpateError::SceneValue {
        origin: origin.to_string(),
        item: "particles.spacing".into(),
        message: format!(
            "{} m makes {}{n:.3e} particles, which the CPU backend needs about {} for ({} neighbours each at kernel_radius {}); {}: use a larger spacing, a smaller kernel_radius or zone, or --backend gpu",
            crate::scene::Num(settings.spacing),
            if about { "about " } else { "" },
            bytes_text(need),
            lattice_neighbours(settings.kernel_radius),
            settings.kernel_radius,
            available_text(available)
        ),
    })
}

/// [`tets_over_memory`] against the memory available ([`available_memory`]; None where it
/// cannot be read).
pub fn tets_over_available_memory(tets: f64, bytes_per_tet: f64, purpose: &str) -> Option<String> {
    available_memory().and_then(|free| tets_over_memory(tets, bytes_per_tet, purpose, free))
}

/// Why a mesh of `tets` tets cannot be afforded: it would need more than `available` bytes
/// at `bytes_per_tet` to `purpose` (e.g. "generate and validate"); None where it fits. The
/// caller names the key or file that sizes the mesh.
pub fn tets_over_memory(
    tets: f64,
    bytes_per_tet: f64,
    purpose: &str,
    available: f64,
) -> Option<String> {
    let need = tets * bytes_per_tet;
    (need > available).then(|| {
        format!(
            "makes {tets:.3e} tets, which need about {} to {purpose}; {} (set {MEMORY_ENV} to plan for another amount): use a coarser mesh",
            bytes_text(need),
            available_text(available)
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lattice_shells_count_as_in_the_scenes() {
        // 6 + 12 + 8 within 1.95 spacings; + 6 at 2 and 24 at √5 within 2.4.
        assert_eq!(lattice_neighbours(1.95), 26);
        assert_eq!(lattice_neighbours(2.4), 56);
    }

    #[test]
    fn a_layer_over_the_memory_is_refused_naming_the_spacing() {
        let settings = ParticleSettings {
            all_active: false,
            exact_coupling: false,
            region: 1,
            spacing: 1e-4,
            model: crate::scene::ParticleModel::Tlsph,
            activation_radius: 1e-3,
            kernel_radius: 1.95,
            hourglass: 0.1,
            hysteresis: 1.5,
            dwell: 0.01,
            blend: 0.01,
            activation_interval: 10,
        };
        let need = particle_bytes(1e6, &settings);
        assert_eq!(
            need,
            1e6 * (BYTES_PER_PARTICLE + 26.0 * BYTES_PER_NEIGHBOUR)
        );
        assert!(check_particles_fit(1e6, true, &settings, need, "s.toml").is_ok());
        let e = check_particles_fit(1e6, true, &settings, 0.5 * need, "s.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("s.toml")
                && e.contains("particles.spacing")
                && e.contains("about 1.000e6 particles"),
            "{e}"
        );
    }

    #[test]
    fn small_amounts_read_in_a_unit_that_shows_them() {
        assert_eq!(super::bytes_text(3.2e9), "3.2 GB");
        assert_eq!(super::bytes_text(50e6), "50.0 MB");
        assert_eq!(super::bytes_text(18_000.0), "18.0 kB");
        assert_eq!(super::bytes_text(1000.0), "1.0 kB");
        assert_eq!(super::bytes_text(999.0), "999 bytes");
    }

    #[test]
    fn a_mesh_over_the_memory_is_refused_with_its_figures() {
        let need = 1e6 * MESH_BYTES_PER_TET;
        assert!(tets_over_memory(1e6, MESH_BYTES_PER_TET, "x", need).is_none());
        let e =
            tets_over_memory(1e6, MESH_BYTES_PER_TET, "generate and validate", 0.5 * need).unwrap();
        assert!(
            e.contains("1.000e6 tets")
                && e.contains("250.0 MB to generate and validate")
                && e.contains("125.0 MB")
                && e.contains(MEMORY_ENV),
            "{e}"
        );
    }
}
