//! Numerical-stability stress cases and the accuracy study at a size CI can afford
//! (`--quick`), asserting what each material survives.

use palpate::bench::{accuracy, stability};
use palpate::sim::Backend;

fn row<'a>(rows: &'a [stability::Row], case: &str, material: &str) -> Vec<&'a stability::Row> {
    rows.iter()
        .filter(|r| r.case == case && r.material == material)
        .collect()
}

#[test]
fn stability_stress_cases() {
    let opts = stability::StabilityOptions {
        backend: Backend::Cpu,
        quick: true,
        ed0_steps: stability::QUICK_ED0_STEPS,
    };
    let rows = stability::study(&opts, &mut |s| eprintln!("{s}")).unwrap();
    for r in &rows {
        eprintln!(
            "({}) {} {} {} = {} {}",
            r.case, r.material, r.mesh, r.quantity, r.value, r.ok
        );
    }
    // (a) every material is stable somewhere between 0.3 and 1.5 × our bound; the bound is
    // not conservative on its own (hence the 0.5 safety factor), but it is the right scale.
    for m in ["stvk", "stable_neohookean", "corotational"] {
        let r = row(&rows, "a", m)
            .into_iter()
            .find(|r| r.quantity == "dt_crit / dt_bound")
            .unwrap();
        assert!(
            r.value > 0.3 && r.value < 1.5,
            "{m}: critical ratio {}",
            r.value
        );
        assert!(
            r.value > stability::DEFAULT_SAFETY_CHECK,
            "{m}: the default safety factor must be stable"
        );
    }
    // (b) everything recovers from a 10 % squash.
    for m in ["stvk", "stable_neohookean", "corotational"] {
        assert!(
            row(&rows, "b", m).iter().all(|r| r.ok),
            "{m} did not recover from the squash"
        );
    }
    // (c) The start really is inverted; StVK stays inverted or diverges (its reflection is a
    // zero-energy state); the robust ones restore.
    for m in ["stvk", "stable_neohookean", "corotational"] {
        let start = row(&rows, "c", m)
            .into_iter()
            .find(|r| r.quantity == "inverted tets at start")
            .unwrap();
        assert!(start.value > 0.0, "{m}: the random start inverted nothing");
    }
    let stvk_end = row(&rows, "c", "stvk")
        .into_iter()
        .find(|r| r.quantity.starts_with("inverted tets at end"))
        .unwrap();
    assert!(
        stvk_end.value > 0.0 || stvk_end.quantity.contains("diverged"),
        "StVK unexpectedly recovered: {}",
        stvk_end.quantity
    );
    for m in ["stable_neohookean", "corotational"] {
        assert!(
            row(&rows, "c", m).iter().all(|r| r.ok),
            "{m} did not recover from inversion"
        );
        assert!(
            row(&rows, "d", m).iter().all(|r| r.ok),
            "{m} did not survive the probe"
        );
    }
    // (e) energy bounded; (f) the Table 1 scenes run at the paper's dt.
    assert!(rows
        .iter()
        .filter(|r| r.case == "e" || r.case == "f")
        .all(|r| r.ok));
    let dir = std::env::temp_dir().join(format!("palpate-stab-{}", std::process::id()));
    stability::write(&dir, &rows, "test").unwrap();
    let md = std::fs::read_to_string(dir.join("stability.md")).unwrap();
    assert_eq!(md.matches("\n| ").count(), rows.len() + 1);
}

#[test]
fn accuracy_study_error_falls_with_resolution_and_writes_a_plot() {
    let opts = accuracy::AccuracyOptions {
        backend: Backend::Cpu,
        quick: true,
    };
    let study = accuracy::study(accuracy::Problem::Beam, &opts, &mut |s| eprintln!("{s}")).unwrap();
    let lv = accuracy::study(accuracy::Problem::Lv, &opts, &mut |s| eprintln!("{s}")).unwrap();
    let lv_err = |k: usize| {
        lv.runs
            .iter()
            .filter(|r| r.cells[0] == k)
            .map(|r| r.error)
            .fold(f64::INFINITY, f64::min)
    };
    eprintln!("lv: k=1 {:.3e}, k=2 {:.3e}", lv_err(1), lv_err(2));
    assert!(lv_err(2) < lv_err(1), "LV error must fall with resolution");
    let coarse = study
        .runs
        .iter()
        .filter(|r| r.cells == [5, 1, 1])
        .map(|r| r.error)
        .fold(f64::INFINITY, f64::min);
    let fine = study
        .runs
        .iter()
        .filter(|r| r.cells == [10, 2, 2])
        .map(|r| r.error)
        .fold(f64::INFINITY, f64::min);
    eprintln!(
        "coarse {coarse:.3e}, fine {fine:.3e}, reference dt change {:.2e}",
        study.reference_dt_change
    );
    assert!(
        fine < coarse,
        "refining must reduce the error: {coarse} → {fine}"
    );
    // The reference is converged in time far beyond the errors it judges.
    assert!(study.reference_dt_change < 0.01 * fine);
    let dir = std::env::temp_dir().join(format!("palpate-acc-{}", std::process::id()));
    let fronts = accuracy::write(&dir, &[study, lv], "cpu").unwrap();
    assert!(!fronts[0].is_empty() && !fronts[1].is_empty());
    assert!(dir.join("accuracy_lv.png").exists());
    let png = std::fs::read(dir.join("accuracy.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    let csv = std::fs::read_to_string(dir.join("accuracy.csv")).unwrap();
    assert_eq!(
        csv.lines().filter(|l| l.ends_with(",true")).count(),
        fronts[0].len() + fronts[1].len()
    );
}

#[test]
fn pareto_front_keeps_only_undominated_points() {
    use palpate::output::png::{pareto_front, PlotPoint};
    let p = |x, y| PlotPoint { x, y, series: 0 };
    let pts = [
        p(1.0, 5.0),
        p(2.0, 3.0),
        p(3.0, 4.0),
        p(4.0, 1.0),
        p(0.5, 9.0),
    ];
    assert_eq!(pareto_front(&pts), vec![4, 0, 1, 3]);
}
