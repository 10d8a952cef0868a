//! The step plan and the steppers built on it: the CPU path is bit-identical for any thread
//! count, each backend runs exactly the stages the plan lists, batches can be queued before
//! the last one is read back, checkpoints restore exactly, and the steppers can move to
//! another thread.

mod common;

use common::gpu;
use palpate::cpu::CpuStepper;
use palpate::gpu::GpuStepper;
use palpate::model::Model;
use palpate::plan::{Stage, StepPlan, When};
use palpate::sim::{Backend, SimOptions, Simulation};
use palpate::stepper::{BatchInput, State, Stepper, RING};
use std::sync::Arc;

fn scene_model(name: &str) -> Arc<Model> {
    let scene = palpate::Scene::load(name).unwrap();
    Arc::new(Model::from_scene(&scene))
}

fn run_cpu(name: &str, threads: usize, steps: u32) -> (State, [f32; 8]) {
    let scene = palpate::Scene::load(name).unwrap();
    let mut sim = Simulation::new(
        &scene,
        Backend::Cpu,
        SimOptions {
            threads: Some(threads),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(sim.threads, threads);
    let mut stats = [0.0; 8];
    for _ in 0..steps / 100 {
        match sim.advance(100).unwrap() {
            palpate::sim::Advance::Done(s) => stats = s.stats,
            other => panic!("{name}: {other:?}"),
        }
    }
    (sim.state().unwrap(), stats)
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Assert that two states' displacements and velocities are the same bits (`what`: how they
/// came to be, for the message).
fn assert_same_bits(a: &State, b: &State, what: &str) {
    assert_eq!(
        bits(&a.displacements),
        bits(&b.displacements),
        "displacements differ {what}"
    );
    assert_eq!(
        bits(&a.velocities),
        bits(&b.velocities),
        "velocities differ {what}"
    );
}

#[test]
fn cpu_results_are_bit_identical_for_any_thread_count() {
    for name in ["beam", "lv"] {
        let (one, s1) = run_cpu(name, 1, 500);
        let umax = one.displacements.iter().fold(0.0f32, |a, x| a.max(x.abs()));
        assert!(umax > 0.0, "{name}: nothing moved");
        for threads in [2, 3] {
            let (many, sn) = run_cpu(name, threads, 500);
            assert_same_bits(
                &one,
                &many,
                &format!("for {name} between 1 and {threads} threads"),
            );
            assert_eq!(bits(&s1), bits(&sn), "{name}: stats differ");
        }
        eprintln!("{name}: 500 steps, max |u| {umax:.3e} m, identical on 1, 2 and 3 threads");
    }
}

/// HM1 pressed for 300 steps on `threads` threads: the vertices' state, the particles'
/// displacements, velocities and modes, and how many particles were dynamic.
fn run_hm1(threads: usize) -> (State, Vec<u32>, usize) {
    run_hybrid(&palpate::Scene::load("hm1").unwrap(), threads, 3)
}

/// `batches` batches of 100 steps of `scene` on `threads` CPU threads: the vertex state, the
/// particles' bits and the dynamic particles at the end.
fn run_hybrid(scene: &palpate::Scene, threads: usize, batches: usize) -> (State, Vec<u32>, usize) {
    let name = &scene.name;
    let options = SimOptions {
        threads: Some(threads),
        ..Default::default()
    };
    let mut sim = Simulation::new(scene, Backend::Cpu, options).unwrap();
    for _ in 0..batches {
        match sim.advance(100).unwrap() {
            palpate::sim::Advance::Done(_) => {}
            other => panic!("{name}: {other:?}"),
        }
    }
    let dynamic = sim.last_particles.map_or(0, |p| p.dynamic as usize);
    let p = sim
        .particle_state()
        .unwrap()
        .expect("the scene has particles");
    let mut particle_bits = bits(&p.displacements);
    particle_bits.extend(bits(&p.velocities));
    particle_bits.extend(&p.modes);
    (sim.state().unwrap(), particle_bits, dynamic)
}

/// On more than one thread the particle stages run beside the core's element forces
/// (`rayon::join`); on one thread in the plan's order. Both must give the same bits.
#[test]
fn hybrid_results_are_bit_identical_for_any_thread_count() {
    let (one, particles_one, dynamic) = run_hm1(1);
    assert!(
        dynamic >= 50,
        "hm1 after 300 steps: only {dynamic} dynamic particles"
    );
    for threads in [2, 3] {
        let (many, particles_many, _) = run_hm1(threads);
        let what = format!("for hm1 between 1 and {threads} threads");
        assert_same_bits(&one, &many, &what);
        assert!(
            particles_one == particles_many,
            "particle state differs {what}"
        );
    }
    eprintln!("hm1: 300 steps, {dynamic} dynamic particles, identical on 1, 2 and 3 threads");
}

/// Design 8 (`hm1_exact`): its chain (follow, the remainder's stress, the pair forces) runs
/// beside the element forces on more than one thread, and its paired force stage splits the
/// pairs over the threads; 1, 2 and 3 threads give the same bits.
#[test]
fn design_8_results_are_bit_identical_for_any_thread_count() {
    let scene = palpate::Scene::load("hm1_exact").unwrap();
    let (one, particles_one, dynamic) = run_hybrid(&scene, 1, 3);
    assert!(
        dynamic >= 50,
        "hm1_exact after 300 steps: only {dynamic} dynamic particles"
    );
    for threads in [2, 3] {
        let (many, particles_many, _) = run_hybrid(&scene, threads, 3);
        let what = format!("for hm1_exact between 1 and {threads} threads");
        assert_same_bits(&one, &many, &what);
        assert!(
            particles_one == particles_many,
            "particle state differs {what}"
        );
    }
}

/// lv_touch (the default haptic scene) with its blood pressure as a follower load: the
/// pressure stands between the particle chain and the element forces, and on two threads
/// runs beside the chain too.
#[test]
fn a_hybrid_scene_with_a_follower_pressure_is_bit_identical_on_one_and_two_threads() {
    let text = palpate::Scene::builtin_text("lv_touch")
        .unwrap()
        .replace("[[loads.pressure]]", "[[loads.follower_pressure]]");
    let scene = palpate::Scene::from_toml(&text, "lv_touch, follower", "lv_f", None).unwrap();
    let (one, particles_one, dynamic) = run_hybrid(&scene, 1, 6);
    assert!(
        dynamic >= 20,
        "lv_touch after 600 steps: only {dynamic} dynamic particles"
    );
    let (two, particles_two, _) = run_hybrid(&scene, 2, 6);
    assert_same_bits(&one, &two, "for lv_touch between 1 and 2 threads");
    assert!(
        particles_one == particles_two,
        "lv_touch: the particle state differs between 1 and 2 threads"
    );
    eprintln!("lv_touch with a follower pressure: 600 steps, {dynamic} dynamic particles, identical on 1 and 2 threads");
}

#[test]
fn a_plain_scene_runs_exactly_the_stages_it_needs() {
    // beam: no viscosity, no tool, no particles.
    let m = scene_model("beam");
    assert!(!m.fem_variant().viscous, "beam has no viscosity");
    let plan = StepPlan::for_model(&m);
    let stages: Vec<(Stage, When)> = plan.stages.iter().map(|p| (p.stage, p.when)).collect();
    assert_eq!(
        stages,
        vec![
            (Stage::FemForces, When::EveryStep),
            (Stage::Gather, When::EveryStep),
            (Stage::Integrate, When::EveryStep),
            (Stage::Reduce, When::LastStepOfBatch),
        ]
    );
    let expected = vec![
        (Stage::FemForces, 10),
        (Stage::Gather, 10),
        (Stage::Integrate, 10),
        (Stage::Reduce, 1),
    ];
    let p = m.step_params(0.5 * m.bounds.dt_bound, 0.0);
    let mut c = CpuStepper::new(m.clone(), p);
    c.run(10).unwrap();
    assert_eq!(c.stage_counts(), expected, "CPU");
    let mut g = GpuStepper::new(gpu(), &m, p).unwrap();
    g.run(10).unwrap();
    assert_eq!(g.stage_counts(), expected, "GPU");
    // ed0 is viscous: the same stages, the viscous fem_forces variant.
    let ed0 = scene_model("ed0");
    assert!(ed0.fem_variant().viscous);
    assert_eq!(StepPlan::for_model(&ed0), plan);
}

fn queue_three_batches(stepper: &mut dyn Stepper) -> Vec<u32> {
    for _ in 0..RING {
        stepper.submit(40, &BatchInput::default()).unwrap();
    }
    assert_eq!(stepper.in_flight(), RING);
    assert!(
        stepper.submit(40, &BatchInput::default()).is_err(),
        "a fourth batch must not fit the ring"
    );
    let mut steps = Vec::new();
    let mut polls = 0;
    while steps.len() < RING {
        match stepper.poll().unwrap() {
            Some(r) => {
                assert!(r.stats.non_finite_vertex.is_none());
                assert!(r.stats.kinetic_energy() > 0.0);
                steps.push(r.steps);
            }
            None => {
                polls += 1;
                assert!(polls < 10_000_000, "batches never came back");
                std::thread::yield_now();
            }
        }
    }
    assert_eq!(stepper.in_flight(), 0);
    assert!(stepper.poll().unwrap().is_none());
    steps
}

#[test]
fn batches_queue_in_a_ring_and_match_one_long_batch() {
    let m = scene_model("beam");
    let p = m.step_params(0.5 * m.bounds.dt_bound, 0.0);
    let ctx = gpu();
    let mut backends: Vec<(Box<dyn Stepper>, Box<dyn Stepper>)> = vec![
        (
            Box::new(CpuStepper::new(m.clone(), p)),
            Box::new(CpuStepper::new(m.clone(), p)),
        ),
        (
            Box::new(GpuStepper::new(ctx.clone(), &m, p).unwrap()),
            Box::new(GpuStepper::new(ctx, &m, p).unwrap()),
        ),
    ];
    for (queued, single) in backends.iter_mut() {
        assert_eq!(queue_three_batches(queued.as_mut()), vec![40; RING]);
        single.run(40 * RING as u32).unwrap();
        let (a, b) = (queued.read_state().unwrap(), single.read_state().unwrap());
        assert_eq!(
            bits(&a.displacements),
            bits(&b.displacements),
            "{}: three queued batches differ from one batch of the same steps",
            queued.name()
        );
    }
}

#[test]
fn restore_returns_exactly_to_the_checkpoint() {
    let m = scene_model("beam");
    let p = m.step_params(0.5 * m.bounds.dt_bound, 0.0);
    let steppers: Vec<Box<dyn Stepper>> = vec![
        Box::new(CpuStepper::new(m.clone(), p)),
        Box::new(GpuStepper::new(gpu(), &m, p).unwrap()),
    ];
    for mut s in steppers {
        s.run(50).unwrap();
        s.checkpoint().unwrap();
        s.run(50).unwrap();
        let first = s.read_state().unwrap();
        s.restore().unwrap();
        s.run(50).unwrap();
        let again = s.read_state().unwrap();
        assert_same_bits(&first, &again, "after a restore");
    }
}

#[test]
fn steppers_and_simulations_can_move_to_another_thread() {
    fn is_send<T: Send>() {}
    is_send::<CpuStepper>();
    is_send::<GpuStepper>();
    is_send::<Box<dyn Stepper>>();
    is_send::<Simulation>();
    // And really do: step on a worker thread, read back on this one.
    let scene = palpate::Scene::load("beam").unwrap();
    let mut sim = Simulation::new(&scene, Backend::Cpu, SimOptions::default()).unwrap();
    let mut sim = std::thread::spawn(move || {
        sim.advance(20).unwrap();
        sim
    })
    .join()
    .unwrap();
    assert_eq!(sim.steps_done, 20);
    assert!(sim.state().unwrap().displacements.iter().any(|u| *u != 0.0));
}

/// A simulation that steps on the thread that made it (`step_on_this_thread`, as a haptic
/// session's physics thread does) runs its stages right there, with no pool worker beside it;
/// its results are the bits of a pool worker's, also after it moved to another thread, where
/// it steps on a worker of its own instead of waiting for its first thread to take the work.
#[test]
fn a_simulation_can_step_on_the_thread_that_made_it() {
    use palpate::cpu::stepper::this_thread_pool;
    let (reference, _) = run_cpu("lv", 1, 500);
    // A fresh thread: the one that becomes a pool stays the pool's for the rest of its life.
    let (sim, here) = std::thread::spawn(|| {
        let here = std::thread::current().id();
        let pool = this_thread_pool().expect("a fresh thread can be a pool of its own");
        assert_eq!(pool.current_num_threads(), 1);
        assert_eq!(
            pool.install(|| std::thread::current().id()),
            here,
            "the work ran on another thread"
        );
        let again = this_thread_pool().expect("the same pool again");
        assert!(
            Arc::ptr_eq(&pool, &again),
            "a second pool on the same thread"
        );
        let m = scene_model("lv");
        let stepper = CpuStepper::on_this_thread(m.clone(), m.step_params(1e-5, 0.0)).unwrap();
        assert_eq!(
            stepper.steps_on(),
            Some(here),
            "the stepper did not take this thread's pool"
        );
        let scene = palpate::Scene::load("lv").unwrap();
        let mut sim = Simulation::new(
            &scene,
            Backend::Cpu,
            SimOptions {
                threads: Some(1),
                step_on_this_thread: true,
                ..Default::default()
            },
        )
        .unwrap();
        for _ in 0..3 {
            sim.advance(100).unwrap();
        }
        (sim, here)
    })
    .join()
    .unwrap();
    // Moved to a thread that is not the pool's: it must not wait for the pool's thread (that
    // would never take the work), so a hang fails the test after a minute.
    let (send, receive) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        assert_ne!(std::thread::current().id(), here);
        let mut sim = sim;
        for _ in 0..2 {
            sim.advance(100).unwrap();
        }
        send.send(sim.state().unwrap()).unwrap();
    });
    let moved = receive
        .recv_timeout(std::time::Duration::from_secs(60))
        .expect("a simulation moved off its pool's thread did not step (or failed)");
    assert_same_bits(&reference, &moved, "from a pool worker's");
}

#[test]
fn thread_counts_out_of_range_are_refused() {
    let m = scene_model("beam");
    let p = m.step_params(1e-5, 0.0);
    let zero = CpuStepper::with_threads(m.clone(), p, 0).err().unwrap();
    assert!(zero.to_string().contains("at least 1"), "{zero}");
    let cores = palpate::cpu::stepper::available_cores();
    let huge = CpuStepper::with_threads(m, p, 1000 * cores).err().unwrap();
    assert!(
        huge.to_string().contains("cores"),
        "{huge}: should name the machine's cores"
    );
}

#[test]
fn particles_without_a_tool_run_no_particle_stage() {
    // hm1 without its tool: nothing can make a particle dynamic, so the plan is the core's
    // (viscous fem_forces, gather, integrate, reduce), with no particle or contact stage.
    let text = palpate::Scene::builtin_text("hm1").unwrap();
    let cut = text.find("[tool]").unwrap();
    let end = cut + text[cut..].find("[solver]").unwrap();
    let no_tool = format!("{}{}", &text[..cut], &text[end..]);
    let scene = palpate::Scene::from_toml(&no_tool, "hm1 without a tool", "hm1", None).unwrap();
    let m = Arc::new(Model::from_scene(&scene));
    assert!(m.particles.as_ref().is_some_and(|p| p.len() > 20_000));
    let stages: Vec<Stage> = StepPlan::for_model(&m)
        .stages
        .iter()
        .map(|p| p.stage)
        .collect();
    assert_eq!(
        stages,
        vec![
            Stage::FemForces,
            Stage::Gather,
            Stage::Integrate,
            Stage::Reduce
        ]
    );
    // With the tool, the particle stages are planned.
    let with_tool = StepPlan::for_model(&scene_model("hm1"));
    for s in [
        Stage::Activate,
        Stage::SphForces,
        Stage::IntegrateParticles,
        Stage::Contact,
    ] {
        assert!(with_tool.stages.iter().any(|p| p.stage == s), "{s:?}");
    }
}

#[test]
fn indirect_dispatch_runs_exactly_the_workgroups_a_kernel_counted() {
    use palpate::cpu::dispatch_probe as twin;
    use palpate::gpu::buffers::{BufferGroup, BufferSpec, GpuBuffers, Usage};
    use palpate::gpu::setup::{read_u32, run_passes, SetupDispatch, SetupPass};
    const SLOTS: usize = 300;
    let ctx = gpu();
    for nonzero in [0usize, 1, 7, 64, 257] {
        // Inputs with `nonzero` nonzero words scattered among zeros.
        let input: Vec<u32> = (0..SLOTS)
            .map(|i| u32::from((i * 37) % SLOTS < nonzero))
            .collect();
        assert_eq!(input.iter().filter(|&&x| x != 0).count(), nonzero);
        let group = BufferGroup {
            name: "probe",
            specs: vec![
                BufferSpec::data("probe_input", Usage::Storage, &input),
                BufferSpec::zeroed("probe_dispatch", Usage::Indirect, 16),
                BufferSpec::zeroed("probe_hit_counts", Usage::Storage, 4 * SLOTS as u64),
                BufferSpec::zeroed("probe_thread_counts", Usage::Storage, 4 * SLOTS as u64),
            ],
        };
        let buffers = GpuBuffers::new(&ctx, &[group]).unwrap();
        run_passes(
            &ctx,
            &buffers,
            &[
                SetupPass {
                    file: "dispatch_probe",
                    entry: "dispatch_probe_args",
                    dispatch: SetupDispatch::One,
                    aliases: &[],
                },
                SetupPass {
                    file: "dispatch_probe",
                    entry: "dispatch_probe_hits",
                    dispatch: SetupDispatch::Indirect("probe_dispatch", 0),
                    aliases: &[],
                },
            ],
        )
        .unwrap();
        let read = |name: &str, n: usize| {
            read_u32(&ctx, buffers.require(name).unwrap(), 0, n as u64).unwrap()
        };
        let mut args = [0u32; 3];
        twin::dispatch_probe_args(&input, &mut args);
        let (mut hits, mut threads) = (vec![0u32; SLOTS], vec![0u32; SLOTS]);
        twin::dispatch_probe_hits(&args, &mut hits, &mut threads);
        assert_eq!(
            read("probe_dispatch", 3),
            args.to_vec(),
            "{nonzero}: arguments"
        );
        assert_eq!(
            read("probe_hit_counts", SLOTS),
            hits,
            "{nonzero}: workgroups run"
        );
        assert_eq!(
            read("probe_thread_counts", SLOTS),
            threads,
            "{nonzero}: threads run"
        );
        // Exactly `nonzero` workgroups ran, once each, with all their threads.
        assert_eq!(hits.iter().filter(|&&h| h == 1).count(), nonzero);
        assert!(hits[nonzero..].iter().all(|&h| h == 0));
    }
}

/// Where the GPU fuses two passes into one dispatch (`StepPlan::gpu_fusions`): on hm1's plan
/// `follow` rides on `fem_forces`, recorded at follow's place, `integrate_particles` on
/// `gather_coupled`, at the gather's, and `sph_stress` on `contact`, at the stress's; with
/// particle sub-steps the first follow, the last integration and the first stress; design 8's
/// plan and one without particles fuse nothing.
#[test]
fn the_gpu_fuses_only_passes_whose_order_the_plan_leaves_free() {
    let hm1 = scene_model("hm1");
    let plan = StepPlan::for_model_at(&hm1, 1);
    let at = |stage: Stage| plan.stages.iter().position(|p| p.stage == stage).unwrap();
    let fusions: Vec<(Stage, Stage, usize, usize)> = plan
        .gpu_fusions()
        .iter()
        .map(|f| (f.host, f.rider, f.at, f.skipped))
        .collect();
    assert_eq!(
        fusions,
        [
            (
                Stage::FemForces,
                Stage::Follow,
                at(Stage::Follow),
                at(Stage::FemForces)
            ),
            (
                Stage::GatherCoupled,
                Stage::IntegrateParticles,
                at(Stage::GatherCoupled),
                at(Stage::IntegrateParticles)
            ),
            (
                Stage::Contact,
                Stage::SphStress,
                at(Stage::SphStress),
                at(Stage::Contact)
            ),
        ]
    );
    // Built by default: the two measured on a GPU.
    let measured: Vec<bool> = plan.gpu_fusions().iter().map(|f| f.measured).collect();
    assert_eq!(measured, [true, true, false]);
    // Each over its host's domain, grown to cover every particle; contact + sph_stress over
    // the grid the activation sizes for the larger of the two (compact_args' fourth).
    for f in plan.gpu_fusions() {
        let host = &f.host.entries()[0].domain;
        let grid = match f.rider {
            Stage::SphStress => palpate::plan::Domain::Indirect("particle_dispatch", 36),
            _ => palpate::plan::Domain::CoveringParticles(host),
        };
        assert_eq!(f.entry.domain, grid, "{f:?}");
    }
    // With two particle sub-steps: the first follow and the last integration.
    let sub = StepPlan::for_model_at(&hm1, 2);
    let all = |stage: Stage| -> Vec<usize> {
        (0..sub.stages.len())
            .filter(|&k| sub.stages[k].stage == stage)
            .collect()
    };
    assert_eq!(all(Stage::Follow).len(), 2);
    let fusions: Vec<(Stage, usize, usize)> = sub
        .gpu_fusions()
        .iter()
        .map(|f| (f.rider, f.at, f.skipped))
        .collect();
    assert_eq!(
        fusions,
        [
            (
                Stage::Follow,
                all(Stage::Follow)[0],
                all(Stage::FemForces)[0]
            ),
            (
                Stage::IntegrateParticles,
                all(Stage::GatherCoupled)[0],
                all(Stage::IntegrateParticles)[1]
            ),
            (
                Stage::SphStress,
                all(Stage::SphStress)[0],
                all(Stage::Contact)[0]
            ),
        ]
    );
    let exact = scene_model("hm1_exact");
    assert!(StepPlan::for_model(&exact).gpu_fusions().is_empty());
    assert!(StepPlan::for_model(&scene_model("lv"))
        .gpu_fusions()
        .is_empty());
    // The hybrid LV, the default haptic scene, at one sub-step: all three.
    let lv_touch = StepPlan::for_model_at(&scene_model("lv_touch"), 1);
    assert_eq!(lv_touch.gpu_fusions().len(), 3);
}

/// A plan's particle sub-step block re-run another number of times
/// (`StepPlan::with_particle_substeps`, what a stepper does when the count changes during a
/// run) is the plan built for that count, from any count; plans without the block (no
/// particles, design 8) are left as they are.
#[test]
fn a_plan_changed_to_other_substeps_is_the_plan_built_for_them() {
    for name in ["hm1", "lv_touch"] {
        let m = scene_model(name);
        for from in 1..=4 {
            let plan = StepPlan::for_model_at(&m, from);
            for to in 1..=6 {
                assert_eq!(
                    plan.with_particle_substeps(to),
                    StepPlan::for_model_at(&m, to),
                    "{name}: {from} -> {to} sub-steps"
                );
            }
        }
    }
    for name in ["hm1_exact", "lv", "beam"] {
        let plan = StepPlan::for_model(&scene_model(name));
        assert_eq!(plan.with_particle_substeps(3), plan, "{name}");
    }
}
