//! The simulation model: a scene's mesh and material turned into the flat f32 arrays that
//! both backends step (rest shape, Dm⁻¹, volumes, lumped masses, CSR incidence).

use crate::material::{HyperelasticParams, MaterialParams};
use crate::mesh::TetMesh;
use crate::params::StepParams;
use crate::scene::Scene;
use crate::timestep::TimeStepBounds;
use glam::DMat3;

/// The divergence guard's speed limit in P-wave speeds: a particle speed v = ε·c_p means a
/// strain ε, so 10 c_p (a strain of 1000 %) is reached only by an instability or a load the
/// body cannot hold; real instabilities grow exponentially, so the exact factor changes the
/// detection step by only a few steps.
pub const SPEED_LIMIT_WAVE_SPEEDS: f64 = 10.0;

/// The fastest a haptic session moves the simulated tool, in shear wave speeds of the
/// stepped material: a tool pushed in faster than the tissue's shear waves carry it out of
/// the way crushes the layer under it (lv_touch, a 5 mm press at mass scaling 700, c_s =
/// 0.096 m/s: 0.062 m/s held, 0.075 m/s and faster diverged, particles inverted under the
/// tool; the same press at 7 mm/s went 7 mm deep). Half leaves a margin below that edge.
pub const TOOL_SPEED_SHEAR_WAVES: f64 = 0.5;

/// The most particle sub-steps per core step: the scene's ([`Model::particle_substeps`])
/// and the ones a compressed layer asks for ([`crate::substeps`]).
pub const MAX_PARTICLE_SUBSTEPS: u32 = 64;

/// Everything the kernels read that does not change during a run.
#[derive(Clone, Debug)]
pub struct Model {
    /// Rest positions, packed xyz, m.
    pub rest: Vec<f32>,
    /// Tets (positively oriented).
    pub tets: Vec<[u32; 4]>,
    /// Region id per tet.
    pub regions: Vec<u32>,
    /// Dm⁻¹ per tet, 9 floats column-major; Dm = [X₁−X₀, X₂−X₀, X₃−X₀] (the paper's β).
    pub dm_inv: Vec<f32>,
    /// Rest volume per tet, m³.
    pub rest_volume: Vec<f32>,
    /// Lumped mass per vertex: Σ ρV/4 over incident tets, kg.
    pub mass: Vec<f32>,
    /// 1/mass, or 0 for fixed vertices and vertices with no tet.
    pub inv_mass: Vec<f32>,
    /// CSR row starts: vertex i's corners are `incidence[offsets[i]..offsets[i+1]]`.
    pub incidence_offsets: Vec<u32>,
    /// Corner ids tet·4 + corner, grouped by vertex, ascending within a vertex.
    pub incidence: Vec<u32>,
    /// Material.
    pub material: MaterialParams,
    /// Gravity, m/s².
    pub gravity: [f32; 3],
    /// Constant external force per vertex (surface pressures), packed xyz, N.
    pub external_forces: Vec<f32>,
    /// Fibre direction per tet, packed xyz (empty when the mesh has none).
    pub fibres: Vec<f32>,
    /// Stability bounds of this mesh and material (and the tool's contact, if any).
    pub bounds: TimeStepBounds,
    /// The scene's safety factor (`[solver] safety`): particle sub-steps are at most this
    /// fraction of the particles' stable step, as the core step is of its own.
    pub safety: f64,
    /// The tool and the surface it touches (None: no contact stages).
    pub tool: Option<crate::contact::ToolModel>,
    /// The particle layer (None: no particle stages).
    pub particles: Option<crate::particles::Particles>,
    /// The split law's constants (Some exactly when `material.model` is a split law).
    pub hyperelastic: Option<HyperelasticParams>,
    /// Follower pressures (None: no follower stages).
    pub follower: Option<FollowerModel>,
    /// `particles.coupling = "exact"`: the vertices slaved to the (fixed) dynamic set and the
    /// masses that go with them (None: the energy blend, or no particles).
    pub slaving: Option<std::sync::Arc<crate::cpu::exact_coupling::Slaving>>,
}

/// Follower pressures as the kernels read them.
#[derive(Clone, Debug, PartialEq)]
pub struct FollowerModel {
    /// Loaded faces, 3 vertex ids each, oriented outward.
    pub faces: Vec<u32>,
    /// Pressure per face, Pa.
    pub face_pressure: Vec<f32>,
    /// CSR row starts of the face-corner incidence (per vertex).
    pub incidence_offsets: Vec<u32>,
    /// Face-corner ids face·3 + corner, grouped by vertex, ascending.
    pub incidence: Vec<u32>,
    /// Ramp time, s (0: full load from the start).
    pub ramp_seconds: f64,
}

impl FollowerModel {
    /// From the resolved scene loads of a mesh with `n_vertices` vertices.
    pub fn new(loads: &crate::scene::FollowerLoads, n_vertices: usize) -> FollowerModel {
        let (incidence_offsets, incidence) =
            crate::cpu::follower_pressure_gather::follower_incidence(n_vertices, &loads.faces);
        FollowerModel {
            faces: loads.faces.iter().flatten().copied().collect(),
            face_pressure: loads.face_pressure.iter().map(|&p| p as f32).collect(),
            incidence_offsets,
            incidence,
            ramp_seconds: loads.ramp_seconds,
        }
    }

    /// Number of loaded faces.
    pub fn n_faces(&self) -> usize {
        self.face_pressure.len()
    }

    /// The ramp factor at simulated time `time`: min(t / t_ramp, 1) (1 without a ramp).
    pub fn load_factor(&self, time: f64) -> f32 {
        if self.ramp_seconds > 0.0 {
            (time / self.ramp_seconds).clamp(0.0, 1.0) as f32
        } else {
            1.0
        }
    }
}

impl Model {
    /// Build from a mesh, per-vertex fixed flags, material and gravity (no other load).
    pub fn new(
        mesh: &TetMesh,
        fixed: &[bool],
        material: MaterialParams,
        gravity: [f64; 3],
    ) -> Model {
        Model::with_loads(mesh, fixed, material, gravity, &[])
    }

    /// Build with constant external vertex forces `external` (N; empty for none).
    pub fn with_loads(
        mesh: &TetMesh,
        fixed: &[bool],
        material: MaterialParams,
        gravity: [f64; 3],
        external: &[glam::DVec3],
    ) -> Model {
        let n = mesh.n_vertices();
        let m = mesh.n_tets();
        let mut dm_inv = Vec::with_capacity(9 * m);
        let mut rest_volume = Vec::with_capacity(m);
        let mut mass = vec![0.0f64; n];
        for (e, tet) in mesh.tets.iter().enumerate() {
            let x = mesh.corners(e);
            let dm = DMat3::from_cols(x[1] - x[0], x[2] - x[0], x[3] - x[0]);
            let vol = dm.determinant() / 6.0;
            dm_inv.extend(dm.inverse().to_cols_array().map(|c| c as f32));
            rest_volume.push(vol as f32);
            for &i in tet {
                mass[i as usize] += material.density * vol / 4.0;
            }
        }
        let mut counts = vec![0u32; n + 1];
        for tet in &mesh.tets {
            for &i in tet {
                counts[i as usize + 1] += 1;
            }
        }
        for i in 0..n {
            counts[i + 1] += counts[i];
        }
        let offsets = counts;
        let mut fill = offsets.clone();
        let mut incidence = vec![0u32; 4 * m];
        for (e, tet) in mesh.tets.iter().enumerate() {
            for (c, &i) in tet.iter().enumerate() {
                incidence[fill[i as usize] as usize] = (4 * e + c) as u32;
                fill[i as usize] += 1;
            }
        }
        let inv_mass = mass
            .iter()
            .zip(fixed)
            .map(|(&mv, &f)| {
                if f || mv <= 0.0 {
                    0.0
                } else {
                    (1.0 / mv) as f32
                }
            })
            .collect();
        let bounds = TimeStepBounds::new(&material, mesh.min_altitude(), mesh.min_edge());
        Model {
            rest: mesh
                .positions
                .iter()
                .flat_map(|p| p.to_array().map(|c| c as f32))
                .collect(),
            tets: mesh.tets.clone(),
            regions: mesh.regions.clone(),
            dm_inv,
            rest_volume,
            mass: mass.iter().map(|&x| x as f32).collect(),
            inv_mass,
            incidence_offsets: offsets,
            incidence,
            material,
            gravity: gravity.map(|g| g as f32),
            external_forces: if external.is_empty() {
                vec![0.0; 3 * n]
            } else {
                external
                    .iter()
                    .flat_map(|f| f.to_array().map(|c| c as f32))
                    .collect()
            },
            fibres: mesh
                .fibres
                .iter()
                .flat_map(|f| f.to_array().map(|c| c as f32))
                .collect(),
            bounds,
            safety: crate::timestep::DEFAULT_SAFETY,
            tool: None,
            particles: None,
            hyperelastic: None,
            follower: None,
            slaving: None,
        }
    }

    /// Use split law constants `h` (the material's model must be a split law; its λ, μ should
    /// be κ − 2μ/3 and the shear modulus) and, if given, a constant fibre for every tet.
    pub fn with_hyperelastic(mut self, h: HyperelasticParams, fibre: Option<[f64; 3]>) -> Model {
        self.hyperelastic = Some(h);
        if let Some(f) = fibre {
            // Checked by the scene (`check_constant_fibre`); a zero one stays zero.
            let f = crate::scene::unit_direction(f).unwrap_or(glam::DVec3::ZERO);
            self.fibres = (0..self.n_tets())
                .flat_map(|_| f.to_array().map(|c| c as f32))
                .collect();
        }
        self
    }

    /// Add follower pressures.
    pub fn with_follower(mut self, follower: FollowerModel) -> Model {
        self.follower = Some(follower);
        self
    }

    /// The split-law variant of `fem_forces_split` (None for the (λ, μ) laws).
    pub fn split_variant(&self) -> Option<crate::cpu::fem_forces_split::SplitVariant> {
        let h = self.hyperelastic.as_ref()?;
        self.material
            .model
            .is_split()
            .then(|| crate::cpu::fem_forces_split::SplitVariant {
                model: self.material.model,
                viscous: self.material.is_viscous(),
                volumetric: h.volumetric,
                nodal_pressure: h.volume_term == crate::material::VolumeTerm::NodalAverage,
            })
    }

    /// The uniform of the split kernels (zeros for the (λ, μ) laws).
    pub fn material_constants(&self) -> crate::material::MaterialConstants {
        self.hyperelastic
            .as_ref()
            .map(|h| h.constants())
            .unwrap_or_default()
    }

    /// Build from a validated scene (a scene with particles samples them here; see
    /// [`Model::try_from_scene`] for the errors that can bring).
    pub fn from_scene(scene: &Scene) -> Model {
        Model::try_from_scene(scene).expect("a validated scene whose particles sample")
    }

    /// The scene's material as the model steps it: its density times the solver's mass
    /// scaling (the inertia the stable step is bounded by).
    pub fn stepped_material(scene: &Scene) -> MaterialParams {
        let mut material = scene.material;
        material.density *= scene.solver.mass_scaling;
        material
    }

    /// Build from a validated scene; sampling the particle zone can fail (a spacing too
    /// coarse for the zone), with an error naming the key.
    pub fn try_from_scene(scene: &Scene) -> crate::error::Result<Model> {
        // Mass scaling s: inertia s·ρ, gravity g/s (the weight ρ·g is unchanged).
        let s = scene.solver.mass_scaling;
        let material = Model::stepped_material(scene);
        let gravity = scene.gravity.map(|g| g / s);
        let mut model = Model::with_loads(
            &scene.mesh,
            &scene.fixed,
            material,
            gravity,
            &scene.external_forces,
        );
        model.safety = scene.solver.safety;
        if let Some(h) = scene.hyperelastic {
            model = model.with_hyperelastic(h, scene.fibre);
        }
        if let Some(f) = &scene.follower {
            model = model.with_follower(FollowerModel::new(f, scene.mesh.n_vertices()));
        }
        if let Some(settings) = &scene.particles {
            let p = crate::particles::Particles::sample(
                &scene.mesh,
                settings,
                material.density,
                &scene.origin,
            )?;
            model = model.with_particles(&scene.fixed, p);
        }
        let Some(tool) = &scene.tool else {
            return model.with_exact_coupling(&scene.origin);
        };
        let model = model.with_tool(&scene.mesh, tool.clone());
        let b = model.bounds;
        if b.dt_contact * crate::timestep::MAX_CONTACT_STIFFENING < b.dt_elastic {
            // Which key: the stiffness when the springs alone, undamped, are already too stiff.
            let undamped = model.tool.as_ref().map_or(f64::INFINITY, |t| {
                t.spring_dt_bound(0.0, &model.mass, &model.inv_mass)
            });
            let item = if undamped * crate::timestep::MAX_CONTACT_STIFFENING < b.dt_elastic {
                "tool.stiffness"
            } else {
                "tool.damping"
            };
            return Err(crate::error::PalpateError::SceneValue {
                origin: scene.origin.clone(),
                item: item.into(),
                message: format!(
                    "the tool's contact springs (stiffness {:e} Pa/m, damping {:e} Pa·s/m) need dt <= {:.3e} s, more than {:e} times below the tissue's {:.3e} s: a run would take that many times the steps; lower it",
                    tool.stiffness,
                    tool.damping,
                    b.dt_contact,
                    crate::timestep::MAX_CONTACT_STIFFENING,
                    b.dt_elastic
                ),
            });
        }
        model.with_exact_coupling(&scene.origin)
    }

    /// `particles.coupling = "exact"`: slave the vertices that carry no core mass to the
    /// initial dynamic set (every unpinned particle under `activation = "all"`, none under
    /// the tool, whose activations re-slave: `cpu/exact_activation.rs`) and take the particles' step bound as the core's
    /// (the exact coupling runs particles and vertices at one rate: no sub-steps). An error
    /// names a vertex that its particles can neither move nor place.
    fn with_exact_coupling(mut self, origin: &str) -> crate::error::Result<Model> {
        let Some(p) = self
            .particles
            .as_ref()
            .filter(|p| p.settings.exact_coupling)
        else {
            return Ok(self);
        };
        let slave = |dynamic: &[bool]| {
            crate::cpu::exact_coupling::Slaving::new(&self, p, dynamic).map_err(|e| {
                crate::error::PalpateError::SceneValue {
                    origin: origin.to_string(),
                    item: "particles.coupling".into(),
                    message: format!("\"exact\" cannot slave this zone: {e}"),
                }
            })
        };
        // Every unpinned particle dynamic: the largest set an activation can make. A vertex
        // that then has no mass hosts only dynamic particles, the same ones under any set
        // that leaves it massless, so if their fit spans three dimensions here it does under
        // every activation (and the closure keeps each follower a corner to lump onto).
        let all: Vec<bool> = p.pinned.iter().map(|&pin| !pin).collect();
        let slaving = slave(&all)?;
        // Under the tool the run starts with nothing dynamic.
        let slaving = if p.settings.all_active {
            slaving
        } else {
            slave(&vec![false; p.len()])?
        };
        let contact = self
            .tool
            .as_ref()
            .map(|t| (t.tool.stiffness, t.tool.damping));
        let bound = p.dt_bound(&self.material, contact);
        self.bounds = self.bounds.with_particles(bound);
        self.slaving = Some(std::sync::Arc::new(slaving));
        Ok(self)
    }

    /// Add the particle layer: vertex masses become the core mass plus the particles'
    /// masses lumped with their barycentric weights (all particles start embedded).
    pub fn with_particles(
        mut self,
        fixed: &[bool],
        mut particles: crate::particles::Particles,
    ) -> Model {
        // Particles on the core side of their host — at least half their barycentric weight on
        // vertices of core tets (outside the particle region) or fixed ones — stay embedded:
        // they tie the particle zone to the rest of the body. (Not "vertices with core mass":
        // a zone tet too thin to hold a lattice point keeps its mass on its vertices, and
        // anchoring those pinned most of a finely layered zone.)
        let mut anchored: Vec<bool> = fixed.to_vec();
        for (t, &region) in self.tets.iter().zip(&self.regions) {
            if region != particles.settings.region {
                for &v in t {
                    anchored[v as usize] = true;
                }
            }
        }
        particles.pinned = (0..particles.len())
            .map(|p| {
                let t = self.tets[particles.host[p] as usize];
                let w: f32 = (0..4)
                    .filter(|&c| anchored[t[c] as usize])
                    .map(|c| particles.weights[4 * p + c])
                    .sum();
                w >= 0.5
            })
            .collect();
        self.mass = particles.embedded_mass();
        self.inv_mass = self
            .mass
            .iter()
            .zip(fixed)
            .map(|(&m, &f)| if f || m <= 0.0 { 0.0 } else { 1.0 / m })
            .collect();
        self.particles = Some(particles);
        self
    }

    /// Add a tool: its surface data, and its contact springs in the stable step
    /// (see [`TimeStepBounds::with_contact`]).
    pub fn with_tool(mut self, mesh: &TetMesh, tool: crate::scene::Tool) -> Model {
        let t = crate::contact::ToolModel::new(mesh, tool);
        self.bounds = self
            .bounds
            .with_contact(t.contact_dt_bound(&self.mass, &self.inv_mass));
        self.tool = Some(t);
        self
    }

    /// Refuse a model whose values do not survive the conversion to f32 (a modulus above
    /// 3e38 Pa, a mesh so small that tet volumes underflow, …): the kernels would produce
    /// Inf/NaN at the first step and the run would blame the time step.
    pub fn check_f32(&self) -> crate::error::Result<()> {
        let bad = |what: String| {
            crate::error::PalpateError::Usage(format!(
                "the scene's values do not fit single precision (f32): {what}; rescale the units"
            ))
        };
        let m = &self.material;
        for (name, v) in [
            ("lambda", m.lambda),
            ("mu", m.mu),
            ("phi", m.phi),
            ("psi", m.psi),
        ] {
            if !(v as f32).is_finite() {
                return Err(bad(format!(
                    "material {name} = {v:e} (as the scene's [material] moduli and viscosity give it)"
                )));
            }
        }
        if (m.mu as f32) <= 0.0 || !(m.p_wave_speed() as f32).is_finite() {
            return Err(bad(format!(
                "shear modulus {:e} Pa, wave speed {:e} m/s",
                m.mu,
                m.p_wave_speed()
            )));
        }
        if let Some(e) = self
            .rest_volume
            .iter()
            .position(|v| !(v.is_finite() && *v > 0.0))
        {
            return Err(bad(format!(
                "tet {e} has volume {:e} m³ in f32",
                self.rest_volume[e]
            )));
        }
        if let Some(k) = self.dm_inv.iter().position(|v| !v.is_finite()) {
            return Err(bad(format!(
                "tet {} has a non-finite inverse rest shape",
                k / 9
            )));
        }
        if let Some(i) = self.inv_mass.iter().position(|v| !v.is_finite()) {
            return Err(bad(format!(
                "vertex {i} has mass {:e} kg in f32",
                self.mass[i]
            )));
        }
        if let Some(k) = self.external_forces.iter().position(|v| !v.is_finite()) {
            return Err(bad(format!("vertex {} has a non-finite load", k / 3)));
        }
        if !self.gravity.iter().all(|g| g.is_finite()) {
            return Err(bad(format!(
                "loads.gravity has a component beyond ±3.4e38 m/s² (in f32: {:?})",
                self.gravity
            )));
        }
        if let Some(f) = &self.follower {
            if let Some(k) = f.face_pressure.iter().position(|p| !p.is_finite()) {
                return Err(bad(format!(
                    "loads.follower_pressure: face {k} has pressure {:e} Pa in f32",
                    f.face_pressure[k]
                )));
            }
        }
        if let Some(t) = &self.tool {
            let tool = &t.tool;
            let fits = |v: f64| (v as f32).is_finite();
            for (key, v) in [
                ("tool.radius", tool.radius),
                ("tool.stiffness", tool.stiffness),
                ("tool.damping", tool.damping),
            ] {
                if !fits(v) {
                    return Err(bad(format!("{key} = {v:e}")));
                }
            }
            let far = std::iter::once(tool.home)
                .chain(tool.path.iter().map(|(_, x)| *x))
                .find(|x| !x.to_array().into_iter().all(fits));
            if let Some(x) = far {
                let x = x.to_array().map(|c| format!("{c:e}"));
                return Err(bad(format!(
                    "tool.path or tool.home has the point [{}] m",
                    x.join(", ")
                )));
            }
        }
        if let Some(p) = &self.particles {
            // The hourglass penalty's weight, ½ α E V² (as `cpu::sph::PairTable` forms it).
            let youngs = self.material.youngs_modulus();
            let weight = 0.5 * p.settings.hourglass as f32 * youngs as f32 * (p.volume * p.volume);
            if !weight.is_finite() {
                return Err(bad(format!(
                    "particles.hourglass = {:e} gives a penalty weight ½·hourglass·E·V² = {weight:e}",
                    p.settings.hourglass
                )));
            }
            if !(p.mass > 0.0
                && p.mass.is_finite()
                && (1.0 / p.mass).is_finite()
                && p.volume > 0.0
                && p.volume.is_finite())
            {
                return Err(bad(format!(
                    "a particle has mass {:e} kg and volume {:e} m³ in f32",
                    p.mass, p.volume
                )));
            }
        }
        Ok(())
    }

    /// The `fem_forces` kernel variant this model needs (material, viscous or not).
    pub fn fem_variant(&self) -> crate::cpu::fem_forces::FemVariant {
        crate::cpu::fem_forces::FemVariant {
            model: self.material.model,
            viscous: self.material.is_viscous(),
        }
    }

    /// Particle sub-steps per core step of `dt`: ⌈dt / (safety·particle bound)⌉ with the
    /// scene's safety factor (1 without particles or with the exact coupling, whose core
    /// step is the particles'; at most 64).
    pub fn particle_substeps(&self, dt: f64) -> u32 {
        self.particle_bound_terms()
            .map_or(1, |t| t.substeps(dt, self.safety, 1.0))
    }

    /// The terms of the particles' step bound with the tool's contact
    /// ([`crate::particles::Particles::bound_terms`]); None without particles or with the
    /// exact coupling (whose particles step at the core's rate).
    pub fn particle_bound_terms(&self) -> Option<crate::particles::ParticleBoundTerms> {
        let p = self.particles.as_ref().filter(|_| self.slaving.is_none())?;
        let contact = self
            .tool
            .as_ref()
            .map(|t| (t.tool.stiffness, t.tool.damping));
        Some(p.bound_terms(&self.material, contact))
    }

    /// The particles' per-run uniform for core step `params.dt` (None without particles).
    pub fn particle_params(
        &self,
        params: &StepParams,
    ) -> Option<crate::particles::params::ParticleParams> {
        let p = self.particles.as_ref()?;
        let s = &p.settings;
        let dt = params.dt as f64;
        let substeps = self.particle_substeps(dt);
        let youngs = self.material.youngs_modulus();
        Some(
            crate::particles::params::ParticleParams {
                n_particles: p.len() as u32,
                model: s.model.index(),
                substeps,
                all_active: s.all_active as u32,
                volume: p.volume,
                mass: p.mass,
                spacing: s.spacing as f32,
                support: p.support,
                hourglass: s.hourglass as f32,
                youngs: youngs as f32,
                activation_radius: s.activation_radius as f32,
                release_radius: (s.activation_radius * s.hysteresis) as f32,
                candidate_radius: (s.activation_radius * s.hysteresis + 2.0 * p.support as f64)
                    as f32,
                dwell: s.dwell as f32,
                blend: s.blend as f32,
                interval: 0.0,
                sub_dt: 0.0,
                n_surface: self.tool_params().n_surface,
                _pad: [0; 2],
            }
            .at_core_dt(params.dt, s.activation_interval),
        )
    }

    /// The tool's per-run uniform with the particle count (the default without a tool).
    pub fn tool_params(&self) -> crate::contact::ToolParams {
        let mut t = self.tool.as_ref().map(|t| t.params()).unwrap_or_default();
        t.n_particles = self.particles.as_ref().map_or(0, |p| p.len() as u32);
        t
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.mass.len()
    }

    /// Shear (S-) wave speed of the stepped material (mass scaling included),
    /// c_s = sqrt(μ/ρ), m/s; μ the small-strain shear modulus (Guccione's effective one).
    pub fn shear_wave_speed(&self) -> f64 {
        let m = &self.material;
        let mu = self
            .hyperelastic
            .as_ref()
            .map_or(m.mu, |h| h.shear_modulus(m.model, m.mu));
        (mu / m.density).sqrt()
    }

    /// The fastest a haptic session moves the simulated tool, m/s:
    /// [`TOOL_SPEED_SHEAR_WAVES`] · c_s ([`Model::shear_wave_speed`]).
    pub fn max_tool_speed(&self) -> f64 {
        TOOL_SPEED_SHEAR_WAVES * self.shear_wave_speed()
    }

    /// Number of tets.
    pub fn n_tets(&self) -> usize {
        self.tets.len()
    }

    /// Step parameters for time step `dt` and damping α.
    pub fn step_params(&self, dt: f64, damping: f64) -> StepParams {
        let m = &self.material;
        StepParams {
            n_vertices: self.n_vertices() as u32,
            n_tets: self.n_tets() as u32,
            dt: dt as f32,
            damping: damping as f32,
            gravity: self.gravity,
            lambda: m.lambda as f32,
            mu: m.mu as f32,
            phi: m.phi as f32,
            psi: m.psi as f32,
            speed_limit: (SPEED_LIMIT_WAVE_SPEEDS * m.p_wave_speed()) as f32,
        }
    }
}
