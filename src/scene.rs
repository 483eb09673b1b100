//! Scene files: TOML, parsed with `deny_unknown_fields` and validated before anything
//! runs. Every error names the file, the key (with line and column when they are
//! known) and what was expected.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;

/// The built-in scene `mpmcg run` uses when no scene file is given.
pub const DEFAULT_SCENE: &str = include_str!("../inputs/default.toml");
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
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    pub name: String,
    pub model: Model,
    pub density: f64,
    pub youngs_modulus: f64,
    pub poisson_ratio: f64,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    Box { lower: Vec<f64>, upper: Vec<f64> },
    /// A disk in 2D, an interval in 1D.
    Sphere { center: Vec<f64>, radius: f64 },
    /// The ring `inner <= |x - center| <= outer` (2D).
    Annulus {
        center: Vec<f64>,
        inner: f64,
        outer: f64,
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
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Output {
    /// Simulated time between snapshots.
    pub every: f64,
    #[serde(default)]
    pub fields: Vec<Field>,
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

/// 1-based line and column of a byte offset.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |s| s.chars().count()) + 1;
    (line, col)
}

/// Byte offset of the value at a dotted key path like `materials[0].density`.
fn locate(text: &str, key: &str) -> Option<usize> {
    use toml::de::{DeTable, DeValue};
    fn walk(t: &DeTable, parts: &[&str]) -> Option<usize> {
        let (part, rest) = parts.split_first()?;
        let (name, idx) = match part.find('[') {
            Some(i) => (&part[..i], part[i + 1..part.len() - 1].parse::<usize>().ok()),
            None => (*part, None),
        };
        let mut v = t.iter().find(|(k, _)| k.get_ref() == name)?.1;
        if let Some(i) = idx {
            match v.get_ref() {
                DeValue::Array(a) => v = a.get(i)?,
                _ => return None,
            }
        }
        if rest.is_empty() {
            return Some(v.span().start);
        }
        match v.get_ref() {
            DeValue::Table(inner) => walk(inner, rest).or(Some(v.span().start)),
            _ => Some(v.span().start),
        }
    }
    let doc = DeTable::parse(text).ok()?;
    let parts: Vec<&str> = key.split('.').collect();
    walk(doc.get_ref(), &parts)
}

/// Parse and validate a scene. `file` is used in messages only.
pub fn parse(text: &str, file: &str) -> Result<Scene, SceneError> {
    let err = |key: Option<String>, pos: Option<usize>, message: String| SceneError {
        file: file.to_string(),
        key,
        line_col: pos.map(|p| line_col(text, p)),
        message,
    };
    if text.trim().is_empty() {
        return Err(err(
            None,
            None,
            "the file is empty; a scene needs at least `name`, `dim`, [time], [grid], [[materials]] and [[bodies]]".into(),
        ));
    }
    let de = toml::Deserializer::parse(text).map_err(|e| {
        err(
            None,
            e.span().map(|s| s.start),
            format!("not valid TOML: {}", e.message()),
        )
    })?;
    let scene: Scene = serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.inner();
        let key = if path == "." || path.is_empty() {
            None
        } else {
            Some(path)
        };
        let pos = inner.span().map(|s| s.start);
        err(key, pos, inner.message().to_string())
    })?;
    validate(&scene).map_err(|(key, message)| {
        let pos = locate(text, &key);
        err(Some(key), pos, message)
    })?;
    Ok(scene)
}

/// Read, parse and validate a scene file.
pub fn load(path: &Path) -> Result<(Scene, String), SceneError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| SceneError {
        file: file.clone(),
        key: None,
        line_col: None,
        message: format!("cannot read the scene file: {e}"),
    })?;
    let text = String::from_utf8(bytes).map_err(|e| SceneError {
        file: file.clone(),
        key: None,
        line_col: None,
        message: format!(
            "not a text file (invalid UTF-8 at byte {}); a scene is a TOML file",
            e.utf8_error().valid_up_to()
        ),
    })?;
    let scene = parse(&text, &file)?;
    Ok((scene, text))
}

type Invalid = (String, String);

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
            format!(
                "must have dim = {dim} components, got {} ({v:?})",
                v.len()
            ),
        ));
    }
    for (i, &x) in v.iter().enumerate() {
        finite(&format!("{key}[{i}]"), x)?;
    }
    Ok(())
}

fn validate(s: &Scene) -> Result<(), Invalid> {
    let d = s.dim;
    if !(1..=3).contains(&d) {
        return Err(("dim".into(), format!("must be 1, 2 or 3, got {d}")));
    }
    if s.name.trim().is_empty()
        || s
            .name
            .chars()
            .any(|c| !(c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.'))
    {
        return Err((
            "name".into(),
            format!(
                "must be a non-empty name of letters, digits, `_`, `-` or `.` (it names the output folder), got {:?}",
                s.name
            ),
        ));
    }
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
        (None, Some(dt)) => positive("time.dt", dt)?,
        (None, None) => {}
    }
    finite("method.flip", s.method.flip)?;
    if !(0.0..=1.0).contains(&s.method.flip) {
        return Err((
            "method.flip".into(),
            format!("must be in [0, 1] (1 = FLIP, 0 = PIC), got {}", s.method.flip),
        ));
    }
    let g = &s.grid;
    vector("grid.lower", &g.lower, d)?;
    vector("grid.upper", &g.upper, d)?;
    if g.cells.len() != d {
        return Err((
            "grid.cells".into(),
            format!("must have dim = {d} components, got {}", g.cells.len()),
        ));
    }
    for a in 0..d {
        if g.cells[a] == 0 {
            return Err((format!("grid.cells[{a}]"), "must be >= 1, got 0".into()));
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
            return Err((
                format!("grid.boundary.{}", Boundary::KEYS[2 * a]),
                "periodic faces come in pairs: set both faces of the axis to `periodic`".into(),
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
    if s.materials.is_empty() {
        return Err((
            "materials".into(),
            "at least one [[materials]] entry is required".into(),
        ));
    }
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
    }
    if s.bodies.is_empty() {
        return Err((
            "bodies".into(),
            "at least one [[bodies]] entry is required".into(),
        ));
    }
    for (i, b) in s.bodies.iter().enumerate() {
        let k = |f: &str| format!("bodies[{i}].{f}");
        if !s.materials.iter().any(|m| m.name == b.material) {
            let names: Vec<_> = s.materials.iter().map(|m| m.name.as_str()).collect();
            return Err((
                k("material"),
                format!(
                    "unknown material {:?}; defined materials: {names:?}",
                    b.material
                ),
            ));
        }
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
        let (blo, bhi) = match &b.shape {
            Shape::Box { lower, upper } => {
                vector(&k("shape.box.lower"), lower, d)?;
                vector(&k("shape.box.upper"), upper, d)?;
                for a in 0..d {
                    if lower[a] >= upper[a] {
                        return Err((
                            k("shape.box.upper"),
                            format!("must be greater than lower on every axis; axis {a}: {} >= {}", lower[a], upper[a]),
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
        };
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
            if blo[a] < g.lower[a] - 1e-12 * (g.upper[a] - g.lower[a])
                || bhi[a] > g.upper[a] + 1e-12 * (g.upper[a] - g.lower[a])
            {
                return Err((
                    k("shape"),
                    format!(
                        "the body sticks out of the grid on axis {a}: body [{}, {}], grid [{}, {}]",
                        blo[a], bhi[a], g.lower[a], g.upper[a]
                    ),
                ));
            }
        }
    }
    if let Some(b) = &s.benchmark {
        if let Some(a) = b.amplitude {
            finite("benchmark.amplitude", a)?;
        }
        if let Some(c) = b.c {
            positive("benchmark.c", c)?;
        }
        if b.mode == Some(0) {
            return Err(("benchmark.mode".into(), "must be >= 1, got 0".into()));
        }
        crate::benchmark::validate(s, b)?;
    }
    if let Some(gr) = &s.gravity {
        vector("gravity.value", &gr.value, d)?;
    }
    if let Some(o) = &s.output {
        positive("output.every", o.every)?;
    }
    Ok(())
}
