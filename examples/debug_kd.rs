use palpate::cpu::CpuStepper;
use palpate::stepper::Stepper;
use std::sync::Arc;
fn main() {
    let scene = palpate::Scene::load("beam").unwrap();
    let model = Arc::new(palpate::model::Model::from_scene(&scene));
    let dt = 0.5 * model.bounds.dt_bound;
    let mut st = CpuStepper::new(model.clone(), model.step_params(dt, 75.0));
    for k in 0..60 {
        let s = st.run(1000).unwrap();
        let f = st.forces();
        let mut worst = (0.0f32, 0usize);
        for i in 0..model.n_vertices() {
            let n =
                (f[3 * i] * f[3 * i] + f[3 * i + 1] * f[3 * i + 1] + f[3 * i + 2] * f[3 * i + 2])
                    .sqrt();
            if model.inv_mass[i] > 0.0 && n > worst.0 {
                worst = (n, i);
            }
        }
        let x = &st.read_state().unwrap().positions;
        if k % 6 == 0 {
            println!(
                "{k} ke {:.3e} res {:.3e} ext {:.3e} worst {:?} at {:?}",
                s.kinetic_energy(),
                s.residual_norm(),
                s.external_norm(),
                worst,
                &model.rest[3 * worst.1..3 * worst.1 + 3]
            );
            let _ = x;
        }
    }
}
