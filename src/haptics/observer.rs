//! The passivity observer and controller (Hannaford & Ryu 2002, "Time-domain passivity
//! control of haptic interfaces").
//!
//! **Observer.** With F_k the force sent to the device at tick k (held until the next tick,
//! a zero-order hold), x_k the device position read at tick k, t_k its time and b the
//! device's physical damping ([`DeviceSpec::physical_damping`]):
//!
//! E(n) = Σ_{k<n} [ −F_k·(x_{k+1} − x_k) + b·|x_{k+1} − x_k|²/(t_{k+1} − t_k) ]
//!
//! The first term is the work the hand did on the device against the rendered force, i.e.
//! the energy that flowed from the hand into the device and the simulation; the second is
//! the energy the device's own damping dissipated over the tick (b·v²·Δt with v = Δx/Δt).
//! E < 0 means the loop gave the hand energy it never received: it was active. Crediting b
//! is what Colgate & Schenkel's condition b > K·T/2 is about — the device's damping
//! absorbing the energy the zero-order hold leaks (for a spring k the sum telescopes to
//! k x_n²/2 + Σ(b/Δt − k/2)|Δx|²) — so the observer measures exactly the property the
//! coupling is designed for. It uses the actual Δt of each tick, so a late tick (a longer
//! hold, a larger leak) earns less credit.
//!
//! **Controller.** Before the force F of tick n is sent, the controller predicts the
//! observer's energy at the end of the tick for a device moving at v over a tick of the
//! last tick's length Δt:
//!
//! Ê = E(n) + (−F·v + b|v|²)·Δt
//!
//! taking the worse (smaller Ê) of two extrapolations of the motion, constant velocity
//! v₁ = (x_n − x_{n−1})/Δt and constant acceleration v₂ = 2v₁ − v₀ (v₀ the tick before): with
//! v₁ alone the hand's acceleration leaves an unseen F·a·Δt² per tick. When Ê < 0 and the
//! device moves, it adds a damping force −α·v with α = −Ê/(|v|²·Δt), so the predicted
//! energy is zero. α is capped at α_gen + `max_damping`, where
//! α_gen = max(0, F·v − b|v|²)/|v|² just cancels the energy F would give the hand this tick:
//! the controller may always refuse to push a hand that is being pushed out with energy the
//! loop does not have, while paying back an existing deficit with at most the device's
//! recommended damping. It acts only on a (predicted) deficit, so a loop that is passive by
//! design never feels it; what it catches is the energy that time-varying gains (start-up
//! ramp, fade-in) and late models (contact appearing after the tool is already deep) would
//! inject.
//!
//! [`DeviceSpec::physical_damping`]: super::device::DeviceSpec::physical_damping

use glam::DVec3;

/// The passivity observer's running energy, J.
#[derive(Clone, Debug)]
pub struct PassivityObserver {
    damping: f64,
    energy: f64,
    min_energy: f64,
    last: Option<(f64, DVec3)>,
    velocity: DVec3,
    previous_velocity: DVec3,
    dt: f64,
    force: DVec3,
}

impl PassivityObserver {
    /// An observer crediting the device with physical damping `b` (N·s/m).
    pub fn new(b: f64) -> Self {
        PassivityObserver {
            damping: b,
            energy: 0.0,
            min_energy: 0.0,
            last: None,
            velocity: DVec3::ZERO,
            previous_velocity: DVec3::ZERO,
            dt: 0.0,
            force: DVec3::ZERO,
        }
    }

    /// Account for the device's motion to `x` at time `t` under the force last set with
    /// [`set_force`](Self::set_force); returns E(n), J.
    pub fn observe(&mut self, t: f64, x: DVec3) -> f64 {
        if let Some((t0, x0)) = self.last {
            let dx = x - x0;
            let dt = t - t0;
            self.energy -= self.force.dot(dx);
            if dt > 0.0 {
                self.energy += self.damping * dx.length_squared() / dt;
                self.previous_velocity = self.velocity;
                self.velocity = dx / dt;
                self.dt = dt;
            }
            self.min_energy = self.min_energy.min(self.energy);
        }
        self.last = Some((t, x));
        self.energy
    }

    /// Take the device as being at `x` at time `t` without accounting for how it got there
    /// (a device that comes back after it stopped being fresh: its jump is no motion the
    /// loop saw, and earns no damping credit).
    pub fn restart(&mut self, t: f64, x: DVec3) {
        self.last = Some((t, x));
        self.velocity = DVec3::ZERO;
        self.previous_velocity = DVec3::ZERO;
    }

    /// The force sent this tick (held until the next `observe`), N.
    pub fn set_force(&mut self, force: DVec3) {
        self.force = force;
    }

    /// E(n), J.
    pub fn energy(&self) -> f64 {
        self.energy
    }

    /// min over n of E(n), J (0 at the start).
    pub fn min_energy(&self) -> f64 {
        self.min_energy
    }

    /// The last tick's device velocity Δx/Δt, m/s, and Δt, s.
    pub fn last_velocity(&self) -> (DVec3, f64) {
        (self.velocity, self.dt)
    }

    /// The velocities the controller extrapolates with: constant velocity v₁ and constant
    /// acceleration 2v₁ − v₀, m/s.
    pub fn predicted_velocities(&self) -> [DVec3; 2] {
        [self.velocity, 2.0 * self.velocity - self.previous_velocity]
    }

    /// The damping b it credits, N·s/m.
    pub fn damping(&self) -> f64 {
        self.damping
    }
}

/// Below this speed (m/s) the controller does not act (there is no motion to damp).
pub const PC_MIN_SPEED: f64 = 1.0e-4;

/// The passivity controller's damping force for observer energy `energy` (J), the force
/// about to be sent `force` (N), the predicted device velocities `velocities` (m/s, see
/// [`PassivityObserver::predicted_velocities`]) over a tick of `dt` (s), physical damping `b`
/// and damping cap `max_damping` (N·s/m); returns the force to add (N) and α (N·s/m).
pub fn passivity_control(
    energy: f64,
    force: DVec3,
    velocities: [DVec3; 2],
    dt: f64,
    b: f64,
    max_damping: f64,
) -> (DVec3, f64) {
    if dt <= 0.0 {
        return (DVec3::ZERO, 0.0);
    }
    let flow = |v: DVec3| (-force.dot(v) + b * v.length_squared()) * dt;
    let v = if flow(velocities[1]) < flow(velocities[0]) {
        velocities[1]
    } else {
        velocities[0]
    };
    let v2 = v.length_squared();
    if v2 < PC_MIN_SPEED * PC_MIN_SPEED {
        return (DVec3::ZERO, 0.0);
    }
    let predicted = energy + flow(v);
    if predicted >= 0.0 {
        return (DVec3::ZERO, 0.0);
    }
    let alpha_gen = (-flow(v)).max(0.0) / (v2 * dt);
    let alpha = (-predicted / (v2 * dt)).min(alpha_gen + max_damping);
    (-alpha * v, alpha)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spring_energy_telescopes() {
        // F = −k x sampled at T with b = kT/2: E(n) = k x_n²/2 exactly.
        let (k, t) = (400.0, 1e-3);
        let mut o = PassivityObserver::new(k * t / 2.0);
        for n in 0..200 {
            let x = DVec3::new(0.0, 0.0, 1e-4 * n as f64);
            let e = o.observe(n as f64 * t, x);
            assert!((e - 0.5 * k * x.z * x.z).abs() < 1e-12);
            o.set_force(-k * x);
        }
    }
}
