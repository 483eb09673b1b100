//! Scene files: TOML, parsed with `deny_unknown_fields` and validated before anything
//! runs. Every error names the file, the key (with line and column when they are
//! known) and what was expected.

use crate::input::plan::{
    BenchmarkPlan, CheckpointEvery, KindPlan, Law, MaterialPlan, Plan, MAX_KINDS,
};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::io::Read;
use std::path::Path;

/// The built-in scene `mpmcg run` uses when no scene file is given.
pub const DEFAULT_SCENE: &str = include_str!("../../inputs/default.toml");
pub const DEFAULT_SCENE_NAME: &str = "<built-in default scene>";

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    pub name: String,
    pub dim: usize,
    pub time: Time,
    #[serde(default)]
    pub method: Method,
    pub grid: GridSpec,
    pub materials: Vec<MaterialSpec>,
    pub bodies: Vec<BodySpec>,
    pub benchmark: Option<BenchmarkSpec>,
    pub gravity: Option<Gravity>,
    pub output: Option<Output>,
    pub checkpoint: Option<CheckpointSpec>,
    #[serde(default)]
    pub parallel: Parallel,
    /// What validation resolved (filled by [`parse`], not a key of the file).
    #[serde(skip)]
    pub plan: Plan,
}

/// `[parallel]`: how the grid's blocks follow the material over ranks.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Parallel {
    /// `off`: equal blocks; `static`: blocks cut once at the start for an equal share
    /// of the particles; `auto`: that, and again whenever the imbalance passes
    /// `imbalance`.
    #[serde(default = "default_balance")]
    pub balance: Balance,
    /// The largest rank's particles over the mean above which `auto` rebalances.
    #[serde(default = "default_imbalance")]
    pub imbalance: f64,
    /// Steps between two checks of the imbalance under `auto` (one reduction each).
    #[serde(default = "default_check_every")]
    pub check_every: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Balance {
    Off,
    Static,
    Auto,
}

impl Balance {
    pub fn name(self) -> &'static str {
        match self {
            Balance::Off => "off",
            Balance::Static => "static",
            Balance::Auto => "auto",
        }
    }
}

fn default_balance() -> Balance {
    Balance::Auto
}
/// Rebalance at 5 % above the mean: the target is 10 % for most of a run, and
/// the imbalance grows between checks.
fn default_imbalance() -> f64 {
    1.05
}
fn default_check_every() -> u64 {
    20
}

impl Default for Parallel {
    fn default() -> Self {
        Self {
            balance: default_balance(),
            imbalance: default_imbalance(),
            check_every: default_check_every(),
        }
    }
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Time {
    pub end: f64,
    pub cfl: Option<f64>,
    pub dt: Option<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Gradient {
    Mpm,
    Gimp,
    Averaged,
    Mpmcg,
}

impl Gradient {
    pub const ALL: [Gradient; 4] = [
        Gradient::Mpm,
        Gradient::Gimp,
        Gradient::Averaged,
        Gradient::Mpmcg,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Gradient::Mpm => "mpm",
            Gradient::Gimp => "gimp",
            Gradient::Averaged => "averaged",
            Gradient::Mpmcg => "mpmcg",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Update {
    Usl,
    Usf,
    Musl,
}

impl Update {
    pub fn name(self) -> &'static str {
        match self {
            Update::Usl => "usl",
            Update::Usf => "usf",
            Update::Musl => "musl",
        }
    }
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Method {
    #[serde(default = "default_gradient")]
    pub gradient: Gradient,
    #[serde(default = "default_update")]
    pub update: Update,
    /// 1 = FLIP, 0 = PIC, in between a blend.
    #[serde(default = "default_flip")]
    pub flip: f64,
    /// The order m of XPIC(m) (Hammerquist & Nairn 2017) in place of the FLIP update
    /// of particle velocities: FLIP with its grid-invisible noise filtered out, at the
    /// cost of m − 1 more particle → grid passes per step. Off when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub xpic: Option<u32>,
}

fn default_gradient() -> Gradient {
    Gradient::Mpmcg
}
/// MUSL: its velocity gradient comes from remapped particle momentum, which stays
/// bounded at nodes that carry little mass (free surfaces). With USL those nodes' force
/// updates can blow up the grid-averaged gradient of `averaged` and `mpmcg`.
fn default_update() -> Update {
    Update::Musl
}
fn default_flip() -> f64 {
    1.0
}

impl Default for Method {
    fn default() -> Self {
        Self {
            gradient: default_gradient(),
            update: default_update(),
            flip: default_flip(),
            xpic: None,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Face {
    /// Every velocity component is zero on the face.
    #[default]
    Fixed,
    /// The normal velocity component is zero on the face.
    Slip,
    /// No constraint; material must not leave the grid.
    Free,
    /// The face is glued to the opposite one.
    Periodic,
}

#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Boundary {
    pub x_lower: Option<Face>,
    pub x_upper: Option<Face>,
    pub y_lower: Option<Face>,
    pub y_upper: Option<Face>,
    pub z_lower: Option<Face>,
    pub z_upper: Option<Face>,
}

impl Face {
    pub fn name(self) -> &'static str {
        match self {
            Face::Fixed => "fixed",
            Face::Slip => "slip",
            Face::Free => "free",
            Face::Periodic => "periodic",
        }
    }
}

impl Boundary {
    const KEYS: [&'static str; 6] = [
        "x_lower", "x_upper", "y_lower", "y_upper", "z_lower", "z_upper",
    ];
    fn get(&self, k: usize) -> Option<Face> {
        [
            self.x_lower,
            self.x_upper,
            self.y_lower,
            self.y_upper,
            self.z_lower,
            self.z_upper,
        ][k]
    }
    /// Face type of axis `a`, side `upper`; unlisted faces are `fixed`.
    pub fn face(&self, a: usize, upper: bool) -> Face {
        self.get(2 * a + usize::from(upper)).unwrap_or_default()
    }
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    pub cells: Vec<usize>,
    #[serde(default)]
    pub boundary: Boundary,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Model {
    LinearElastic,
    NeoHookean,
    /// J2 plasticity at finite strain with linear isotropic hardening.
    J2Plastic,
    /// Linear elastic with tensile failure.
    Brittle,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    pub name: String,
    pub model: Model,
    pub density: f64,
    pub youngs_modulus: f64,
    pub poisson_ratio: f64,
    /// Initial yield stress (`j2_plastic`).
    pub yield_stress: Option<f64>,
    /// Linear isotropic hardening modulus (`j2_plastic`, default 0).
    pub hardening: Option<f64>,
    /// Largest principal stress before failure (`brittle`).
    pub tensile_strength: Option<f64>,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    Box {
        lower: Vec<f64>,
        upper: Vec<f64>,
    },
    /// A disk in 2D, an interval in 1D.
    Sphere {
        center: Vec<f64>,
        radius: f64,
    },
    /// The ring `inner <= |x - center| <= outer` (2D).
    Annulus {
        center: Vec<f64>,
        inner: f64,
        outer: f64,
    },
    /// A cylinder along z (3D): axis through `center` = [x, y], from `z[0]` to `z[1]`.
    Cylinder {
        center: Vec<f64>,
        radius: f64,
        z: Vec<f64>,
    },
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BodySpec {
    pub material: String,
    pub shape: Shape,
    /// Particles per cell along each direction.
    #[serde(default = "default_ppc")]
    pub particles_per_cell: usize,
    pub velocity: Option<Vec<f64>>,
    /// A linear initial velocity field added to `velocity`: `v += value · (x − about)`.
    pub velocity_gradient: Option<VelocityGradient>,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct VelocityGradient {
    /// Rows of the gradient: `value[i][j] = ∂v_i/∂x_j`.
    pub value: Vec<Vec<f64>>,
    /// The point where this part of the velocity vanishes (default: the origin).
    pub about: Option<Vec<f64>>,
}

fn default_ppc() -> usize {
    2
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BenchmarkKind {
    VibratingBar,
    AxisAlignedMms,
    GeneralizedVortex,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BenchmarkSpec {
    pub kind: BenchmarkKind,
    pub amplitude: Option<f64>,
    pub mode: Option<u32>,
    pub c: Option<f64>,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Gravity {
    pub value: Vec<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Field {
    Velocity,
    Stress,
    Displacement,
    /// Equivalent plastic strain (scenes with a `j2_plastic` material).
    PlasticStrain,
    /// Damage (scenes with a `brittle` material).
    Damage,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Output {
    /// Simulated time between snapshots; `None`: only the initial and final states.
    pub every: Option<f64>,
    /// `None`: velocity and stress.
    pub fields: Option<Vec<Field>>,
    /// `Some(false)`: no snapshots at all (`every` and `fields` must then be absent).
    pub snapshots: Option<bool>,
}

/// The snapshots a run writes.
#[derive(Debug, Clone, PartialEq)]
pub struct SnapshotPlan {
    /// Simulated time between snapshots (infinite: the initial and final states only).
    pub every: f64,
    pub fields: Vec<Field>,
}

impl Scene {
    /// What the scene asks to write: `None` for `[output] snapshots = false`. Without
    /// `[output]` a run still writes its initial and final states, so that every run
    /// leaves something to look at.
    pub fn snapshot_plan(&self) -> Option<SnapshotPlan> {
        let o = self.output.as_ref();
        if o.and_then(|o| o.snapshots) == Some(false) {
            return None;
        }
        Some(SnapshotPlan {
            every: o.and_then(|o| o.every).unwrap_or(f64::INFINITY),
            fields: o
                .and_then(|o| o.fields.clone())
                .unwrap_or_else(|| vec![Field::Velocity, Field::Stress]),
        })
    }
}

/// When to write restart checkpoints: exactly one of `every` (simulated time),
/// `every_steps` or `every_seconds` (wall clock), keeping the last `keep` files.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CheckpointSpec {
    /// Simulated time between checkpoints.
    pub every: Option<f64>,
    /// Steps between checkpoints.
    pub every_steps: Option<u64>,
    /// Wall-clock seconds between checkpoints (rank 0's clock decides).
    pub every_seconds: Option<f64>,
    /// How many of the newest checkpoints to keep (older ones are deleted).
    #[serde(default = "default_keep")]
    pub keep: usize,
}

fn default_keep() -> usize {
    2
}

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

/// The most bytes of a message's key or text (which quote the input) printed.
const MAX_QUOTE: usize = 1000;

/// 1-based line and column (in characters) of a byte offset.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |s| s.chars().count()) + 1;
    (line, col)
}

/// Escapes control characters (newlines included) so that a message stays on one line.
fn one_line(s: &str) -> String {
    let mut out = String::with_capacity(s.len().min(MAX_QUOTE + 64));
    for (i, c) in s.char_indices() {
        // Messages quote the input, which may be megabytes on one line.
        if out.len() >= MAX_QUOTE {
            out += &format!("... ({} more bytes)", s.len() - i);
            break;
        }
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

/// The value at a dotted key path like `materials[0].density`, and whether the whole
/// path was found (`false`: the value is the deepest enclosing one that exists).
fn find<'a>(
    t: &'a toml::de::DeTable<'a>,
    parts: &[&str],
) -> Option<(&'a toml::Spanned<toml::de::DeValue<'a>>, bool)> {
    use toml::de::DeValue;
    let (part, rest) = parts.split_first()?;
    let (name, idx) = match part.find('[') {
        Some(i) => (
            &part[..i],
            part[i + 1..]
                .strip_suffix(']')
                .and_then(|n| n.parse::<usize>().ok()),
        ),
        None => (*part, None),
    };
    let mut v = t.iter().find(|(k, _)| k.get_ref() == name)?.1;
    if let Some(i) = idx {
        match v.get_ref() {
            DeValue::Array(a) => match a.get(i) {
                Some(x) => v = x,
                None => return Some((v, false)),
            },
            _ => return Some((v, false)),
        }
    }
    if rest.is_empty() {
        return Some((v, true));
    }
    match v.get_ref() {
        DeValue::Table(inner) => find(inner, rest).or(Some((v, false))),
        _ => Some((v, false)),
    }
}

/// Calls `f` with the value at `key` and its source text, if the key is in the file.
fn with_value<R>(
    text: &str,
    key: &str,
    exact: bool,
    f: impl FnOnce(&toml::de::DeValue<'_>, std::ops::Range<usize>) -> R,
) -> Option<R> {
    let doc = toml::de::DeTable::parse(text).ok()?;
    let parts: Vec<&str> = key.split('.').collect();
    let (v, found) = find(doc.get_ref(), &parts)?;
    (found || !exact).then(|| f(v.get_ref(), v.span()))
}

/// Byte offset of the value at a dotted key path like `materials[0].density`, or of
/// the deepest enclosing value that exists.
fn locate(text: &str, key: &str) -> Option<usize> {
    with_value(text, key, false, |_, span| span.start)
}

/// What the file holds at `key`, for messages: "the string \"heavy\"", "a table".
fn describe(text: &str, key: &str) -> Option<String> {
    use toml::de::DeValue;
    with_value(text, key, true, |v, span| {
        let raw = text.get(span).unwrap_or("").trim();
        let raw = if raw.chars().count() > 40 {
            format!("{}...", raw.chars().take(40).collect::<String>())
        } else {
            raw.to_string()
        };
        match v {
            DeValue::Table(t) if t.is_empty() => "an empty table".to_string(),
            DeValue::Table(t) => {
                let keys: Vec<String> = t
                    .iter()
                    .map(|(k, _)| format!("`{}`", k.get_ref()))
                    .collect();
                format!("a table with keys {}", keys.join(", "))
            }
            DeValue::Array(_) => "an array".to_string(),
            other => format!("the {} {raw}", other.type_str()),
        }
    })
}

/// The variant names of a unit-variant enum, as serde spells them.
fn variants<T: serde::de::DeserializeOwned>() -> &'static [&'static str] {
    use serde::de::{Error, Visitor};
    use std::cell::Cell;
    struct Probe<'a>(&'a Cell<&'static [&'static str]>);
    impl<'de> serde::Deserializer<'de> for Probe<'_> {
        type Error = serde::de::value::Error;
        fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Self::Error> {
            Err(Self::Error::custom("not an enum"))
        }
        fn deserialize_enum<V: Visitor<'de>>(
            self,
            _: &'static str,
            variants: &'static [&'static str],
            _: V,
        ) -> Result<V::Value, Self::Error> {
            self.0.set(variants);
            Err(Self::Error::custom("probe"))
        }
        serde::forward_to_deserialize_any! {
            bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes
            byte_buf option unit unit_struct newtype_struct seq tuple tuple_struct map
            struct identifier ignored_any
        }
    }
    let cell = Cell::new(&[][..]);
    let _ = T::deserialize(Probe(&cell));
    cell.get()
}

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
    first(&strip(a), &strip(b), "")
}

/// The variants allowed at a key path whose value is an enum (indices written `[]`).
fn choices(key: &str) -> Option<&'static [&'static str]> {
    Some(match key {
        "method.gradient" => variants::<Gradient>(),
        "method.update" => variants::<Update>(),
        "materials[].model" => variants::<Model>(),
        "bodies[].shape" => variants::<Shape>(),
        "benchmark.kind" => variants::<BenchmarkKind>(),
        "output.fields[]" => variants::<Field>(),
        _ => match key.strip_prefix("grid.boundary.") {
            Some(face) if Boundary::KEYS.contains(&face) => variants::<Face>(),
            _ => return None,
        },
    })
}

fn one_of(names: &[&str]) -> String {
    let names: Vec<String> = names.iter().map(|n| format!("`{n}`")).collect();
    format!("one of {}", names.join(", "))
}

/// Serde's name for an expected type, in TOML words.
fn toml_words(expected: &str) -> String {
    match expected {
        "f64" | "f32" => "a number".into(),
        "usize" | "u64" | "u32" | "u16" | "u8" => "a non-negative integer".into(),
        "a sequence" => "an array".into(),
        "a boolean" | "a string" => expected.into(),
        e if e.starts_with("struct") => "a table".into(),
        e if e.starts_with("enum ") => "a string".into(),
        e => e.into(),
    }
}

/// A deserialisation error explained: the key, its byte offset, the message.
type Explained = (Option<String>, Option<usize>, String);

/// Turns a deserialisation error into (key, byte offset, message) with the full key
/// path and what the key expects.
fn explain(text: &str, path: &serde_path_to_error::Path, inner: &toml::de::Error) -> Explained {
    let parts = key_parts(path);
    let pos = inner.span().map(|s| s.start);
    let msg = inner.message();
    // A required key is absent: name it, not the table that lacks it.
    if let Some(field) = msg
        .strip_prefix("missing field `")
        .and_then(|m| m.strip_suffix('`'))
    {
        return missing_key(parts, field, pos);
    }
    // Unknown keys in an enum variant's table (the toml crate checks those itself).
    if let Some((extra, available)) = msg
        .strip_prefix("unexpected keys in table: ")
        .and_then(|m| m.split_once(", available keys: "))
    {
        return unknown_keys(parts, extra, available, pos);
    }
    if let Some(rest) = msg.strip_prefix("unknown field ") {
        return (join_key(&parts), pos, format!("unknown key {rest}"));
    }
    if let Some(e) = enum_form(text, &parts, msg, pos) {
        return e;
    }
    if let Some(e) = wrong_value(text, join_key(&parts), msg, pos) {
        return e;
    }
    (join_key(&parts), pos, msg.to_string())
}

/// The keys of a serde path, an array index joined to its key (`bodies[0]`).
fn key_parts(path: &serde_path_to_error::Path) -> Vec<String> {
    use serde_path_to_error::Segment;
    let mut parts: Vec<String> = Vec::new();
    for seg in path.iter() {
        match seg {
            Segment::Seq { index } => match parts.last_mut() {
                Some(last) => last.push_str(&format!("[{index}]")),
                None => parts.push(format!("[{index}]")),
            },
            Segment::Map { key } => parts.push(key.clone()),
            Segment::Enum { variant } => parts.push(variant.clone()),
            Segment::Unknown => parts.push("?".into()),
        }
    }
    parts
}

/// `bodies[0].shape`; `None` for the root.
fn join_key(p: &[String]) -> Option<String> {
    (!p.is_empty()).then(|| p.join("."))
}

/// The key without its indices: `bodies[].shape`.
fn generic_key(p: &[String]) -> String {
    p.iter()
        .map(|s| match s.find('[') {
            Some(i) => format!("{}[]", &s[..i]),
            None => s.clone(),
        })
        .collect::<Vec<_>>()
        .join(".")
}

/// The required key `field` of the table at `parts` is missing.
fn missing_key(mut parts: Vec<String>, field: &str, mut pos: Option<usize>) -> Explained {
    let message = if parts.is_empty() {
        // The span is the whole file; a position would only mislead.
        pos = None;
        match field {
            "time" | "grid" => format!("the required table [{field}] is missing"),
            "materials" | "bodies" => {
                format!("missing; at least one [[{field}]] entry is required")
            }
            _ => "this required key is missing".to_string(),
        }
    } else {
        "this required key is missing".to_string()
    };
    parts.push(field.to_string());
    (join_key(&parts), pos, message)
}

/// Unknown keys `extra` (comma-separated) in a table whose keys are `available`.
fn unknown_keys(
    mut parts: Vec<String>,
    extra: &str,
    available: &str,
    pos: Option<usize>,
) -> Explained {
    let extra: Vec<&str> = extra.split(", ").collect();
    let available: Vec<&str> = available.split(", ").collect();
    let mut message = format!(
        "unknown key `{}`, expected {}",
        extra[0],
        one_of(&available)
    );
    if extra.len() > 1 {
        let more: Vec<String> = extra[1..].iter().map(|k| format!("`{k}`")).collect();
        message.push_str(&format!(" (also unknown: {})", more.join(", ")));
    }
    parts.push(extra[0].to_string());
    (join_key(&parts), pos, message)
}

/// Errors about an enum's form rather than about a variant's contents: the toml crate
/// may have stepped into the variant (`gradient = { mpm = 1 }`) or reported a string
/// where a table variant was expected (`shape = "box"`). `None` if not an enum's.
fn enum_form(text: &str, parts: &[String], msg: &str, pos: Option<usize>) -> Option<Explained> {
    let n = if choices(&generic_key(parts)).is_some() {
        parts.len()
    } else if parts.len() > 1 && choices(&generic_key(&parts[..parts.len() - 1])).is_some() {
        let shape = generic_key(&parts[..parts.len() - 1]) == "bodies[].shape";
        (!shape || msg.contains("unit variant")).then(|| parts.len() - 1)?
    } else {
        return None;
    };
    if msg.starts_with("unknown variant") {
        return Some((join_key(&parts[..n]), pos, msg.to_string()));
    }
    let k = join_key(&parts[..n]).unwrap_or_default();
    let names = choices(&generic_key(&parts[..n])).unwrap_or(&[]);
    let expected = if generic_key(&parts[..n]) == "bodies[].shape" {
        format!(
            "a table with exactly one of the keys {}, e.g. `shape = {{ box = {{ lower = [...], upper = [...] }} }}`",
            names.iter().map(|n| format!("`{n}`")).collect::<Vec<_>>().join(", ")
        )
    } else {
        format!("a string, {}", one_of(names))
    };
    let got = describe(text, &k).map_or(String::new(), |g| format!(", got {g}"));
    let pos = locate(text, &k).or(pos);
    Some((Some(k), pos, format!("expected {expected}{got}")))
}

/// "invalid type: string \"heavy\", expected f64" and the like, in TOML's words, for
/// the value at `key`. `None` for other errors.
fn wrong_value(
    text: &str,
    key: Option<String>,
    msg: &str,
    pos: Option<usize>,
) -> Option<Explained> {
    let (unexpected, expected) = ["invalid type: ", "invalid value: "].iter().find_map(|p| {
        msg.strip_prefix(p)
            .and_then(|m| m.rsplit_once(", expected "))
    })?;
    let got = match unexpected.strip_suffix(" as i128") {
        Some(n) => format!("{n}, which is out of range"),
        None => key
            .as_deref()
            .and_then(|k| describe(text, k))
            .unwrap_or_else(|| unexpected.to_string()),
    };
    let expected = match key.as_deref() {
        Some(k @ ("materials" | "bodies")) if expected == "a sequence" => {
            format!("[[{k}]] entries (an array of tables)")
        }
        _ => toml_words(expected),
    };
    Some((key, pos, format!("expected {expected}, got {got}")))
}

/// Parse and validate a scene. `file` is used in messages only.
pub fn parse(text: &str, file: &str) -> Result<Scene, SceneError> {
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
    scene.plan = validate(&scene).map_err(|(key, message)| {
        let pos = locate(text, &key);
        err(Some(key), pos, message)
    })?;
    Ok(scene)
}

/// The largest scene file read.
pub const MAX_SCENE_BYTES: u64 = 16 << 20;

/// Read, parse and validate a scene file.
pub fn load(path: &Path) -> Result<(Scene, String), SceneError> {
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
    let scene = parse(&text, &file)?;
    Ok((scene, text))
}

type Invalid = (String, String);

/// The highest XPIC order accepted: each order costs one particle → grid pass per step,
/// and past a few the filter differs from FLIP only in the exact null space.
pub const MAX_XPIC: u32 = 8;

fn finite(key: &str, x: f64) -> Result<(), Invalid> {
    if x.is_finite() {
        Ok(())
    } else {
        Err((key.into(), format!("must be a finite number, got {x}")))
    }
}

fn positive(key: &str, x: f64) -> Result<(), Invalid> {
    finite(key, x)?;
    if x > 0.0 {
        Ok(())
    } else {
        Err((key.into(), format!("must be > 0, got {x}")))
    }
}

fn vector(key: &str, v: &[f64], dim: usize) -> Result<(), Invalid> {
    if v.len() != dim {
        return Err((
            key.into(),
            format!("must have dim = {dim} components, got {} ({v:?})", v.len()),
        ));
    }
    for (i, &x) in v.iter().enumerate() {
        finite(&format!("{key}[{i}]"), x)?;
    }
    Ok(())
}

/// The largest grid a scene may ask for, in nodes: 2^40, about 10^12, which at
/// [`BYTES_PER_NODE`] is a few hundred terabytes of dense grid fields.
const MAX_GRID_NODES: u64 = 1 << 40;
/// Grid field bytes per node of a 3D MPMCG run (scatter record, velocities, σ̄/L̄,
/// fill, weight and volume), for the message above.
const BYTES_PER_NODE: u64 = 8 * (1 + 6 + 9 + 1 + 6 + 9 + 3);

/// The most cells a grid axis may have: the tile pass keeps a cell per run of
/// particles as 32-bit numbers.
pub const MAX_CELLS_PER_AXIS: usize = i32::MAX as usize;

/// The most snapshots or time-interval checkpoints a scene may ask for over its run:
/// each is a file, and an interval far below the step size makes every step write one.
pub const MAX_OUTPUTS: f64 = 1e6;
/// The most steps a fixed `time.dt` may ask for.
pub const MAX_STEPS: f64 = 1e12;

/// An output interval gives at most [`MAX_OUTPUTS`] outputs up to `end`.
fn interval(key: &str, every: f64, end: f64, what: &str) -> Result<(), Invalid> {
    positive(key, every)?;
    let n = end / every;
    if n > MAX_OUTPUTS {
        return Err((
            key.into(),
            format!(
                "{every:e} would write {n:.3e} {what} up to time.end = {end:e}; at most {MAX_OUTPUTS:e} (an interval >= {:.3e})",
                end / MAX_OUTPUTS
            ),
        ));
    }
    Ok(())
}

/// A scene name is a plain file name (it names the output folder).
fn plain_name(name: &str) -> Result<(), Invalid> {
    // A plain file name: `.` and `..` would put the output folder on `out/` itself or
    // outside it, and a leading dot hides it.
    if name.trim().is_empty()
        || name.starts_with('.')
        || name
            .chars()
            .any(|c| !(c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.'))
    {
        return Err((
            "name".into(),
            format!(
                "must be a plain file name of letters, digits, `_`, `-` and `.`, not starting with `.` (it names the output folder), got {:?}",
                name
            ),
        ));
    }
    Ok(())
}

/// The grid is small enough to hold.
fn grid_size(cells: &[usize]) -> Result<(), Invalid> {
    // The grid is stored dense per rank: a node count whose product overflows, or that
    // no machine could hold, is an input error, not a crash in the allocator.
    let nodes = cells.iter().try_fold(1u64, |n, &c| {
        (c as u64).checked_add(1).and_then(|c1| n.checked_mul(c1))
    });
    if nodes.is_none_or(|n| n > MAX_GRID_NODES) {
        let approx: f64 = cells.iter().map(|&c| c as f64 + 1.0).product();
        return Err((
            "grid.cells".into(),
            format!(
                "{approx:.3e} grid nodes (about {:.1e} bytes of grid fields) is beyond what a run can hold; at most {MAX_GRID_NODES:.0e} nodes",
                approx * BYTES_PER_NODE as f64
            ),
        ));
    }
    Ok(())
}

/// What each benchmark kind needs of the scene (the benchmark module relies on it; the
/// check lives here so that the scene does not depend on the solutions' code).
fn validate_benchmark(s: &Scene, b: &BenchmarkSpec) -> Result<BenchmarkPlan, Invalid> {
    let m0 = &s.materials[0];
    let body = &s.bodies[0];
    let need_model = |model: Model, what: &str| {
        if s.materials.iter().any(|m| m.model != model) {
            Err((
                "benchmark.kind".to_string(),
                format!("`{what}` needs every material to be `{model:?}`")
                    .replace("LinearElastic", "linear_elastic")
                    .replace("NeoHookean", "neo_hookean"),
            ))
        } else {
            Ok(())
        }
    };
    match b.kind {
        BenchmarkKind::VibratingBar => {
            need_model(Model::LinearElastic, "vibrating_bar")?;
            if b.c.is_some() {
                return Err(("benchmark.c".into(), "not used by `vibrating_bar`".into()));
            }
            let Shape::Box { lower, upper } = &body.shape else {
                return Err((
                    "bodies[0].shape".into(),
                    "`vibrating_bar` needs the bar as a `box`".into(),
                ));
            };
            if m0.poisson_ratio != 0.0 && s.dim > 1 {
                return Err((
                    "materials[0].poisson_ratio".into(),
                    "the 2D/3D vibrating bar needs poisson_ratio = 0 for the 1D solution to hold"
                        .into(),
                ));
            }
            Ok(BenchmarkPlan::VibratingBar {
                amplitude: b.amplitude.unwrap_or(0.1),
                mode: b.mode.unwrap_or(1),
                bar: [lower[0], upper[0]],
            })
        }
        BenchmarkKind::AxisAlignedMms | BenchmarkKind::GeneralizedVortex => {
            let name = if b.kind == BenchmarkKind::AxisAlignedMms {
                "axis_aligned_mms"
            } else {
                "generalized_vortex"
            };
            need_model(Model::NeoHookean, name)?;
            if b.mode.is_some() {
                return Err(("benchmark.mode".into(), format!("not used by `{name}`")));
            }
            if b.kind == BenchmarkKind::GeneralizedVortex {
                if s.dim != 2 {
                    return Err(("dim".into(), "`generalized_vortex` is a 2D problem".into()));
                }
                let Shape::Annulus { center, .. } = &body.shape else {
                    return Err((
                        "bodies[0].shape".into(),
                        "`generalized_vortex` needs the ring as an `annulus`".into(),
                    ));
                };
                Ok(BenchmarkPlan::GeneralizedVortex {
                    amplitude: b.amplitude.unwrap_or(1.0),
                    c: b.c.unwrap_or(1.0),
                    center: [center[0], center[1]],
                })
            } else {
                for a in 0..s.dim {
                    if s.grid.lower[a] != 0.0 || s.grid.upper[a] != 1.0 {
                        return Err((
                            "grid.lower".into(),
                            "`axis_aligned_mms` is posed on the unit interval/square/cube: lower = 0, upper = 1".into(),
                        ));
                    }
                }
                Ok(BenchmarkPlan::AxisAlignedMms {
                    amplitude: b.amplitude.unwrap_or(0.05),
                    c: b.c.unwrap_or(100.0),
                })
            }
        }
    }
}

/// Check every key and resolve what the run reads in typed form.
fn validate(s: &Scene) -> Result<Plan, Invalid> {
    let d = s.dim;
    if !(1..=3).contains(&d) {
        return Err(("dim".into(), format!("must be 1, 2 or 3, got {d}")));
    }
    plain_name(&s.name)?;
    validate_time(s)?;
    validate_method(s)?;
    validate_grid(s)?;
    let materials = validate_materials(s)?;
    let body_material = validate_bodies(s)?;
    let (kinds, body_kind) = kinds_of(s, &body_material)?;
    let benchmark = validate_benchmark_table(s)?;
    if let Some(gr) = &s.gravity {
        vector("gravity.value", &gr.value, s.dim)?;
    }
    validate_output(s)?;
    let checkpoint = validate_checkpoint(s)?;
    validate_parallel(s)?;
    Ok(Plan {
        materials,
        kinds,
        body_kind,
        benchmark,
        checkpoint,
    })
}

/// `[parallel]`: an imbalance threshold of at least 1 and a positive check interval.
fn validate_parallel(s: &Scene) -> Result<(), Invalid> {
    let p = &s.parallel;
    finite("parallel.imbalance", p.imbalance)?;
    if p.imbalance < 1.0 {
        return Err((
            "parallel.imbalance".into(),
            format!(
                "is the largest rank's particles over the mean, so it must be >= 1, got {}",
                p.imbalance
            ),
        ));
    }
    if p.check_every == 0 {
        return Err((
            "parallel.check_every".into(),
            "must be >= 1 (steps between imbalance checks), got 0".into(),
        ));
    }
    Ok(())
}

/// `[time]`: a positive end, and either a CFL number in (0, 1] or a step that does not
/// make more than [`MAX_STEPS`] steps.
fn validate_time(s: &Scene) -> Result<(), Invalid> {
    positive("time.end", s.time.end)?;
    match (s.time.cfl, s.time.dt) {
        (Some(_), Some(_)) => {
            return Err((
                "time.dt".into(),
                "give either `cfl` or `dt`, not both".into(),
            ))
        }
        (Some(c), None) => {
            positive("time.cfl", c)?;
            if c > 1.0 {
                return Err(("time.cfl".into(), format!("must be <= 1, got {c}")));
            }
        }
        (None, Some(dt)) => {
            positive("time.dt", dt)?;
            let n = s.time.end / dt;
            if n > MAX_STEPS {
                return Err((
                    "time.dt".into(),
                    format!(
                        "{dt:e} makes {n:.3e} steps up to time.end = {:e}; at most {MAX_STEPS:e}",
                        s.time.end
                    ),
                ));
            }
        }
        (None, None) => {}
    }
    Ok(())
}

/// `[method]`: the FLIP fraction and the XPIC order.
fn validate_method(s: &Scene) -> Result<(), Invalid> {
    finite("method.flip", s.method.flip)?;
    if !(0.0..=1.0).contains(&s.method.flip) {
        return Err((
            "method.flip".into(),
            format!(
                "must be in [0, 1] (1 = FLIP, 0 = PIC), got {}",
                s.method.flip
            ),
        ));
    }
    if let Some(m) = s.method.xpic {
        if !(1..=MAX_XPIC).contains(&m) {
            return Err((
                "method.xpic".into(),
                format!("the XPIC order must be an integer in [1, {MAX_XPIC}], got {m}"),
            ));
        }
        if s.method.flip != 1.0 {
            return Err((
                "method.xpic".into(),
                format!(
                    "XPIC replaces the FLIP/PIC blend: leave method.flip at 1 (got {})",
                    s.method.flip
                ),
            ));
        }
    }
    Ok(())
}

/// `[grid]`: bounds and cells per axis, paired periodic faces, no face beyond `dim`.
fn validate_grid(s: &Scene) -> Result<(), Invalid> {
    let d = s.dim;
    let g = &s.grid;
    vector("grid.lower", &g.lower, d)?;
    vector("grid.upper", &g.upper, d)?;
    if g.cells.len() != d {
        return Err((
            "grid.cells".into(),
            format!("must have dim = {d} components, got {}", g.cells.len()),
        ));
    }
    grid_size(&g.cells)?;
    for a in 0..d {
        if g.cells[a] == 0 {
            return Err((format!("grid.cells[{a}]"), "must be >= 1, got 0".into()));
        }
        if g.cells[a] > MAX_CELLS_PER_AXIS {
            return Err((
                format!("grid.cells[{a}]"),
                format!(
                    "must be at most {MAX_CELLS_PER_AXIS} cells per axis, got {}",
                    g.cells[a]
                ),
            ));
        }
        if g.lower[a] >= g.upper[a] {
            return Err((
                "grid.upper".into(),
                format!(
                    "must be greater than grid.lower on every axis; axis {a}: lower {} >= upper {}",
                    g.lower[a], g.upper[a]
                ),
            ));
        }
        let lo = g.boundary.face(a, false);
        let hi = g.boundary.face(a, true);
        if (lo == Face::Periodic) != (hi == Face::Periodic) {
            let (p, other, face) = if lo == Face::Periodic {
                (2 * a, 2 * a + 1, hi)
            } else {
                (2 * a + 1, 2 * a, lo)
            };
            let given = if g.boundary.get(other).is_some() {
                ""
            } else {
                " (the default)"
            };
            return Err((
                format!("grid.boundary.{}", Boundary::KEYS[p]),
                format!(
                    "periodic faces come in pairs, but `{}` is `{}`{given}: set both to `periodic`",
                    Boundary::KEYS[other],
                    face.name()
                ),
            ));
        }
        if lo == Face::Periodic && g.cells[a] < 2 {
            return Err((
                format!("grid.cells[{a}]"),
                "a periodic axis needs at least 2 cells".into(),
            ));
        }
    }
    for k in 2 * d..6 {
        if g.boundary.get(k).is_some() {
            return Err((
                format!("grid.boundary.{}", Boundary::KEYS[k]),
                format!("this face does not exist in a {d}D scene"),
            ));
        }
    }
    Ok(())
}

/// `[[materials]]`: at least one, unique names, elastic constants in range and each
/// model's own parameters, resolved into typed materials.
fn validate_materials(s: &Scene) -> Result<Vec<MaterialPlan>, Invalid> {
    if s.materials.is_empty() {
        return Err((
            "materials".into(),
            "at least one [[materials]] entry is required".into(),
        ));
    }
    let mut plans = Vec::with_capacity(s.materials.len());
    for (i, m) in s.materials.iter().enumerate() {
        let k = |f: &str| format!("materials[{i}].{f}");
        if m.name.is_empty() {
            return Err((k("name"), "must not be empty".into()));
        }
        if s.materials[..i].iter().any(|o| o.name == m.name) {
            return Err((k("name"), format!("duplicate material name {:?}", m.name)));
        }
        positive(&k("density"), m.density)?;
        positive(&k("youngs_modulus"), m.youngs_modulus)?;
        finite(&k("poisson_ratio"), m.poisson_ratio)?;
        if !(-1.0 < m.poisson_ratio && m.poisson_ratio < 0.5) {
            return Err((
                k("poisson_ratio"),
                format!("must be in (-1, 0.5), got {}", m.poisson_ratio),
            ));
        }
        plans.push(MaterialPlan {
            density: m.density,
            youngs_modulus: m.youngs_modulus,
            poisson_ratio: m.poisson_ratio,
            law: model_parameters(i, m)?,
        });
    }
    Ok(plans)
}

/// The parameters of one model (`materials[i]`): rejected for the other models; a
/// required one must be > 0, an optional one (default 0) >= 0. Returns the model's
/// law with its parameters.
fn model_parameters(i: usize, m: &MaterialSpec) -> Result<Law, Invalid> {
    let k = |f: &str| format!("materials[{i}].{f}");
    let own = [
        ("yield_stress", m.yield_stress, Model::J2Plastic, true),
        ("hardening", m.hardening, Model::J2Plastic, false),
        ("tensile_strength", m.tensile_strength, Model::Brittle, true),
    ];
    for (key, v, model, required) in own {
        let name = variants::<Model>()[model as usize];
        match v {
            Some(_) if m.model != model => {
                return Err((k(key), format!("is a parameter of model = \"{name}\" only")))
            }
            Some(x) if required => positive(&k(key), x)?,
            Some(x) => {
                finite(&k(key), x)?;
                if x < 0.0 {
                    return Err((k(key), format!("must be >= 0, got {x}")));
                }
            }
            None => {}
        }
    }
    let required = |key: &str, v: Option<f64>| {
        let name = variants::<Model>()[m.model as usize];
        v.ok_or_else(|| (k(key), format!("is required by model = \"{name}\"")))
    };
    Ok(match m.model {
        Model::LinearElastic => Law::LinearElastic,
        Model::NeoHookean => Law::NeoHookean,
        Model::J2Plastic => Law::J2Plastic {
            yield_stress: required("yield_stress", m.yield_stress)?,
            hardening: m.hardening.unwrap_or(0.0),
        },
        Model::Brittle => Law::Brittle {
            tensile_strength: required("tensile_strength", m.tensile_strength)?,
        },
    })
}

/// `[[bodies]]`: at least one, each valid. Returns each body's material index.
fn validate_bodies(s: &Scene) -> Result<Vec<usize>, Invalid> {
    if s.bodies.is_empty() {
        return Err((
            "bodies".into(),
            "at least one [[bodies]] entry is required".into(),
        ));
    }
    s.bodies
        .iter()
        .enumerate()
        .map(|(i, b)| validate_body(s, i, b))
        .collect()
}

/// The kinds of particle the bodies seed (distinct material and particles per cell, in
/// the bodies' order) and each body's kind; at most [`MAX_KINDS`].
fn kinds_of(s: &Scene, body_material: &[usize]) -> Result<(Vec<KindPlan>, Vec<usize>), Invalid> {
    let mut kinds: Vec<KindPlan> = Vec::new();
    let mut index = std::collections::HashMap::new();
    let mut body_kind = Vec::with_capacity(body_material.len());
    for (b, &material) in s.bodies.iter().zip(body_material) {
        let kind = KindPlan {
            material,
            particles_per_cell: b.particles_per_cell,
        };
        body_kind.push(*index.entry(kind).or_insert_with(|| {
            kinds.push(kind);
            kinds.len() - 1
        }));
    }
    if kinds.len() > MAX_KINDS {
        return Err((
            "bodies".into(),
            format!(
                "the bodies seed {} kinds of particle (distinct pairs of material and \
                 particles_per_cell); at most {MAX_KINDS}",
                kinds.len()
            ),
        ));
    }
    Ok((kinds, body_kind))
}

/// `bodies[i]`: a defined material, particles per cell in 1..=16, velocities of `dim`
/// components, a valid shape inside the grid (or cut by slip faces only). Returns its
/// material's index.
fn validate_body(s: &Scene, i: usize, b: &BodySpec) -> Result<usize, Invalid> {
    let k = |f: &str| format!("bodies[{i}].{f}");
    let (d, g) = (s.dim, &s.grid);
    let Some(material) = s.materials.iter().position(|m| m.name == b.material) else {
        let names: Vec<_> = s.materials.iter().map(|m| m.name.as_str()).collect();
        return Err((
            k("material"),
            format!(
                "unknown material {:?}; defined materials: {names:?}",
                b.material
            ),
        ));
    };
    if b.particles_per_cell == 0 {
        return Err((k("particles_per_cell"), "must be >= 1, got 0".into()));
    }
    if b.particles_per_cell > 16 {
        return Err((
            k("particles_per_cell"),
            format!("must be <= 16 per direction, got {}", b.particles_per_cell),
        ));
    }
    if let Some(v) = &b.velocity {
        vector(&k("velocity"), v, d)?;
    }
    if let Some(g) = &b.velocity_gradient {
        if g.value.len() != d {
            return Err((
                k("velocity_gradient.value"),
                format!("must have dim = {d} rows, got {}", g.value.len()),
            ));
        }
        for (r, row) in g.value.iter().enumerate() {
            vector(&k(&format!("velocity_gradient.value[{r}]")), row, d)?;
        }
        if let Some(c) = &g.about {
            vector(&k("velocity_gradient.about"), c, d)?;
        }
    }
    let (blo, bhi) = body_bounds(b, d, &k)?;
    for a in 0..d {
        if bhi[a] <= g.lower[a] || blo[a] >= g.upper[a] {
            return Err((
                k("shape"),
                format!(
                    "the body lies entirely outside the grid on axis {a}: body [{}, {}], grid [{}, {}]",
                    blo[a], bhi[a], g.lower[a], g.upper[a]
                ),
            ));
        }
        // A slip face may cut a body: it is a symmetry plane, and only the part
        // inside the grid is modelled (a quarter of the Taylor bar).
        let tol = 1e-12 * (g.upper[a] - g.lower[a]);
        let out_lo = blo[a] < g.lower[a] - tol && g.boundary.face(a, false) != Face::Slip;
        let out_hi = bhi[a] > g.upper[a] + tol && g.boundary.face(a, true) != Face::Slip;
        if out_lo || out_hi {
            return Err((
                k("shape"),
                format!(
                    "the body sticks out of the grid on axis {a}: body [{}, {}], grid [{}, {}] \
                     (only a slip face, a symmetry plane, may cut a body)",
                    blo[a], bhi[a], g.lower[a], g.upper[a]
                ),
            ));
        }
    }
    Ok(material)
}

/// A body's shape, checked, and its bounding box; `k` names a key of the body.
fn body_bounds(
    b: &BodySpec,
    d: usize,
    k: &dyn Fn(&str) -> String,
) -> Result<(Vec<f64>, Vec<f64>), Invalid> {
    Ok(match &b.shape {
        Shape::Box { lower, upper } => {
            vector(&k("shape.box.lower"), lower, d)?;
            vector(&k("shape.box.upper"), upper, d)?;
            for a in 0..d {
                if lower[a] >= upper[a] {
                    return Err((
                        k("shape.box.upper"),
                        format!(
                            "must be greater than lower on every axis; axis {a}: {} >= {}",
                            lower[a], upper[a]
                        ),
                    ));
                }
            }
            (lower.clone(), upper.clone())
        }
        Shape::Sphere { center, radius } => {
            vector(&k("shape.sphere.center"), center, d)?;
            positive(&k("shape.sphere.radius"), *radius)?;
            (
                center.iter().map(|c| c - radius).collect(),
                center.iter().map(|c| c + radius).collect(),
            )
        }
        Shape::Cylinder { center, radius, z } => {
            if d != 3 {
                return Err((k("shape.cylinder"), "a cylinder needs dim = 3".into()));
            }
            vector(&k("shape.cylinder.center"), center, 2)?;
            positive(&k("shape.cylinder.radius"), *radius)?;
            vector(&k("shape.cylinder.z"), z, 2)?;
            if z[0] >= z[1] {
                return Err((
                    k("shape.cylinder.z"),
                    format!("must be [bottom, top] with bottom < top, got {z:?}"),
                ));
            }
            (
                vec![center[0] - radius, center[1] - radius, z[0]],
                vec![center[0] + radius, center[1] + radius, z[1]],
            )
        }
        Shape::Annulus {
            center,
            inner,
            outer,
        } => {
            vector(&k("shape.annulus.center"), center, d)?;
            if d != 2 {
                return Err((k("shape.annulus"), "an annulus needs dim = 2".into()));
            }
            finite(&k("shape.annulus.inner"), *inner)?;
            positive(&k("shape.annulus.outer"), *outer)?;
            if !(0.0 <= *inner && inner < outer) {
                return Err((
                    k("shape.annulus.inner"),
                    format!("must satisfy 0 <= inner < outer, got inner {inner}, outer {outer}"),
                ));
            }
            (
                center.iter().map(|c| c - outer).collect(),
                center.iter().map(|c| c + outer).collect(),
            )
        }
    })
}

/// `[benchmark]`: its numbers, then what the kind needs of the scene.
fn validate_benchmark_table(s: &Scene) -> Result<Option<BenchmarkPlan>, Invalid> {
    let Some(b) = &s.benchmark else {
        return Ok(None);
    };
    {
        if let Some(a) = b.amplitude {
            finite("benchmark.amplitude", a)?;
        }
        if let Some(c) = b.c {
            positive("benchmark.c", c)?;
        }
        if b.mode == Some(0) {
            return Err(("benchmark.mode".into(), "must be >= 1, got 0".into()));
        }
    }
    validate_benchmark(s, b).map(Some)
}

/// `[output]`: no snapshot keys with `snapshots = false`, an interval that makes a
/// bounded number of snapshots, fields that some material carries.
fn validate_output(s: &Scene) -> Result<(), Invalid> {
    if let Some(o) = &s.output {
        if o.snapshots == Some(false) {
            if let Some(k) = [("every", o.every.is_some()), ("fields", o.fields.is_some())]
                .iter()
                .find(|k| k.1)
            {
                return Err((
                    format!("output.{}", k.0),
                    "is given, but `snapshots = false` writes no snapshots: remove one of the two"
                        .into(),
                ));
            }
        }
        if let Some(every) = o.every {
            interval("output.every", every, s.time.end, "snapshots")?;
        }
        for (i, f) in o.fields.iter().flatten().enumerate() {
            let needs = match f {
                Field::PlasticStrain => Some(Model::J2Plastic),
                Field::Damage => Some(Model::Brittle),
                _ => None,
            };
            if let Some(m) = needs.filter(|m| !s.materials.iter().any(|x| x.model == *m)) {
                return Err((
                    format!("output.fields[{i}]"),
                    format!(
                        "{:?} needs a material with model = \"{}\"; this scene has none",
                        variants::<Field>()[*f as usize],
                        variants::<Model>()[m as usize]
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// `[checkpoint]`: exactly one schedule, each in range, and `keep >= 1`.
fn validate_checkpoint(s: &Scene) -> Result<Option<CheckpointEvery>, Invalid> {
    let Some(c) = &s.checkpoint else {
        return Ok(None);
    };
    {
        let given: Vec<&str> = [
            ("every", c.every.is_some()),
            ("every_steps", c.every_steps.is_some()),
            ("every_seconds", c.every_seconds.is_some()),
        ]
        .iter()
        .filter(|k| k.1)
        .map(|k| k.0)
        .collect();
        if given.len() > 1 {
            return Err((
                format!("checkpoint.{}", given[1]),
                format!(
                    "give only one of `every`, `every_steps`, `every_seconds`, not both `{}` and `{}`",
                    given[0], given[1]
                ),
            ));
        }
        if let Some(t) = c.every {
            interval("checkpoint.every", t, s.time.end, "checkpoints")?;
        }
        if c.every_steps == Some(0) {
            return Err((
                "checkpoint.every_steps".into(),
                "must be >= 1, got 0".into(),
            ));
        }
        if let Some(t) = c.every_seconds {
            positive("checkpoint.every_seconds", t)?;
        }
        if c.keep == 0 {
            return Err((
                "checkpoint.keep".into(),
                "must be >= 1 (the newest checkpoint is always kept), got 0".into(),
            ));
        }
    }
    Ok(Some(match (c.every, c.every_steps, c.every_seconds) {
        (Some(t), _, _) => CheckpointEvery::Time(t),
        (_, Some(n), _) => CheckpointEvery::Steps(n),
        (_, _, Some(s)) => CheckpointEvery::Seconds(s),
        (None, None, None) => return Err((
            "checkpoint".into(),
            "give one of `every` (simulated time), `every_steps` or `every_seconds` (wall clock)"
                .into(),
        )),
    }))
}
