//! Every material against mathematics: stress is the derivative of energy (central
//! differences), zero stress at rest, the same linearisation (λ, μ), objectivity, and what
//! each does to an inverted element.

use glam::{Mat3, Quat, Vec3};
use palpate::material::{elastic_stress_energy, MaterialModel, MaterialParams};

fn lame() -> (f32, f32) {
    let (l, m) = MaterialParams::lame_from_young(3.0e5, 0.4);
    (l as f32, m as f32)
}

fn psi(model: MaterialModel, h: Mat3) -> f64 {
    let (l, m) = lame();
    elastic_stress_energy(model, h, l, m).1 as f64
}

fn sample_h(seed: u32) -> Mat3 {
    let mut s = seed.wrapping_mul(2654435761).wrapping_add(12345);
    let mut r = || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        (s as f32 / u32::MAX as f32) * 2.0 - 1.0
    };
    Mat3::from_cols_array(&std::array::from_fn(|_| 0.15 * r()))
}

#[test]
fn stress_is_the_energy_derivative_for_every_material() {
    let (l, m) = lame();
    for model in MaterialModel::ALL {
        let mut worst: f64 = 0.0;
        for seed in 1..12 {
            let h = sample_h(seed);
            let (p, _) = elastic_stress_energy(model, h, l, m);
            let pmax = p.to_cols_array().iter().fold(0.0f32, |a, x| a.max(x.abs())) as f64;
            let d = 1e-3f32;
            for k in 0..9 {
                let mut plus = h.to_cols_array();
                let mut minus = plus;
                plus[k] += d;
                minus[k] -= d;
                let fd = (psi(model, Mat3::from_cols_array(&plus))
                    - psi(model, Mat3::from_cols_array(&minus)))
                    / (2.0 * d as f64);
                worst = worst.max((fd - p.to_cols_array()[k] as f64).abs() / pmax);
            }
        }
        eprintln!("{}: worst |P − ∂Ψ/∂F| / max|P| = {worst:.2e}", model.name());
        assert!(worst < 5e-3, "{}: {worst}", model.name());
    }
}

#[test]
fn rest_is_stress_free_and_linearisation_matches_lame_parameters() {
    let (l, m) = lame();
    for model in MaterialModel::ALL {
        let (p0, e0) = elastic_stress_energy(model, Mat3::ZERO, l, m);
        assert_eq!(p0, Mat3::ZERO, "{}", model.name());
        assert_eq!(e0, 0.0);
        // Small symmetric strain: P ≈ σ = 2μ ε + λ tr(ε) I.
        let eps = Mat3::from_cols(
            Vec3::new(1e-4, 2e-5, -1e-5),
            Vec3::new(2e-5, -5e-5, 3e-5),
            Vec3::new(-1e-5, 3e-5, 7e-5),
        );
        let tr = eps.x_axis.x + eps.y_axis.y + eps.z_axis.z;
        let linear = eps * (2.0 * m) + Mat3::from_diagonal(Vec3::splat(l * tr));
        let (p, _) = elastic_stress_energy(model, eps, l, m);
        let err = (p - linear)
            .to_cols_array()
            .iter()
            .fold(0.0f32, |a, x| a.max(x.abs()));
        let scale = linear
            .to_cols_array()
            .iter()
            .fold(0.0f32, |a, x| a.max(x.abs()));
        eprintln!(
            "{}: linearisation rel err {:.2e}",
            model.name(),
            err / scale
        );
        assert!(
            err < 2e-3 * scale,
            "{}: P {p:?} vs linear {linear:?}",
            model.name()
        );
    }
}

#[test]
fn energy_is_objective_for_every_material() {
    let (l, m) = lame();
    let r = Mat3::from_quat(Quat::from_axis_angle(
        Vec3::new(0.3, -1.0, 0.5).normalize(),
        1.1,
    ));
    for model in MaterialModel::ALL {
        // A pure rotation: no stress.
        let (p, e) = elastic_stress_energy(model, r - Mat3::IDENTITY, l, m);
        let pmax = p.to_cols_array().iter().fold(0.0f32, |a, x| a.max(x.abs()));
        assert!(
            pmax < 1e-5 * m && e.abs() < 1e-5 * m,
            "{}: rotation gives P {pmax}, Ψ {e}",
            model.name()
        );
        // Rotating a deformed state leaves the energy unchanged.
        let h = sample_h(7);
        let hr = r * (Mat3::IDENTITY + h) - Mat3::IDENTITY;
        let (a, b) = (psi(model, h), psi(model, hr));
        assert!(
            (a - b).abs() < 1e-4 * a.abs(),
            "{}: Ψ(F) {a} vs Ψ(RF) {b}",
            model.name()
        );
    }
}

#[test]
fn inverted_elements_stvk_collapses_robust_materials_restore() {
    let (l, m) = lame();
    // A reflection (F = diag(1, 1, −1)) is a zero-energy state of StVK, not of the others.
    let reflect = Mat3::from_diagonal(Vec3::new(0.0, 0.0, -2.0));
    let e_stvk = psi(MaterialModel::Stvk, reflect);
    assert!(e_stvk.abs() < 1e-6, "StVK energy of a reflection {e_stvk}");
    for model in [MaterialModel::StableNeohookean, MaterialModel::Corotational] {
        assert!(
            psi(model, reflect) > 0.1 * m as f64,
            "{}: reflection costs no energy",
            model.name()
        );
    }
    // Half inverted, F = diag(1, 1, −0.5): the force −∂Ψ/∂F₃₃ must push F₃₃ back up.
    let h = Mat3::from_diagonal(Vec3::new(0.0, 0.0, -1.5));
    for model in MaterialModel::ALL {
        let p33 = elastic_stress_energy(model, h, l, m).0.z_axis.z;
        eprintln!("{}: P33 at F33 = −0.5: {p33:.3e}", model.name());
        match model {
            MaterialModel::Stvk => assert!(p33 > 0.0, "StVK pushes further into inversion"),
            _ => assert!(p33 < 0.0, "{} must restore", model.name()),
        }
    }
}
