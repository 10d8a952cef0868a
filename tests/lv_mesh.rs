//! Heart and test geometry: the LV and ellipsoid-shell generators produce conforming,
//! positively oriented, watertight meshes whose volume converges to the analytic one; tags,
//! regions and fibres are right; a 1M-tet LV steps on the GPU path.

mod common;

use glam::DVec3;
use palpate::mesh::generators::{self, LvGeometry, HELIX_ENDO_DEG};
use palpate::mesh::{tags, TetMesh};
use std::collections::{HashMap, HashSet};

fn check_conforming_and_oriented(mesh: &TetMesh, what: &str) {
    let mut m = mesh.clone();
    let report = m.validate(what).unwrap_or_else(|e| panic!("{what}: {e}"));
    assert!(
        report.reoriented.is_empty(),
        "{what}: generator left {} inverted tets",
        report.reoriented.len()
    );
    assert_eq!(report.unused_vertices, 0, "{what}: unused vertices");
    // No duplicate elements.
    let mut seen = HashSet::new();
    for t in &mesh.tets {
        let mut k = *t;
        k.sort_unstable();
        assert!(seen.insert(k), "{what}: duplicate tet {t:?}");
    }
    // No duplicate nodes (two vertices closer than 1e-9 of the mesh size).
    let size = mesh.positions.iter().fold(0.0f64, |a, p| a.max(p.length()));
    let q = 1e-9 * size;
    let mut grid: HashMap<[i64; 3], u32> = HashMap::new();
    for (i, p) in mesh.positions.iter().enumerate() {
        let key = (*p / q).round().as_i64vec3().to_array();
        assert!(
            grid.insert(key, i as u32).is_none(),
            "{what}: duplicate node at {p:?}"
        );
    }
    // Every interior face is shared by exactly two tets, with opposite orientation.
    let mut faces: HashMap<[u32; 3], Vec<[u32; 3]>> = HashMap::new();
    for t in &mesh.tets {
        for f in palpate::mesh::TET_FACES {
            let face = [t[f[0]], t[f[1]], t[f[2]]];
            let mut k = face;
            k.sort_unstable();
            faces.entry(k).or_default().push(face);
        }
    }
    for (k, fs) in &faces {
        assert!(
            fs.len() <= 2,
            "{what}: face {k:?} in {} tets (non-conforming)",
            fs.len()
        );
    }
}

/// The boundary surface is closed and manifold: every edge in exactly two boundary faces,
/// used once in each direction; and it is a sphere: V − E + F = 2.
fn check_watertight(mesh: &TetMesh, what: &str) {
    let faces = mesh.boundary_faces();
    let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
    let mut verts = HashSet::new();
    for f in &faces {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
            verts.insert(a);
        }
    }
    let mut count: HashMap<(u32, u32), usize> = HashMap::new();
    for f in &faces {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    for (e, c) in &count {
        assert_eq!(
            *c, 2,
            "{what}: boundary edge {e:?} in {c} faces (not manifold / not closed)"
        );
        assert_eq!(
            edges[e], 0,
            "{what}: boundary edge {e:?} not used once each way"
        );
    }
    let chi = verts.len() as i64 - count.len() as i64 + faces.len() as i64;
    assert_eq!(chi, 2, "{what}: Euler characteristic {chi}");
}

#[test]
fn lv_is_conforming_oriented_and_watertight_at_every_resolution() {
    for k in [1, 2, 3, 5] {
        let mesh = generators::lv(LvGeometry::default(), k, 4 * k);
        check_conforming_and_oriented(&mesh, &format!("lv k={k}"));
        check_watertight(&mesh, &format!("lv k={k}"));
        assert_eq!(mesh.n_tets(), 96 * k * k * k);
        let s = mesh.stats();
        eprintln!(
            "lv k={k}: {} tets, volume min {:.3e} mean {:.3e} m^3 (min/mean {:.2}), dihedral {:.1}..{:.1} deg",
            s.tets, s.min_volume, s.mean_volume, s.min_volume / s.mean_volume, s.min_dihedral_deg, s.max_dihedral_deg
        );
        // The apex and the square's corners do not hold the time step hostage: the smallest
        // altitude stays within a factor 2 of the wall-layer thickness.
        let layer = 0.003 / k as f64;
        assert!(
            s.min_altitude > 0.45 * layer,
            "k={k}: min altitude {:.3e} vs layer {layer:.3e}",
            s.min_altitude
        );
        assert!(
            s.min_dihedral_deg > 5.0,
            "k={k}: min dihedral {}",
            s.min_dihedral_deg
        );
    }
    let shell = generators::ellipsoid_shell([0.6, 0.6, 0.9], [1.0, 1.0, 1.3], 2, 6);
    check_conforming_and_oriented(&shell, "ellipsoid shell");
    // A closed shell's boundary is two spheres: χ = 4.
    let faces = shell.boundary_faces();
    let mut e = HashSet::new();
    let mut v = HashSet::new();
    for f in &faces {
        for k in 0..3 {
            e.insert((f[k].min(f[(k + 1) % 3]), f[k].max(f[(k + 1) % 3])));
            v.insert(f[k]);
        }
    }
    assert_eq!(v.len() as i64 - e.len() as i64 + faces.len() as i64, 4);
}

#[test]
fn lv_volume_converges_to_the_analytic_truncated_shell() {
    let geo = LvGeometry::default();
    let exact = geo.wall_volume();
    let mut errors = Vec::new();
    for k in [1, 2, 4, 8] {
        let v = generators::lv(geo, k, 4 * k).volume();
        let e = (v - exact).abs() / exact;
        eprintln!("lv k={k}: volume {v:.6e} m^3, exact {exact:.6e}, rel error {e:.3e}");
        errors.push(e);
    }
    let orders: Vec<f64> = errors.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
    eprintln!("observed orders: {orders:?}");
    assert!(errors[3] < 0.01, "finest error {}", errors[3]);
    assert!(
        orders[1] > 1.5 && orders[2] > 1.5,
        "second-order convergence expected, got {orders:?}"
    );
}

#[test]
fn ellipsoid_shell_volume_converges() {
    let (a, b) = ([0.6, 0.6, 0.9], [1.0, 1.0, 1.3]);
    let exact = 4.0 / 3.0 * std::f64::consts::PI * (b[0] * b[1] * b[2] - a[0] * a[1] * a[2]);
    let e: Vec<f64> = [4, 8, 16]
        .iter()
        .map(|&n| (generators::ellipsoid_shell(a, b, 2, n).volume() - exact).abs() / exact)
        .collect();
    eprintln!("ellipsoid shell volume errors {e:?}");
    assert!(e[2] < e[1] && e[1] < e[0] && e[2] < 0.01, "{e:?}");
}

#[test]
fn lv_tags_regions_and_fibres() {
    let geo = LvGeometry::default();
    let k = 4;
    let mesh = generators::lv(geo, k, 4 * k);
    // Tags sit on the right surfaces.
    for (i, p) in mesh.positions.iter().enumerate() {
        let t = mesh.vertex_tags[i];
        if t & tags::BASE != 0 {
            assert!(
                (p.z - geo.base_z).abs() < 1e-12,
                "base vertex {i} at z = {}",
                p.z
            );
        }
        if t & tags::ENDOCARDIUM != 0 {
            // on the inner spheroid (x² + y²)/r_s² + z²/r_l² = 1
            let r = (p.x * p.x + p.y * p.y) / 0.007f64.powi(2) + p.z * p.z / 0.017f64.powi(2);
            assert!(
                (r - 1.0).abs() < 1e-9,
                "endocardial vertex {i} off the spheroid: {r}"
            );
        }
    }
    // Every boundary face is tagged on all its vertices with one common tag.
    for f in mesh.boundary_faces() {
        let common = f
            .iter()
            .fold(u32::MAX, |acc, &v| acc & mesh.vertex_tags[v as usize]);
        assert!(common != 0, "untagged boundary face {f:?}");
    }
    let regions: HashSet<u32> = mesh.regions.iter().copied().collect();
    assert_eq!(
        regions,
        HashSet::from([generators::REGION_INNER_WALL, generators::REGION_OUTER_WALL])
    );
    // Fibres: unit, tangent to the wall (⊥ to the transmural direction), helix angle from
    // +60° (endo) to −60° (epi) measured from the circumferential direction.
    assert_eq!(mesh.fibres.len(), mesh.n_tets());
    let mut inner = Vec::new();
    let mut outer = Vec::new();
    for (t, f) in mesh.fibres.iter().enumerate() {
        assert!((f.length() - 1.0).abs() < 1e-9);
        let c: DVec3 = mesh.corners(t).iter().sum::<DVec3>() / 4.0;
        let radial_xy = DVec3::new(c.x, c.y, 0.0);
        if radial_xy.length() < 0.004 || c.z > 0.0 {
            continue; // near the apex axis or at the base the circumferential direction is ill-defined
        }
        let e_circ = DVec3::Z.cross(radial_xy).normalize();
        // Apex-to-base direction: +z projected onto the wall's tangent plane (mid-wall spheroid normal).
        let n = DVec3::new(
            c.x / 0.0085f64.powi(2),
            c.y / 0.0085f64.powi(2),
            c.z / 0.0185f64.powi(2),
        )
        .normalize();
        let e_long = (DVec3::Z - n * n.z).normalize();
        // Signed helix angle, folded to (−90°, 90°] (a fibre and its negative are the same).
        let mut angle = f.dot(e_long).atan2(f.dot(e_circ)).to_degrees();
        if angle > 90.0 {
            angle -= 180.0;
        } else if angle <= -90.0 {
            angle += 180.0;
        }
        let t_wall = {
            let z = mesh.tets[t]
                .iter()
                .map(|&v| v as usize / ((4 * k + 1) * (4 * k + 1)))
                .sum::<usize>();
            z as f64 / (4.0 * k as f64)
        };
        if t_wall < 0.2 {
            inner.push(angle);
        }
        if t_wall > 0.8 {
            outer.push(angle);
        }
    }
    let mean = |v: &Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
    // Innermost layer of 4: t̄ = 1/8 → α = 60° − 120°/8 = 45°; outermost: −45°.
    let expect = HELIX_ENDO_DEG * (1.0 - 2.0 / 8.0);
    let (a_in, a_out) = (mean(&inner), mean(&outer));
    eprintln!("signed helix angle: inner wall {a_in:.1} deg, outer wall {a_out:.1} deg (expected ±{expect:.1})");
    assert!(
        a_in * a_out < 0.0,
        "helix angle must change sign across the wall: {a_in} vs {a_out}"
    );
    assert!(
        (a_in.abs() - expect).abs() < 8.0 && (a_out.abs() - expect).abs() < 8.0,
        "{a_in} {a_out}"
    );
}

#[test]
fn scene_selects_by_tag_and_loads_the_endocardium() {
    let scene = palpate::Scene::load("lv").unwrap();
    let base = scene
        .mesh
        .vertex_tags
        .iter()
        .filter(|t| **t & tags::BASE != 0)
        .count();
    assert_eq!(
        scene.fixed.iter().filter(|f| **f).count(),
        base,
        "fixed = base vertices"
    );
    // The pressure resultant on the truncated cavity: p × (area of the base opening) along −z…
    // the closed cavity would give zero; the open base leaves p·π r_endo(base)² pointing at the apex.
    let total: DVec3 = scene.external_forces.iter().sum();
    let r_base = 0.007 * (1.0 - (0.005f64 / 0.017).powi(2)).sqrt();
    let expected = 1000.0 * std::f64::consts::PI * r_base * r_base;
    eprintln!("pressure resultant {total:?}, expected |F_z| ≈ {expected:.4e} N");
    assert!(total.x.abs() < 1e-3 * expected && total.y.abs() < 1e-3 * expected);
    assert!(
        (total.z.abs() - expected).abs() < 0.05 * expected,
        "{total:?} vs {expected}"
    );
}

#[test]
fn one_million_tet_lv_steps_on_the_gpu() {
    let text = include_str!("../scenes/lv.toml").replace("resolution = 3 ", "resolution = 22 ");
    assert!(text.contains("resolution = 22"));
    let t0 = std::time::Instant::now();
    let scene = palpate::Scene::from_toml(&text, "lv 1M", "lv", None).unwrap();
    let gen = t0.elapsed().as_secs_f64();
    assert!(scene.mesh.n_tets() > 1_000_000);
    let mut sim = palpate::Simulation::new(
        &scene,
        palpate::Backend::Gpu,
        palpate::sim::SimOptions {
            gpu: Some(common::gpu()),
            ..Default::default()
        },
    )
    .unwrap();
    let t1 = std::time::Instant::now();
    let r = sim.advance(5).unwrap();
    eprintln!(
        "1M-tet LV: scene built in {gen:.2} s, 5 GPU steps in {:.2} s on {}",
        t1.elapsed().as_secs_f64(),
        sim.backend_name()
    );
    assert!(matches!(r, palpate::sim::Advance::Done(_)));
    let u = sim.state().unwrap().displacements;
    let umax = u.iter().fold(0.0f32, |a, x| a.max(x.abs()));
    assert!(umax > 0.0 && umax.is_finite(), "{umax}");
}

/// The lv generator's smallest disk is 2 cells: 1 is refused naming `mesh.cells` (it made
/// flat tets, reported as a degenerate tet the user never wrote); 2 makes a valid mesh.
#[test]
fn lv_with_one_disk_cell_is_refused_naming_the_key() {
    let scene = |cells: &str| {
        palpate::Scene::from_toml(
            &format!("[mesh]\ngenerator = \"lv\"\ncells = {cells}\n[material]\nyoungs_modulus = 3.0e4\npoisson_ratio = 0.3\ndensity = 1000.0\n"),
            "lv cells",
            "lv",
            None,
        )
    };
    let err = scene("[100, 1]").unwrap_err().to_string();
    assert!(
        err.contains("mesh.cells") && err.contains("at least 2"),
        "{err}"
    );
    assert!(!err.contains('\n'), "{err}");
    scene("[1, 2]").unwrap();
}
