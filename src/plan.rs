//! The step plan: which stages one step runs, in which order and how often, built from the
//! model. The GPU stepper records this list and the CPU stepper executes the same list, so
//! the two backends cannot drift apart; profiling, `palpate info` and `ARCHITECTURE.md` name
//! stages from it. The GPU may record two stages of it as one dispatch where the list leaves
//! their order free ([`StepPlan::gpu_fusions`]): the same work, one pass fewer.
//!
//! Adding a stage means: a [`Stage`] variant with its row in [`Stage::entries`], a line in
//! `StepPlan::for_model_at` (behind [`StepPlan::for_model`]) that says when it runs, its kernel in `kernels/`, its CPU twin in
//! `src/cpu/` (called from the CPU stepper's `run_stage`), and its test.

use crate::model::Model;

/// One stage of a step: a kernel file in `kernels/` and its CPU twin in `src/cpu/`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// One thread: the tool's centre for this step of the batch.
    ToolMotion,
    /// Particles: which are dynamic, the stress and force sets, compacted lists with
    /// indirect dispatch arguments, tet energy weights, vertex masses (every K steps).
    Activate,
    /// Per particle of the force set: embedded particles follow their host.
    Follow,
    /// Per particle of the stress set: deformation gradient and stress.
    SphStress,
    /// Per particle of the force set: SPH forces (the first sub-step of a core step).
    SphForces,
    /// Per particle of the force set: SPH forces, added to the sub-step sum (later sub-steps).
    SphForcesAccumulate,
    /// Per dynamic particle: symplectic Euler with the particle sub-step.
    IntegrateParticles,
    /// Per loaded face: follower-pressure corner forces on the deformed surface; then per
    /// vertex: external forces = dead loads + the follower forces around it.
    FollowerPressure,
    /// Average nodal Jacobian: per tet the volume change, then per vertex the pressure
    /// U′(J_a) and volumetric energy density U(J_a).
    NodalPressure,
    /// Per tet: deformation gradient, material stress, four corner forces, energy.
    FemForces,
    /// Per tet: as `FemForces` for the volume/shape split laws (`MATERIAL` 3–6).
    FemForcesSplit,
    /// Per surface vertex: the tool's penalty contact force.
    Contact,
    /// Per vertex: Σ incident corner forces + m·g + f_ext (CSR, fixed order).
    Gather,
    /// Per vertex: as `Gather`, plus the tool's contact force and the forces of the embedded
    /// particles the vertex hosts (scenes with a tool or particles).
    GatherCoupled,
    /// Per vertex: symplectic Euler, constraints, divergence flag.
    Integrate,
    /// Force on the tool and its frozen-tissue stiffness (two-level tree reduction).
    ToolForce,
    /// Energies, max speed, residual (two-level tree reduction).
    Reduce,
    /// The particles' energies, max speed and residual (two-level tree reduction).
    ParticleReduce,
    /// Design 8 (`particles.coupling = "exact"`): `Activate`, then the vertices' masses of
    /// the slaving and the slaved vertices placed on their particles' fit (every K steps).
    ActivateExact,
    /// Design 8, per dynamic particle: its offset δ = u − Σ wₐ uₐ off its embedded place;
    /// then per particle of S: the remainder's stress, energy and its host's tangent forces.
    ExactStress,
    /// Design 8, per particle of F: the pair force (dynamic) and hourglass penalty, and what
    /// its host vertices take through its weights.
    ExactForces,
    /// Design 8, per vertex: `GatherCoupled`'s core sum plus, over its force-set slots, the
    /// host forces and the tangent corner forces.
    ExactGather,
    /// Design 8: slaved vertices pass their force to their particles, vertices and dynamic
    /// particles step, slaved vertices take their particles' fit.
    ExactIntegrate,
}

/// The threads a kernel entry point is dispatched over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Domain {
    /// One thread per tet.
    Tets,
    /// One thread per vertex.
    Vertices,
    /// One thread per index below max(vertices, tets) (reduction blocks).
    VerticesAndTets,
    /// One thread per boundary-surface vertex.
    SurfaceVertices,
    /// One thread per face loaded by a follower pressure.
    FollowerFaces,
    /// One thread per particle.
    Particles,
    /// One thread per particle and one more (prefix sums over n + 1 marks).
    ParticlesPlusOne,
    /// One thread per run of `cpu::scan::SCAN_BLOCK` of the n + 1 marks (a prefix sum's
    /// `scan_local`).
    ParticleScanRuns,
    /// One thread per entry of the dynamic list: indirect over its arguments (64-thread
    /// workgroups) when the model has particles, else a single idle workgroup.
    DynamicParticles,
    /// A single workgroup.
    OneWorkgroup,
    /// Workgroup counts read from an indirect-argument buffer written by an earlier kernel:
    /// (buffer name, byte offset of the `DispatchIndirectArgs`).
    Indirect(&'static str, u64),
    /// The activation's gated passes: this domain's whole grid when the activation gate is
    /// raised (a particle became or stopped being dynamic), else no workgroup; indirect,
    /// from the arguments `activate_gate` writes (`activation_args`).
    Gated(&'static Domain),
    /// A fused dispatch ([`Fusion`]): the host's domain, grown where the particles
    /// outnumber it so that its threads cover every particle in at most
    /// [`MAX_RIDER_ROUNDS`] rounds of the rider's grid-stride loop (a few hundred tets or
    /// vertices under thousands of dynamic particles do not walk them in series).
    CoveringParticles(&'static Domain),
}

/// The most rounds a fused dispatch's rider loop takes ([`Domain::CoveringParticles`]). A
/// round is one particle's loads and stores, a pass of its own a launch and a barrier: four
/// rounds cost about as much as the pass the fusion saves. Covering every particle in one
/// round instead gives hm1's fused passes 4.5× (fem_forces) and 4.7× (gather) the host's
/// workgroups, mostly empty, which lavapipe pays for dearly (BENCHMARKS.md).
pub const MAX_RIDER_ROUNDS: u32 = 4;

/// One kernel entry point of a stage.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Entry {
    /// Kernel file in `kernels/` (without `.wgsl`).
    pub file: &'static str,
    /// Entry point name.
    pub entry: &'static str,
    /// What it is dispatched over.
    pub domain: Domain,
    /// Bindings whose buffer has another name than the WGSL global: (global, buffer). A
    /// generic kernel (a prefix sum) runs over different buffers this way.
    pub aliases: &'static [(&'static str, &'static str)],
}

impl Stage {
    /// Every stage, in step order.
    pub const ALL: [Stage; 4] = [
        Stage::FemForces,
        Stage::Gather,
        Stage::Integrate,
        Stage::Reduce,
    ];

    /// The stage's name: its kernel file and the label of its GPU debug group.
    pub fn name(self) -> &'static str {
        match self {
            Stage::ToolMotion => "tool_motion",
            Stage::Activate => "activate",
            Stage::Follow => "follow",
            Stage::SphStress => "sph_stress",
            Stage::SphForces => "sph_forces",
            Stage::SphForcesAccumulate => "sph_forces_accumulate",
            Stage::IntegrateParticles => "integrate_particles",
            Stage::GatherCoupled => "gather_coupled",
            Stage::ParticleReduce => "particle_reduce",
            Stage::Contact => "contact",
            Stage::ToolForce => "tool_force",
            Stage::FemForces => "fem_forces",
            Stage::FollowerPressure => "follower_pressure",
            Stage::NodalPressure => "nodal_pressure",
            Stage::FemForcesSplit => "fem_forces_split",
            Stage::Gather => "gather",
            Stage::Integrate => "integrate",
            Stage::Reduce => "reduce",
            Stage::ActivateExact => "activate_exact",
            Stage::ExactStress => "exact_stress",
            Stage::ExactForces => "exact_forces",
            Stage::ExactGather => "exact_gather",
            Stage::ExactIntegrate => "exact_integrate",
        }
    }

    /// The kernel entry points the stage dispatches, in order.
    pub fn entries(self) -> &'static [Entry] {
        match self {
            Stage::ToolMotion => &[Entry {
                file: "tool_motion",
                entry: "tool_motion",
                domain: Domain::OneWorkgroup,
                aliases: &[],
            }],
            Stage::Activate => ACTIVATE,
            Stage::ActivateExact => ACTIVATE_EXACT,
            Stage::ExactStress => &[
                Entry {
                    file: "exact_stress",
                    entry: "exact_offsets",
                    domain: Domain::Indirect("particle_dispatch", 12),
                    aliases: &[],
                },
                Entry {
                    file: "exact_stress",
                    entry: "exact_stress",
                    domain: Domain::Indirect("particle_dispatch", 12),
                    aliases: &[],
                },
            ],
            Stage::ExactForces => &[Entry {
                file: "exact_forces",
                entry: "exact_forces",
                domain: Domain::Indirect("particle_dispatch", 24),
                aliases: &[],
            }],
            Stage::ExactGather => &[Entry {
                file: "gather",
                entry: "gather_exact",
                domain: Domain::Vertices,
                aliases: &[],
            }],
            Stage::ExactIntegrate => &[
                Entry {
                    file: "exact_slaving",
                    entry: "exact_slaving_transfer",
                    domain: Domain::Indirect("particle_dispatch", 0),
                    aliases: &[],
                },
                Entry {
                    file: "integrate",
                    entry: "integrate",
                    domain: Domain::Vertices,
                    aliases: &[],
                },
                Entry {
                    file: "integrate_particles",
                    entry: "integrate_particles",
                    domain: Domain::Indirect("particle_dispatch", 0),
                    aliases: &[],
                },
                Entry {
                    file: "exact_slaving",
                    entry: "exact_slaving_place",
                    domain: Domain::Vertices,
                    aliases: &[],
                },
            ],
            Stage::Follow => &[Entry {
                file: "follow",
                entry: "follow",
                domain: Domain::Indirect("particle_dispatch", 24),
                aliases: &[],
            }],
            Stage::SphStress => &[Entry {
                file: "sph_stress",
                entry: "sph_stress",
                domain: Domain::Indirect("particle_dispatch", 12),
                aliases: &[],
            }],
            Stage::SphForces | Stage::SphForcesAccumulate => &[Entry {
                file: "sph_forces",
                entry: "sph_forces",
                domain: Domain::Indirect("particle_dispatch", 24),
                aliases: &[],
            }],
            Stage::IntegrateParticles => &[Entry {
                file: "integrate_particles",
                entry: "integrate_particles",
                domain: Domain::Indirect("particle_dispatch", 0),
                aliases: &[],
            }],
            Stage::GatherCoupled => &[Entry {
                file: "gather",
                entry: "gather_coupled",
                domain: Domain::Vertices,
                aliases: &[],
            }],
            Stage::ParticleReduce => &[
                Entry {
                    file: "particle_reduce",
                    entry: "particle_reduce_partial",
                    domain: Domain::Indirect("particle_dispatch", 12),
                    aliases: &[],
                },
                Entry {
                    file: "particle_reduce",
                    entry: "particle_reduce_final",
                    domain: Domain::OneWorkgroup,
                    aliases: &[],
                },
            ],
            Stage::Contact => &[Entry {
                file: "contact",
                entry: "contact",
                domain: Domain::SurfaceVertices,
                aliases: &[],
            }],
            Stage::ToolForce => &[
                Entry {
                    file: "tool_force",
                    entry: "tool_force_partial",
                    domain: Domain::SurfaceVertices,
                    aliases: &[],
                },
                Entry {
                    file: "tool_force",
                    entry: "tool_force_particles",
                    domain: Domain::DynamicParticles,
                    aliases: &[],
                },
                Entry {
                    file: "tool_force",
                    entry: "tool_force_final",
                    domain: Domain::OneWorkgroup,
                    aliases: &[],
                },
            ],
            Stage::FemForces => &[Entry {
                file: "fem_forces",
                entry: "fem_forces",
                domain: Domain::Tets,
                aliases: &[],
            }],
            Stage::FollowerPressure => &[
                Entry {
                    file: "follower_pressure",
                    entry: "follower_pressure",
                    domain: Domain::FollowerFaces,
                    aliases: &[],
                },
                Entry {
                    file: "follower_pressure_gather",
                    entry: "follower_pressure_gather",
                    domain: Domain::Vertices,
                    aliases: &[],
                },
            ],
            Stage::NodalPressure => &[
                Entry {
                    file: "tet_volume_change",
                    entry: "tet_volume_change",
                    domain: Domain::Tets,
                    aliases: &[],
                },
                Entry {
                    file: "nodal_pressure",
                    entry: "nodal_pressure",
                    domain: Domain::Vertices,
                    aliases: &[],
                },
            ],
            Stage::FemForcesSplit => &[Entry {
                file: "fem_forces_split",
                entry: "fem_forces_split",
                domain: Domain::Tets,
                aliases: &[],
            }],
            Stage::Gather => &[Entry {
                file: "gather",
                entry: "gather",
                domain: Domain::Vertices,
                aliases: &[],
            }],
            Stage::Integrate => &[Entry {
                file: "integrate",
                entry: "integrate",
                domain: Domain::Vertices,
                aliases: &[],
            }],
            Stage::Reduce => &[
                Entry {
                    file: "reduce",
                    entry: "reduce_partial",
                    domain: Domain::VerticesAndTets,
                    aliases: &[],
                },
                Entry {
                    file: "reduce",
                    entry: "reduce_final",
                    domain: Domain::OneWorkgroup,
                    aliases: &[],
                },
            ],
        }
    }
}

/// The activation stage: the mode machine, the gate, the two set marks, the compaction
/// (marks, one prefix sum per list, scatter, dispatch arguments), tet weights and vertex
/// masses. The passes between the gate and the relump ([`Domain::Gated`]) run only when the
/// dynamic set changed.
const ACTIVATE: &[Entry] = {
    const fn e(file: &'static str, entry: &'static str, domain: Domain) -> Entry {
        Entry {
            file,
            entry,
            domain,
            aliases: &[],
        }
    }
    const fn scan(
        entry: &'static str,
        domain: Domain,
        aliases: &'static [(&'static str, &'static str)],
    ) -> Entry {
        Entry {
            file: "scan",
            entry,
            domain,
            aliases,
        }
    }
    const D: &[(&str, &str)] = &[
        ("scan_params", "list_scan_params"),
        ("scan_data", "dynamic_scan"),
        ("scan_blocks", "dynamic_scan_blocks"),
    ];
    const S: &[(&str, &str)] = &[
        ("scan_params", "list_scan_params"),
        ("scan_data", "stress_scan"),
        ("scan_blocks", "stress_scan_blocks"),
    ];
    const F: &[(&str, &str)] = &[
        ("scan_params", "list_scan_params"),
        ("scan_data", "force_scan"),
        ("scan_blocks", "force_scan_blocks"),
    ];
    // Gated: they run only when the dynamic set changed (activate_gate).
    const PARTICLES: Domain = Domain::Gated(&Domain::Particles);
    const P1: Domain = Domain::Gated(&Domain::ParticlesPlusOne);
    const RUNS: Domain = Domain::Gated(&Domain::ParticleScanRuns);
    const ONE: Domain = Domain::Gated(&Domain::OneWorkgroup);
    &[
        e("activate", "activate", Domain::Particles),
        e("activate", "activate_gate", Domain::OneWorkgroup),
        e("activate", "activate_clear_sets", PARTICLES),
        e("activate", "activate_stress_set", PARTICLES),
        e("activate", "activate_force_set", PARTICLES),
        e("compact", "compact_mark", P1),
        scan("scan_local", RUNS, D),
        scan("scan_totals", ONE, D),
        scan("scan_apply", P1, D),
        scan("scan_local", RUNS, S),
        scan("scan_totals", ONE, S),
        scan("scan_apply", P1, S),
        scan("scan_local", RUNS, F),
        scan("scan_totals", ONE, F),
        scan("scan_apply", P1, F),
        e("compact", "compact_scatter", PARTICLES),
        e("compact", "compact_args", ONE),
        e(
            "activate",
            "activate_tet_weights",
            Domain::Gated(&Domain::Tets),
        ),
        e("activate", "activate_relump", Domain::Vertices),
    ]
};

/// How many passes of the activation stage are gated: one `DispatchIndirectArgs` each in
/// `activation_args` and `activation_full_args`, in entry order.
pub const ACTIVATE_GATED_PASSES: usize = {
    let mut n = 0;
    let mut k = 0;
    while k < ACTIVATE.len() {
        if matches!(ACTIVATE[k].domain, Domain::Gated(_)) {
            n += 1;
        }
        k += 1;
    }
    n
};

/// Design 8's activation (`particles.coupling = "exact"`, activation = "all" on the GPU):
/// [`ACTIVATE`], then the slaving's vertex masses and the slaved vertices placed on their fit.
const ACTIVATE_EXACT: &[Entry] = &{
    let mut all = [ACTIVATE[0]; ACTIVATE.len() + 1];
    let mut k = 0;
    while k < ACTIVATE.len() {
        all[k] = ACTIVATE[k];
        k += 1;
    }
    all[ACTIVATE.len()] = Entry {
        file: "exact_slaving",
        entry: "exact_slaving_relump",
        domain: Domain::Vertices,
        aliases: &[],
    };
    all
};

/// Two stages of a plan the GPU records as one dispatch: `entry`, a kernel of the host's file
/// that does the host's per-item work and, in a grid-stride loop over its list on the same
/// grid, the rider's. The two read nothing the other writes, and nothing the plan runs
/// between their positions reads or writes what the moved one writes or reads, so the result
/// is the plan's, bit for bit, with one pass fewer a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Fusion {
    /// The stage whose grid the dispatch covers.
    pub host: Stage,
    /// The stage whose work rides on it.
    pub rider: Stage,
    /// The fused kernel entry (over [`Domain::CoveringParticles`] of the host's domain, or
    /// an indirect grid the activation sizes for both).
    pub entry: Entry,
    /// Plan position where the fused dispatch is recorded.
    pub at: usize,
    /// Plan position whose pass is then not recorded.
    pub skipped: usize,
    /// Measured to pay on a real GPU, so built by default ([`Fusions::Measured`]); the others
    /// only with [`Fusions::All`].
    pub measured: bool,
}

/// Which of a plan's fused dispatches ([`StepPlan::gpu_fusions`]) a GPU stepper builds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fusions {
    /// None: every stage its own passes.
    None,
    /// Those measured to pay on a real GPU (follow on fem_forces, integrate_particles on
    /// gather_coupled; NVIDIA H200, BENCHMARKS.md): the default.
    Measured,
    /// Also those not measured on a real GPU yet (sph_stress on contact).
    All,
}

impl Fusions {
    /// From `PALPATE_GPU_FUSION`: `0` none, `1` (or unset, or empty) the measured, `all`
    /// all; any other value is an error naming the variable.
    pub fn from_env() -> crate::error::Result<Fusions> {
        Fusions::parse(std::env::var("PALPATE_GPU_FUSION").ok().as_deref())
    }

    /// [`Self::from_env`] of the variable's value (None: unset).
    pub fn parse(value: Option<&str>) -> crate::error::Result<Fusions> {
        match value {
            Some("0") => Ok(Fusions::None),
            None | Some("") | Some("1") => Ok(Fusions::Measured),
            Some("all") => Ok(Fusions::All),
            Some(other) => Err(crate::error::PalpateError::Usage(format!(
                "PALPATE_GPU_FUSION='{other}' is not one of 0 (no fused passes), 1 (the measured ones, the default), all"
            ))),
        }
    }

    /// Whether fusion `f` is built under this choice.
    pub fn builds(self, f: &Fusion) -> bool {
        match self {
            Fusions::None => false,
            Fusions::Measured => f.measured,
            Fusions::All => true,
        }
    }
}

/// A pair of stages the GPU may record as one dispatch ([`StepPlan::gpu_fusions`]).
struct FusionRule {
    host: Stage,
    rider: Stage,
    entry: Entry,
    /// Which of the rider's places in the plan: its last (else its first).
    last_rider: bool,
    /// Record the fused dispatch at the rider's place (else at the host's).
    at_rider: bool,
    /// The stages that may lie between that rider and the host.
    between: &'static [Stage],
    /// [`Fusion::measured`].
    measured: bool,
}

/// The pairs the GPU fuses where the plan allows.
const FUSION_RULES: [FusionRule; 3] = [
    // `follow` on `fem_forces`' grid, at the first follow's place: the element forces move
    // ahead of the particle sub-steps, which neither read nor write their arrays.
    FusionRule {
        host: Stage::FemForces,
        rider: Stage::Follow,
        entry: Entry {
            file: "fem_forces",
            entry: "fem_forces_follow",
            domain: Domain::CoveringParticles(&Domain::Tets),
            aliases: &[],
        },
        last_rider: false,
        at_rider: true,
        between: &[
            Stage::SphStress,
            Stage::SphForces,
            Stage::SphForcesAccumulate,
            Stage::IntegrateParticles,
            Stage::Follow,
        ],
        measured: true,
    },
    // The last `integrate_particles` on `gather_coupled`'s grid, at the gather's place: the
    // element forces and the contact between read no particle position or velocity.
    FusionRule {
        host: Stage::GatherCoupled,
        rider: Stage::IntegrateParticles,
        entry: Entry {
            file: "gather",
            entry: "gather_coupled_integrate",
            domain: Domain::CoveringParticles(&Domain::Vertices),
            aliases: &[],
        },
        last_rider: true,
        at_rider: false,
        between: &[Stage::FemForces, Stage::Contact],
        measured: true,
    },
    // The first `sph_stress` on `contact`'s grid, at its place: the contact moves ahead of
    // the particle sub-steps and the element forces, which neither read nor write what it
    // does (the vertices' state, the tool's, the contact weights; its contact forces are
    // read by the gather and the tool's force, after).
    FusionRule {
        host: Stage::Contact,
        rider: Stage::SphStress,
        entry: Entry {
            file: "contact",
            entry: "contact_sph_stress",
            // The larger of the stress set's grid and the surface's (`compact_args`).
            domain: Domain::Indirect("particle_dispatch", 36),
            aliases: &[],
        },
        last_rider: false,
        at_rider: true,
        between: &[
            Stage::SphForces,
            Stage::SphForcesAccumulate,
            Stage::IntegrateParticles,
            Stage::Follow,
            Stage::SphStress,
            Stage::FemForces,
        ],
        // On lavapipe the fused pass takes 1.7x the two it replaces (hm1: 2.45 ms against
        // 1.25 + 0.17); not measured on a GPU, so not built by default.
        measured: false,
    },
];

/// When a planned stage runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum When {
    /// Every step.
    EveryStep,
    /// Every `k`-th step of the run (global step index divisible by k).
    EveryKSteps(u32),
    /// Only on the last step of a batch (diagnostics read back once per batch).
    LastStepOfBatch,
}

/// A stage and when it runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct PlannedStage {
    /// The stage.
    pub stage: Stage,
    /// Its schedule.
    pub when: When,
}

impl PlannedStage {
    /// True when it runs at step `global_step` (0-based over the run), which is step
    /// `step_in_batch` of a batch of `batch_len` steps.
    pub fn runs_at(&self, global_step: u64, step_in_batch: u32, batch_len: u32) -> bool {
        match self.when {
            When::EveryStep => true,
            When::EveryKSteps(k) => global_step.is_multiple_of(k.max(1) as u64),
            When::LastStepOfBatch => step_in_batch + 1 == batch_len,
        }
    }
}

/// The particle stages of one core step, every step: `substeps` times Follow, SphStress,
/// SphForces (the first time; then SphForcesAccumulate), IntegrateParticles.
fn particle_substep_block(substeps: u32) -> impl Iterator<Item = PlannedStage> {
    (0..substeps.max(1)).flat_map(|k| {
        [
            Stage::Follow,
            Stage::SphStress,
            if k == 0 {
                Stage::SphForces
            } else {
                Stage::SphForcesAccumulate
            },
            Stage::IntegrateParticles,
        ]
        .map(|stage| PlannedStage {
            stage,
            when: When::EveryStep,
        })
    })
}

/// The ordered list of stages of one step.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct StepPlan {
    /// Stages in execution order.
    pub stages: Vec<PlannedStage>,
}

impl StepPlan {
    /// The plan a model needs: only the stages its scene uses (one particle sub-step).
    pub fn for_model(model: &Model) -> StepPlan {
        StepPlan::for_model_at(model, 1)
    }

    /// The plan with `substeps` particle sub-steps per core step.
    pub fn for_model_at(model: &Model, substeps: u32) -> StepPlan {
        let every = |stage| PlannedStage {
            stage,
            when: When::EveryStep,
        };
        let last = |stage| PlannedStage {
            stage,
            when: When::LastStepOfBatch,
        };
        let tool = model.tool.is_some();
        // Particles run when something can make them dynamic: a tool, or activation = "all".
        let particles = model
            .particles
            .as_ref()
            .filter(|p| tool || p.settings.all_active);
        let mut stages = Vec::new();
        if tool {
            stages.push(every(Stage::ToolMotion));
        }
        // Design 8 runs particles and vertices at one rate, with its own stages.
        let exact = particles.is_some() && model.slaving.is_some();
        if let Some(p) = particles {
            stages.push(PlannedStage {
                stage: if exact {
                    Stage::ActivateExact
                } else {
                    Stage::Activate
                },
                when: When::EveryKSteps(p.settings.activation_interval),
            });
            if exact {
                stages.push(every(Stage::Follow));
                stages.push(every(Stage::ExactStress));
                stages.push(every(Stage::ExactForces));
            } else {
                stages.extend(particle_substep_block(substeps));
            }
        }
        if model.follower.is_some() {
            stages.push(every(Stage::FollowerPressure));
        }
        match model.split_variant() {
            Some(v) => {
                if v.nodal_pressure {
                    stages.push(every(Stage::NodalPressure));
                }
                stages.push(every(Stage::FemForcesSplit));
            }
            None => stages.push(every(Stage::FemForces)),
        }
        if tool {
            stages.push(every(Stage::Contact));
        }
        stages.push(every(if exact {
            Stage::ExactGather
        } else if tool || particles.is_some() {
            Stage::GatherCoupled
        } else {
            Stage::Gather
        }));
        stages.push(every(if exact {
            Stage::ExactIntegrate
        } else {
            Stage::Integrate
        }));
        if tool {
            stages.push(last(Stage::ToolForce));
        }
        stages.push(last(Stage::Reduce));
        if particles.is_some() {
            stages.push(last(Stage::ParticleReduce));
        }
        StepPlan { stages }
    }

    /// The stages step `global_step` (0-based, counted over the run) runs when it is step
    /// `step_in_batch` of a batch of `batch_len` steps, in order.
    pub fn stages_at(
        &self,
        global_step: u64,
        step_in_batch: u32,
        batch_len: u32,
    ) -> impl Iterator<Item = Stage> + '_ {
        self.stages
            .iter()
            .filter(move |p| p.runs_at(global_step, step_in_batch, batch_len))
            .map(|p| p.stage)
    }

    /// The pairs of stages the GPU records as one dispatch ([`Fusion`]) in a plan of the
    /// blend (design 8 and the split laws keep their passes): the first `follow` with
    /// `fem_forces`, when only the particle sub-steps lie between them; the last
    /// `integrate_particles` with `gather_coupled`, when only the element forces and the
    /// contact lie between them; and the first `sph_stress` with `contact`, when only the
    /// particle sub-steps and the element forces lie between them. Empty otherwise.
    pub fn gpu_fusions(&self) -> Vec<Fusion> {
        let every = |stage: Stage| {
            self.stages
                .iter()
                .enumerate()
                .filter(move |(_, p)| p.stage == stage && p.when == When::EveryStep)
                .map(|(k, _)| k)
        };
        FUSION_RULES
            .iter()
            .filter_map(|r| {
                let rider = match r.last_rider {
                    true => every(r.rider).next_back()?,
                    false => every(r.rider).next()?,
                };
                let host = every(r.host).next()?;
                let free = rider < host
                    && self.stages[rider + 1..host]
                        .iter()
                        .all(|p| r.between.contains(&p.stage));
                free.then_some(Fusion {
                    host: r.host,
                    rider: r.rider,
                    entry: r.entry,
                    at: if r.at_rider { rider } else { host },
                    skipped: if r.at_rider { host } else { rider },
                    measured: r.measured,
                })
            })
            .collect()
    }

    /// This plan with its particle sub-step block (`Follow`, `SphStress`, `SphForces` or
    /// `SphForcesAccumulate`, `IntegrateParticles`, repeated) run `substeps` times: what
    /// [`StepPlan::for_model_at`] gives for that count. Unchanged without the block (no
    /// particle stages, or design 8's, whose particles step at the core's rate).
    pub fn with_particle_substeps(&self, substeps: u32) -> StepPlan {
        let in_block = |s: Stage| {
            matches!(
                s,
                Stage::Follow
                    | Stage::SphStress
                    | Stage::SphForces
                    | Stage::SphForcesAccumulate
                    | Stage::IntegrateParticles
            )
        };
        if self.contains(Stage::ActivateExact) {
            return self.clone();
        }
        let Some(first) = self.stages.iter().position(|p| in_block(p.stage)) else {
            return self.clone();
        };
        let end = first
            + self.stages[first..]
                .iter()
                .take_while(|p| in_block(p.stage))
                .count();
        let mut stages = self.stages[..first].to_vec();
        stages.extend(particle_substep_block(substeps));
        stages.extend_from_slice(&self.stages[end..]);
        StepPlan { stages }
    }

    /// True when the plan contains `stage`.
    pub fn contains(&self, stage: Stage) -> bool {
        self.stages.iter().any(|p| p.stage == stage)
    }

    /// One line per stage: name, schedule and kernel entry points (for `palpate info` and
    /// the docs); then one per pair the GPU fuses ([`StepPlan::gpu_fusions`]).
    pub fn describe(&self) -> Vec<String> {
        self.stages
            .iter()
            .map(|p| {
                let when = match p.when {
                    When::EveryStep => "every step".to_string(),
                    When::EveryKSteps(k) => format!("every {k} steps"),
                    When::LastStepOfBatch => "last step of a batch".to_string(),
                };
                let entries: Vec<String> = p
                    .stage
                    .entries()
                    .iter()
                    .map(|e| format!("{}::{}", e.file, e.entry))
                    .collect();
                format!("{:<12} {:<22} {}", p.stage.name(), when, entries.join(", "))
            })
            .chain(self.gpu_fusions().iter().map(|f| {
                format!(
                    "{:<12} {:<22} {}::{} (on a GPU that builds it, {}: one dispatch for both, at {}'s place)",
                    format!("{}+{}", f.host.name(), f.rider.name()),
                    "fused",
                    f.entry.file,
                    f.entry.entry,
                    if f.measured {
                        "unless PALPATE_GPU_FUSION=0"
                    } else {
                        "with PALPATE_GPU_FUSION=all"
                    },
                    self.stages[f.at].stage.name()
                )
            }))
            .collect()
    }
}
