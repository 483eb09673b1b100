//! The library's layers import downward only, and its modules import each other in
//! one direction only. `src/` holds one folder per layer, in this order from the
//! bottom: input, physics, mpm (the core), output, driver. The graph of
//! `crate::LAYER::MODULE` references in non-test code (a module's folder counts as
//! the module) has no circle, and no module names a layer above its own. Test
//! modules, at the end of each file, may reach across.

#![forbid(unsafe_code)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The layers, bottom first.
const LAYERS: [&str; 5] = ["input", "physics", "mpm", "output", "driver"];

/// Every `.rs` file under `dir`.
fn rs_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            rs_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// `layer::module` → the `layer::module`s its non-test code names.
fn graph() -> BTreeMap<String, BTreeSet<String>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut files = Vec::new();
    rs_files(&src, &mut files);
    for path in files {
        let rel: Vec<String> = path
            .strip_prefix(&src)
            .unwrap()
            .with_extension("")
            .iter()
            .map(|c| c.to_string_lossy().into_owned())
            .collect();
        // src/LAYER/MODULE.rs or src/LAYER/MODULE/...; lib.rs, main.rs and the
        // layers' mod.rs only declare modules.
        if rel.len() < 2 || rel[1] == "mod" {
            continue;
        }
        assert!(
            LAYERS.contains(&rel[0].as_str()),
            "{}: not in a layer folder ({LAYERS:?})",
            path.display()
        );
        let module = format!("{}::{}", rel[0], rel[1]);
        let text = std::fs::read_to_string(&path).unwrap();
        let deps = g.entry(module.clone()).or_default();
        for line in text.lines() {
            // Test modules come last in every file.
            if line.starts_with("#[cfg(test)]") {
                break;
            }
            let code = line.split("//").next().unwrap_or("");
            for (i, _) in code.match_indices("crate::") {
                let name: Vec<String> = code[i + "crate::".len()..]
                    .split("::")
                    .take(2)
                    .map(|s| {
                        s.chars()
                            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                            .collect()
                    })
                    .collect();
                let name = name.join("::");
                if name.contains("::") && name != module {
                    deps.insert(name);
                }
            }
        }
    }
    g
}

fn layer(module: &str) -> usize {
    let l = module.split("::").next().unwrap();
    LAYERS
        .iter()
        .position(|x| *x == l)
        .unwrap_or_else(|| panic!("{module}: no such layer"))
}

#[test]
fn layers_import_downward_only() {
    let g = graph();
    assert!(
        g.contains_key("driver::run") && g["driver::run"].contains("mpm::solver"),
        "{g:?}"
    );
    for (m, deps) in &g {
        for d in deps {
            assert!(
                layer(d) <= layer(m),
                "{m} imports {d}, a module of a higher layer"
            );
        }
    }
}

#[test]
fn module_imports_have_no_circle() {
    let g = graph();
    // Depth-first search; a module met again while on the path closes a circle.
    fn visit(
        m: &str,
        g: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) {
        if let Some(at) = path.iter().position(|p| p == m) {
            panic!("import circle: {} -> {m}", path[at..].join(" -> "));
        }
        if done.contains(m) {
            return;
        }
        path.push(m.to_string());
        for d in g.get(m).into_iter().flatten() {
            visit(d, g, path, done);
        }
        path.pop();
        done.insert(m.to_string());
    }
    let mut done = BTreeSet::new();
    for m in g.keys() {
        visit(m, &g, &mut Vec::new(), &mut done);
    }
}

/// The backquoted names in `text`: spans between two backquotes on one line.
fn quoted(text: &str) -> Vec<&str> {
    text.lines()
        .flat_map(|l| l.split('`').skip(1).step_by(2))
        .collect()
}

/// `docs/architecture.md` is where a newcomer learns where to add a material, a scheme,
/// a field or a benchmark: every file it names exists, and every Rust name it quotes
/// (`Type`, `function`, `Type::item`, `macro!`) occurs as a word in the code, so its
/// recipes cannot point at something renamed or removed.
#[test]
fn architecture_doc_names_only_what_exists() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let doc = std::fs::read_to_string(root.join("docs/architecture.md")).unwrap();
    let mut files = Vec::new();
    for dir in ["src", "decomposition/src", "tests"] {
        rs_files(&root.join(dir), &mut files);
    }
    let code: String = files
        .iter()
        .map(|p| std::fs::read_to_string(p).unwrap())
        .collect();
    let word = |w: &str| {
        code.match_indices(w).any(|(i, _)| {
            let ident = |c: char| c.is_alphanumeric() || c == '_';
            let before = code[..i].chars().next_back().is_none_or(|c| !ident(c));
            let after = code[i + w.len()..].chars().next().is_none_or(|c| !ident(c));
            before && after
        })
    };
    let (mut paths, mut names) = (0, 0);
    let mut missing = Vec::new();
    for q in quoted(&doc) {
        let is_path = ["src/", "tests/", "inputs/", "scripts/", "docs/"]
            .iter()
            .any(|p| q.starts_with(p));
        if q.contains("NAME") {
            continue; // a placeholder: `src/physics/material/NAME.rs`
        } else if is_path {
            paths += 1;
            if !root.join(q.split_whitespace().next().unwrap()).exists() {
                missing.push(format!("file {q}"));
            }
        } else if !q.is_empty()
            && q.split("::").all(|s| {
                let s = s.trim_end_matches('!');
                !s.is_empty() && s.chars().all(|c| c.is_alphanumeric() || c == '_')
            })
        {
            names += 1;
            for seg in q.split("::") {
                if !word(seg.trim_end_matches('!')) {
                    missing.push(format!("name {seg} (in `{q}`)"));
                }
            }
        }
    }
    assert!(paths >= 10 && names >= 40, "{paths} paths, {names} names");
    assert!(missing.is_empty(), "docs/architecture.md names {missing:?}");
}

/// Every material module carries its closed-form tests beside it (the recipe's first
/// step), and every `Law` of the plan has a `Material` of the same name.
#[test]
fn every_material_module_has_its_tests_and_its_law() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = root.join("src/physics/material");
    let registry = std::fs::read_to_string(dir.join("mod.rs")).unwrap();
    let plan = std::fs::read_to_string(root.join("src/input/plan.rs")).unwrap();
    let modules: Vec<&str> = registry
        .lines()
        .filter_map(|l| l.strip_prefix("pub mod ")?.strip_suffix(';'))
        .collect();
    assert_eq!(modules.len(), 4, "{modules:?}");
    for m in modules {
        let text = std::fs::read_to_string(dir.join(format!("{m}.rs"))).unwrap();
        assert!(
            text.contains("#[cfg(test)]"),
            "{m}.rs has no tests beside it"
        );
        let camel: String = m
            .split('_')
            .map(|w| w[..1].to_uppercase() + &w[1..])
            .collect();
        assert!(
            registry.contains(&format!("Material::{camel}(")),
            "no Material::{camel}"
        );
        assert!(
            plan.contains(&format!("    {camel},")) || plan.contains(&format!("    {camel} {{")),
            "no Law::{camel} in src/input/plan.rs"
        );
    }
}
