//! A tiny `#import NAME` preprocessor for WGSL: each `#import NAME` line is replaced by the
//! text of `kernels/shared/NAME.wgsl`, once per kernel (later imports of the same name are
//! dropped). Shared by `build.rs` (validation at build time) and the crate.

/// Expand `#import` lines in `source`; `lookup(name)` returns a shared file's text.
pub fn preprocess(source: &str, lookup: &dyn Fn(&str) -> Option<String>) -> Result<String, String> {
    let mut seen: Vec<String> = Vec::new();
    expand(source, lookup, &mut seen, 0)
}

fn expand(
    source: &str,
    lookup: &dyn Fn(&str) -> Option<String>,
    seen: &mut Vec<String>,
    depth: usize,
) -> Result<String, String> {
    if depth > 8 {
        return Err("#import nested more than 8 deep".into());
    }
    let mut out = String::with_capacity(source.len());
    for (n, line) in source.lines().enumerate() {
        match line.trim().strip_prefix("#import") {
            Some(rest) => {
                let name = rest.trim();
                if name.is_empty() {
                    return Err(format!("line {}: #import without a name", n + 1));
                }
                if seen.iter().any(|s| s == name) {
                    continue;
                }
                seen.push(name.to_string());
                let text = lookup(name).ok_or_else(|| {
                    format!(
                        "line {}: #import {name}: no kernels/shared/{name}.wgsl",
                        n + 1
                    )
                })?;
                out.push_str(&expand(&text, lookup, seen, depth + 1)?);
            }
            None => {
                out.push_str(line);
                out.push('\n');
            }
        }
    }
    Ok(out)
}
