use palpate::cpu::CpuStepper;
use palpate::model::Model;
use palpate::stepper::{State, Stepper};
use std::sync::Arc;
fn main() {
    let hg: f64 = std::env::args()
        .nth(1)
        .map(|a| a.parse().unwrap())
        .unwrap_or(0.1);
    let kr: f64 = std::env::args()
        .nth(2)
        .map(|a| a.parse().unwrap())
        .unwrap_or(2.4);
    let text = format!("[mesh]\ngenerator = \"beam\"\nsize = [0.012, 0.012, 0.012]\ncells = [2, 2, 2]\n[material]\nyoungs_modulus = 3.0e4\npoisson_ratio = 0.3\ndensity = 1000.0\n[particles]\nregion = 0\nspacing = 0.001\nactivation_radius = 0.003\nactivation = \"all\"\nhourglass = {hg}\nkernel_radius = {kr}\n");
    let scene = palpate::Scene::from_toml(&text, "b", "b", None).unwrap();
    for psafe in [0.8, 0.6, 0.5, 0.4, 0.3, 0.25, 0.2] {
        std::env::set_var("PALPATE_PSAFE", psafe.to_string());
        let m = Arc::new(Model::from_scene(&scene));
        let pb = m.particles.as_ref().unwrap().dt_bound(&m.material, None);
        let dt = 0.5 * m.bounds.dt_bound;
        let p = m.step_params(dt, 0.0);
        let mut s = CpuStepper::new(m.clone(), p);
        s.run(1).unwrap();
        let ps = s.particle_state().unwrap();
        let mut vel = ps.velocities.clone();
        let mut x: u64 = 12345;
        for v in vel.iter_mut() {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            *v = ((x >> 11) as f64 / (1u64 << 53) as f64 - 0.5) as f32 * 0.01;
        }
        s.set_particle_state(&State {
            displacements: ps.displacements,
            velocities: vel,
        });
        s.submit(3000, &palpate::stepper::BatchInput::default())
            .unwrap();
        let rep = s.wait().unwrap();
        let r = rep.stats;
        let pk = rep.particles.unwrap();
        let sub = m.particle_substeps(dt);
        println!("hourglass {hg} kr {kr} psafe {psafe}: sub_dt/(dx/c_p) = {:.3}, diverged: {:?}, particle KE {:.2e} (dynamic {})", dt / sub as f64 / pb, r.non_finite_vertex.is_some(), pk.kinetic_energy, pk.dynamic);
    }
}
