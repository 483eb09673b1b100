//! The checks of what a scene puts on the grid: its materials and their models, its
//! bodies and the kinds of particle they seed, and what a benchmark needs of them.

use super::super::schema::{
    variants, BenchmarkKind, BenchmarkSpec, BodySpec, Face, MaterialSpec, Model, Scene, Seeding,
    Shape, Strain,
};
use super::{finite, positive, vector, Invalid};
use crate::input::plan::{cut_levels, BenchmarkPlan, KindPlan, Law, MaterialPlan, MAX_KINDS};

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
            if b.body_force.is_some() {
                return Err((
                    "benchmark.body_force".into(),
                    "not used by `vibrating_bar`, which has no body force".into(),
                ));
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
                mms_grid(s)?;
                Ok(BenchmarkPlan::AxisAlignedMms {
                    amplitude: b.amplitude.unwrap_or(0.05),
                    c: b.c.unwrap_or(100.0),
                })
            }
        }
    }
}

/// The axis-aligned MMS's grid: [0, 1] per axis between slip faces, or [0, 2] on a
/// periodic axis.
fn mms_grid(s: &Scene) -> Result<(), Invalid> {
    // sin(πX) is exact between slip faces at X = 0 and 1, and periodic with
    // period 2 (its odd extension), so a periodic axis spans [0, 2].
    for a in 0..s.dim {
        let periodic = s.grid.boundary.face(a, false) == Face::Periodic;
        let upper = if periodic { 2.0 } else { 1.0 };
        if s.grid.lower[a] != 0.0 || s.grid.upper[a] != upper {
            let key = if s.grid.lower[a] != 0.0 {
                "grid.lower"
            } else {
                "grid.upper"
            };
            return Err((
                key.into(),
                format!(
                    "`axis_aligned_mms` is posed on [0, 1] per axis between slip faces, or on [0, 2] on a periodic axis (the solution's period); axis {a} spans [{}, {}]{}",
                    s.grid.lower[a],
                    s.grid.upper[a],
                    if periodic { " and is periodic" } else { "" }
                ),
            ));
        }
    }
    Ok(())
}

/// `[[materials]]`: at least one, unique names, elastic constants in range and each
/// model's own parameters, resolved into typed materials.
pub(super) fn validate_materials(s: &Scene) -> Result<Vec<MaterialPlan>, Invalid> {
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
    if m.strain.is_some() && m.model != Model::LinearElastic {
        return Err((
            k("strain"),
            "is a parameter of model = \"linear_elastic\" only".into(),
        ));
    }
    let required = |key: &str, v: Option<f64>| {
        let name = variants::<Model>()[m.model as usize];
        v.ok_or_else(|| (k(key), format!("is required by model = \"{name}\"")))
    };
    Ok(match m.model {
        Model::LinearElastic => Law::LinearElastic {
            small: m.strain == Some(Strain::Small),
        },
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
pub(super) fn validate_bodies(s: &Scene) -> Result<Vec<usize>, Invalid> {
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

/// The kinds of particle the bodies seed (distinct material, particles per cell and
/// share of the lattice box, in the bodies' order), each body's kind of whole boxes and,
/// for a body seeded `cut`, the first of its run of partial kinds; at most [`MAX_KINDS`].
pub(super) fn kinds_of(s: &Scene, body_material: &[usize]) -> Result<BodyKinds, Invalid> {
    let mut kinds: Vec<KindPlan> = Vec::new();
    let mut index = std::collections::HashMap::new();
    let mut add = |kind: KindPlan| {
        *index.entry(kind).or_insert_with(|| {
            kinds.push(kind);
            kinds.len() - 1
        })
    };
    let levels = cut_levels(s.dim);
    let mut body_kind = Vec::with_capacity(body_material.len());
    let mut body_cut_kinds = Vec::with_capacity(body_material.len());
    for (b, &material) in s.bodies.iter().zip(body_material) {
        let kind = |share| KindPlan {
            material,
            particles_per_cell: b.particles_per_cell,
            share,
        };
        body_kind.push(add(kind(levels)));
        // The partial shares enter together, so a run found once is whole and in order.
        body_cut_kinds.push((b.seeding == Seeding::Cut).then(|| {
            let first = add(kind(1));
            (2..levels).for_each(|q| {
                add(kind(q));
            });
            first
        }));
    }
    if kinds.len() > MAX_KINDS {
        return Err((
            "bodies".into(),
            format!(
                "the bodies seed {} kinds of particle (distinct material, \
                 particles_per_cell and, seeded `cut`, share of a box); at most {MAX_KINDS}",
                kinds.len()
            ),
        ));
    }
    Ok(BodyKinds {
        kinds,
        body_kind,
        body_cut_kinds,
    })
}

/// What [`kinds_of`] finds.
pub(super) struct BodyKinds {
    pub kinds: Vec<KindPlan>,
    pub body_kind: Vec<usize>,
    pub body_cut_kinds: Vec<Option<usize>>,
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
pub(super) fn validate_benchmark_table(s: &Scene) -> Result<Option<BenchmarkPlan>, Invalid> {
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
