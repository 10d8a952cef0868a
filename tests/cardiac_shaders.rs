//! The cardiac kernels need no GPU to check: every uniform struct's size and offsets against
//! naga's layout of its WGSL twin, and each kernel's entry point and bindings (by name, the
//! way the engine binds them) as documented in its CPU twin.

use palpate::cpu::follower_pressure::FollowerLoad;
use palpate::gpu::kernel::reflect;
use palpate::gpu::kernel_source;
use palpate::material::MaterialConstants;

fn module(kernel: &str) -> naga::Module {
    let source = kernel_source(kernel).unwrap_or_else(|| panic!("kernel {kernel} not embedded"));
    let module = naga::front::wgsl::parse_str(source).expect("parse");
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::empty(),
    )
    .validate(&module)
    .expect("validate");
    module
}

/// (member names, offsets) and size of WGSL struct `name`.
fn layout(module: &naga::Module, name: &str) -> (Vec<(String, u32)>, u32) {
    for (_, ty) in module.types.iter() {
        if ty.name.as_deref() == Some(name) {
            if let naga::TypeInner::Struct { members, span } = &ty.inner {
                return (
                    members
                        .iter()
                        .map(|m| (m.name.clone().unwrap_or_default(), m.offset))
                        .collect(),
                    *span,
                );
            }
        }
    }
    panic!("struct {name} not found");
}

fn check(module: &naga::Module, name: &str, size: usize, rust: &[(&str, usize)]) {
    let (members, span) = layout(module, name);
    assert_eq!(span as usize, size, "size of {name}");
    assert_eq!(members.len(), rust.len(), "{name}: wgsl {members:?}");
    for ((wname, woff), (rname, roff)) in members.iter().zip(rust) {
        assert_eq!(wname, rname, "{name}: member order");
        assert_eq!(*woff as usize, *roff, "{name}: offset of {rname}");
    }
}

#[test]
fn material_constants_matches_wgsl_layout() {
    use std::mem::offset_of;
    for kernel in ["fem_forces_split", "nodal_pressure"] {
        check(
            &module(kernel),
            "MaterialConstants",
            std::mem::size_of::<MaterialConstants>(),
            &[
                ("bulk_modulus", offset_of!(MaterialConstants, bulk_modulus)),
                ("guccione_c", offset_of!(MaterialConstants, guccione_c)),
                ("guccione_bf", offset_of!(MaterialConstants, guccione_bf)),
                ("guccione_bt", offset_of!(MaterialConstants, guccione_bt)),
                ("guccione_bfs", offset_of!(MaterialConstants, guccione_bfs)),
                ("_pad0", offset_of!(MaterialConstants, _pad0)),
                ("_pad1", offset_of!(MaterialConstants, _pad1)),
                ("_pad2", offset_of!(MaterialConstants, _pad2)),
            ],
        );
    }
    assert_eq!(std::mem::size_of::<MaterialConstants>() % 16, 0);
}

#[test]
fn follower_load_matches_wgsl_layout() {
    use std::mem::offset_of;
    check(
        &module("follower_pressure"),
        "FollowerLoad",
        std::mem::size_of::<FollowerLoad>(),
        &[
            ("n_faces", offset_of!(FollowerLoad, n_faces)),
            ("load_factor", offset_of!(FollowerLoad, load_factor)),
            ("_pad0", offset_of!(FollowerLoad, _pad0)),
            ("_pad1", offset_of!(FollowerLoad, _pad1)),
        ],
    );
}

#[test]
fn cardiac_kernels_bind_what_their_twins_read_in_the_same_order() {
    let expected: [(&str, &[&str]); 5] = [
        (
            "fem_forces_split",
            &[
                "params",
                "material_constants",
                "displacements",
                "velocities",
                "tets",
                "dm_inv",
                "rest_volume",
                "fibres",
                "vertex_pressure",
                "vertex_volumetric_energy",
                "corner_forces",
                "tet_energy",
            ],
        ),
        (
            "tet_volume_change",
            &[
                "params",
                "displacements",
                "tets",
                "dm_inv",
                "rest_volume",
                "tet_delta_volume",
            ],
        ),
        (
            "nodal_pressure",
            &[
                "params",
                "material_constants",
                "incidence_offsets",
                "incidence",
                "rest_volume",
                "tet_delta_volume",
                "vertex_pressure",
                "vertex_volumetric_energy",
            ],
        ),
        (
            "follower_pressure",
            &[
                "follower_load",
                "rest_positions",
                "displacements",
                "follower_faces",
                "follower_face_pressure",
                "follower_corner_forces",
            ],
        ),
        (
            "follower_pressure_gather",
            &[
                "params",
                "follower_corner_forces",
                "follower_incidence_offsets",
                "follower_incidence",
                "dead_load_forces",
                "external_forces",
            ],
        ),
    ];
    for (kernel, names) in expected {
        let r = reflect(kernel_source(kernel).unwrap(), kernel)
            .unwrap_or_else(|e| panic!("{kernel}: {e}"));
        let (bindings, workgroup) = (r.bindings, r.workgroup_size);
        let got: Vec<&str> = bindings.iter().map(|b| b.name.as_str()).collect();
        assert_eq!(got, names, "{kernel}");
        assert_eq!(workgroup, 64, "{kernel}");
        // Only the outputs are writable.
        let outputs: &[&str] = match kernel {
            "fem_forces_split" => &["corner_forces", "tet_energy"],
            "tet_volume_change" => &["tet_delta_volume"],
            "nodal_pressure" => &["vertex_pressure", "vertex_volumetric_energy"],
            "follower_pressure" => &["follower_corner_forces"],
            _ => &["external_forces"],
        };
        for b in &bindings {
            let writable = b.ty == wgpu::BufferBindingType::Storage { read_only: false };
            assert_eq!(
                writable,
                outputs.contains(&b.name.as_str()),
                "{kernel}: {}",
                b.name
            );
        }
    }
    // The original laws' kernel keeps its own bindings (plus the particles' tet weights).
    let bindings = reflect(kernel_source("fem_forces").unwrap(), "fem_forces")
        .unwrap()
        .bindings;
    let names: Vec<&str> = bindings.iter().map(|b| b.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "params",
            "displacements",
            "velocities",
            "tets",
            "dm_inv",
            "rest_volume",
            "corner_forces",
            "tet_energy",
            "tet_weight"
        ]
    );
}
