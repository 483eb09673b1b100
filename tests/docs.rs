//! The documentation checks itself: `README.md` and every `docs/*.md` page.
//!
//! **Quoted paths and names** (`quoted_paths_and_names_exist`). Every inline code span
//! (text between single backticks outside fenced blocks; a span may wrap across lines)
//! is looked at:
//!
//! - A span whose first word starts with `src/`, `tests/`, `inputs/`, `scripts/`,
//!   `docs/` or `decomposition/` is a repository path and must exist (trailing `:`,
//!   `,`, `)` and a `#anchor` are dropped). A path with a placeholder (`*`, `<`, `{`,
//!   `NAME`, `NNN`) is checked up to the directory before the placeholder.
//! - A span made only of ASCII identifier characters and `::`, optionally ending in
//!   `!` or `()`, is a name. It is checked when it looks like Rust: it contains `::`,
//!   ends in `!` or `()`, or is one word that is CamelCase (`ScatterSums`), snake_case
//!   (`max_relative_drift`) or SCREAMING_CASE (`MPMCG_DRY_RUN`). snake and screaming
//!   words whose first part is a single letter (`x_i`, `w_c`, `G_i`) are mathematics,
//!   not names, and other single words (`mpmcg`, `musl`, `SI`) are not checked.
//!   A name with `::`, `!` or `()` must occur, segment by segment, as a whole word in
//!   the Rust code of `src`, `decomposition/src` and `tests` (as the architecture
//!   check of `tests/imports.rs` does). A single word may also be a scene key, a CSV
//!   column, a dataset or an environment variable of a script: it must occur as a whole
//!   word in that Rust code (string literals and comments included), in `inputs/*.toml`,
//!   in `scripts/` or in `.cargo/config.toml`. This file itself is not searched.
//!
//! **Runnable examples** (`runnable_examples_run`). A fence opened with ```` ```sh
//! runnable ```` is run, and must exit 0: each such block of a page in turn, as
//! `bash -euo pipefail -c BLOCK`, in a fresh temporary directory per page that holds
//! symbolic links `inputs` and `scripts` to the repository's, with this test's own
//! `mpmcg` binary first on `PATH`, the repository root in `MPMCG_ROOT`, and Open MPI
//! allowed to run as root and to yield while idle (set here, not in the pages). A fence
//! whose info string has `file=NAME` (```` ```toml file=bar.toml ````) is written to
//! `NAME` in that directory before the page's first block runs, so the pages can show a
//! scene and then run it. Mark only quick commands (seconds, small scenes); give long
//! ones (sweeps at full size, benchmarks) in plain fences beside a small runnable
//! variant. Each block has 120 s.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const PATH_PREFIXES: [&str; 6] = [
    "src/",
    "tests/",
    "inputs/",
    "scripts/",
    "docs/",
    "decomposition/",
];

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// `README.md` and `docs/*.md`, sorted.
fn pages() -> Vec<PathBuf> {
    let mut pages = vec![root().join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root().join("docs"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == "md"))
        .collect();
    docs.sort();
    pages.extend(docs);
    pages
}

/// A fenced block: its info string (after the backticks) and its text.
struct Fence {
    info: String,
    text: String,
}

/// The page's text outside fences, and its fences in order.
fn split(page: &str) -> (String, Vec<Fence>) {
    let mut prose = String::new();
    let mut fences = Vec::new();
    let mut open: Option<Fence> = None;
    for line in page.lines() {
        let t = line.trim_start();
        match &mut open {
            None if t.starts_with("```") => {
                open = Some(Fence {
                    info: t.trim_start_matches('`').trim().to_string(),
                    text: String::new(),
                })
            }
            None => {
                prose += line;
                prose.push('\n');
            }
            Some(_) if t.starts_with("```") => fences.push(open.take().unwrap()),
            Some(f) => {
                f.text += line;
                f.text.push('\n');
            }
        }
    }
    assert!(open.is_none(), "a fence is not closed");
    (prose, fences)
}

/// Inline code spans of the prose (pairs of single backticks, across lines).
fn spans(prose: &str) -> Vec<String> {
    prose
        .split('`')
        .skip(1)
        .step_by(2)
        .map(|s| s.split_whitespace().collect::<Vec<_>>().join(" "))
        .collect()
}

fn files_under(dir: &Path, keep: &dyn Fn(&Path) -> bool, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            if p.file_name().is_some_and(|n| n != "__pycache__") {
                files_under(&p, keep, out);
            }
        } else if keep(&p) {
            out.push(p);
        }
    }
}

fn read_all(files: &[PathBuf]) -> String {
    files
        .iter()
        .filter_map(|p| std::fs::read_to_string(p).ok())
        .collect::<Vec<_>>()
        .join("\n")
}

/// Whether `w` occurs in `text` with no identifier character on either side.
fn has_word(text: &str, w: &str) -> bool {
    let ident = |c: char| c.is_alphanumeric() || c == '_';
    text.match_indices(w).any(|(i, _)| {
        let before = text[..i].chars().next_back().is_none_or(|c| !ident(c));
        let after = text[i + w.len()..].chars().next().is_none_or(|c| !ident(c));
        before && after
    })
}

/// The path part of a span that names a repository path, if it does.
fn path_of(span: &str) -> Option<&str> {
    let first = span.split_whitespace().next()?;
    if !PATH_PREFIXES.iter().any(|p| first.starts_with(p)) {
        return None;
    }
    let first = first.split('#').next().unwrap();
    Some(first.trim_end_matches([':', ',', ')', '.']))
}

/// The part of a path that can be checked: up to the directory before a placeholder.
fn checkable(path: &str) -> &str {
    let markers = ['*', '<', '{'];
    let cut = path
        .split('/')
        .scan(0, |at, part| {
            let start = *at;
            *at += part.len() + 1;
            Some((start, part))
        })
        .find(|(_, part)| part.contains(markers) || part.contains("NAME") || part.contains("NNN"))
        .map(|(start, _)| start);
    match cut {
        Some(start) => &path[..start],
        None => path,
    }
}

enum Name<'a> {
    /// `a::b`, `f()`, `m!`: every segment a word of the Rust code.
    Rust(Vec<&'a str>),
    /// A single CamelCase, snake_case or SCREAMING_CASE word.
    Word(&'a str),
}

fn name_of(span: &str) -> Option<Name<'_>> {
    let core = span
        .strip_suffix("()")
        .or_else(|| span.strip_suffix('!'))
        .unwrap_or(span);
    let ident = |s: &str| {
        !s.is_empty()
            && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
            && !s.starts_with(|c: char| c.is_ascii_digit())
    };
    let segments: Vec<&str> = core.split("::").collect();
    if !segments.iter().all(|s| ident(s)) {
        return None;
    }
    if segments.len() > 1 || core.len() != span.len() {
        return Some(Name::Rust(segments));
    }
    let w = core;
    let lower = w.chars().any(|c| c.is_ascii_lowercase());
    let upper_first = w.starts_with(|c: char| c.is_ascii_uppercase());
    let head_long = w.split('_').next().is_some_and(|h| h.len() >= 2);
    let camel = upper_first && lower && !w.contains('_');
    let snake = w.starts_with(|c: char| c.is_ascii_lowercase()) && w.contains('_') && head_long;
    let screaming = upper_first && !lower && w.contains('_') && head_long;
    (camel || snake || screaming).then_some(Name::Word(w))
}

#[test]
fn quoted_paths_and_names_exist() {
    let root = root();
    let mut rust = Vec::new();
    for dir in ["src", "decomposition/src", "tests"] {
        files_under(
            &root.join(dir),
            &|p| p.extension().is_some_and(|x| x == "rs") && !p.ends_with("tests/docs.rs"),
            &mut rust,
        );
    }
    let code = read_all(&rust);
    let mut other = Vec::new();
    files_under(
        &root.join("inputs"),
        &|p| p.extension().is_some_and(|x| x == "toml"),
        &mut other,
    );
    files_under(&root.join("scripts"), &|_| true, &mut other);
    other.push(root.join(".cargo/config.toml"));
    let words = read_all(&other);

    let (mut paths, mut names) = (0, 0);
    let mut missing = BTreeSet::new();
    for page in pages() {
        let rel = page.strip_prefix(root).unwrap().display().to_string();
        let (prose, _) = split(&std::fs::read_to_string(&page).unwrap());
        for span in spans(&prose) {
            if let Some(p) = path_of(&span) {
                paths += 1;
                if !root.join(checkable(p)).exists() {
                    missing.insert(format!("{rel}: file `{p}`"));
                }
            } else if let Some(name) = name_of(&span) {
                names += 1;
                match name {
                    Name::Rust(segments) => {
                        for s in segments {
                            if !has_word(&code, s) {
                                missing.insert(format!("{rel}: name `{s}` (in `{span}`)"));
                            }
                        }
                    }
                    Name::Word(w) => {
                        if !has_word(&code, w) && !has_word(&words, w) {
                            missing.insert(format!("{rel}: word `{w}`"));
                        }
                    }
                }
            }
        }
    }
    assert!(paths >= 40 && names >= 80, "{paths} paths, {names} names");
    assert!(
        missing.is_empty(),
        "the docs quote what does not exist:\n{}",
        missing.into_iter().collect::<Vec<_>>().join("\n")
    );
}

/// Runs `block` with bash in `dir`; the exit status and the output, or why it did not
/// end.
fn run_block(dir: &Path, block: &str) -> Result<(), String> {
    let bin = Path::new(env!("CARGO_BIN_EXE_mpmcg"));
    let path = format!(
        "{}:{}",
        bin.parent().unwrap().display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let out_file = dir.join(".block_output");
    let log = std::fs::File::create(&out_file).unwrap();
    let mut c = Command::new("bash");
    c.args(["-euo", "pipefail", "-c", block])
        .current_dir(dir)
        .env("PATH", path)
        .env("MPMCG_ROOT", root())
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OMPI_MCA_mpi_yield_when_idle", "1")
        .stdin(Stdio::null())
        .stdout(log.try_clone().unwrap())
        .stderr(log);
    for (k, _) in std::env::vars().filter(|(k, _)| k.starts_with("SLURM_")) {
        c.env_remove(k);
    }
    let mut child = c.spawn().map_err(|e| format!("bash: {e}"))?;
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        if start.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let output = std::fs::read_to_string(&out_file).unwrap_or_default();
    let _ = std::fs::remove_file(&out_file);
    match status {
        Some(s) if s.success() => Ok(()),
        Some(s) => Err(format!("exit {s}\n{output}")),
        None => Err(format!("did not end within 120 s\n{output}")),
    }
}

/// Whether a fence's info string marks it runnable; a `runnable` mark on anything but
/// `sh` is a mistake.
fn runnable(info: &str) -> bool {
    let mut words = info.split_whitespace();
    let lang = words.next().unwrap_or("");
    let marked = words.any(|w| w == "runnable");
    assert!(!marked || lang == "sh", "```{info}: only sh fences run");
    marked
}

#[test]
fn runnable_examples_run() {
    let root = root();
    let mut ran = 0;
    let mut failures = Vec::new();
    for page in pages() {
        let rel = page.strip_prefix(root).unwrap().display().to_string();
        let (_, fences) = split(&std::fs::read_to_string(&page).unwrap());
        let blocks: Vec<&Fence> = fences.iter().filter(|f| runnable(&f.info)).collect();
        if blocks.is_empty() {
            continue;
        }
        let dir = std::env::temp_dir().join(format!(
            "mpmcg-docs-{}-{}",
            std::process::id(),
            rel.replace('/', "_")
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        for link in ["inputs", "scripts"] {
            std::os::unix::fs::symlink(root.join(link), dir.join(link)).unwrap();
        }
        for f in &fences {
            if let Some(name) = f
                .info
                .split_whitespace()
                .find_map(|w| w.strip_prefix("file="))
            {
                std::fs::write(dir.join(name), &f.text).unwrap();
            }
        }
        let mut page_ok = true;
        for (i, b) in blocks.iter().enumerate() {
            let start = Instant::now();
            let result = run_block(&dir, &b.text);
            eprintln!(
                "{rel}, block {}: {:.1} s{}",
                i + 1,
                start.elapsed().as_secs_f64(),
                if result.is_ok() { "" } else { ", FAILED" }
            );
            ran += 1;
            if let Err(e) = result {
                page_ok = false;
                failures.push(format!(
                    "{rel}, block {}:\n{}\n--- gave:\n{e}",
                    i + 1,
                    b.text
                ));
            }
        }
        if page_ok {
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
    assert!(ran >= 10, "only {ran} runnable blocks");
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}
