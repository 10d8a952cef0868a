//! Mesh validation: degenerate tets are refused with an error naming the tet, inverted tets
//! are reoriented (and reported), bad indices and non-finite coordinates are refused.

use glam::DVec3;
use palpate::mesh::TetMesh;

fn unit() -> Vec<DVec3> {
    vec![
        DVec3::ZERO,
        DVec3::X,
        DVec3::Y,
        DVec3::Z,
        DVec3::new(1.0, 1.0, 1.0),
    ]
}

#[test]
fn inverted_tets_are_reoriented_and_reported() {
    let (mesh, report) = TetMesh::new(
        "two tets",
        unit(),
        vec![[0, 1, 2, 3], [1, 2, 3, 4], [0, 2, 1, 3]],
        None,
    )
    .unwrap();
    // [1, 2, 3, 4] is positive (det = 2); [0, 2, 1, 3] swaps two nodes of the unit tet.
    assert_eq!(report.reoriented, vec![2]);
    for t in 0..mesh.n_tets() {
        assert!(mesh.tet_volume(t) > 0.0, "tet {t} still inverted");
    }
    assert_eq!(report.unused_vertices, 0);
}

#[test]
fn degenerate_tets_and_bad_indices_are_named() {
    let flat = vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::new(1.0, 1.0, 0.0)];
    let err = TetMesh::new("flat.node", flat, vec![[0, 1, 2, 3]], None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("flat.node") && err.contains("tet 0") && err.contains("degenerate"),
        "{err}"
    );
    let err = TetMesh::new("rep", unit(), vec![[0, 1, 2, 3], [0, 1, 1, 3]], None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("tet 1") && err.contains("repeats vertex 1"),
        "{err}"
    );
    let err = TetMesh::new("oob", unit(), vec![[0, 1, 2, 9]], None)
        .unwrap_err()
        .to_string();
    assert!(err.contains("tet 0") && err.contains("vertex 9"), "{err}");
    let mut p = unit();
    p[2].y = f64::NAN;
    let err = TetMesh::new("nan", p, vec![[0, 1, 2, 3]], None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("vertex 2") && err.contains("non-finite"),
        "{err}"
    );
    let err = TetMesh::new("empty", unit(), vec![], None)
        .unwrap_err()
        .to_string();
    assert!(err.contains("no tetrahedra"), "{err}");
}
