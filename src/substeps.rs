//! Adaptive particle sub-steps: a particle layer pressed hard stiffens, and the sub-step the
//! scene was set up with ([`Model::particle_substeps`], from the rest wave speed) stops
//! being stable. Under lv_touch's tool pressed 8–10 mm into the wall at its speed limit the
//! layer's ‖cof F‖²/3 reaches 16–23 and one sub-step per core step diverged (two at about
//! 46, 13 mm in); with the count raised from the measured stiffening the same press runs on
//! until the tool has gone through the wall (BENCHMARKS.md). Every batch's particle report
//! carries the largest stiffening of the particles that carry stress (`particle_reduce`, on
//! either backend, from the H the last sub-step's `sph_stress` stored); while any particle is
//! dynamic, [`SubstepControl`] raises the count at once when the stiffened bound asks for
//! more, and lowers it once every batch over [`CALM_STEPS`] steps asked for fewer. The core
//! step is not changed: its tets under the tool stayed stable at the scene's dt in every
//! such press.

use crate::model::Model;
use glam::Mat3;

/// The longest batch `run` takes while particles are dynamic, so that the count follows
/// the layer (a haptic session's batches are shorter): a batch end costs a checkpoint and
/// the last step's reductions (`run lv_touch` took 2.4 times as long in one-step batches,
/// 4 % longer in batches of 8 than of 200).
pub const CHECK_STEPS: u32 = 8;

/// Steps over which every check must ask for fewer sub-steps before the count is lowered (a
/// release, not a flicker between two counts).
pub const CALM_STEPS: u32 = 64;

/// How much a deformation F has stiffened a hyperelastic particle, relative to its rest
/// stiffness: κ = max(1, ‖F‖²/3, ‖cof F‖²/3). The volumetric term's tangent is
/// λ (∂J/∂F)⊗(∂J/∂F) with ∂J/∂F = cof F, and StVK's stretch terms grow like F⊗F (stable
/// neo-Hookean's μ term does not); both norms are 3 at rest. A layer squeezed flat under a
/// tool bulges sideways, and the product of its two lateral stretches (a cofactor entry) is
/// what grows. The norms average over directions: the stiffest one can be up to 3 times κ
/// (F = diag(1.6, 1.6, 1/3): κ 2.4, through the thickness 6.6), which the scene's safety
/// factor covers: on lv_touch one sub-step diverged only at κ 16–22, where κ asked for 2
/// from 1.8 and 3 from 10 (BENCHMARKS.md).
pub fn stiffening(f: Mat3) -> f32 {
    let c = f.transpose() * f;
    let i1 = c.x_axis.x + c.y_axis.y + c.z_axis.z;
    let c2 = c * c;
    let i2 = 0.5 * (i1 * i1 - (c2.x_axis.x + c2.y_axis.y + c2.z_axis.z));
    let k = (i1.max(i2) / 3.0).max(1.0);
    if k.is_finite() {
        k
    } else {
        f32::MAX
    }
}

/// The particle sub-step count of a run, adapted to how stiff its particles have become.
pub struct SubstepControl {
    /// The particles' step bound, in parts (computed once).
    terms: crate::particles::ParticleBoundTerms,
    /// The scene's safety factor.
    safety: f64,
    /// Sub-steps per core step now.
    pub current: u32,
    /// The most sub-steps the run has used.
    pub most: u32,
    /// Times the count was raised.
    pub raises: u32,
    /// The largest stiffening κ measured.
    pub max_stiffening: f32,
    steps_since_check: u32,
    calm_steps: u32,
    /// The most sub-steps a check of the calm spell needed.
    calm_needed: u32,
}

impl SubstepControl {
    /// The control of `model` starting at `substeps` (None where its particles never carry
    /// stress of their own: no particles, the exact coupling, or no tool and no
    /// `activation = "all"`).
    pub fn new(model: &Model, substeps: u32) -> Option<SubstepControl> {
        let p = model.particles.as_ref()?;
        if model.tool.is_none() && !p.settings.all_active {
            return None;
        }
        Some(SubstepControl {
            terms: model.particle_bound_terms()?,
            safety: model.safety,
            current: substeps,
            most: substeps,
            raises: 0,
            max_stiffening: 1.0,
            steps_since_check: 0,
            calm_steps: 0,
            calm_needed: 0,
        })
    }

    /// The sub-steps a core step of `dt` needs for particles stiffened `stiffening` times
    /// ([`crate::particles::ParticleBoundTerms::substeps`] with the scene's safety factor;
    /// κ = 1: the scene's count, [`Model::particle_substeps`]).
    pub fn needed(&self, dt: f64, stiffening: f64) -> u32 {
        self.terms.substeps(dt, self.safety, stiffening)
    }

    /// Whether the count is watched now: while any particle is `dynamic`, or the count is
    /// not the scene's `base` one (to lower it once they are all gone).
    pub fn watching(&self, dynamic: bool, base: u32) -> bool {
        dynamic || self.current != base
    }

    /// Count a batch of `steps` steps; true when the count is to be checked after it
    /// ([`Self::watching`]).
    pub fn step(&mut self, steps: u32, dynamic: bool, base: u32) -> bool {
        self.steps_since_check = self.steps_since_check.saturating_add(steps);
        self.watching(dynamic, base)
    }

    /// The count after a check that needs `needed` sub-steps: raised at once; once the
    /// checks over [`CALM_STEPS`] steps in a row needed fewer, lowered to the most any of
    /// them needed. Some(count) when it changes.
    pub fn decide(&mut self, needed: u32, stiffening: f32) -> Option<u32> {
        let elapsed = std::mem::take(&mut self.steps_since_check);
        self.max_stiffening = self.max_stiffening.max(stiffening);
        if needed > self.current {
            (self.calm_steps, self.calm_needed) = (0, 0);
            self.raises += 1;
            self.current = needed;
            self.most = self.most.max(needed);
            return Some(needed);
        }
        if needed == self.current {
            (self.calm_steps, self.calm_needed) = (0, 0);
            return None;
        }
        self.calm_steps = self.calm_steps.saturating_add(elapsed);
        self.calm_needed = self.calm_needed.max(needed);
        if self.calm_steps < CALM_STEPS {
            return None;
        }
        self.current = self.calm_needed;
        (self.calm_steps, self.calm_needed) = (0, 0);
        Some(self.current)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn stiffening_is_one_at_rest_and_under_a_rotation_and_grows_with_a_lateral_bulge() {
        assert_eq!(stiffening(Mat3::IDENTITY), 1.0);
        let r = Mat3::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
        assert!((stiffening(r) - 1.0).abs() < 1e-5);
        // Squeezed to a third along z, bulged 1.6x sideways (J = 0.85).
        let f = Mat3::from_diagonal(Vec3::new(1.6, 1.6, 1.0 / 3.0));
        let k = stiffening(f);
        let i2 = (1.6f32.powi(4) + 2.0 * (1.6f32 / 3.0).powi(2)) / 3.0;
        assert!((k - i2).abs() < 1e-5, "{k} vs {i2}");
        // A uniform stretch of 2: ‖cof F‖² = 3·16.
        assert!((stiffening(Mat3::from_diagonal(Vec3::splat(2.0))) - 16.0).abs() < 1e-4);
        // Compression alone does not stiffen below rest.
        assert_eq!(stiffening(Mat3::from_diagonal(Vec3::splat(0.5))), 1.0);
        assert_eq!(stiffening(Mat3::from_diagonal(Vec3::splat(f32::NAN))), 1.0);
    }

    fn control(current: u32) -> SubstepControl {
        let scene = crate::scene::Scene::load("lv_touch").unwrap();
        let model = Model::from_scene(&scene);
        let mut c = SubstepControl::new(&model, 1).unwrap();
        c.current = current;
        c.most = current;
        c
    }

    /// A check CHECK_STEPS steps after the last that needs `needed`.
    fn check(c: &mut SubstepControl, needed: u32, stiffening: f32) -> Option<u32> {
        assert!(c.step(CHECK_STEPS, true, 1));
        c.decide(needed, stiffening)
    }

    #[test]
    fn the_count_rises_at_once_and_falls_after_a_calm_spell() {
        let mut c = control(1);
        let calm = CALM_STEPS / CHECK_STEPS;
        assert_eq!(check(&mut c, 1, 1.0), None);
        assert_eq!(check(&mut c, 3, 20.0), Some(3));
        assert_eq!((c.current, c.most, c.raises), (3, 3, 1));
        for _ in 0..calm - 1 {
            assert_eq!(check(&mut c, 1, 1.0), None);
        }
        // A check that needs the count again starts the calm over.
        assert_eq!(check(&mut c, 3, 20.0), None);
        for _ in 0..calm - 1 {
            assert_eq!(check(&mut c, 2, 5.0), None);
        }
        // Lowered to the most the calm spell needed, not to its last check's count.
        assert_eq!(check(&mut c, 1, 1.0), Some(2));
        assert_eq!((c.current, c.most, c.raises), (2, 3, 1));
        for _ in 0..calm - 1 {
            assert_eq!(check(&mut c, 1, 1.0), None);
        }
        assert_eq!(check(&mut c, 1, 1.0), Some(1));
        assert_eq!(c.max_stiffening, 20.0);
    }

    #[test]
    fn the_count_is_watched_while_particles_are_dynamic_or_it_is_not_the_scenes() {
        let mut c = control(1);
        assert!(c.step(1, true, 1));
        c.decide(1, 1.0);
        // Nothing dynamic at the scene's count: nothing to measure.
        assert!(!c.step(10, false, 1));
        c.current = 2;
        assert!(c.step(1, false, 1));
        // A calm spell counts steps, not checks: 63 one-step batches are not enough.
        let mut c = control(2);
        for _ in 0..CALM_STEPS - 1 {
            assert!(c.step(1, true, 1));
            assert_eq!(c.decide(1, 1.0), None);
        }
        assert!(c.step(1, true, 1));
        assert_eq!(c.decide(1, 1.0), Some(1));
    }
}
