//! Snapshots say what their numbers mean: the material names behind the `material`
//! index, the units, and the symmetry planes of a scene that models part of a body,
//! as HDF5 attributes of every snapshot and as XDMF `Information` elements.

#![forbid(unsafe_code)]

mod common;

use hdf5::types::VarLenUnicode;
use mpmcg::output::io::Labels;

/// A quarter disk of "steel" cut by the slip faces x = 0 and y = 0, and a box of
/// "rubber"; the materials are listed in the other order than the bodies.
const SCENE: &str = r#"name = "labels"
dim = 2
[time]
end = 0.01
cfl = 0.3
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [10, 10]
boundary = { x_lower = "slip", y_lower = "slip" }
[[materials]]
name = "rubber"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1.0e6
poisson_ratio = 0.3
[[materials]]
name = "steel"
model = "linear_elastic"
density = 7800.0
youngs_modulus = 2.0e8
poisson_ratio = 0.3
[[bodies]]
material = "steel"
shape = { sphere = { center = [0.0, 0.0], radius = 0.4 } }
[[bodies]]
material = "rubber"
shape = { box = { lower = [0.6, 0.6], upper = [0.9, 0.9] } }
"#;

fn text_attr(f: &hdf5::File, name: &str) -> String {
    f.attr(name)
        .unwrap_or_else(|e| panic!("attribute {name}: {e}"))
        .read_scalar::<VarLenUnicode>()
        .unwrap()
        .to_string()
}

#[test]
fn snapshots_name_materials_units_and_symmetry_planes() {
    let (_, out) = common::run_text(SCENE, "labels");
    let snaps = common::files(&out, "particles_");
    assert_eq!(snaps.len(), 2);
    for path in &snaps {
        let f = hdf5::File::open(path).unwrap();
        let names: Vec<String> = f
            .attr("material_names")
            .unwrap()
            .read_raw::<VarLenUnicode>()
            .unwrap()
            .iter()
            .map(|s| s.to_string())
            .collect();
        assert_eq!(names, ["rubber", "steel"]);
        // The index names each particle's material: the quarter disk is steel.
        let mat: Vec<i64> = f.dataset("material").unwrap().read_raw().unwrap();
        let x: Vec<f64> = f.dataset("position").unwrap().read_raw().unwrap();
        for (p, &m) in mat.iter().enumerate() {
            let expect = if x[3 * p] < 0.5 { "steel" } else { "rubber" };
            assert_eq!(names[m as usize], expect, "particle {p}");
        }
        assert_eq!(text_attr(&f, "units"), "SI");
        let sym = text_attr(&f, "symmetry");
        assert!(sym.starts_with("x = 0, y = 0: "), "{sym}");
    }
    let xmf = std::fs::read_to_string(out.join("particles.xmf")).unwrap();
    for info in [
        "<Information Name=\"material_names\" Value=\"0: rubber; 1: steel\"/>",
        "<Information Name=\"units\" Value=\"SI\"/>",
        "<Information Name=\"symmetry\" Value=\"x = 0, y = 0: ",
    ] {
        assert!(xmf.contains(info), "{info} missing:\n{xmf}");
    }
    let _ = std::fs::remove_dir_all(&out);
}

/// The scenes in inputs/: the benchmarks are dimensionless, the others SI; the Taylor
/// bar, a quarter model, is the one scene cut by symmetry planes.
#[test]
fn input_scenes_are_labelled() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/inputs");
    let mut seen = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_none_or(|x| x != "toml") {
            continue;
        }
        let (s, _) = mpmcg::input::scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
        let l = match s.dim {
            1 => Labels::of::<1>(&s),
            2 => Labels::of::<2>(&s),
            _ => Labels::of::<3>(&s),
        };
        let name = p.file_stem().unwrap().to_string_lossy().into_owned();
        let units = if s.benchmark.is_some() {
            "dimensionless"
        } else {
            "SI"
        };
        assert_eq!(l.units, units, "{name}");
        let names: Vec<&str> = s.materials.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(l.materials, names, "{name}");
        let planes = (name == "taylor_bar").then(|| "x = 0, y = 0".to_string());
        assert_eq!(l.symmetry_planes, planes, "{name}");
        seen += 1;
    }
    assert!(seen >= 11, "{seen} scenes");
}
