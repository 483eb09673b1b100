//! Scene files: TOML, parsed with `deny_unknown_fields` and validated before anything
//! runs. Every error names the file, the key (with line and column when they are
//! known) and what was expected.
//!
//! The keys a scene may hold are in `schema`, the explanation of what serde
//! reports when a file does not fit them in `explain`, and the checks that follow
//! parsing in `validate`.

mod explain;
mod schema;
mod validate;

pub use schema::{
    Balance, BenchmarkKind, BenchmarkSpec, BodySpec, Boundary, CheckpointSpec, Face, Field,
    Gradient, Gravity, GridSpec, MaterialSpec, Method, Model, Output, Parallel, Quadrature, Scene,
    Seeding, Shape, SnapshotPlan, Strain, Time, Update, VelocityGradient, DEFAULTS, PLAIN_DEFAULTS,
};
pub use validate::{MAX_CELLS_PER_AXIS, MAX_OUTPUTS, MAX_STEPS, MAX_XPIC};

use explain::{explain, line_col, locate, one_line};
use std::fmt;
use std::io::Read;
use std::path::Path;
use validate::validate;

/// The built-in scene `mpmcg run` uses when no scene file is given.
pub const DEFAULT_SCENE: &str = include_str!("../../inputs/default.toml");
pub const DEFAULT_SCENE_NAME: &str = "<built-in default scene>";

/// A scene error: file, key, position and what was expected.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneError {
    pub file: String,
    pub key: Option<String>,
    pub line_col: Option<(usize, usize)>,
    pub message: String,
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some((l, c)) = self.line_col {
            write!(f, ":{l}:{c}")?;
        }
        write!(f, ": ")?;
        if let Some(k) = &self.key {
            write!(f, "key `{k}`: ")?;
        }
        write!(f, "{}", self.message)
    }
}

impl std::error::Error for SceneError {}

/// The first key (as `a.b[0].c`) in which scene `b` differs from `a` beyond what a
/// restart may change: how long to run (`time.end`), the step size (`time.cfl`,
/// `time.dt`), how often to write snapshots (`output.every`; their fields must stay,
/// the XDMF index lists one set for the whole series) and the `[checkpoint]` table.
pub fn restart_difference(a: &Scene, b: &Scene) -> Option<String> {
    fn strip(s: &Scene) -> serde_json::Value {
        let mut v = serde_json::to_value(s).expect("a scene serialises");
        let o = v.as_object_mut().expect("a table");
        o.remove("checkpoint");
        if let Some(t) = o.get_mut("time").and_then(|t| t.as_object_mut()) {
            for k in ["end", "cfl", "dt"] {
                t.remove(k);
            }
        }
        // No `[output]` table means `[output]` with its defaults: a restart may add
        // an interval to a run that wrote only its initial and final states.
        let out = o.entry("output").or_insert(serde_json::Value::Null);
        if out.is_null() {
            *out = serde_json::json!({});
        }
        if let Some(t) = out.as_object_mut() {
            t.remove("every");
        }
        v
    }
    fn first(a: &serde_json::Value, b: &serde_json::Value, path: &str) -> Option<String> {
        use serde_json::Value;
        let join = |k: &str| {
            if path.is_empty() {
                k.to_string()
            } else {
                format!("{path}.{k}")
            }
        };
        match (a, b) {
            (Value::Object(x), Value::Object(y)) => {
                let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
                keys.sort();
                keys.dedup();
                keys.into_iter().find_map(|k| match (x.get(k), y.get(k)) {
                    (Some(p), Some(q)) => first(p, q, &join(k)),
                    (None, Some(Value::Null)) | (Some(Value::Null), None) => None,
                    _ => Some(join(k)),
                })
            }
            (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
                .iter()
                .zip(y)
                .enumerate()
                .find_map(|(i, (p, q))| first(p, q, &format!("{path}[{i}]"))),
            _ if a == b => None,
            _ => Some(if path.is_empty() {
                "(scene)".into()
            } else {
                path.into()
            }),
        }
    }
    // The method keys the defaults resolve follow from the others (`gradient`,
    // `update`, `xpic`): name a key the scene changed before one that followed.
    let (a, b) = (strip(a), strip(b));
    let unresolved = |v: &serde_json::Value| {
        let mut v = v.clone();
        if let Some(m) = v.get_mut("method").and_then(|m| m.as_object_mut()) {
            for k in Method::RESOLVED {
                m.remove(k);
            }
        }
        v
    };
    first(&unresolved(&a), &unresolved(&b), "").or_else(|| first(&a, &b, ""))
}

/// Parse and validate a scene under the current defaults. `file` is used in messages
/// only.
pub fn parse(text: &str, file: &str) -> Result<Scene, SceneError> {
    parse_with(text, file, DEFAULTS)
}

/// Parse and validate a scene, its absent `[method]` keys taking the values of the
/// scene defaults `version` (a restart's is its checkpoint's).
pub fn parse_with(text: &str, file: &str, version: u32) -> Result<Scene, SceneError> {
    let err = |key: Option<String>, pos: Option<usize>, message: String| SceneError {
        file: file.to_string(),
        key: key.map(|k| one_line(&k)),
        line_col: pos.map(|p| line_col(text, p)),
        message: one_line(&message),
    };
    if text.trim().is_empty() {
        return Err(err(
            None,
            None,
            "the file is empty; a scene needs at least `name`, `dim`, [time], [grid], [[materials]] and [[bodies]]".into(),
        ));
    }
    let de = toml::Deserializer::parse(text).map_err(|e| {
        let span = e.span();
        let mut message = format!("not valid TOML: {}", e.message());
        // The parser names neither the key nor the table of a duplicate; its span
        // covers the repeated key, so quote that.
        if let Some(k) = span
            .clone()
            .and_then(|s| text.get(s))
            .filter(|k| e.message().starts_with("duplicate key") && !k.trim().is_empty())
        {
            message = format!("{message} `{}`", k.trim());
        }
        err(None, span.map(|s| s.start), message)
    })?;
    let mut scene: Scene = serde_path_to_error::deserialize(de).map_err(|e| {
        let (key, pos, message) = explain(text, e.path(), e.inner());
        err(key, pos, message)
    })?;
    // The text parsed once as a scene, so it is a table with a `[method]` table if any.
    let table: toml::Table = text.parse().unwrap_or_default();
    let method = table.get("method").and_then(|m| m.as_table());
    scene
        .method
        .resolve(version, |k| method.is_some_and(|m| m.contains_key(k)));
    scene.defaults = version;
    scene.plan = validate(&scene).map_err(|(key, message)| {
        let pos = locate(text, &key);
        err(Some(key), pos, message)
    })?;
    Ok(scene)
}

/// The largest scene file read.
pub const MAX_SCENE_BYTES: u64 = 16 << 20;

/// Read, parse and validate a scene file under the current defaults.
pub fn load(path: &Path) -> Result<(Scene, String), SceneError> {
    load_with(path, DEFAULTS)
}

/// Read, parse and validate a scene file under the scene defaults `version`.
pub fn load_with(path: &Path, version: u32) -> Result<(Scene, String), SceneError> {
    let file = path.display().to_string();
    let fail = |message: String| SceneError {
        file: file.clone(),
        key: None,
        line_col: None,
        message,
    };
    // At most MAX_SCENE_BYTES (+1 to notice more): `/dev/zero` or a huge file given by
    // mistake must not be read without end.
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(MAX_SCENE_BYTES + 1).read_to_end(&mut bytes))
        .map_err(|e| fail(format!("cannot read the scene file: {e}")))?;
    if bytes.len() as u64 > MAX_SCENE_BYTES {
        return Err(fail(format!(
            "larger than {} MiB: not a scene file (a scene is a short TOML text)",
            MAX_SCENE_BYTES >> 20
        )));
    }
    let text = String::from_utf8(bytes).map_err(|e| {
        let n = e.utf8_error().valid_up_to();
        let valid = std::str::from_utf8(&e.as_bytes()[..n]).unwrap_or_default();
        SceneError {
            file: file.clone(),
            key: None,
            line_col: Some(line_col(valid, n)),
            message: format!(
                "not a text file (invalid UTF-8 at byte {n}); a scene is a UTF-8 TOML file"
            ),
        }
    })?;
    let scene = parse_with(&text, &file, version)?;
    Ok((scene, text))
}

#[cfg(test)]
mod defaults_tests {
    use super::*;

    /// A minimal 2D scene with `method` as its `[method]` table.
    fn text(method: &str) -> String {
        format!(
            "name = \"d\"\ndim = 2\n[time]\nend = 0.1\n[method]\n{method}\n[grid]\n\
             lower = [0.0, 0.0]\nupper = [1.0, 1.0]\ncells = [4, 4]\n[[materials]]\n\
             name = \"m\"\nmodel = \"neo_hookean\"\ndensity = 1.0\nyoungs_modulus = 1.0\n\
             poisson_ratio = 0.3\n[[bodies]]\nmaterial = \"m\"\n\
             shape = {{ box = {{ lower = [0.25, 0.25], upper = [0.75, 0.75] }} }}\n"
        )
    }

    fn method(m: &str, version: u32) -> (Quadrature, u32, f64) {
        let s = parse_with(&text(m), "t", version).unwrap();
        assert_eq!(s.defaults, version);
        (
            s.method.quadrature,
            s.method.centroid_passes,
            s.method.sharpen,
        )
    }

    /// Under scene defaults 2, MPMCG takes the domain rule, `sharpen = 1` where its
    /// quadrature is the domain rule, and four centroid passes only where they may run
    /// (MUSL, no XPIC); the other schemes and scene defaults 1 take none of them; a key
    /// the scene gives is kept.
    #[test]
    fn absent_method_keys_take_the_versions_defaults() {
        use Quadrature::{Domain, Point};
        assert_eq!(method("", 2), (Domain, 4, 1.0));
        assert_eq!(method("update = \"usl\"", 2), (Domain, 0, 1.0));
        assert_eq!(method("xpic = 2", 2), (Domain, 0, 1.0));
        assert_eq!(method("gradient = \"mpm\"", 2), (Point, 0, 0.0));
        assert_eq!(method("gradient = \"averaged\"", 2), (Point, 0, 0.0));
        assert_eq!(method("sharpen = 2.0", 2), (Domain, 4, 2.0));
        // Sharpened only with the domain rule, by default.
        assert_eq!(method("quadrature = \"point\"", 2), (Point, 4, 0.0));
        assert_eq!(
            method("quadrature = \"point\"\nsharpen = 1.0", 2),
            (Point, 4, 1.0)
        );
        assert_eq!(method("", 1), (Point, 0, 0.0));
        assert_eq!(method("centroid_passes = 2", 1), (Point, 2, 0.0));
        // No `[method]` table at all is the same as an empty one.
        let bare = text("").replace("[method]\n", "");
        let s = parse(&bare, "t").unwrap();
        assert_eq!(
            (
                s.method.quadrature,
                s.method.centroid_passes,
                s.method.sharpen
            ),
            (Domain, 4, 1.0)
        );
    }

    /// A scene written out names every method key, so it reads the same under either
    /// version of the defaults (a sweep's `scene.toml`, the stored built-in scene).
    #[test]
    fn a_written_scene_reads_the_same_under_any_defaults() {
        for (m, version) in [("", 1), ("", 2), ("update = \"usl\"", 2)] {
            let s = parse_with(&text(m), "t", version).unwrap();
            let written = toml::to_string(&s).unwrap();
            for v in [1, DEFAULTS] {
                let again = parse_with(&written, "w", v).unwrap();
                assert_eq!(
                    restart_difference(&s, &again),
                    None,
                    "{m:?} under {version}, read under {v}"
                );
            }
        }
    }

    /// A restart with a scene whose gradient changed names `method.gradient`, not the
    /// keys whose defaults followed from it.
    #[test]
    fn a_changed_gradient_is_named_before_what_follows_from_it() {
        let a = parse(&text(""), "a").unwrap();
        let b = parse(&text("gradient = \"gimp\""), "b").unwrap();
        assert_eq!(
            restart_difference(&a, &b).as_deref(),
            Some("method.gradient")
        );
    }
}
