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
    let mut p = unit();
    p.push(DVec3::new(0.3, 0.3, -1.0));
    let (mesh, report) = TetMesh::new(
        "three tets",
        p,
        vec![[0, 1, 2, 3], [1, 2, 3, 4], [0, 1, 2, 5]],
        None,
    )
    .unwrap();
    // [1, 2, 3, 4] is positive (det = 2); [0, 1, 2, 5] has its apex below the face that the
    // unit tet has its apex above.
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

/// A tet given twice (in any vertex order) and a face shared by three tets are refused with
/// an error naming the tets: either leaves a mesh whose boundary silently loses faces, so a
/// tool passed through it and a follower pressure found no face.
#[test]
fn repeated_tets_and_overshared_faces_are_named() {
    let mut p = unit();
    p.push(DVec3::new(0.3, 0.3, -1.0));
    let err = TetMesh::new(
        "dup",
        p.clone(),
        vec![[0, 1, 2, 3], [1, 2, 3, 4], [3, 1, 0, 2]],
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("dup") && err.contains("tets 0 and 2") && err.contains("same tetrahedron"),
        "{err}"
    );
    // Face [0, 1, 2] in the unit tet, in [0, 1, 2, 5] below it, and in a third tet that
    // overlaps the unit tet: three tets on one face.
    let err = TetMesh::new(
        "three",
        p.clone(),
        vec![[0, 1, 2, 3], [0, 1, 2, 5], [0, 1, 2, 4]],
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("three") && err.contains("[0, 1, 2]") && err.contains("3 tets [0, 1, 2]"),
        "{err}"
    );
    // Two tets on each side of a face are fine.
    TetMesh::new("pair", p, vec![[0, 1, 2, 3], [0, 1, 2, 5]], None).unwrap();
}

#[test]
fn overlapping_tets_are_refused_and_coincident_vertices_reported() {
    // Two tets on the same side of their shared face [0, 1, 2]: they overlap.
    let mut p = unit();
    p.push(DVec3::new(0.2, 0.2, 0.5));
    let err = TetMesh::new("overlap.msh", p, vec![[0, 1, 2, 3], [0, 1, 2, 5]], None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("overlap.msh: tets 0 and 1 overlap: they share face [0, 1, 2]"),
        "{err}"
    );
    // On opposite sides they are a valid pair (tet 1 is reoriented, as any inverted tet).
    let mut p = unit();
    p.push(DVec3::new(0.2, 0.2, -0.5));
    let (_, report) = TetMesh::new("pair", p, vec![[0, 1, 2, 3], [0, 1, 2, 5]], None).unwrap();
    assert_eq!(report.coincident, (vec![], 0));
    // The same pair with the lower tet's face vertices duplicated (and -0.0 for 0.0): the
    // mesh is split there, which is reported pair by pair; an unused duplicate is not.
    let mut p = unit();
    p.extend([
        DVec3::new(-0.0, 0.0, 0.0),
        DVec3::X,
        DVec3::Y,
        DVec3::new(0.2, 0.2, -0.5),
        DVec3::Z,
    ]);
    let (_, report) = TetMesh::new("split", p, vec![[0, 1, 2, 3], [5, 6, 7, 8]], None).unwrap();
    assert_eq!(report.coincident, (vec![(0, 5), (2, 7), (1, 6)], 3));
}
