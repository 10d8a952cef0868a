//! `beam --until-static` at three mesh resolutions: the tip deflection converges and
//! approaches the Euler–Bernoulli cantilever value.

use palpate::run::{run, RunLength, RunOptions};
use palpate::sim::Backend;
use palpate::Scene;

const BEAM: &str = include_str!("../scenes/beam.toml");

/// Mean vertical displacement of the vertices at the free end x = L, m.
fn tip_deflection(cells: [usize; 3]) -> (f64, palpate::run::RunSummary) {
    let text = BEAM.replace(
        "cells = [20, 4, 4]",
        &format!("cells = [{}, {}, {}]", cells[0], cells[1], cells[2]),
    );
    let scene = Scene::from_toml(&text, "beam (convergence)", "beam", None).unwrap();
    let out =
        std::env::temp_dir().join(format!("palpate-conv-{}-{}", std::process::id(), cells[0]));
    let opts = RunOptions {
        backend: Backend::Cpu,
        length: RunLength::UntilStatic { max_steps: 100_000 },
        out: out.clone(),
        ..Default::default()
    };
    let summary = run(&scene, &opts).unwrap();
    assert_eq!(summary.status, "ok", "{cells:?}: {}", summary.status);
    let vtu = std::fs::read_to_string(out.join("final.vtu")).unwrap();
    assert!(vtu.contains("displacement"));
    // The summary holds only the largest displacement; read the tip average from final.vtu.
    let model = palpate::model::Model::from_scene(&scene);
    let u = read_displacement(&vtu);
    let l = 0.1f32;
    let tip: Vec<usize> = (0..model.n_vertices())
        .filter(|&i| (model.rest[3 * i] - l).abs() < 1e-6)
        .collect();
    let d = -tip.iter().map(|&i| u[3 * i + 2] as f64).sum::<f64>() / tip.len() as f64;
    (d, summary)
}

/// Decode the `displacement` array of a palpate .vtu (base64, UInt64 header).
fn read_displacement(vtu: &str) -> Vec<f32> {
    let start = vtu.find("Name=\"displacement\"").unwrap();
    let body = &vtu[start..];
    let open = body.find('>').unwrap() + 1;
    let close = body.find("</DataArray>").unwrap();
    let bytes = base64_decode(body[open..close].trim());
    bytemuck::cast_slice::<u8, f32>(&bytes[8..]).to_vec()
}

fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        b'/' => 63,
        _ => 0,
    };
    let mut out = Vec::new();
    for chunk in s.as_bytes().chunks(4) {
        let n = chunk.iter().fold(0u32, |acc, &c| acc << 6 | val(c) as u32);
        let pad = chunk.iter().filter(|&&c| c == b'=').count();
        let b = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
        out.extend_from_slice(&b[..3 - pad]);
    }
    out
}

#[test]
fn static_tip_deflection_converges_under_refinement() {
    // Scene values: E = 300 kPa, ρ = 1000 kg/m³, g = 9.81 m/s², 0.1 × 0.02 × 0.02 m.
    let (e, rho, g) = (3.0e5f64, 1000.0, 9.81);
    let (l, b, h) = (0.1f64, 0.02, 0.02);
    let euler_bernoulli = rho * g * b * h * l.powi(4) / (8.0 * e * b * h.powi(3) / 12.0);
    let mut d = Vec::new();
    for cells in [[10, 2, 2], [20, 4, 4], [40, 8, 8]] {
        let (tip, s) = tip_deflection(cells);
        eprintln!(
            "beam {cells:?}: {} tets, tip deflection {:.4} mm in {} steps (residual {:.1e}), Euler-Bernoulli {:.4} mm",
            s.tets,
            tip * 1e3,
            s.steps,
            s.static_residual.unwrap(),
            euler_bernoulli * 1e3
        );
        d.push(tip);
    }
    assert!(
        d[0] < d[1] && d[1] < d[2],
        "deflection must grow as locking eases: {d:?}"
    );
    assert!(
        d[2] - d[1] < d[1] - d[0],
        "increments must shrink (convergence): {d:?}"
    );
    assert!(
        (d[2] - euler_bernoulli).abs() < 0.15 * euler_bernoulli,
        "finest {:.4} mm vs Euler-Bernoulli {:.4} mm",
        d[2] * 1e3,
        euler_bernoulli * 1e3
    );
}
