//! Mesh file I/O: writer round trips, files written by real tools (Gmsh, meshio, VTK; see
//! tests/fixtures/meshes/README.md), one-line errors for bad input, and a short mutation fuzz.

mod common;
#[path = "mesh_io/fuzz.rs"]
mod fuzz;

use glam::DVec3;
use palpate::mesh::io::{read, write};
use palpate::mesh::{generators, tags, TetMesh};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/meshes")
}

fn fixture(name: &str) -> TetMesh {
    let path = fixtures().join(name);
    read(&path).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// A fresh scratch folder for one test.
fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("palpate-mesh-io-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("scratch folder");
    d
}

/// Tets per region.
fn region_counts(m: &TetMesh) -> BTreeMap<u32, usize> {
    let mut c = BTreeMap::new();
    for &r in &m.regions {
        *c.entry(r).or_insert(0) += 1;
    }
    c
}

fn count_tagged(m: &TetMesh, bit: u32) -> usize {
    m.vertex_tags.iter().filter(|&&t| t & bit != 0).count()
}

/// A small LV: two regions, vertex tags and a unit fibre per tet.
fn lv() -> TetMesh {
    let m = generators::lv(Default::default(), 2, 4);
    assert!(!m.vertex_tags.is_empty() && region_counts(&m).len() == 2);
    assert_eq!(m.fibres.len(), m.n_tets());
    m
}

/// Same vertices (within `pos_tol`) and tets.
fn assert_same_geometry(a: &TetMesh, b: &TetMesh, pos_tol: f64) {
    assert_eq!(a.positions.len(), b.positions.len(), "vertex count");
    for (i, (p, q)) in a.positions.iter().zip(&b.positions).enumerate() {
        assert!(p.distance(*q) <= pos_tol, "vertex {i}: {p} vs {q}");
    }
    assert_eq!(a.tets, b.tets, "tets");
}

/// Same geometry, regions, tags and fibres (within `fibre_tol`).
fn assert_same_mesh(a: &TetMesh, b: &TetMesh, pos_tol: f64, fibre_tol: f64) {
    assert_same_geometry(a, b, pos_tol);
    assert_eq!(a.regions, b.regions, "regions");
    assert_eq!(a.vertex_tags, b.vertex_tags, "vertex tags");
    assert_eq!(a.fibres.len(), b.fibres.len(), "fibre count");
    for (t, (f, g)) in a.fibres.iter().zip(&b.fibres).enumerate() {
        assert!(f.distance(*g) <= fibre_tol, "fibre {t}: {f} vs {g}");
    }
}

// ---------------------------------------------------------------- round trips

#[test]
fn vtu_round_trip_keeps_positions_tets_regions_tags_and_fibres() {
    let m = lv();
    let path = scratch("rt-vtu").join("lv.vtu");
    write(&path, &m).unwrap();
    let back = read(&path).unwrap();
    // Points are Float64 (exact); fibres Float32.
    assert_same_mesh(&m, &back, 0.0, 1e-6);
}

#[test]
fn msh_round_trip_keeps_positions_tets_regions_tags_and_fibres() {
    let m = lv();
    let path = scratch("rt-msh").join("lv.msh");
    write(&path, &m).unwrap();
    let back = read(&path).unwrap();
    // Shortest round-trip decimal: exact.
    assert_same_mesh(&m, &back, 0.0, 1e-15);
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.starts_with("$MeshFormat\n4.1 0 8\n"));
    assert!(
        text.contains("$Entities\n0 0 0 2\n"),
        "one volume per region"
    );
}

#[test]
fn round_trips_without_tags_or_fibres_and_with_region_zero() {
    let m = generators::beam([0.03, 0.01, 0.01], [3, 1, 1]);
    assert!(m.vertex_tags.is_empty() && m.fibres.is_empty());
    let dir = scratch("rt-beam");
    for name in ["beam.vtu", "beam.msh"] {
        let path = dir.join(name);
        write(&path, &m).unwrap();
        let back = read(&path).unwrap();
        assert_same_mesh(&m, &back, 0.0, 0.0);
        assert!(back.regions.iter().all(|&r| r == 0), "{name}");
    }
}

#[test]
fn written_files_are_read_back_by_every_writer_with_validation() {
    let m = lv();
    let dir = scratch("rt-validate");
    for name in ["lv.vtu", "lv.msh"] {
        let path = dir.join(name);
        write(&path, &m).unwrap();
        let mut back = read(&path).unwrap();
        back.validate(name).unwrap();
        assert!((back.volume() - m.volume()).abs() <= 1e-12 * m.volume().abs());
        assert!(back.volume() > 0.0);
    }
}

#[test]
fn write_refuses_unknown_formats_and_inconsistent_meshes() {
    let dir = scratch("write-bad");
    let m = generators::beam([0.01; 3], [1, 1, 1]);
    let e = write(&dir.join("m.stl"), &m).unwrap_err().to_string();
    assert!(e.contains("m.stl") && e.contains(".stl"), "{e}");
    let mut bad = m.clone();
    bad.regions.pop();
    for name in ["m.vtu", "m.msh"] {
        let e = write(&dir.join(name), &bad).unwrap_err().to_string();
        assert!(e.contains(name) && e.contains("region ids"), "{e}");
        assert!(!dir.join(name).exists(), "no file left behind");
    }
    let mut bad = m.clone();
    bad.tets[0][2] = 999;
    let e = write(&dir.join("m.vtu"), &bad).unwrap_err().to_string();
    assert!(e.contains("vertex 999"), "{e}");
}

// ---------------------------------------------------------------- files from real tools

// Counts reported by the generating tools (make_fixtures.py output, see the README).
const BOX_NODES: usize = 78;
const BOX_TETS: usize = 200;
const BOX_REGION_7: usize = 100;
const BOX_REGION_9: usize = 100;
const BOX_BASE_NODES: usize = 12;
const BOX_VOLUME: f64 = 0.01 * 0.01 * 0.02;

fn check_box(name: &str, m: &TetMesh) {
    assert_eq!(m.n_vertices(), BOX_NODES, "{name}: nodes");
    assert_eq!(m.n_tets(), BOX_TETS, "{name}: tets");
    let regions = region_counts(m);
    assert_eq!(
        regions,
        BTreeMap::from([(7, BOX_REGION_7), (9, BOX_REGION_9)]),
        "{name}: regions"
    );
    assert_eq!(
        count_tagged(m, tags::BASE),
        BOX_BASE_NODES,
        "{name}: base nodes"
    );
    for &i in m
        .vertex_tags
        .iter()
        .enumerate()
        .filter(|(_, t)| **t != 0)
        .map(|(i, _)| i)
        .collect::<Vec<_>>()
        .iter()
    {
        assert!(
            m.positions[i].z.abs() < 1e-12,
            "{name}: tagged vertex {i} is not on z = 0"
        );
    }
    let mut v = m.clone();
    v.validate(name).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        (v.volume() - BOX_VOLUME).abs() < 1e-9 * BOX_VOLUME,
        "{name}: volume {}",
        v.volume()
    );
}

#[test]
fn gmsh_box_in_four_encodings_reads_the_same_mesh() {
    let reference = fixture("box_v41_ascii.msh");
    check_box("box_v41_ascii.msh", &reference);
    assert!(reference.fibres.is_empty());
    for name in [
        "box_v41_binary.msh",
        "box_v22_ascii.msh",
        "box_v22_binary.msh",
    ] {
        let m = fixture(name);
        check_box(name, &m);
        // Format 2.2 stores 16 significant digits, 4.1 17.
        assert_same_mesh(&reference, &m, 1e-17, 0.0);
    }
}

#[test]
fn gmsh_second_order_sphere_keeps_corners_only() {
    // Gmsh: 28 nodes at order 1, 130 at order 2, 50 tets of type 11, volume entity 1.
    let m = fixture("sphere_tet10_v41.msh");
    assert_eq!(m.n_vertices(), 28);
    assert_eq!(m.n_tets(), 50);
    assert_eq!(
        region_counts(&m),
        BTreeMap::from([(1, 50)]),
        "entity tag as region"
    );
    let mut v = m.clone();
    v.validate("sphere").unwrap();
    let ball = 4.0 / 3.0 * std::f64::consts::PI * 0.01f64.powi(3);
    assert!(
        v.volume() > 0.5 * ball && v.volume() < ball,
        "volume {}",
        v.volume()
    );
}

#[test]
fn meshio_and_vtk_written_files_read_like_the_gmsh_original() {
    let reference = fixture("box_v41_ascii.msh");
    let files = [
        "box_meshio_v42_ascii.vtk",
        "box_meshio_v42_binary.vtk",
        "box_meshio_v51_ascii.vtk",
        "box_meshio_ascii.vtu",
        "box_meshio_binary.vtu",
        "box_meshio_zlib.vtu",
        "box_vtk_appended_b64_zlib.vtu",
        "box_vtk_appended_raw.vtu",
        "box_vtk_appended_raw_zlib.vtu",
        "box_vtk_binary_bigendian.vtu",
        "box_vtk_v42_binary.vtk",
        "box_vtk_v51_binary.vtk",
    ];
    let first = fixture(files[0]);
    for name in files {
        let m = fixture(name);
        check_box(name, &m);
        // meshio keeps Gmsh's node and element order (its ASCII files keep 12 significant
        // digits); the 14 base triangles are skipped.
        assert_same_geometry(&reference, &m, 1e-13);
        assert_eq!(m.regions, reference.regions, "{name}");
        assert_eq!(m.vertex_tags, reference.vertex_tags, "{name}");
        assert_eq!(m.fibres.len(), BOX_TETS, "{name}: fibres");
        for (f, g) in m.fibres.iter().zip(&first.fibres) {
            assert!(
                (f.length() - 1.0).abs() < 1e-9 && f.distance(*g) < 1e-12,
                "{name}"
            );
        }
    }
}

#[test]
fn meshio_quadratic_vtu_keeps_corners_only() {
    let m = fixture("sphere_tet10_meshio.vtu");
    let gmsh = fixture("sphere_tet10_v41.msh");
    assert_eq!(m.n_vertices(), 28);
    assert_eq!(m.n_tets(), 50);
    assert_same_geometry(&gmsh, &m, 1e-14);
}

#[test]
fn tetgen_files_zero_and_one_based() {
    let m = fixture("box_meshio.node");
    let reference = fixture("box_v41_ascii.msh");
    assert_eq!((m.n_vertices(), m.n_tets()), (BOX_NODES, BOX_TETS));
    assert_eq!(
        region_counts(&m),
        BTreeMap::from([(7, BOX_REGION_7), (9, BOX_REGION_9)])
    );
    assert_eq!(m.tets, reference.tets);
    assert_eq!(m.positions, reference.positions);
    // Either file of the pair may be named.
    assert_eq!(fixture("box_meshio.ele").tets, m.tets);

    let m = fixture("cube_1based.node");
    assert_eq!((m.n_vertices(), m.n_tets()), (8, 6));
    assert_eq!(m.tets[0], [0, 1, 2, 6]);
    assert_eq!(m.regions, vec![1, 2, 1, 2, 1, 2]);
    let mut v = m.clone();
    v.validate("cube").unwrap();
    assert!((v.volume() - 1.0).abs() < 1e-12);
}

#[test]
fn opencarp_files_keep_micrometres_and_read_fibres() {
    for name in ["cube_carp.pts", "cube_carp.elem", "cube_carp.lon"] {
        let m = fixture(name);
        assert_eq!((m.n_vertices(), m.n_tets()), (8, 6), "{name}");
        assert_eq!(m.positions[6], DVec3::splat(1000.0), "µm, not rescaled");
        assert_eq!(m.regions, vec![1, 1, 1, 2, 2, 2]);
        assert_eq!(m.fibres.len(), 6);
        for (i, f) in m.fibres.iter().enumerate() {
            let a = std::f64::consts::PI * i as f64 / 6.0;
            assert!(
                f.distance(DVec3::new(a.cos(), a.sin(), 0.0)) < 1e-5,
                "fibre {i}: {f}"
            );
        }
        let mut v = m.clone();
        v.validate(name).unwrap();
        assert!((v.volume() - 1e9).abs() < 1e-3);
    }
}

#[test]
fn every_fixture_validates() {
    let mut n = 0;
    for t in fuzz::targets(&fixtures()) {
        let path = &t.files[t.read];
        let mut m = read(path).unwrap_or_else(|e| panic!("{e}"));
        m.validate(&path.display().to_string()).unwrap();
        n += 1;
    }
    assert_eq!(n, 21, "fixture count");
}

// ---------------------------------------------------------------- bad input

/// Write `files` (name, bytes) into a scratch folder, read the first, and return the error.
fn read_err(test: &str, files: &[(&str, &[u8])]) -> String {
    let dir = scratch(test);
    for (name, bytes) in files {
        std::fs::write(dir.join(name), bytes).unwrap();
    }
    let path = dir.join(files[0].0);
    let start = Instant::now();
    let r = std::panic::catch_unwind(|| read(&path))
        .unwrap_or_else(|_| panic!("{test}: reader panicked"));
    assert!(start.elapsed() < Duration::from_secs(2), "{test}: slow");
    let e = match r {
        Ok(m) => panic!("{test}: read {} tets from bad input", m.n_tets()),
        Err(e) => e.to_string(),
    };
    assert!(!e.contains('\n'), "{test}: multi-line error {e:?}");
    e
}

/// The error names one of the files and a place in it.
fn assert_located(e: &str, file: &str, place: &str) {
    assert!(e.contains(file), "error {e:?} does not name {file}");
    assert!(e.contains(place), "error {e:?} does not say {place:?}");
}

const TET_V22: &str = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n$Elements\n1\n1 4 2 5 1 1 2 3 4\n$EndElements\n";

const TET_VTK: &str = "# vtk DataFile Version 4.2\ntet\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n0 0 0 1 0 0 0 1 0 0 0 1\nCELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n10\n";

fn vtu_ascii(points: &str, conn: &str, offsets: &str, types: &str, cell_data: &str) -> String {
    format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"4\" NumberOfCells=\"1\">\n<Points><DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">{points}</DataArray></Points>\n<Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">{conn}</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">{offsets}</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">{types}</DataArray>\n</Cells>\n<CellData>{cell_data}</CellData>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n"
    )
}

const PTS: &str = "0 0 0 1 0 0 0 1 0 0 0 1";

#[test]
fn hand_made_minimal_files_are_read() {
    let dir = scratch("minimal");
    let cases: [(&str, String); 4] = [
        ("t.msh", TET_V22.into()),
        ("t.vtk", TET_VTK.into()),
        ("t.vtu", vtu_ascii(PTS, "0 1 2 3", "4", "10", "")),
        (
            "t.node",
            "4 3 0 0\n0 0 0 0\n1 1 0 0\n2 0 1 0\n3 0 0 1\n".into(),
        ),
    ];
    std::fs::write(dir.join("t.ele"), "1 4 0\n0 0 1 2 3\n").unwrap();
    for (name, text) in cases {
        std::fs::write(dir.join(name), text).unwrap();
        let m = read(&dir.join(name)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((m.n_vertices(), m.n_tets()), (4, 1), "{name}");
        assert_eq!(m.tets[0], [0, 1, 2, 3], "{name}");
    }
}

/// A TetGen `.ele` line whose values disagree with its header's nodes and attributes per
/// element (a 10-node file declared as 4-node, a lost attribute) names the line and the count.
#[test]
fn tetgen_elements_that_disagree_with_their_header_are_refused() {
    let node = b"10 3 0 0\n0 0 0 0\n1 1 0 0\n2 0 1 0\n3 0 0 1\n4 .5 0 0\n5 0 .5 0\n6 0 0 .5\n7 .5 .5 0\n8 0 .5 .5\n9 .5 0 .5\n";
    for (ele, line, expected) in [
        ("1 4 0\n0 0 1 2 3 4 5 6 7 8 9\n", "line 2", "expected 5"),
        ("1 10 0\n0 0 1 2 3\n", "line 2", "expected 11"),
        ("1 4 1\n0 0 1 2 3\n", "line 2", "expected 6"),
    ] {
        let e = read_err(
            "tetgen_count",
            &[("h.ele", ele.as_bytes()), ("h.node", node)],
        );
        assert_located(&e, "h.ele", line);
        assert!(e.contains(expected), "{e}");
    }
}

/// A TetGen `.node` row whose width disagrees with its header's attributes and boundary
/// markers (a lost column, a 2-D row, an extra value), or a header with a marker count other
/// than 0 or 1, is refused at its line.
#[test]
fn tetgen_nodes_that_disagree_with_their_header_are_refused() {
    let ele = b"1 4 0\n0 0 1 2 3\n";
    for (node, line, expected) in [
        (
            "4 3 1 0\n0 0 0 0\n1 1 0 0 7\n2 0 1 0 7\n3 0 0 1 7\n",
            "line 2",
            "expected 5",
        ),
        (
            "4 3 0 1\n0 0 0 0 1\n1 1 0 0 1\n2 0 1\n3 0 0 1 1\n",
            "line 4",
            "expected 5",
        ),
        (
            "4 3 0 0\n0 0 0 0\n1 1 0 0 5\n2 0 1 0\n3 0 0 1\n",
            "line 3",
            "expected 4",
        ),
        (
            "4 3 0 2\n0 0 0 0 1 1\n1 1 0 0 1 1\n2 0 1 0 1 1\n3 0 0 1 1 1\n",
            "line 1",
            "marker count 2",
        ),
    ] {
        let e = read_err(
            "tetgen_node_width",
            &[("w.ele", ele.as_slice()), ("w.node", node.as_bytes())],
        );
        assert_located(&e, "w.node", line);
        assert!(e.contains(expected), "{e}");
    }
    // The header's columns read as declared: an attribute and a marker after x, y, z.
    let node = "4 3 1 1\n0 0 0 0 9 1\n1 1 0 0 9 1\n2 0 1 0 9 0\n3 0 0 1 9 0\n";
    let dir = scratch("tetgen_node_width_ok");
    std::fs::write(dir.join("k.node"), node).unwrap();
    std::fs::write(dir.join("k.ele"), ele).unwrap();
    let m = read(&dir.join("k.node")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((m.n_vertices(), m.n_tets()), (4, 1));
}

/// A `.vtu` piece whose NumberOfPoints or NumberOfCells disagrees with its arrays, or is not
/// a count, is refused at the piece's line.
#[test]
fn vtu_piece_counts_that_disagree_with_the_arrays_are_refused() {
    let ok = vtu_ascii(PTS, "0 1 2 3", "4", "10", "");
    for (from, to, says) in [
        (
            "NumberOfPoints=\"4\"",
            "NumberOfPoints=\"3\"",
            "Points array holds 4",
        ),
        (
            "NumberOfPoints=\"4\"",
            "NumberOfPoints=\"-4\"",
            "is not a count",
        ),
        (
            "NumberOfCells=\"1\"",
            "NumberOfCells=\"7\"",
            "types array holds 1",
        ),
    ] {
        assert_eq!(ok.matches(from).count(), 1);
        let bad = ok.replace(from, to);
        let e = read_err("vtu_counts", &[("p.vtu", bad.as_bytes())]);
        assert_located(&e, "p.vtu", "line 4");
        assert!(e.contains(says), "{e}");
    }
}

/// A legacy `.vtk` file's bad point or cell is named by its section and that section's
/// keyword line (it used to carry the label of the last section read, CELL_TYPES).
#[test]
fn vtk_legacy_errors_name_the_section_they_are_about() {
    for (from, to, says) in [
        ("0 0 1\nCELLS", "0 0 nan\nCELLS", "line 5 (POINTS): point 3"),
        ("4 0 1 2 3", "4 0 1 2 9", "line 7 (CELLS): cell 0"),
    ] {
        assert_eq!(TET_VTK.matches(from).count(), 1);
        let bad = TET_VTK.replace(from, to);
        let e = read_err("vtk_sections", &[("s.vtk", bad.as_bytes())]);
        assert_located(&e, "s.vtk", says);
    }
}

#[test]
fn empty_files_are_refused() {
    for name in ["e.msh", "e.vtk", "e.vtu", "e.node", "e.pts"] {
        let e = read_err("empty", &[(name, b""), ("e.ele", b""), ("e.elem", b"")]);
        assert_located(&e, name, "empty");
    }
}

#[test]
fn truncated_files_are_refused_with_a_location() {
    let cut = |name: &str, at: f64| {
        let bytes = std::fs::read(fixtures().join(name)).unwrap();
        bytes[..(bytes.len() as f64 * at) as usize].to_vec()
    };
    for (name, place) in [
        ("box_v41_ascii.msh", "line "),
        ("box_v41_binary.msh", "byte "),
        ("box_v22_ascii.msh", "line "),
        ("box_v22_binary.msh", "byte "),
        ("box_meshio_v42_ascii.vtk", "line "),
        ("box_meshio_v51_ascii.vtk", "line "),
        ("box_vtk_v51_binary.vtk", "byte "),
        ("box_meshio_binary.vtu", "line "),
        ("box_meshio_zlib.vtu", "line "),
        ("box_vtk_appended_raw.vtu", "line "),
        ("box_vtk_appended_b64_zlib.vtu", "line "),
    ] {
        for at in [0.3, 0.6, 0.97] {
            let e = read_err("truncated", &[(name, &cut(name, at))]);
            assert_located(&e, name, place);
        }
    }
    let ele = std::fs::read(fixtures().join("box_meshio.ele")).unwrap();
    let e = read_err(
        "truncated",
        &[
            ("b.ele", &cut("box_meshio.ele", 0.5)),
            (
                "b.node",
                &std::fs::read(fixtures().join("box_meshio.node")).unwrap(),
            ),
        ],
    );
    assert_located(&e, "b.ele", "line ");
    let e = read_err(
        "truncated",
        &[("b.node", &cut("box_meshio.node", 0.5)), ("b.ele", &ele)],
    );
    assert_located(&e, "b.node", "declares 78 nodes");
    let e = read_err(
        "truncated",
        &[
            ("c.elem", b"6\nTt 0 1 2 6 1\nTt 0 2 3"),
            (
                "c.pts",
                &std::fs::read(fixtures().join("cube_carp.pts")).unwrap(),
            ),
        ],
    );
    assert_located(&e, "c.elem", "line 3");
}

#[test]
fn indices_out_of_range_are_refused() {
    let msh = TET_V22.replace("1 2 3 4\n$EndElements", "1 2 3 99\n$EndElements");
    // The element's own line (13), not the count's before it.
    assert_located(
        &read_err("range", &[("r.msh", msh.as_bytes())]),
        "r.msh",
        "line 13 ($Elements)",
    );
    assert!(read_err("range", &[("r.msh", msh.as_bytes())]).contains("node tag 99"));
    let vtk = TET_VTK.replace("4 0 1 2 3", "4 0 1 2 4");
    assert_located(
        &read_err("range", &[("r.vtk", vtk.as_bytes())]),
        "r.vtk",
        "point index 4",
    );
    let vtu = vtu_ascii(PTS, "0 1 2 -1", "4", "10", "");
    assert_located(
        &read_err("range", &[("r.vtu", vtu.as_bytes())]),
        "r.vtu",
        "point index -1",
    );
    let e = read_err(
        "range",
        &[
            ("r.ele", b"1 4 0\n0 0 1 2 4\n"),
            ("r.node", b"4 3 0 0\n0 0 0 0\n1 1 0 0\n2 0 1 0\n3 0 0 1\n"),
        ],
    );
    assert_located(&e, "r.ele", "line 2: node index 4 out of range");
    let e = read_err(
        "range",
        &[
            ("r.elem", b"1\nTt 0 1 2 8 0\n"),
            ("r.pts", format!("4\n{PTS}\n").as_bytes()),
        ],
    );
    assert_located(&e, "r.elem", "line 2");
}

#[test]
fn huge_header_counts_fail_fast_without_allocating() {
    let t = "1000000000000";
    let msh41 =
        format!("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 {t} 1 {t}\n3 1 0 {t}\n1\n2\n");
    let msh22 = format!("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n{t}\n1 0 0 0\n");
    let vtk = format!("# vtk DataFile Version 4.2\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS {t} float\n0 0 0\n");
    let vtk_bin = format!("# vtk DataFile Version 4.2\nx\nBINARY\nDATASET UNSTRUCTURED_GRID\nPOINTS {t} float\n\0\0\0\0");
    let cells = format!("# vtk DataFile Version 4.2\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n{PTS}\nCELLS {t} {t}\n4 0 1 2 3\n");
    let mut msh41_bin =
        b"$MeshFormat\n4.1 1 8\n\x01\x00\x00\x00\n$EndMeshFormat\n$Nodes\n".to_vec();
    for v in [1u64, 1_000_000_000_000, 1, 1_000_000_000_000] {
        msh41_bin.extend_from_slice(&v.to_le_bytes());
    }
    msh41_bin.extend_from_slice(&[3, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0]);
    msh41_bin.extend_from_slice(&1_000_000_000_000u64.to_le_bytes());
    // A base64 block whose UInt64 header claims 10^12 bytes; and a zlib header claiming
    // 10^6 blocks of 10^12 bytes.
    let claim = palpate::output::vtu::base64(&1_000_000_000_000u64.to_le_bytes());
    let vtu_b64 = vtu_ascii(PTS, "0 1 2 3", "4", "10", "").replace(
        "<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">0 0 0 1 0 0 0 1 0 0 0 1",
        &format!("<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"binary\">{claim}"),
    ).replace("version=\"1.0\">", "version=\"1.0\" header_type=\"UInt64\">");
    let mut z = Vec::new();
    for v in [1_000_000u64, 1_000_000_000_000, 0, 16] {
        z.extend_from_slice(&v.to_le_bytes());
    }
    let vtu_zlib = vtu_b64
        .replace(&claim, &palpate::output::vtu::base64(&z))
        .replace(
            "header_type=\"UInt64\"",
            "header_type=\"UInt64\" compressor=\"vtkZLibDataCompressor\"",
        );
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("h.msh", msh41.into_bytes(), "line "),
        ("h2.msh", msh22.into_bytes(), "line "),
        ("hb.msh", msh41_bin, "byte "),
        ("h.vtk", vtk.into_bytes(), "line "),
        ("hb.vtk", vtk_bin.into_bytes(), "byte "),
        ("hc.vtk", cells.into_bytes(), "line "),
        ("h.vtu", vtu_b64.into_bytes(), "line "),
        ("hz.vtu", vtu_zlib.into_bytes(), "line "),
    ];
    for (name, bytes, place) in &cases {
        let e = read_err("huge", &[(name, bytes)]);
        assert_located(&e, name, place);
    }
    let e = read_err(
        "huge",
        &[
            ("h.node", format!("{t} 3 0 0\n0 0 0 0\n").as_bytes()),
            ("h.ele", b"1 4 0\n0 0 0 0 0\n"),
        ],
    );
    assert_located(&e, "h.node", "declares 1000000000000 nodes");
    let e = read_err(
        "huge",
        &[
            ("h.pts", format!("{t}\n0 0 0\n").as_bytes()),
            ("h.elem", b"1\nTt 0 0 0 0\n"),
        ],
    );
    assert_located(&e, "h.pts", "line 3: file ends");
    let e = read_err(
        "huge",
        &[
            ("g.elem", format!("{t}\nTt 0 1 2 3\n").as_bytes()),
            ("g.pts", format!("4\n{PTS}\n").as_bytes()),
        ],
    );
    assert_located(&e, "g.elem", "declares 1000000000000 elements");
}

#[test]
fn files_without_tets_are_refused_with_a_location() {
    let msh = TET_V22.replace("1 4 2 5 1 1 2 3 4", "1 2 2 5 1 1 2 3");
    let e = read_err("notets", &[("n.msh", msh.as_bytes())]);
    assert_located(&e, "n.msh", "line 12 ($Elements): no tetrahedron");
    let vtk = TET_VTK.replace(
        "CELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n10",
        "CELLS 1 4\n3 0 1 2\nCELL_TYPES 1\n5",
    );
    assert_located(
        &read_err("notets", &[("n.vtk", vtk.as_bytes())]),
        "n.vtk",
        "line 9",
    );
    let vtu = vtu_ascii(PTS, "0 1 2", "3", "5", "");
    assert_located(
        &read_err("notets", &[("n.vtu", vtu.as_bytes())]),
        "n.vtu",
        "line 4: no cell is a tetrahedron",
    );
    let e = read_err(
        "notets",
        &[("n.ele", b"0 4 0\n"), ("n.node", b"1 3 0 0\n0 0 0 0\n")],
    );
    assert_located(&e, "n.ele", "line 1: no tetrahedra");
    let e = read_err("notets", &[("n.elem", b"0\n"), ("n.pts", b"1\n0 0 0\n")]);
    assert_located(&e, "n.elem", "line 1: no tetrahedra");
    // Hexahedra are refused rather than dropped.
    let hex = TET_VTK.replace("CELL_TYPES 1\n10", "CELL_TYPES 1\n12");
    assert_located(
        &read_err("notets", &[("x.vtk", hex.as_bytes())]),
        "x.vtk",
        "hexahedron",
    );
}

#[test]
fn mismatched_lengths_are_refused() {
    let vtk = TET_VTK.replace("CELL_TYPES 1\n10", "CELL_TYPES 2\n10 10");
    assert_located(
        &read_err("len", &[("l.vtk", vtk.as_bytes())]),
        "l.vtk",
        "2 cell types for 1 cells",
    );
    let material = "<DataArray type=\"Int32\" Name=\"material\" format=\"ascii\">1 2</DataArray>";
    let vtu = vtu_ascii(PTS, "0 1 2 3", "4", "10", material);
    assert_located(
        &read_err("len", &[("l.vtu", vtu.as_bytes())]),
        "l.vtu",
        "array 'material' has 2 values for 1 cells",
    );
    let vtu = vtu_ascii("0 0 0 1 0 0 0 1 0 0 0", "0 1 2 3", "4", "10", "");
    assert_located(
        &read_err("len", &[("p.vtu", vtu.as_bytes())]),
        "p.vtu",
        "not a multiple of 3",
    );
    // Points declared with 2 components (12 values: six 2-D points) are not read as xyz.
    let vtu = vtu_ascii(PTS, "0 1 2 3", "4", "10", "").replacen(
        "NumberOfComponents=\"3\"",
        "NumberOfComponents=\"2\"",
        1,
    );
    assert!(vtu.contains("NumberOfComponents=\"2\""));
    assert_located(
        &read_err("points2", &[("p2.vtu", vtu.as_bytes())]),
        "p2.vtu",
        "the Points array has NumberOfComponents = \"2\": points need 3",
    );
    let msh = TET_V22.replace("$Nodes\n4\n", "$Nodes\n5\n");
    assert_located(
        &read_err("len", &[("l.msh", msh.as_bytes())]),
        "l.msh",
        "line 10",
    );
    let dir_files: [(&str, &[u8]); 3] = [
        ("c.lon", b"1\n1 0 0\n"),
        ("c.pts", PTS_4.as_bytes()),
        ("c.elem", b"2\nTt 0 1 2 3\nTt 0 1 3 2\n"),
    ];
    assert_located(
        &read_err("len", &dir_files),
        "c.lon",
        "2 elements but the file has 1 fibres",
    );
}

const PTS_4: &str = "4\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n";

#[test]
fn garbage_and_non_utf8_are_refused() {
    let mut rng = common::Rng(0x9E37_79B9_7F4A_7C15);
    let garbage: Vec<u8> = (0..4096).map(|_| (rng.next() * 256.0) as u8).collect();
    for name in ["g.msh", "g.vtk", "g.vtu", "g.node", "g.pts"] {
        let e = read_err(
            "garbage",
            &[(name, &garbage), ("g.ele", &garbage), ("g.elem", &garbage)],
        );
        assert!(e.contains(name) || e.contains("g.e"), "{e}");
    }
    let msh = TET_V22.replace("2 1 0 0", "2 1\u{ff} 0 0");
    let mut bytes = msh.into_bytes();
    let k = bytes
        .windows(2)
        .position(|w| w == "\u{ff}".as_bytes())
        .unwrap();
    bytes.splice(k..k + 2, [0xFF]);
    assert_located(&read_err("utf8", &[("u.msh", &bytes)]), "u.msh", "line 7");
    let mut vtk = TET_VTK.as_bytes().to_vec();
    vtk[60] = 0xC3;
    let e = read_err("utf8", &[("u.vtk", &vtk)]);
    assert_located(&e, "u.vtk", "line ");
}

#[test]
fn degenerate_tets_pass_the_reader_and_fail_validation() {
    let flat = TET_VTK.replace("0 0 1\nCELLS", "1 1 0\nCELLS");
    let dir = scratch("degenerate");
    let path = dir.join("flat.vtk");
    std::fs::write(&path, flat).unwrap();
    let mut m = read(&path).unwrap();
    let e = m
        .validate(&path.display().to_string())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("flat.vtk") && e.contains("tet 0") && e.contains("degenerate"),
        "{e}"
    );
}

// ---------------------------------------------------------------- fuzz

#[test]
fn mutation_fuzz_never_panics() {
    let dir = scratch("fuzz");
    let start = Instant::now();
    let stats = fuzz::run(&fixtures(), &dir, 600, 0x5EED_0001);
    println!("{stats:?} in {:?}", start.elapsed());
    assert!(stats.executions >= 12_000, "{}", stats.executions);
    assert!(stats.panics.is_empty(), "panics: {:?}", stats.panics);
    assert!(
        stats.bad_messages.is_empty(),
        "bad error messages: {:?}",
        stats.bad_messages
    );
    assert!(
        stats.slowest.0 < Duration::from_secs(1),
        "slowest read {:?}",
        stats.slowest
    );
    assert!(
        stats.errors > stats.executions / 2,
        "mutations mostly caught: {stats:?}"
    );
}

#[test]
fn gmsh_ascii_records_are_read_one_line_each_and_errors_name_that_line() {
    // TET_V22's lines: 6-9 the nodes, 13 the element.
    for (test, from, to, place) in [
        (
            "extra_node_value",
            "2 1 0 0\n",
            "2 1 0 0 7\n",
            "line 7 ($Nodes): unexpected \" 7\" at the end of the line",
        ),
        (
            "missing_coordinate",
            "2 1 0 0\n",
            "2 1 0\n",
            "line 7 ($Nodes): the line ends where the z coordinate was expected",
        ),
        (
            "extra_element_value",
            "1 2 3 4\n$End",
            "1 2 3 4 4\n$End",
            "line 13 ($Elements): unexpected \" 4\" at the end of the line",
        ),
        (
            "missing_node_tag",
            "1 2 3 4\n$End",
            "1 2 3\n$End",
            "line 13 ($Elements): the line ends where a node tag of the element was expected",
        ),
    ] {
        assert!(TET_V22.contains(from), "{test}");
        let e = read_err(test, &[("t.msh", TET_V22.replacen(from, to, 1).as_bytes())]);
        assert_located(&e, "t.msh", place);
    }
}

/// A count that declares more entries than its section holds: the error says so, where the
/// section's end marker or the next keyword stands (it used to call `$EndNodes` a node tag
/// that "is not a valid number").
#[test]
fn a_count_larger_than_its_section_is_named_as_such() {
    let short = "(a count larger than the entries after it, or a value missing)";
    let e = read_err(
        "nodes_declared_10",
        &[(
            "t.msh",
            TET_V22
                .replacen("$Nodes\n4\n", "$Nodes\n10\n", 1)
                .as_bytes(),
        )],
    );
    assert_located(
        &e,
        "t.msh",
        "line 10 ($Nodes): found the keyword \"$EndNodes\" where",
    );
    assert!(e.contains(short), "{e}");
    let e = read_err(
        "cells_declared_9",
        &[(
            "t.vtk",
            TET_VTK.replacen("CELLS 1 5", "CELLS 1 9", 1).as_bytes(),
        )],
    );
    assert!(
        e.contains("keyword \"CELL_TYPES\" where") && e.contains(short),
        "{e}"
    );
    // A word that is no keyword stays "not a valid number".
    let e = read_err(
        "node_tag_word",
        &[(
            "t.msh",
            TET_V22.replacen("\n3 0 1 0", "\nthree 0 1 0", 1).as_bytes(),
        )],
    );
    assert!(
        e.contains("is not a valid number") && !e.contains(short),
        "{e}"
    );
    // An openCARP fibre line with two directions where the header says one: the count found.
    let files: [(&str, &[u8]); 3] = [
        ("c.pts", PTS_4.as_bytes()),
        ("c.elem", b"1\nTt 0 1 2 3\n"),
        ("c.lon", b"1\n0 0 0 0 1 0\n"),
    ];
    assert_located(
        &read_err("lon_two_directions", &files),
        "c.lon",
        "element 0: expected 3 finite numbers (1 direction an element, as the header says), found 6 values",
    );
}

#[test]
fn fibres_of_any_finite_length_keep_their_direction_and_a_zero_one_names_the_mesh_file() {
    // Lengths that over- or underflow when squared (1e300, 1e-200) were read as zero.
    let dir = scratch("fibre_lengths");
    let pts = format!("{}1 1 1\n", PTS_4.replacen('4', "5", 1));
    std::fs::write(dir.join("c.pts"), pts).unwrap();
    std::fs::write(dir.join("c.elem"), "2\nTt 0 1 2 3\nTt 1 2 3 4\n").unwrap();
    std::fs::write(dir.join("c.lon"), "1\n1e300 1e300 0\n1e-200 0 0\n").unwrap();
    let m = read(&dir.join("c.pts")).unwrap();
    let h = std::f64::consts::FRAC_1_SQRT_2;
    assert!(
        m.fibres[0].distance(DVec3::new(h, h, 0.0)) < 1e-12,
        "{}",
        m.fibres[0]
    );
    assert_eq!(m.fibres[1], DVec3::X);
    // A zero fibre under a fibred law: the error names the mesh file's key and the tet, not
    // material.fibre (which the scene does not give).
    std::fs::write(dir.join("c.lon"), "1\n1 0 0\n0 0 0\n").unwrap();
    let scene = r#"name = "fibred"
[mesh]
file = "c.pts"
[material]
model = "guccione"
guccione_c = 2000.0
guccione_bf = 8.0
guccione_bt = 2.0
guccione_bfs = 4.0
bulk_modulus = 2.0e5
density = 1000.0
"#;
    let e = palpate::Scene::from_toml(scene, "fibred.toml", "fibred.toml", Some(&dir))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("mesh.file") && e.contains("fibre of tet 1") && !e.contains("material.fibre:"),
        "{e}"
    );
}
