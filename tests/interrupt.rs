//! A stop asked for before a job has written or removed anything ends it with the output
//! folder as it was. (Its own test binary: the stop flag is process-wide, and would stop the
//! jobs of tests running beside it.)

use palpate::error::PalpateError;
use palpate::haptic_run::{run_haptic, HapticOptions};
use palpate::run::{run, RunLength, RunOptions};
use palpate::scene::Scene;
use palpate::sim::Backend;

/// A run and a haptic session asked to stop while they were being built (the signal came
/// between the build and the first write: here asked for before they start) refuse to start:
/// the error says so, and an earlier run's outputs stay untouched.
#[test]
fn a_stop_before_the_first_write_keeps_the_earlier_outputs() {
    let out = std::env::temp_dir().join(format!("palpate-stop-before-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let beam = Scene::load("beam").unwrap();
    let opts = RunOptions {
        backend: Backend::Cpu,
        length: RunLength::Steps(2),
        out: out.clone(),
        ..Default::default()
    };
    run(&beam, &opts).unwrap();
    let earlier = std::fs::read(out.join("summary.json")).unwrap();
    palpate::interrupt::request();
    let e = run(&beam, &opts).unwrap_err();
    assert!(matches!(e, PalpateError::StoppedBeforeStart(_)), "{e}");
    assert!(e.to_string().contains("nothing was written"), "{e}");
    assert_eq!(std::fs::read(out.join("summary.json")).unwrap(), earlier);
    let lv_touch = Scene::load("lv_touch").unwrap();
    let e = run_haptic(
        &lv_touch,
        &HapticOptions {
            backend: Backend::Cpu,
            device: "null".into(),
            seconds: Some(0.1),
            out: out.clone(),
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(matches!(e, PalpateError::StoppedBeforeStart(_)), "{e}");
    assert_eq!(std::fs::read(out.join("summary.json")).unwrap(), earlier);
    assert!(!out.join("haptic.csv").exists());
    palpate::interrupt::clear();
}
