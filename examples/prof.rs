use palpate::cpu::CpuStepper;
use palpate::model::Model;
use palpate::plan::Stage;
use palpate::stepper::{BatchInput, Stepper};
use std::sync::Arc;
use std::time::Instant;
fn main() {
    let name = std::env::args().nth(1).unwrap_or("hm1".into());
    let steps: u32 = std::env::args()
        .nth(2)
        .map(|a| a.parse().unwrap())
        .unwrap_or(430);
    let scene = palpate::Scene::load(&name).unwrap();
    let m = Arc::new(Model::from_scene(&scene));
    let dt = scene.solver.dt.unwrap_or(0.5 * m.bounds.dt_bound);
    let mut s = CpuStepper::new(m.clone(), m.step_params(dt, scene.solver.damping));
    let t = scene.tool.clone().unwrap();
    // press to the deepest point, then profile stage by stage
    let n = steps;
    let mut time = 0.0;
    for _ in 0..n / 10 {
        let a = t.position_at(time);
        time += 10.0 * dt;
        let b = t.position_at(time);
        s.submit(10, &BatchInput { tool: Some((a, b)) }).unwrap();
        s.wait().unwrap();
    }
    let plan = s.plan().clone();
    let mut totals: Vec<(Stage, f64)> = Vec::new();
    let reps = 50;
    for _ in 0..reps {
        for p in &plan.stages {
            let t0 = Instant::now();
            s.run_stage_pooled(p.stage);
            let e = t0.elapsed().as_secs_f64();
            match totals.iter_mut().find(|(st, _)| *st == p.stage) {
                Some(x) => x.1 += e,
                None => totals.push((p.stage, e)),
            }
        }
    }
    let r = {
        s.submit(1, &BatchInput::default()).unwrap();
        s.wait().unwrap()
    };
    println!(
        "{name}: {} tets, particles {:?}, substeps {}",
        m.n_tets(),
        r.particles.map(|p| (p.dynamic, p.stress, p.force)),
        m.particle_substeps(dt)
    );
    for (st, e) in totals {
        println!(
            "  {:<22} {:8.1} us per run",
            st.name(),
            e / reps as f64 * 1e6
        );
    }
}
