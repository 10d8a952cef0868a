//! Every kernel parses and validates under naga with no GPU, and every uniform struct's size
//! and field offsets match naga's layout of its WGSL twin.

use palpate::gpu::preprocess::preprocess;
use palpate::params::StepParams;
use std::path::Path;

fn kernel_files() -> Vec<std::path::PathBuf> {
    let mut v: Vec<_> = std::fs::read_dir("kernels")
        .expect("kernels/")
        .map(|e| e.expect("dir entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "wgsl"))
        .collect();
    v.sort();
    v
}

fn load(path: &Path) -> String {
    let text = std::fs::read_to_string(path).expect("read kernel");
    preprocess(&text, &|name| {
        std::fs::read_to_string(format!("kernels/shared/{name}.wgsl")).ok()
    })
    .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn validate(source: &str, what: &str) -> naga::Module {
    let module = naga::front::wgsl::parse_str(source)
        .unwrap_or_else(|e| panic!("{what}: {}", e.emit_to_string(source)));
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::empty(),
    )
    .validate(&module)
    .unwrap_or_else(|e| panic!("{what}: {}", e.emit_to_string(source)));
    module
}

#[test]
fn every_kernel_file_validates_and_is_embedded() {
    let files = kernel_files();
    assert!(
        files.len() >= 4,
        "expected the step kernels in kernels/, found {files:?}"
    );
    for path in &files {
        let source = load(path);
        let module = validate(&source, &path.display().to_string());
        let stem = path.file_stem().unwrap().to_string_lossy();
        // The entry point is named after the stage (reduce has reduce_partial/reduce_final).
        assert!(
            module
                .entry_points
                .iter()
                .any(|e| e.name.starts_with(stem.as_ref())),
            "{}: no entry point named after the stage",
            path.display()
        );
        assert_eq!(
            palpate::gpu::kernel_source(&stem),
            Some(source.as_str()),
            "{}: embedded source is stale (build.rs output differs)",
            path.display()
        );
    }
}

#[test]
fn shared_files_validate_on_their_own() {
    for entry in std::fs::read_dir("kernels/shared").expect("kernels/shared") {
        let path = entry.unwrap().path();
        validate(&load(&path), &path.display().to_string());
    }
}

#[test]
fn broken_shader_is_rejected_by_the_same_validation() {
    let bad = "@compute @workgroup_size(64) fn main() { let x: f32 = 1u; }";
    assert!(
        naga::front::wgsl::parse_str(bad).is_err() || {
            let m = naga::front::wgsl::parse_str(bad).unwrap();
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::empty(),
            )
            .validate(&m)
            .is_err()
        }
    );
}

/// (name, offset) of each member of WGSL struct `name`, and its size.
fn wgsl_layout(module: &naga::Module, name: &str) -> (Vec<(String, u32)>, u32) {
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

#[test]
fn step_params_matches_wgsl_layout() {
    let source = load(Path::new("kernels/fem_forces.wgsl"));
    let module = validate(&source, "fem_forces");
    let (members, span) = wgsl_layout(&module, "StepParams");
    assert_eq!(
        span as usize,
        std::mem::size_of::<StepParams>(),
        "size of StepParams"
    );
    let rust: Vec<(&str, usize)> = vec![
        ("n_vertices", std::mem::offset_of!(StepParams, n_vertices)),
        ("n_tets", std::mem::offset_of!(StepParams, n_tets)),
        ("dt", std::mem::offset_of!(StepParams, dt)),
        ("damping", std::mem::offset_of!(StepParams, damping)),
        ("gravity", std::mem::offset_of!(StepParams, gravity)),
        ("lambda", std::mem::offset_of!(StepParams, lambda)),
        ("mu", std::mem::offset_of!(StepParams, mu)),
        ("phi", std::mem::offset_of!(StepParams, phi)),
        ("psi", std::mem::offset_of!(StepParams, psi)),
        ("speed_limit", std::mem::offset_of!(StepParams, speed_limit)),
    ];
    assert_eq!(members.len(), rust.len(), "member count: wgsl {members:?}");
    for ((wname, woff), (rname, roff)) in members.iter().zip(&rust) {
        assert_eq!(wname, rname, "member order");
        assert_eq!(*woff as usize, *roff, "offset of {rname}");
    }
}

#[test]
fn reflection_sees_bindings_in_shader_order() {
    let source = palpate::gpu::kernel_source("gather").unwrap();
    let palpate::gpu::kernel::Reflected {
        bindings,
        workgroup_size,
        items_per_workgroup,
    } = palpate::gpu::kernel::reflect(source, "gather").unwrap();
    let names: Vec<&str> = bindings.iter().map(|b| b.name.as_str()).collect();
    let expected = [
        "params",
        "corner_forces",
        "incidence_offsets",
        "incidence",
        "mass",
        "external_forces",
        "forces",
    ];
    assert_eq!(names, expected);
    // Four lanes per vertex: 256 threads cover 64 vertices (gather.wgsl's ITEMS_PER_WORKGROUP).
    assert_eq!((workgroup_size, items_per_workgroup), (256, 64));
    assert_eq!(bindings[0].ty, wgpu::BufferBindingType::Uniform);
    assert_eq!(
        bindings[5].ty,
        wgpu::BufferBindingType::Storage { read_only: true }
    );
    assert_eq!(
        bindings[6].ty,
        wgpu::BufferBindingType::Storage { read_only: false }
    );
}

/// Kernels that give each item several lanes declare `ITEMS_PER_WORKGROUP`; reflection reads
/// it (direct dispatches then cover items, and the compacted lists' indirect arguments, which
/// count 64-item workgroups, stay valid), a kernel without it covers one item a thread, and a
/// value that does not divide the workgroup is refused.
#[test]
fn reflection_reads_the_items_a_workgroup_covers() {
    use palpate::gpu::kernel::reflect;
    for (file, entry) in [
        ("gather", "gather"),
        ("gather", "gather_coupled"),
        ("sph_stress", "sph_stress"),
        ("sph_forces", "sph_forces"),
    ] {
        let r = reflect(palpate::gpu::kernel_source(file).unwrap(), entry).unwrap();
        assert_eq!(
            (r.workgroup_size, r.items_per_workgroup),
            (256, 64),
            "{entry}"
        );
    }
    let r = reflect(
        palpate::gpu::kernel_source("integrate").unwrap(),
        "integrate",
    )
    .unwrap();
    assert_eq!(r.items_per_workgroup, r.workgroup_size);
    let bad = "const ITEMS_PER_WORKGROUP: u32 = 48u;\n@compute @workgroup_size(64) fn main() {}";
    let e = reflect(bad, "main").unwrap_err().to_string();
    assert!(
        e.contains("ITEMS_PER_WORKGROUP = 48") && e.contains("64"),
        "{e}"
    );
}
