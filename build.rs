//! Build script: preprocess every `kernels/*.wgsl`, validate it with naga, and emit
//! `$OUT_DIR/kernels.rs`, a table of (name, preprocessed source) that the crate embeds.
//! A shader that does not parse or validate fails the build with naga's message.

#[path = "src/gpu/preprocess.rs"]
mod preprocess;

use std::fs;
use std::path::Path;

fn main() {
    println!("cargo:rerun-if-changed=kernels");
    let kernels = Path::new("kernels");
    let shared = kernels.join("shared");
    let lookup = |name: &str| fs::read_to_string(shared.join(format!("{name}.wgsl"))).ok();
    let mut names: Vec<String> = fs::read_dir(kernels)
        .expect("kernels/ directory")
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "wgsl"))
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    names.sort();
    let out_dir = std::env::var("OUT_DIR").expect("OUT_DIR");
    let mut table = String::from("/// (kernel name, preprocessed WGSL) for every file in kernels/.\npub const KERNELS: &[(&str, &str)] = &[\n");
    for name in &names {
        let path = kernels.join(format!("{name}.wgsl"));
        println!("cargo:rerun-if-changed={}", path.display());
        let text = fs::read_to_string(&path).expect("read kernel");
        let source = preprocess::preprocess(&text, &lookup)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let module = naga::front::wgsl::parse_str(&source)
            .unwrap_or_else(|e| panic!("{}: {}", path.display(), e.emit_to_string(&source)));
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{}: {}", path.display(), e.emit_to_string(&source)));
        let out = Path::new(&out_dir).join(format!("{name}.wgsl"));
        fs::write(&out, &source).expect("write preprocessed kernel");
        table.push_str(&format!(
            "    ({name:?}, include_str!({:?})),\n",
            out.display().to_string()
        ));
    }
    table.push_str("];\n");
    fs::write(Path::new(&out_dir).join("kernels.rs"), table).expect("write kernels.rs");
}
