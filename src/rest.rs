//! Sleep and wake for a haptic session's physics (DESIGN §1: "a body at rest with no load
//! sleeps and wakes on contact"). While the body sits in equilibrium under constant loads and
//! the tool is well clear of it, stepping it changes nothing the hand can feel, so the physics
//! thread only lets simulated time pass; it steps again as soon as the tool comes within
//! [`RestWatch::wake_margin`] of the tissue's surface.
//!
//! At rest means, for two batches running: no contact, no dynamic particle and none released
//! within the blend time, loads no longer ramping, the residual force below the scene's
//! static tolerance relative to the load (the `--until-static` test), and
//! kinetic ≤ tolerance² × elastic energy (an oscillation about equilibrium of relative
//! amplitude a has KE/E ≈ a² as it crosses it, where the residual alone reads zero). The load
//! and the elastic energy are taken as at least the largest tool force and elastic energy of
//! the session so far: after a touch, a body under no other load rests when what is left of
//! the touch is small against the touch itself. Before any touch, a body under no load at
//! all is at rest only exactly so (zero residual and kinetic energy).

use crate::particles::sampling::{distance_to_triangles, segment_distance_to_triangles};
use crate::run::{BodyEnergy, ResidualAndLoad};
use crate::scene::Scene;
use crate::sim::Simulation;
use crate::stepper::{BatchStats, State};
use glam::DVec3;

/// Batches in a row that must find the body at rest before it sleeps.
pub const CALM_BATCHES: u32 = 2;

/// Batches to wait after the tool was found too close to sleep before trying again (each
/// try reads the state back and measures the tool's clearance over the whole surface).
pub const RETRY_BATCHES: u32 = 50;

/// Watches a haptic session's batches and decides when its physics sleeps and wakes.
pub struct RestWatch {
    tolerance: f64,
    loads_settle_at: f64,
    particle_quiet: f64,
    last_particle_activity: f64,
    wake_margin: f64,
    tool_radius: f64,
    faces: Vec<[u32; 3]>,
    rest_positions: Vec<DVec3>,
    calm: u32,
    retry_in: u32,
    peak_tool_force: f64,
    peak_elastic: f64,
    /// The body while asleep (None: awake).
    asleep: Option<Sleeping>,
}

/// The sleeping body: its deformed surface, that surface's bounding box, and where the tool
/// was at the last check.
struct Sleeping {
    surface: Vec<[DVec3; 3]>,
    min: DVec3,
    max: DVec3,
    tool: DVec3,
}

/// [`RestWatch::survey_stride`]'s answer: how far the tool's surface is from the body's (m)
/// where a move starts and where it ends, and the least of it over the whole move (the tool
/// swept along the segment between its centres; ≤ 0: it touches or enters the body on the
/// way).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StrideSurvey {
    /// Clearance at the start.
    pub clear: f64,
    /// Clearance at the end.
    pub clear_after: f64,
    /// The least clearance over the move.
    pub swept_clear: f64,
}

/// Whether a batch finds the body at rest: residual ≤ `tolerance` × load and
/// kinetic ≤ `tolerance`² × elastic energy.
pub fn at_rest(force: ResidualAndLoad, energy: BodyEnergy, tolerance: f64) -> bool {
    force.residual <= tolerance * force.load
        && energy.kinetic <= tolerance * tolerance * energy.elastic
}

impl RestWatch {
    /// The watch for `scene` (which has a tool), awake.
    pub fn new(scene: &Scene) -> RestWatch {
        let tool_radius = scene.tool.as_ref().map_or(0.0, |t| t.radius);
        let (activation, particle_quiet) = scene
            .particles
            .as_ref()
            .map_or((0.0, 0.0), |p| (p.activation_radius, p.blend));
        RestWatch {
            tolerance: scene.solver.static_tolerance,
            loads_settle_at: scene.follower.as_ref().map_or(0.0, |f| f.ramp_seconds),
            particle_quiet,
            last_particle_activity: 0.0,
            // The tool's radius again as slack: the tool is checked where each batch leaves
            // it, and a jump longer than the margin wakes the body too.
            wake_margin: activation + tool_radius,
            tool_radius,
            faces: scene.mesh.boundary_faces(),
            rest_positions: scene.mesh.positions.clone(),
            calm: 0,
            retry_in: 0,
            peak_tool_force: 0.0,
            peak_elastic: 0.0,
            asleep: None,
        }
    }

    /// Distance from the tool's surface to the tissue's surface at which a sleeping body
    /// wakes: the particles' activation radius plus the tool's radius.
    pub fn wake_margin(&self) -> f64 {
        self.wake_margin
    }

    /// Whether the physics sleeps.
    pub fn is_asleep(&self) -> bool {
        self.asleep.is_some()
    }

    /// After an awake batch `s` of `sim` (`in_contact`: it ended with the tool touching):
    /// true when the body has now been at rest for [`CALM_BATCHES`] batches (and no try to
    /// sleep failed in the last [`RETRY_BATCHES`]).
    pub fn after_batch(&mut self, sim: &Simulation, s: &BatchStats, in_contact: bool) -> bool {
        let particles_busy = sim.last_particles.is_some_and(|p| p.dynamic > 0);
        if particles_busy {
            self.last_particle_activity = sim.time;
        }
        let mut force = ResidualAndLoad::of(sim, s);
        let mut energy = BodyEnergy::of(sim, s);
        if let Some(t) = sim.last_tool {
            self.peak_tool_force = self.peak_tool_force.max(t.force.length());
        }
        self.peak_elastic = self.peak_elastic.max(energy.elastic);
        force.load = force.load.max(self.peak_tool_force);
        energy.elastic = energy.elastic.max(self.peak_elastic);
        let calm = !in_contact
            && !particles_busy
            && sim.time - self.last_particle_activity >= self.particle_quiet
            && sim.time >= self.loads_settle_at
            && at_rest(force, energy, self.tolerance);
        self.calm = if calm { self.calm + 1 } else { 0 };
        self.retry_in = self.retry_in.saturating_sub(1);
        self.calm >= CALM_BATCHES && self.retry_in == 0
    }

    /// Distance from a tool centred at `centre` to the surface of the body in `state`, less
    /// the tool's radius (negative: it overlaps).
    pub fn clearance(&self, state: &State, centre: DVec3) -> f64 {
        self.clearance_to(&self.surface(state), centre)
    }

    fn surface(&self, state: &State) -> Vec<[DVec3; 3]> {
        let at = |i: u32| {
            let i = i as usize;
            let u = &state.displacements[3 * i..3 * i + 3];
            self.rest_positions[i] + DVec3::new(u[0] as f64, u[1] as f64, u[2] as f64)
        };
        self.faces
            .iter()
            .map(|f| [at(f[0]), at(f[1]), at(f[2])])
            .collect()
    }

    fn clearance_to(&self, surface: &[[DVec3; 3]], centre: DVec3) -> f64 {
        distance_to_triangles(surface.iter().copied(), centre) - self.tool_radius
    }

    /// What a tool move from `from` to `to` meets on the body in `state` (the sleeping body's
    /// while asleep, `state` may then be None; nothing without either): the clearances where
    /// it starts and ends ([`RestWatch::clearance`]) and the least over the move, the surface
    /// built once.
    pub fn survey_stride(&self, state: Option<&State>, from: DVec3, to: DVec3) -> StrideSurvey {
        self.survey_faces(state, from, to, |_| true)
    }

    /// [`RestWatch::survey_stride`] of the rest of a withdrawal, `from` → `to`, against the
    /// body less the surface the tool at `tool` touches: the faces within a tool radius of
    /// its surface (closer than 2r to its centre), which it withdraws from. (Where particles
    /// resolve a deep press, the coarse surface there may pass through the tool; its unsigned
    /// distance would read the way out of it as a way in.)
    pub fn survey_withdrawal(
        &self,
        state: Option<&State>,
        tool: DVec3,
        from: DVec3,
        to: DVec3,
    ) -> StrideSurvey {
        let touched = 2.0 * self.tool_radius;
        self.survey_faces(state, from, to, |f| {
            distance_to_triangles([*f], tool) >= touched
        })
    }

    fn survey_faces(
        &self,
        state: Option<&State>,
        from: DVec3,
        to: DVec3,
        keep: impl Fn(&[DVec3; 3]) -> bool,
    ) -> StrideSurvey {
        let built;
        let surface = match (&self.asleep, state) {
            (Some(s), _) => &s.surface,
            (None, Some(state)) => {
                built = self.surface(state);
                &built
            }
            (None, None) => {
                return StrideSurvey {
                    clear: f64::INFINITY,
                    clear_after: f64::INFINITY,
                    swept_clear: f64::INFINITY,
                }
            }
        };
        let kept = || surface.iter().copied().filter(|f| keep(f));
        let r = self.tool_radius;
        StrideSurvey {
            clear: distance_to_triangles(kept(), from) - r,
            clear_after: distance_to_triangles(kept(), to) - r,
            swept_clear: segment_distance_to_triangles(kept(), from, to) - r,
        }
    }

    /// Sleep, with the body as it is in `state`, if the tool at `tool` is clear of it by
    /// more than the wake margin; returns whether it sleeps.
    pub fn try_sleep(&mut self, state: &State, tool: DVec3) -> bool {
        let surface = self.surface(state);
        if self.clearance_to(&surface, tool) > self.wake_margin {
            let corners = surface.iter().flatten();
            let min = corners.clone().fold(DVec3::INFINITY, |m, p| m.min(*p));
            let max = corners.fold(DVec3::NEG_INFINITY, |m, p| m.max(*p));
            self.asleep = Some(Sleeping {
                surface,
                min,
                max,
                tool,
            });
        } else {
            self.retry_in = RETRY_BATCHES;
        }
        self.is_asleep()
    }

    /// While asleep: wake (and return true) when the tool, now at `tool`, has come within
    /// the wake margin of the sleeping body's surface, or jumped farther than the margin
    /// since the last check (it may have crossed the body in between). The surface is
    /// searched only when the tool is that close to its bounding box.
    pub fn wakes_for(&mut self, tool: DVec3) -> bool {
        let reach = self.wake_margin + self.tool_radius;
        let near = self.asleep.as_ref().is_some_and(|s| {
            let jumped = (tool - s.tool).length() > self.wake_margin;
            let to_box = (tool.clamp(s.min, s.max) - tool).length();
            jumped || (to_box <= reach && self.clearance_to(&s.surface, tool) <= self.wake_margin)
        });
        match &mut self.asleep {
            Some(_) if near => {
                self.asleep = None;
                self.calm = 0;
            }
            Some(s) => s.tool = tool,
            None => {}
        }
        near
    }
}

/// Let `steps` steps of simulated time pass on a sleeping `sim`: the time advances and the
/// tool moves to its target; the body's state is left as it is.
pub fn pass_time_at_rest(sim: &mut Simulation, steps: u32) {
    sim.time += steps as f64 * sim.dt;
    if let Some(target) = sim.tool_target {
        sim.tool_position = target;
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::RestWatch;
    use crate::scene::Scene;
    use crate::stepper::State;
    use glam::DVec3;

    /// The watch of the built-in scene `name` with a `[tool]` of this TOML text added, and
    /// the scene's body at rest in its reference shape.
    pub(crate) fn watch_at_rest(name: &str, tool: &str) -> (RestWatch, State) {
        let text = Scene::builtin_text(name).unwrap().to_string() + "\n[tool]\n" + tool;
        let scene = Scene::from_toml(&text, name, name, None).unwrap();
        let n = scene.mesh.positions.len();
        let state = State {
            displacements: vec![0.0; 3 * n],
            velocities: vec![0.0; 3 * n],
        };
        (RestWatch::new(&scene), state)
    }

    #[test]
    fn a_stride_is_surveyed_along_the_whole_sweep_of_the_tool() {
        // The built-in beam, a 10 × 2 × 2 cm bar (x from 0 to 10 cm, y and z from 0 to 2 cm,
        // cells of 5 mm), and a 1 cm tool.
        let (watch, state) = watch_at_rest(
            "beam",
            "radius = 0.01\nstiffness = 2.0e7\nhome = [0.08, 0.01, 0.031]\n",
        );
        let near = |a: f64, b: f64| (a - b).abs() < 1e-9;
        // Above the top face, on the mesh's grid lines and off them.
        for above in [
            DVec3::new(0.08, 0.01, 0.031),
            DVec3::new(0.083, 0.013, 0.031),
        ] {
            let survey = |by: DVec3| watch.survey_stride(Some(&state), above, above + by);
            // Straight up: clear all the way, 1 mm at the start.
            let up = survey(DVec3::new(0.0, 0.0, 0.5));
            assert!(
                near(up.clear, 0.001) && near(up.swept_clear, 0.001),
                "{up:?}"
            );
            assert!(near(up.clear_after, 0.501), "{up:?}");
            // Down through the bar to 0.47 m below it: the centre crosses the top face.
            let through = survey(DVec3::new(0.0, 0.0, -0.5));
            assert!(near(through.swept_clear, -0.01), "{through:?}");
            // Along the top, 1 mm clear, and on past its end.
            let along = survey(DVec3::new(0.5, 0.0, 0.0));
            assert!(near(along.swept_clear, 0.001), "{along:?}");
            // Down, stopping with the tool 1 mm into the top face.
            let into = survey(DVec3::new(0.0, 0.0, -0.002));
            assert!(near(into.swept_clear, -0.001), "{into:?}");
        }
        // Across the bar's far top edge (x = 0.1, z = 0.02), from above it to below beyond
        // its end: the centre passes 2 mm outside the edge, the 1 cm tool 8 mm into it.
        let h = 0.002 / 2f64.sqrt();
        let closest = DVec3::new(0.1 + h, 0.01, 0.02 + h);
        let along = DVec3::new(1.0, 0.0, -1.0) / 2f64.sqrt();
        let (from, to) = (closest - 0.2 * along, closest + 0.2 * along);
        let past = watch.survey_stride(Some(&state), from, to);
        assert!(
            past.clear > 0.1 && near(past.swept_clear, -0.008),
            "{past:?}"
        );
        // The centre passing through the edge itself, shared by two faces.
        let edge = watch.survey_stride(
            Some(&state),
            DVec3::new(0.1 + 0.2, 0.01, 0.02 + 0.2),
            DVec3::new(0.1 - 0.2, 0.01, 0.02 - 0.2),
        );
        assert!(near(edge.swept_clear, -0.01), "{edge:?}");
        // No state and awake: nothing known.
        let none = watch.survey_stride(None, from, to);
        assert!(none.clear.is_infinite() && none.swept_clear.is_infinite());
    }
}
