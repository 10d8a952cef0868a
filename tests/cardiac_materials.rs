//! The volume/shape split laws and Guccione against mathematics: P = ∂Ψ/∂F by central
//! differences (isotropic and fibred, with and without the volume term, every U(J), also
//! for strongly compressed and inverted tets), zero stress at rest, the small-strain
//! limit 2μ dev ε + κ tr ε I (also at strains of 1e-5, where a naive f32 J^(−1/3) F
//! would cancel), objectivity, Guccione's isotropic limit and sheet independence, the
//! series helpers against f64, the volumetric laws, and the input checks.

use glam::{Mat3, Quat, Vec3};
use palpate::material::{
    expm1_f32, fibre_frame, guccione_q, guccione_q_in_frame, guccione_second_piola,
    hyperelastic_stress_energy, inv_cbrt_minus_one_f32, log1p_f32, volumetric_energy_pressure,
    x_minus_log1p_f32, GuccioneParams, HyperelasticParams, MaterialConstants, MaterialModel,
    MaterialParams, VolumetricLaw,
};

const MU: f32 = 1.0e4;
const KAPPA: f32 = 2.0e5;

/// The fibred Guccione constants of Land et al. 2015 problem 1 (C in Pa) with κ = 50 C.
fn guccione_land_p1(kappa: f32) -> MaterialConstants {
    let mut h = HyperelasticParams::new(kappa as f64);
    h.guccione = GuccioneParams::new(2000.0, 8.0, 2.0, 4.0);
    h.constants()
}

fn guccione_iso(kappa: f32, b: f64) -> MaterialConstants {
    let mut h = HyperelasticParams::new(kappa as f64);
    h.guccione = GuccioneParams::isotropic(10_000.0, b);
    h.constants()
}

fn split(kappa: f32) -> MaterialConstants {
    HyperelasticParams::new(kappa as f64).constants()
}

/// Every (model, constants, fibre, label) the tests sweep, with volume term κ.
fn cases(kappa: f32) -> Vec<(MaterialModel, MaterialConstants, Vec3, String)> {
    let fibre = Vec3::new(0.6, -0.3, 0.74).normalize();
    let mut v: Vec<_> = [
        MaterialModel::StvkSplit,
        MaterialModel::StableNeohookeanSplit,
        MaterialModel::CorotationalSplit,
    ]
    .into_iter()
    .map(|m| (m, split(kappa), Vec3::ZERO, m.name().to_string()))
    .collect();
    v.push((
        MaterialModel::Guccione,
        guccione_land_p1(kappa),
        fibre,
        "guccione fibred".into(),
    ));
    v.push((
        MaterialModel::Guccione,
        guccione_iso(kappa, 1.0),
        Vec3::ZERO,
        "guccione isotropic".into(),
    ));
    v
}

fn eval(
    model: MaterialModel,
    c: &MaterialConstants,
    law: VolumetricLaw,
    fibre: Vec3,
    h: Mat3,
) -> (Mat3, f32) {
    hyperelastic_stress_energy(model, h, 0.0, MU, c, law, fibre)
}

fn sample_h(seed: u32, amplitude: f32) -> Mat3 {
    let mut s = seed.wrapping_mul(2654435761).wrapping_add(12345);
    let mut r = || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        (s as f32 / u32::MAX as f32) * 2.0 - 1.0
    };
    Mat3::from_cols_array(&std::array::from_fn(|_| amplitude * r()))
}

fn max_abs(m: Mat3) -> f32 {
    m.to_cols_array().iter().fold(0.0f32, |a, x| a.max(x.abs()))
}

/// Worst |P − ∂Ψ/∂F| / max|P| over the 9 components, central differences with step `d`.
fn fd_error(
    model: MaterialModel,
    c: &MaterialConstants,
    law: VolumetricLaw,
    fibre: Vec3,
    h: Mat3,
    d: f32,
) -> f64 {
    let (p, _) = eval(model, c, law, fibre, h);
    let pmax = max_abs(p) as f64;
    let mut worst: f64 = 0.0;
    for k in 0..9 {
        let mut plus = h.to_cols_array();
        let mut minus = plus;
        plus[k] += d;
        minus[k] -= d;
        let step = plus[k] as f64 - minus[k] as f64;
        let fd = (eval(model, c, law, fibre, Mat3::from_cols_array(&plus)).1 as f64
            - eval(model, c, law, fibre, Mat3::from_cols_array(&minus)).1 as f64)
            / step;
        worst = worst.max((fd - p.to_cols_array()[k] as f64).abs() / pmax);
    }
    worst
}

#[test]
fn stress_is_the_energy_derivative_for_every_split_law() {
    for kappa in [0.0, KAPPA] {
        // Without a bulk modulus U(J) plays no part: one law is enough.
        let laws = if kappa == 0.0 {
            &VolumetricLaw::ALL[..1]
        } else {
            &VolumetricLaw::ALL[..]
        };
        for &law in laws {
            for (model, c, fibre, label) in cases(kappa) {
                let mut worst: f64 = 0.0;
                for seed in 1..10 {
                    worst = worst.max(fd_error(model, &c, law, fibre, sample_h(seed, 0.15), 1e-3));
                }
                eprintln!(
                    "{label:>24} κ = {kappa:8.1e} U = {:<11}: worst |P − ∂Ψ/∂F| / max|P| = {worst:.2e}",
                    law.name()
                );
                assert!(worst < 5e-3, "{label} {} κ {kappa}: {worst}", law.name());
            }
        }
    }
}

#[test]
fn stress_is_the_energy_derivative_when_compressed_below_the_floor_and_inverted() {
    // J ≈ 0.3, 0.05 (below J_min = 0.1) and −0.2 (inverted): φ(J) and U(J) extensions.
    for j33 in [0.3f32, 0.05, -0.2] {
        let h = Mat3::from_diagonal(Vec3::new(0.02, -0.01, j33 - 1.0)) + sample_h(3, 0.02);
        for law in VolumetricLaw::ALL {
            for (model, c, fibre, label) in cases(KAPPA) {
                let (p, psi) = eval(model, &c, law, fibre, h);
                assert!(
                    p.is_finite() && psi.is_finite(),
                    "{label}: non-finite at J33 {j33}"
                );
                // Far from rest e^Q is steep (Q ≈ 50 for the fibred law here): a finer step.
                let worst = fd_error(model, &c, law, fibre, h, 1e-4);
                eprintln!(
                    "{label:>24} U = {:<11} J33 = {j33:5.2}: FD error {worst:.2e}",
                    law.name()
                );
                assert!(worst < 1e-2, "{label} {} J33 {j33}: {worst}", law.name());
            }
        }
    }
    // The volume term resists inversion: pushing F33 further down costs energy.
    for law in [VolumetricLaw::LogSquared, VolumetricLaw::SimoTaylor] {
        let (p, _) = eval(
            MaterialModel::StableNeohookeanSplit,
            &split(KAPPA),
            law,
            Vec3::ZERO,
            Mat3::from_diagonal(Vec3::new(0.0, 0.0, -1.2)),
        );
        assert!(
            p.z_axis.z < 0.0,
            "{}: P33 {} must restore",
            law.name(),
            p.z_axis.z
        );
    }
}

#[test]
fn rest_is_stress_free() {
    for law in VolumetricLaw::ALL {
        for (model, c, fibre, label) in cases(KAPPA) {
            let (p, psi) = eval(model, &c, law, fibre, Mat3::ZERO);
            assert_eq!(p, Mat3::ZERO, "{label}");
            assert_eq!(psi, 0.0, "{label}");
        }
    }
}

/// P ≈ 2μ_eff dev ε + κ tr ε I for a small symmetric ε (relative error returned).
fn linearisation_error(
    model: MaterialModel,
    c: &MaterialConstants,
    fibre: Vec3,
    mu_eff: f32,
    eps: Mat3,
) -> f32 {
    let tr = eps.x_axis.x + eps.y_axis.y + eps.z_axis.z;
    let dev = eps - Mat3::from_diagonal(Vec3::splat(tr / 3.0));
    let linear = dev * (2.0 * mu_eff) + Mat3::from_diagonal(Vec3::splat(c.bulk_modulus * tr));
    let (p, _) = eval(model, c, VolumetricLaw::SimoTaylor, fibre, eps);
    max_abs(p - linear) / max_abs(linear)
}

#[test]
fn small_strain_limit_is_2mu_dev_plus_kappa_trace_even_at_1e_minus_5() {
    let shape = Mat3::from_cols(
        Vec3::new(1.0, 0.2, -0.1),
        Vec3::new(0.2, -0.5, 0.3),
        Vec3::new(-0.1, 0.3, 0.7),
    );
    // At 1e-5 and 1e-6 the geometric nonlinearity (relative ~ ε κ/μ) is below the tolerance, so
    // what is left is f32 round-off: the split must not lose the shape part in the rounding of
    // J^(−1/3) (a naive F̄ = J^(−1/3) F would leave ~1e-7/ε of it).
    for scale in [1e-5f32, 1e-6] {
        for (model, c, fibre, label) in cases(KAPPA) {
            if model == MaterialModel::Guccione && fibre != Vec3::ZERO {
                continue; // anisotropic: no single μ
            }
            let mu_eff = if model == MaterialModel::Guccione {
                0.5 * c.guccione_c * c.guccione_bt
            } else {
                MU
            };
            // Volume-dominated and shape-only strains: the shape part must not be lost in the
            // volume part's rounding, nor the other way round.
            for eps in [
                shape * scale,
                (shape - Mat3::from_diagonal(Vec3::splat(1.2 / 3.0))) * scale,
            ] {
                let err = linearisation_error(model, &c, fibre, mu_eff, eps);
                eprintln!("{label:>24} ε ~ {scale:.0e}: linearisation rel err {err:.2e}");
                // The corotational shape part needs F̄ − R, which cancels in any f32 form
                // (as the legacy corotational law does): R is good to ~1e-7 absolute.
                let tol = if model == MaterialModel::CorotationalSplit {
                    0.5e-7 / scale
                } else {
                    1e-3
                };
                assert!(err < tol, "{label} at {scale}: {err}");
            }
        }
    }
}

#[test]
fn energy_is_objective_and_a_rotation_is_stress_free() {
    let r = Mat3::from_quat(Quat::from_axis_angle(
        Vec3::new(0.3, -1.0, 0.5).normalize(),
        1.1,
    ));
    for law in VolumetricLaw::ALL {
        for (model, c, fibre, label) in cases(KAPPA) {
            let (p, e) = eval(model, &c, law, fibre, r - Mat3::IDENTITY);
            assert!(
                max_abs(p) < 2e-4 * KAPPA && e.abs() < 2e-4 * KAPPA,
                "{label}: a rotation gives P {} Ψ {e}",
                max_abs(p)
            );
            let h = sample_h(7, 0.15);
            let hr = r * (Mat3::IDENTITY + h) - Mat3::IDENTITY;
            let (p0, a) = eval(model, &c, law, fibre, h);
            let (p1, b) = eval(model, &c, law, fibre, hr);
            assert!(
                (a - b).abs() < 1e-4 * a.abs(),
                "{label}: Ψ(F) {a} vs Ψ(RF) {b}"
            );
            assert!(
                max_abs(p1 - r * p0) < 1e-4 * max_abs(p0),
                "{label}: P(RF) ≠ R P(F)"
            );
        }
    }
}

#[test]
fn guccione_invariant_q_equals_the_frame_components_for_any_sheet() {
    for seed in 1..20 {
        let h = sample_h(seed, 0.3);
        let e = (h + h.transpose() + h.transpose() * h) * 0.5;
        let fibre = (sample_h(seed + 100, 1.0) * Vec3::ONE).normalize();
        let (f, s, n) = fibre_frame(fibre);
        assert!(f.dot(s).abs() < 1e-6 && f.dot(n).abs() < 1e-6 && s.dot(n).abs() < 1e-6);
        let q = guccione_q(e, f, 8.0, 2.0, 4.0);
        let q_frame = guccione_q_in_frame(e, (f, s, n), 8.0, 2.0, 4.0);
        // Any other sheet in the plane normal to f gives the same Q (transverse isotropy).
        let rot = Mat3::from_quat(Quat::from_axis_angle(f, 0.7 + seed as f32));
        let q_turned = guccione_q_in_frame(e, (f, rot * s, rot * n), 8.0, 2.0, 4.0);
        assert!(
            (q - q_frame).abs() < 1e-5 * q_frame.abs().max(1e-6),
            "{q} vs {q_frame}"
        );
        assert!(
            (q - q_turned).abs() < 1e-5 * q.abs().max(1e-6),
            "{q} vs {q_turned}"
        );
    }
}

#[test]
fn guccione_isotropic_limit_needs_no_fibre_and_is_stiffer_along_the_fibre_otherwise() {
    let c_iso = guccione_iso(KAPPA, 1.5);
    for seed in 1..10 {
        let h = sample_h(seed, 0.2);
        let e = (h + h.transpose() + h.transpose() * h) * 0.5;
        let (s0, w0) = guccione_second_piola(e, Vec3::ZERO, 1e4, 1.5, 1.5, 1.5);
        let fibre = (sample_h(seed + 50, 1.0) * Vec3::ONE).normalize();
        let (s1, w1) = guccione_second_piola(e, fibre, 1e4, 1.5, 1.5, 1.5);
        assert!(max_abs(s0 - s1) < 1e-5 * max_abs(s0) && (w0 - w1).abs() < 1e-5 * w0);
        // W = C/2 (e^{b E:E} − 1).
        let ee = (e.transpose() * e)
            .to_cols_array()
            .iter()
            .step_by(4)
            .sum::<f32>();
        let expected = 0.5 * 1e4 * ((1.5 * ee) as f64).exp_m1();
        assert!(((w0 as f64) - expected).abs() < 1e-5 * expected);
        let (p_iso, _) = eval(
            MaterialModel::Guccione,
            &c_iso,
            VolumetricLaw::SimoTaylor,
            fibre,
            h,
        );
        let (p_none, _) = eval(
            MaterialModel::Guccione,
            &c_iso,
            VolumetricLaw::SimoTaylor,
            Vec3::ZERO,
            h,
        );
        assert!(max_abs(p_iso - p_none) < 1e-5 * max_abs(p_none));
    }
    // Problem 1's constants: a 5 % isochoric stretch along the fibre costs more than across it.
    let c = guccione_land_p1(KAPPA);
    let stretch = |a: Vec3| {
        let f = Mat3::from_diagonal(Vec3::splat(1.05f32.powf(-0.5)))
            + outer(a, a) * (1.05 - 1.05f32.powf(-0.5));
        eval(
            MaterialModel::Guccione,
            &c,
            VolumetricLaw::SimoTaylor,
            Vec3::X,
            f - Mat3::IDENTITY,
        )
        .1
    };
    let (along, across) = (stretch(Vec3::X), stretch(Vec3::Y));
    eprintln!("5 % fibre stretch Ψ = {along:.3} J/m³, cross-fibre {across:.3} J/m³");
    // Q along = b_f E_ff² + 2 b_t E_⊥² = 0.0233, across = 0.0109 for these constants.
    assert!(along > 2.0 * across, "along {along} vs across {across}");
}

fn outer(a: Vec3, b: Vec3) -> Mat3 {
    palpate::material::outer(a, b)
}

#[test]
fn series_helpers_match_f64_to_f32_precision() {
    let mut worst = [0.0f64; 4];
    for i in -2000..=2000 {
        let x = i as f32 * 1e-4 * (1.0 + 0.37 * (i as f32 * 0.01).sin()); // ±0.27, dense near 0
        if x == 0.0 {
            continue;
        }
        let xd = x as f64;
        let rel = |a: f32, b: f64| ((a as f64 - b) / b).abs();
        worst[0] = worst[0].max(rel(log1p_f32(x), xd.ln_1p()));
        worst[1] = worst[1].max(rel(x_minus_log1p_f32(x), xd - xd.ln_1p()));
        worst[2] = worst[2].max(rel(expm1_f32(x), xd.exp_m1()));
        worst[3] = worst[3].max(rel(
            inv_cbrt_minus_one_f32(x),
            (1.0 + xd).powf(-1.0 / 3.0) - 1.0,
        ));
    }
    eprintln!(
        "log1p, x−log1p, expm1, (1+x)^(−1/3)−1: worst rel err {:?}",
        worst.map(|w| format!("{w:.2e}"))
    );
    // x − log1p(x) cancels in f64 too for tiny x; 1e-5 is still 60 ulp of f32.
    assert!(worst.iter().all(|&w| w < 2e-5), "{worst:?}");
}

#[test]
fn volumetric_laws_have_zero_pressure_at_rest_unit_stiffness_and_consistent_pressure() {
    let kappa = 3.0e5f32;
    for law in VolumetricLaw::ALL {
        assert_eq!(volumetric_energy_pressure(law, kappa, 0.0), (0.0, 0.0));
        let h = 1e-3f32;
        let stiffness = (volumetric_energy_pressure(law, kappa, h).1
            - volumetric_energy_pressure(law, kappa, -h).1)
            / (2.0 * h);
        assert!(
            (stiffness / kappa - 1.0).abs() < 1e-3,
            "{}: U''(1) {stiffness}",
            law.name()
        );
        // p = dU/dJ over J ∈ [−0.5, 3], across the floor J_min = 0.1.
        for i in 0..200 {
            let j = -0.5 + 3.5 * i as f64 / 199.0;
            let d = (j - 1.0) as f32;
            let dd = 1e-3f32;
            let (ua, _) = volumetric_energy_pressure(law, kappa, d + dd);
            let (ub, _) = volumetric_energy_pressure(law, kappa, d - dd);
            let (u, p) = volumetric_energy_pressure(law, kappa, d);
            assert!(u.is_finite() && p.is_finite());
            let fd = (ua as f64 - ub as f64) / (((d + dd) - (d - dd)) as f64);
            assert!(
                (fd - p as f64).abs() < 2e-3 * (p.abs() as f64).max(0.05 * kappa as f64),
                "{} at J {j}: p {p} vs dU/dJ {fd}",
                law.name()
            );
        }
    }
    // Under compression: quadratic stays bounded, the logarithmic laws build a barrier.
    let at = |law, j: f32| volumetric_energy_pressure(law, kappa, j - 1.0).0 / kappa;
    eprintln!(
        "U(J=0.2)/κ: quadratic {:.3}, log_squared {:.3}, simo_taylor {:.3}",
        at(VolumetricLaw::Quadratic, 0.2),
        at(VolumetricLaw::LogSquared, 0.2),
        at(VolumetricLaw::SimoTaylor, 0.2)
    );
    assert!(at(VolumetricLaw::Quadratic, 0.2) < 0.5);
    // κ/2 (ln 0.2)² = 1.295, κ/4 (0.04 − 1 − 2 ln 0.2) = 0.565, against κ/2 · 0.64 = 0.32.
    assert!(at(VolumetricLaw::LogSquared, 0.2) > 1.2 && at(VolumetricLaw::SimoTaylor, 0.2) > 0.5);
}

#[test]
fn bad_constants_are_refused_with_a_one_line_message_naming_the_key() {
    let ok = {
        let mut h = HyperelasticParams::new(1e5);
        h.guccione = GuccioneParams::new(2000.0, 8.0, 2.0, 4.0);
        h
    };
    assert!(ok.validate(MaterialModel::Guccione).is_ok());
    let cases: Vec<(HyperelasticParams, MaterialModel, &str)> = vec![
        (
            HyperelasticParams::new(0.0),
            MaterialModel::StvkSplit,
            "bulk_modulus",
        ),
        (
            HyperelasticParams::new(-3.0),
            MaterialModel::Guccione,
            "bulk_modulus",
        ),
        (
            HyperelasticParams::new(f64::NAN),
            MaterialModel::CorotationalSplit,
            "bulk_modulus",
        ),
        (
            HyperelasticParams {
                guccione: GuccioneParams::new(0.0, 8.0, 2.0, 4.0),
                ..ok
            },
            MaterialModel::Guccione,
            "guccione_c",
        ),
        (
            HyperelasticParams {
                guccione: GuccioneParams::new(2000.0, 8.0, -2.0, 4.0),
                ..ok
            },
            MaterialModel::Guccione,
            "guccione_bt",
        ),
        (
            HyperelasticParams {
                guccione: GuccioneParams::new(2000.0, 0.0, 0.0, 0.0),
                ..ok
            },
            MaterialModel::Guccione,
            "guccione_bf",
        ),
    ];
    for (h, model, key) in cases {
        let msg = h.validate(model).expect_err(key);
        eprintln!("{msg}");
        assert!(msg.contains(key) && !msg.contains('\n'), "{msg}");
    }
    // The (λ, μ) laws ignore the constants.
    assert!(HyperelasticParams::new(-1.0)
        .validate(MaterialModel::Stvk)
        .is_ok());
    // Fibres: needed only by a fibred law; present, complete, non-zero.
    let iso = HyperelasticParams {
        guccione: GuccioneParams::isotropic(1e4, 1.0),
        ..ok
    };
    assert!(iso.check_fibres(MaterialModel::Guccione, &[], 5).is_ok());
    // None or too few: the scene's material.fibre is the fix; a zero one is the mesh
    // file's (per-tet fibres come from it).
    for (fibres, n, key) in [
        (vec![], 2, "material.fibre"),
        (vec![1.0, 0.0, 0.0], 2, "material.fibre"),
        (vec![1.0, 0.0, 0.0, 0.0, 0.0, 0.0], 2, "mesh.file"),
    ] {
        let msg = ok
            .check_fibres(MaterialModel::Guccione, &fibres, n)
            .expect_err("fibres");
        eprintln!("{msg}");
        assert!(msg.starts_with(key) && !msg.contains('\n'), "{msg}");
    }
    assert!(ok
        .check_fibres(MaterialModel::Guccione, &[0.0, 0.0, 2.0, 1.0, 1.0, 0.0], 2)
        .is_ok());
    assert!(HyperelasticParams::check_constant_fibre([0.0; 3]).is_err());
    assert!(HyperelasticParams::check_constant_fibre([1.0, 0.0, 0.0]).is_ok());
}

#[test]
fn bulk_modulus_from_poisson_ratio_and_wave_modulus() {
    let (lambda, mu) = MaterialParams::lame_from_young(3.0e4, 0.499);
    let kappa = HyperelasticParams::bulk_modulus_from_poisson(mu, 0.499);
    // κ = λ + 2μ/3.
    assert!((kappa - (lambda + 2.0 * mu / 3.0)).abs() < 1e-9 * kappa);
    let h = HyperelasticParams::new(kappa);
    let m = h.p_wave_modulus(MaterialModel::StableNeohookeanSplit, lambda, mu);
    assert!((m - (lambda + 2.0 * mu)).abs() < 1e-9 * m);
    assert_eq!(
        HyperelasticParams::recommended_volume_term(kappa, mu),
        palpate::material::VolumeTerm::NodalAverage
    );
    assert_eq!(
        HyperelasticParams::recommended_volume_term(
            HyperelasticParams::bulk_modulus_from_poisson(mu, 0.3),
            mu
        ),
        palpate::material::VolumeTerm::Element
    );
    for m in MaterialModel::EVERY {
        assert_eq!(MaterialModel::from_any_name(m.name()), Some(m));
        assert_eq!(m.is_split(), MaterialModel::SPLIT.contains(&m));
    }
}
