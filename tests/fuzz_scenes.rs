//! A small fuzz test of scene input: every scene in `inputs/`, mutated many times at
//! random (deterministic seeds), goes through what `mpmcg check` does (parsing,
//! validation, the bodies' seeding check). Each mutated scene must be accepted or
//! refused with an error, never panic: a panic reachable from a scene file would be
//! exit 101 instead of a clear exit 2. The number of cases is printed
//! (`cargo test --test fuzz_scenes -- --nocapture`).

#![forbid(unsafe_code)]

use mpmcg::driver::run::check_bodies;
use mpmcg::input::scene::parse;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// xorshift64*: reproducible, no dependency.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Values that have broken parsers and numerics elsewhere.
const NASTY: [&str; 16] = [
    "0",
    "-1",
    "0.0",
    "-0.0",
    "1e308",
    "-1e308",
    "1e-308",
    "nan",
    "inf",
    "-inf",
    "18446744073709551616",
    "9223372036854775807",
    "\"\"",
    "[]",
    "[[]]",
    "{}",
];

/// One random edit of a scene's text: a number replaced by a nasty value, a line
/// deleted, duplicated or swapped with another, the text cut short, or a character
/// inserted.
fn mutate(text: &str, rng: &mut Rng) -> String {
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    if lines.is_empty() {
        // An earlier edit cut the text to nothing: edit one empty line.
        lines.push(String::new());
    }
    let k = rng.below(lines.len());
    match rng.below(6) {
        0 => {
            // Replace the first number-looking token of line k.
            let line = &lines[k];
            let start = line.find(|c: char| c.is_ascii_digit() || c == '-');
            if let Some(s) = start {
                let end = line[s..]
                    .find(|c: char| !(c.is_ascii_alphanumeric() || ".-+".contains(c)))
                    .map_or(line.len(), |e| s + e);
                let v = NASTY[rng.below(NASTY.len())];
                lines[k] = format!("{}{}{}", &line[..s], v, &line[end..]);
            }
        }
        1 => {
            lines.remove(k);
        }
        2 => {
            let l = lines[k].clone();
            lines.insert(k, l);
        }
        3 => {
            let j = rng.below(lines.len());
            lines.swap(k, j);
        }
        4 => {
            let joined = lines.join("\n");
            let mut cut = rng.below(joined.len());
            while !joined.is_char_boundary(cut) {
                cut -= 1;
            }
            return joined[..cut].to_string();
        }
        _ => {
            let line = &lines[k];
            let mut at = rng.below(line.len() + 1);
            while !line.is_char_boundary(at) {
                at -= 1;
            }
            let c = ['=', '[', ']', '{', '}', '"', ',', '#', '\0', 'é'][rng.below(10)];
            lines[k] = format!("{}{}{}", &line[..at], c, &line[at..]);
        }
    }
    lines.join("\n") + "\n"
}

#[test]
fn mutated_scenes_never_panic() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("inputs");
    let mut scenes: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    scenes.sort();
    assert!(scenes.len() >= 5);
    let (mut cases, mut accepted) = (0usize, 0usize);
    for (i, path) in scenes.iter().enumerate() {
        let text = std::fs::read_to_string(path).unwrap();
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ (i as u64 + 1));
        for round in 0..400 {
            // One to three edits on top of each other.
            let mut t = text.clone();
            for _ in 0..1 + round % 3 {
                t = mutate(&t, &mut rng);
            }
            let outcome = catch_unwind(AssertUnwindSafe(|| {
                parse(&t, "fuzz.toml").map(|s| check_bodies(&s).is_ok())
            }));
            match outcome {
                Ok(Ok(true)) => accepted += 1,
                Ok(_) => {}
                Err(_) => panic!(
                    "{} mutated (round {round}) panics the scene check:\n{t}",
                    path.display()
                ),
            }
            cases += 1;
        }
    }
    eprintln!("{cases} mutated scenes checked, {accepted} accepted, none panicked");
    // Mutations are not all fatal (a duplicated comment line, a harmless number): the
    // fuzz reaches validation and the seeding check, not only the TOML parser.
    assert!(accepted > cases / 20, "{accepted} of {cases} accepted");
}
