//! The mesh-free particle layer (paper §3–4): sampling, embedding in host tets, and the
//! static index structures the particle stages run over.
//!
//! ## The hybrid model
//!
//! The particle zone (the tets of one region) stays meshed by its coarse tets, and is also
//! filled with particles on a lattice of spacing Δx. Each particle p lives in the zone tet
//! that contains it (its host) with barycentric weights wᵢ (paper eq. 9–11; SOFA's
//! barycentric mapping):
//!
//! * an **embedded** particle follows its host: x_p = Σ wᵢ xᵢ, and whatever force acts on it
//!   goes to the host nodes as wᵢ·f (the exact transpose), so linear and angular momentum
//!   are conserved; its mass is lumped onto the host nodes with the same weights;
//! * a **dynamic** particle (near the tool) has its own position, velocity and mass.
//!
//! The strain energy is split by a partition of unity: a tet keeps the fraction 1 − φₑ of
//! its energy, φₑ the fraction of its particles that carry SPH stress; stress-carrying
//! particles are the dynamic ones and the embedded ones within a kernel support of them (so
//! every dynamic particle sees a full neighbourhood). The zone's mass is carried once: by
//! the particles (lumped or their own), never by the zone tets — except zone tets too small
//! to hold a particle, which keep their own. Where S ends this split leaves a ghost force
//! under an affine stretch, first order in Δx/h (docs/hybrid_coupling.md).
//!
//! Volumes are uniform, V = (volume of the particle-holding zone tets)/N, so the interior of
//! the lattice is symmetric and a uniform stress leaves no residual force on interior
//! particles.

pub mod params;
pub mod sampling;

use crate::mesh::TetMesh;
use crate::scene::ParticleSettings;

/// Particles of one scene and their static index structures.
#[derive(Clone, Debug)]
pub struct Particles {
    /// The scene's settings.
    pub settings: ParticleSettings,
    /// Rest positions X_p, packed xyz, m.
    pub rest: Vec<f32>,
    /// Volume of every particle, m³.
    pub volume: f32,
    /// Mass of every particle, kg.
    pub mass: f32,
    /// Host tet of each particle (particles are sorted by host).
    pub host: Vec<u32>,
    /// Barycentric weights in the host, 4 per particle (Σ = 1).
    pub weights: Vec<f32>,
    /// CSR over tets: the particles of tet e are `tet_offsets[e]..tet_offsets[e+1]`.
    pub tet_offsets: Vec<u32>,
    /// CSR over vertices: vertex i's particle slots are `slots[slot_offsets[i]..slot_offsets[i+1]]`.
    pub slot_offsets: Vec<u32>,
    /// Particle slots `p·4 + corner`, grouped by the host corner's vertex, ascending.
    pub slots: Vec<u32>,
    /// Contact area of each particle, m² (Δx² on the lattice's surface, 0 inside).
    pub contact_area: Vec<f32>,
    /// Per surface particle, the rest offset o_p from the particle to the nearest point of the
    /// body's boundary, packed xyz, m (zero inside): the lattice's outer layer lies up to a
    /// spacing inside the true surface, and contact is taken at x_p + F_p o_p.
    pub contact_offset: Vec<f32>,
    /// Kernel support radius R = kernel_radius·Δx, m.
    pub support: f32,
    /// Per vertex: the lumped mass of the tets that are not particle-holding zone tets, kg.
    pub core_mass: Vec<f32>,
    /// Per particle: it lies on the core side of its host (at least half its barycentric
    /// weight on vertices of core tets, outside the particle region, or fixed ones), so it
    /// always stays embedded and ties the particles to the rest of the body.
    pub pinned: Vec<bool>,
    /// Design 8's lumped vertex masses with no particle dynamic and no vertex slaved, f64
    /// (`cpu::exact_coupling::Slaving`'s lumping of every particle), made at its first use:
    /// a slaving recomputes only the vertices its dynamic particles and slaved vertices
    /// reach and copies the rest from here.
    pub follower_lumping: std::sync::OnceLock<Vec<f64>>,
}

/// The particles' stable step, in parts ([`Particles::bound_terms`]): 1/dt² of the
/// lattice's elastic waves, of the contact springs and of the hourglass penalty.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParticleBoundTerms {
    /// 1/dt² of the elastic waves at the rest stiffness, 1/s².
    pub elastic_inv2: f64,
    /// 1/dt² of the tool's contact springs (0 without a tool), 1/s².
    pub contact_inv2: f64,
    /// 1/dt² of the hourglass penalty, ω_h²/4, 1/s².
    pub hourglass_inv2: f64,
}

impl ParticleBoundTerms {
    /// The stable step where the material's stiffness is `stiffening` (κ ≥ 1) times its rest
    /// value: the elastic frequency scales by √κ (ω² ∝ stiffness), the contact springs and
    /// the hourglass penalty stay as they are. κ is what a deformed particle's tangent
    /// stiffness has grown to ([`crate::substeps::stiffening`]).
    pub fn dt_bound(&self, stiffening: f64) -> f64 {
        let inv2 = stiffening.max(1.0) * self.elastic_inv2 + self.contact_inv2;
        1.0 / (inv2 + self.hourglass_inv2).sqrt()
    }

    /// Sub-steps per core step of `dt` with safety factor `safety`: ⌈dt / (safety ·
    /// bound(κ))⌉, at least 1, at most [`crate::model::MAX_PARTICLE_SUBSTEPS`].
    pub fn substeps(&self, dt: f64, safety: f64, stiffening: f64) -> u32 {
        (dt / (safety * self.dt_bound(stiffening)))
            .ceil()
            .clamp(1.0, crate::model::MAX_PARTICLE_SUBSTEPS as f64) as u32
    }
}

impl Particles {
    /// Number of particles.
    pub fn len(&self) -> usize {
        self.host.len()
    }

    /// True when there are none.
    pub fn is_empty(&self) -> bool {
        self.host.is_empty()
    }

    /// Per vertex, the lumped mass with every particle embedded: the core mass plus
    /// Σ wᵢ m_p over the particles hosted by the vertex's tets.
    pub fn embedded_mass(&self) -> Vec<f32> {
        let mut m: Vec<f64> = self.core_mass.iter().map(|&x| x as f64).collect();
        for (i, mi) in m.iter_mut().enumerate() {
            for k in self.slot_offsets[i]..self.slot_offsets[i + 1] {
                *mi += self.weights[self.slots[k as usize] as usize] as f64 * self.mass as f64;
            }
        }
        m.into_iter().map(|x| x as f32).collect()
    }

    /// The modes at rest: `PINNED` for the pinned particles, nothing else.
    pub fn initial_modes(&self) -> Vec<u32> {
        self.pinned
            .iter()
            .map(|&pin| if pin { params::mode::PINNED } else { 0 })
            .collect()
    }

    /// The rest position of particle p.
    pub fn rest_position(&self, p: usize) -> glam::Vec3 {
        glam::Vec3::new(self.rest[3 * p], self.rest[3 * p + 1], self.rest[3 * p + 2])
    }

    /// Embedded displacement of particle p from node displacements: Σ wᵢ uᵢ.
    pub fn embed(&self, tets: &[[u32; 4]], displacements: &[f32], p: usize) -> glam::Vec3 {
        let t = tets[self.host[p] as usize];
        (0..4)
            .map(|c| crate::cpu::load3(displacements, t[c] as usize) * self.weights[4 * p + c])
            .fold(glam::Vec3::ZERO, |a, b| a + b)
    }

    /// The largest stable particle step: the lattice's highest frequency, ω ≈ 2 c_p/Δx, as
    /// for a tet of altitude Δx (with the tets' viscous damping ratio ζ = (φ + 2ψ)ω/(2(λ + 2μ)):
    /// (Δx/c_p)(sqrt(1 + ζ²) − ζ), the particle stress being viscous too in the blend; design 8,
    /// whose particles stay elastic, keeps the factor, a little conservative), the tool's contact springs on surface particles of area
    /// Δx², ω_c² = k Δx²/m with damping ratio ζ = b Δx²/(2 m ω_c), whose bound
    /// (2/ω_c)(sqrt(1 + ζ²) − ζ) is the vertices' one, and the hourglass penalty's
    /// [`Self::hourglass_omega`]; combined in quadrature (see [`crate::timestep`]).
    /// `contact` is the tool's (stiffness k, damping b per unit area).
    pub fn dt_bound(
        &self,
        material: &crate::material::MaterialParams,
        contact: Option<(f64, f64)>,
    ) -> f64 {
        self.bound_terms(material, contact).dt_bound(1.0)
    }

    /// The terms of [`Self::dt_bound`], computed once: what [`ParticleBoundTerms::dt_bound`]
    /// combines for a stiffened material.
    pub fn bound_terms(
        &self,
        material: &crate::material::MaterialParams,
        contact: Option<(f64, f64)>,
    ) -> ParticleBoundTerms {
        let dx = self.settings.spacing;
        let c = material.p_wave_speed();
        let m = material;
        let zeta = (m.phi + 2.0 * m.psi) * (2.0 * c / dx) / (2.0 * (m.lambda + 2.0 * m.mu));
        let elastic = dx / c * crate::timestep::damped_step_factor(zeta);
        // 1/dt² of each spring, each dt = 2/ω (summed in quadrature, as the vertices').
        let contact_inv2 = contact.map_or(0.0, |(k, b)| {
            let (area, m) = (dx * dx, self.mass as f64);
            let omega = (k * area / m).sqrt();
            let zeta = b * area / (2.0 * m * omega);
            let contact = 2.0 / omega * crate::timestep::damped_step_factor(zeta);
            1.0 / (contact * contact)
        });
        let omega_h = self.hourglass_omega(material);
        ParticleBoundTerms {
            elastic_inv2: 1.0 / (elastic * elastic),
            contact_inv2,
            hourglass_inv2: 0.25 * omega_h * omega_h,
        }
    }

    /// A bound on the highest frequency of tlsph's hourglass penalty: each pair is a spring
    /// of stiffness k_b = 2·½αEV²·W(r_b)/r_b² along it (the penalty's linearisation), and a
    /// network of springs on equal masses has ω² ≤ 2 Σ_b k_b / m (the zig-zag mode of a chain
    /// reaches it; on the cubic lattice the highest mode is about a third of it), summed
    /// over the lattice points within the kernel support. 0 without hourglass control or for
    /// the paper model.
    pub fn hourglass_omega(&self, material: &crate::material::MaterialParams) -> f64 {
        let s = &self.settings;
        if s.hourglass <= 0.0 || s.model != crate::scene::ParticleModel::Tlsph {
            return 0.0;
        }
        let (dx, support) = (s.spacing, self.support as f64);
        let youngs = material.youngs_modulus();
        let v = self.volume as f64;
        let h = 0.5 * s.hourglass * youngs * v * v;
        let reach = (support / dx).ceil() as i32;
        let mut sum = 0.0;
        for i in -reach..=reach {
            for j in -reach..=reach {
                for k in -reach..=reach {
                    let r = dx * ((i * i + j * j + k * k) as f64).sqrt();
                    if r > 0.0 && r < support {
                        let w = crate::cpu::sph::wendland(r as f32, support as f32) as f64;
                        sum += w / (r * r);
                    }
                }
            }
        }
        (2.0 * 2.0 * h * sum / self.mass as f64).sqrt()
    }

    /// Sample the particle zone of `mesh` (see [`sampling::sample`]).
    pub fn sample(
        mesh: &TetMesh,
        settings: &ParticleSettings,
        density: f64,
        origin: &str,
    ) -> crate::error::Result<Particles> {
        sampling::sample(mesh, settings, density, origin)
    }
}
