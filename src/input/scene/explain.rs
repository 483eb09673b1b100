//! Serde's deserialisation errors explained in the scene's words: the full key, where
//! it is in the text, what was given and what the key expects.

use super::schema::{
    variants, BenchmarkKind, Boundary, Face, Field, Gradient, Model, Quadrature, Shape, Update,
};

/// The most bytes of a message's key or text (which quote the input) printed.
const MAX_QUOTE: usize = 1000;

/// 1-based line and column (in characters) of a byte offset.
pub(super) fn line_col(text: &str, offset: usize) -> (usize, usize) {
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
pub(super) fn one_line(s: &str) -> String {
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
pub(super) fn locate(text: &str, key: &str) -> Option<usize> {
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

/// The variants allowed at a key path whose value is an enum (indices written `[]`).
fn choices(key: &str) -> Option<&'static [&'static str]> {
    Some(match key {
        "method.gradient" => variants::<Gradient>(),
        "method.update" => variants::<Update>(),
        "method.quadrature" => variants::<Quadrature>(),
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
pub(super) fn explain(
    text: &str,
    path: &serde_path_to_error::Path,
    inner: &toml::de::Error,
) -> Explained {
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
