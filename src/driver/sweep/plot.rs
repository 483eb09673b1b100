//! Log–log line plots as hand-written SVG: one polyline with markers per series,
//! dashed reference slopes, a legend, axes with labelled decades (and 2 and 5 between
//! them when the axis spans at most two decades), a title. The output is a standalone
//! SVG 1.1 document that any browser opens.
//!
//! Not `plotters`: its text layout needs font files (its `ttf` feature: font-kit with
//! fontconfig and freetype, or a bundled font) even to write SVG, where a browser lays
//! out the text anyway; these plots need log axes, markers and a legend, a few hundred
//! lines with tests.

use std::fmt::Write as _;

/// One scheme's curve: `(x, y)` points in the order they are joined. Points with a
/// coordinate that is not finite and positive cannot be shown on log axes and are left
/// out.
#[derive(Clone, Debug)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// A dashed line `y ∝ x^slope` to compare the curves' slopes with (convergence orders).
#[derive(Clone, Debug)]
pub struct Reference {
    pub name: String,
    pub slope: f64,
}

#[derive(Clone, Debug)]
pub struct Plot<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub series: &'a [Series],
    pub references: &'a [Reference],
}

const WIDTH: f64 = 760.0;
const HEIGHT: f64 = 500.0;
const LEFT: f64 = 90.0;
const RIGHT: f64 = 170.0;
const TOP: f64 = 50.0;
const BOTTOM: f64 = 70.0;
const COLOURS: [&str; 6] = [
    "#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b",
];

fn usable(p: &(f64, f64)) -> bool {
    p.0.is_finite() && p.0 > 0.0 && p.1.is_finite() && p.1 > 0.0
}

/// A logarithmic axis spanning whole decades `10^lo ..= 10^hi`, drawn from pixel `from`
/// (at `10^lo`) to pixel `to` (at `10^hi`).
#[derive(Clone, Copy, Debug)]
struct Axis {
    lo: i32,
    hi: i32,
    from: f64,
    to: f64,
}

impl Axis {
    /// The smallest whole-decade range holding every value (at least one decade).
    fn fit(values: impl Iterator<Item = f64>, from: f64, to: f64) -> Self {
        let (mut min, mut max) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in values {
            min = min.min(v);
            max = max.max(v);
        }
        let (lo, mut hi) = if min <= max {
            (
                (min.log10() + 1e-9).floor() as i32,
                (max.log10() - 1e-9).ceil() as i32,
            )
        } else {
            (0, 1)
        };
        if hi <= lo {
            hi = lo + 1;
        }
        Self { lo, hi, from, to }
    }

    fn map(&self, v: f64) -> f64 {
        let f = (v.log10() - f64::from(self.lo)) / f64::from(self.hi - self.lo);
        self.from + f * (self.to - self.from)
    }

    fn decades(&self) -> impl Iterator<Item = i32> {
        self.lo..=self.hi
    }

    /// Minor ticks `m · 10^k`, m = 2..9, inside the range.
    fn minors(&self) -> impl Iterator<Item = f64> + '_ {
        (self.lo..self.hi).flat_map(|k| (2..10).map(move |m| f64::from(m) * 10f64.powi(k)))
    }

    /// Labelled values `(m, k)` for `m · 10^k`: the decades, and 2 and 5 between them
    /// when the axis spans at most two decades (a sweep's 8–64 cells or 1–30 s of wall
    /// time would otherwise show one or two labels).
    fn labelled(&self) -> Vec<(u32, i32)> {
        let mut v: Vec<(u32, i32)> = self.decades().map(|k| (1, k)).collect();
        if self.hi - self.lo <= 2 {
            v.extend((self.lo..self.hi).flat_map(|k| [(2, k), (5, k)]));
        }
        v
    }

    /// `m · 10^k` as a plain number while the axis's numbers stay short, else with a
    /// power of ten.
    fn label(&self, m: u32, k: i32) -> String {
        if self.lo >= -3 && self.hi <= 4 {
            if k >= 0 {
                format!("{m}{}", "0".repeat(k as usize))
            } else {
                format!("0.{}{m}", "0".repeat((-k - 1) as usize))
            }
        } else {
            let exp = if k < 0 {
                format!("\u{2212}{}", -k)
            } else {
                k.to_string()
            };
            let mant = if m == 1 {
                String::new()
            } else {
                format!("{m}\u{00d7}")
            };
            format!("{mant}10<tspan dy=\"-7\" font-size=\"9\">{exp}</tspan>")
        }
    }
}

/// Text for SVG character data and attribute values.
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            _ => o.push(c),
        }
    }
    o
}

/// A marker of shape `k` (circle, square, diamond, triangle) at `(x, y)` with a tooltip.
fn marker(k: usize, x: f64, y: f64, colour: &str, tip: &str) -> String {
    let r = 4.0;
    let shape = match k % 4 {
        0 => format!("<circle cx=\"{x:.2}\" cy=\"{y:.2}\" r=\"{r}\""),
        1 => format!(
            "<rect x=\"{:.2}\" y=\"{:.2}\" width=\"{}\" height=\"{}\"",
            x - r,
            y - r,
            2.0 * r,
            2.0 * r
        ),
        2 => format!(
            "<polygon points=\"{x:.2},{:.2} {:.2},{y:.2} {x:.2},{:.2} {:.2},{y:.2}\"",
            y - 1.3 * r,
            x + 1.3 * r,
            y + 1.3 * r,
            x - 1.3 * r
        ),
        _ => format!(
            "<polygon points=\"{x:.2},{:.2} {:.2},{:.2} {:.2},{:.2}\"",
            y - 1.3 * r,
            x + 1.2 * r,
            y + 0.9 * r,
            x - 1.2 * r,
            y + 0.9 * r
        ),
    };
    let tag = shape[1..].split(' ').next().unwrap_or("circle").to_string();
    format!(
        "{shape} fill=\"{colour}\" stroke=\"white\" stroke-width=\"0.8\"><title>{}</title></{tag}>",
        escape(tip)
    )
}

/// The ends of a reference line of `slope` across the x range of the series. It starts
/// [`REFERENCE_BELOW`] times below the lowest of the series' first (smallest x) points,
/// so that it runs beside the curves rather than hiding one of the same slope. `None`
/// without two distinct plottable x values.
pub fn reference_ends(series: &[Series], slope: f64) -> Option<[(f64, f64); 2]> {
    let all = || {
        series
            .iter()
            .flat_map(|s| s.points.iter().copied().filter(usable))
    };
    let lo = all().map(|p| p.0).min_by(f64::total_cmp)?;
    let hi = all().map(|p| p.0).max_by(f64::total_cmp)?;
    if lo == hi {
        return None;
    }
    let (ax, ay) = series
        .iter()
        .filter_map(|s| {
            s.points
                .iter()
                .copied()
                .filter(usable)
                .min_by(|a, b| a.0.total_cmp(&b.0))
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    let y = |x: f64| ay / REFERENCE_BELOW * (x / ax).powf(slope);
    Some([(lo, y(lo)), (hi, y(hi))])
}

/// How far below the lowest first point the reference lines start.
const REFERENCE_BELOW: f64 = 2.0;
/// Dash patterns of the reference lines, in order.
const DASHES: [&str; 2] = ["6 4", "2 3"];

/// The SVG document of a log–log plot.
pub fn loglog(plot: &Plot) -> String {
    let refs: Vec<(&Reference, [(f64, f64); 2])> = plot
        .references
        .iter()
        .filter_map(|r| reference_ends(plot.series, r.slope).map(|e| (r, e)))
        .collect();
    // The axes hold the reference lines too.
    let pts = || {
        plot.series
            .iter()
            .flat_map(|s| s.points.iter().copied().filter(usable))
            .chain(refs.iter().flat_map(|(_, e)| e.iter().copied()))
    };
    let f = Frame::new(|| pts().map(|p| p.0), || pts().map(|p| p.1));
    let mut s = String::new();
    header(&mut s, plot, &f);
    grid_and_ticks(&mut s, &f);
    labels(&mut s, plot, &f);
    reference_lines(&mut s, &refs, &f);
    curves(&mut s, plot, &f);
    legend(&mut s, plot, &refs, &f);
    let _ = writeln!(s, "</svg>");
    s
}

/// The plot area (`x0..x1` left to right, `y0..y1` top to bottom) and its two axes.
struct Frame {
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    xa: Axis,
    ya: Axis,
}

impl Frame {
    fn new<X, Y>(xs: impl Fn() -> X, ys: impl Fn() -> Y) -> Self
    where
        X: Iterator<Item = f64>,
        Y: Iterator<Item = f64>,
    {
        let (x0, x1) = (LEFT, WIDTH - RIGHT);
        let (y0, y1) = (TOP, HEIGHT - BOTTOM);
        Frame {
            x0,
            x1,
            y0,
            y1,
            xa: Axis::fit(xs(), x0, x1),
            ya: Axis::fit(ys(), y1, y0),
        }
    }
}

/// XML declaration, `svg` element, background and title.
fn header(s: &mut String, plot: &Plot, f: &Frame) {
    let _ = writeln!(s, "<?xml version=\"1.0\" encoding=\"UTF-8\"?>");
    let _ = writeln!(
        s,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" version=\"1.1\" width=\"{WIDTH}\" \
         height=\"{HEIGHT}\" viewBox=\"0 0 {WIDTH} {HEIGHT}\" font-family=\"sans-serif\" \
         font-size=\"12\">"
    );
    let title = escape(plot.title);
    let _ = writeln!(s, "<title>{title}</title>");
    let _ = writeln!(
        s,
        "<rect width=\"{WIDTH}\" height=\"{HEIGHT}\" fill=\"white\"/>"
    );
    let _ = writeln!(
        s,
        "<text x=\"{:.1}\" y=\"28\" text-anchor=\"middle\" font-size=\"16\" \
         font-weight=\"bold\">{title}</text>",
        (f.x0 + f.x1) / 2.0
    );
}

/// Vertical lines at `xs` from `ya` to `yb` and horizontal lines at `ys` from `xa` to
/// `xb`, each with `attrs` (coordinates of the ends given as already formatted text).
fn cross_lines(
    s: &mut String,
    f: &Frame,
    (xs, ys): (&[f64], &[f64]),
    (ya, yb, xa, xb): (&str, &str, &str, &str),
    attrs: &str,
) {
    for &v in xs {
        let x = f.xa.map(v);
        let _ = writeln!(
            s,
            "<line x1=\"{x:.2}\" y1=\"{ya}\" x2=\"{x:.2}\" y2=\"{yb}\"{attrs}/>"
        );
    }
    for &v in ys {
        let y = f.ya.map(v);
        let _ = writeln!(
            s,
            "<line x1=\"{xa}\" y1=\"{y:.2}\" x2=\"{xb}\" y2=\"{y:.2}\"{attrs}/>"
        );
    }
}

/// Grid lines (light at minor values, darker at decades), the frame, and tick marks.
fn grid_and_ticks(s: &mut String, f: &Frame) {
    let minors: (Vec<f64>, Vec<f64>) = (f.xa.minors().collect(), f.ya.minors().collect());
    let decade = |a: &Axis| a.decades().map(|k| 10f64.powi(k)).collect::<Vec<f64>>();
    let decades = (decade(&f.xa), decade(&f.ya));
    let (x0, x1, y0, y1) = (
        f.x0.to_string(),
        f.x1.to_string(),
        f.y0.to_string(),
        f.y1.to_string(),
    );
    let _ = writeln!(s, "<g class=\"grid\" stroke-width=\"1\">");
    let across = (y0.as_str(), y1.as_str(), x0.as_str(), x1.as_str());
    cross_lines(s, f, (&minors.0, &[]), across, " stroke=\"#eeeeee\"");
    cross_lines(s, f, (&[], &minors.1), across, " stroke=\"#eeeeee\"");
    cross_lines(s, f, (&decades.0, &[]), across, " stroke=\"#cccccc\"");
    cross_lines(s, f, (&[], &decades.1), across, " stroke=\"#cccccc\"");
    let _ = writeln!(s, "</g>");
    let _ = writeln!(
        s,
        "<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"black\"/>",
        f.x0,
        f.y0,
        f.x1 - f.x0,
        f.y1 - f.y0
    );
    let _ = writeln!(s, "<g class=\"ticks\" stroke=\"black\">");
    for (len, (xs, ys)) in [(4.0, &minors), (8.0, &decades)] {
        let (ye, xe) = (format!("{:.1}", f.y1 - len), format!("{:.1}", f.x0 + len));
        let ends = (y1.as_str(), ye.as_str(), x0.as_str(), xe.as_str());
        cross_lines(s, f, (xs, &[]), ends, "");
        cross_lines(s, f, (&[], ys), ends, "");
    }
    let _ = writeln!(s, "</g>");
}

/// Tick labels and axis titles.
fn labels(s: &mut String, plot: &Plot, f: &Frame) {
    let _ = writeln!(s, "<g class=\"tick-labels\">");
    for (m, k) in f.xa.labelled() {
        let _ = writeln!(
            s,
            "<text x=\"{:.2}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
            f.xa.map(f64::from(m) * 10f64.powi(k)),
            f.y1 + 20.0,
            f.xa.label(m, k)
        );
    }
    for (m, k) in f.ya.labelled() {
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.2}\" text-anchor=\"end\">{}</text>",
            f.x0 - 8.0,
            f.ya.map(f64::from(m) * 10f64.powi(k)) + 4.0,
            f.ya.label(m, k)
        );
    }
    let _ = writeln!(s, "</g>");
    let _ = writeln!(
        s,
        "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\" font-size=\"14\">{}</text>",
        (f.x0 + f.x1) / 2.0,
        HEIGHT - 22.0,
        escape(plot.x_label)
    );
    let (lx, ly) = (24.0, (f.y0 + f.y1) / 2.0);
    let _ = writeln!(
        s,
        "<text x=\"{lx}\" y=\"{ly:.1}\" transform=\"rotate(-90 {lx} {ly:.1})\" \
         text-anchor=\"middle\" font-size=\"14\">{}</text>",
        escape(plot.y_label)
    );
}

/// Reference slopes, drawn first so that the curves lie on top.
fn reference_lines(s: &mut String, refs: &[(&Reference, [(f64, f64); 2])], f: &Frame) {
    let _ = writeln!(s, "<g class=\"reference\" stroke=\"#777777\">");
    for (j, (r, [a, b])) in refs.iter().enumerate() {
        let _ = writeln!(
            s,
            "<line x1=\"{:.2}\" y1=\"{:.2}\" x2=\"{:.2}\" y2=\"{:.2}\" stroke-width=\"1.2\" stroke-dasharray=\"{}\"><title>{}</title></line>",
            f.xa.map(a.0),
            f.ya.map(a.1),
            f.xa.map(b.0),
            f.ya.map(b.1),
            DASHES[j % DASHES.len()],
            escape(&r.name)
        );
    }
    let _ = writeln!(s, "</g>");
}

/// One polyline with markers per series.
fn curves(s: &mut String, plot: &Plot, f: &Frame) {
    for (i, ser) in plot.series.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        let name = escape(&ser.name);
        let shown: Vec<(f64, f64)> = ser.points.iter().copied().filter(usable).collect();
        let coords: Vec<String> = shown
            .iter()
            .map(|&(x, y)| format!("{:.2},{:.2}", f.xa.map(x), f.ya.map(y)))
            .collect();
        let _ = writeln!(s, "<g class=\"series\">");
        let _ = writeln!(
            s,
            "<polyline points=\"{}\" fill=\"none\" stroke=\"{colour}\" stroke-width=\"2\"><title>{name}</title></polyline>",
            coords.join(" ")
        );
        for &(x, y) in &shown {
            let tip = format!("{}: x = {x:.4e}, y = {y:.4e}", ser.name);
            let _ = writeln!(s, "{}", marker(i, f.xa.map(x), f.ya.map(y), colour, &tip));
        }
        let _ = writeln!(s, "</g>");
    }
}

/// The legend right of the plot: the series, then the reference slopes.
fn legend(s: &mut String, plot: &Plot, refs: &[(&Reference, [(f64, f64); 2])], f: &Frame) {
    let _ = writeln!(s, "<g class=\"legend\">");
    let lx = f.x1 + 16.0;
    for (i, ser) in plot.series.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        let y = f.y0 + 14.0 + 22.0 * i as f64;
        let _ = writeln!(
            s,
            "<line x1=\"{lx}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"{colour}\" stroke-width=\"2\"/>",
            lx + 28.0
        );
        let _ = writeln!(s, "{}", marker(i, lx + 14.0, y, colour, &ser.name));
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\">{}</text>",
            lx + 36.0,
            y + 4.0,
            escape(&ser.name)
        );
    }
    for (j, (r, _)) in refs.iter().enumerate() {
        let y = f.y0 + 14.0 + 22.0 * (plot.series.len() + j) as f64;
        let _ = writeln!(
            s,
            "<line x1=\"{lx}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"#777777\" stroke-width=\"1.2\" stroke-dasharray=\"{}\"/>",
            lx + 28.0,
            DASHES[j % DASHES.len()]
        );
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\">{}</text>",
            lx + 36.0,
            y + 4.0,
            escape(&r.name)
        );
    }
    let _ = writeln!(s, "</g>");
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Checks the document is well-formed in the sense that matters here: one XML
    /// declaration, then properly nested and balanced elements under a single `svg`
    /// root, quoted attributes, no stray `<` or `&` in text. Returns the element names
    /// in document order.
    pub(crate) fn check_xml(doc: &str) -> Vec<String> {
        let body = doc
            .strip_prefix("<?xml version=\"1.0\" encoding=\"UTF-8\"?>")
            .expect("XML declaration first");
        let mut stack: Vec<String> = Vec::new();
        let mut names = Vec::new();
        let mut roots = 0;
        let mut rest = body;
        while let Some(i) = rest.find('<') {
            let text = &rest[..i];
            assert!(!text.contains('>'), "stray '>' in text {text:?}");
            for (j, _) in text.match_indices('&') {
                let ent = &text[j..];
                assert!(
                    ["&amp;", "&lt;", "&gt;", "&quot;"]
                        .iter()
                        .any(|e| ent.starts_with(e)),
                    "bare '&' in {text:?}"
                );
            }
            if stack.is_empty() {
                assert!(text.trim().is_empty(), "text outside the root: {text:?}");
            }
            let end = rest[i..].find('>').expect("unterminated tag") + i;
            let tag = &rest[i + 1..end];
            assert!(!tag.contains('<'), "'<' inside tag {tag:?}");
            assert_eq!(
                tag.matches('"').count() % 2,
                0,
                "unbalanced quotes in {tag:?}"
            );
            if let Some(name) = tag.strip_prefix('/') {
                let open = stack
                    .pop()
                    .unwrap_or_else(|| panic!("</{name}> closes nothing"));
                assert_eq!(open, name.trim(), "</{name}> closes <{open}>");
            } else {
                let name = tag.split_whitespace().next().unwrap().trim_end_matches('/');
                assert!(!name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric()));
                if stack.is_empty() {
                    roots += 1;
                    assert_eq!(name, "svg", "root element");
                }
                names.push(name.to_string());
                if !tag.ends_with('/') {
                    stack.push(name.to_string());
                }
            }
            rest = &rest[end + 1..];
        }
        assert!(stack.is_empty(), "unclosed elements {stack:?}");
        assert!(rest.trim().is_empty(), "trailing text {rest:?}");
        assert_eq!(roots, 1);
        names
    }

    /// The `points` of every polyline, as pixel coordinates.
    pub(crate) fn polylines(doc: &str) -> Vec<Vec<(f64, f64)>> {
        doc.match_indices("<polyline points=\"")
            .map(|(i, m)| {
                let start = i + m.len();
                let end = start + doc[start..].find('"').unwrap();
                doc[start..end]
                    .split_whitespace()
                    .map(|p| {
                        let (x, y) = p.split_once(',').unwrap();
                        (x.parse().unwrap(), y.parse().unwrap())
                    })
                    .collect()
            })
            .collect()
    }

    fn example() -> Vec<Series> {
        let curve = |name: &str, c: f64, p: i32| Series {
            name: name.into(),
            points: [8.0, 16.0, 32.0, 64.0]
                .iter()
                .map(|&n: &f64| (n, c * n.powi(-p)))
                .collect(),
        };
        vec![
            curve("mpm", 1.0, 1),
            curve("gimp", 0.5, 2),
            curve("mpmcg & <co>", 0.2, 2),
        ]
    }

    #[test]
    fn svg_is_well_formed_with_one_polyline_per_series() {
        let series = example();
        let doc = loglog(&Plot {
            title: "error \"vs\" cells",
            x_label: "cells",
            y_label: "displacement L2 error",
            series: &series,
            references: &[],
        });
        let names = check_xml(&doc);
        assert_eq!(names.iter().filter(|n| *n == "polyline").count(), 3);
        assert_eq!(
            polylines(&doc).iter().map(Vec::len).collect::<Vec<_>>(),
            [4, 4, 4]
        );
        // 12 data markers and 3 legend markers, each with a tooltip.
        let markers = names
            .iter()
            .filter(|n| ["circle", "rect", "polygon"].contains(&n.as_str()))
            .count();
        assert_eq!(
            markers,
            12 + 3 + 2,
            "markers plus background and frame rects"
        );
        assert!(doc.contains("mpmcg &amp; &lt;co&gt;"));
        assert!(doc.contains("<title>error &quot;vs&quot; cells</title>"));
        assert!(doc.contains(">cells</text>") && doc.contains(">displacement L2 error</text>"));
    }

    #[test]
    fn coordinates_are_log_scaled_and_monotone() {
        let series = example();
        let doc = loglog(&Plot {
            title: "t",
            x_label: "x",
            y_label: "y",
            series: &series,
            references: &[],
        });
        for line in polylines(&doc) {
            for w in line.windows(2) {
                // Larger n further right, smaller error further down (SVG y grows down).
                assert!(w[1].0 > w[0].0 && w[1].1 > w[0].1, "{line:?}");
            }
            // n doubles and e ∝ n^-p: equal steps in log n and in log e, so equal
            // pixel steps on both axes.
            let dx: Vec<f64> = line.windows(2).map(|w| w[1].0 - w[0].0).collect();
            let dy: Vec<f64> = line.windows(2).map(|w| w[1].1 - w[0].1).collect();
            for k in 1..dx.len() {
                assert!((dx[k] - dx[0]).abs() < 0.02, "{dx:?}");
                assert!((dy[k] - dy[0]).abs() < 0.02, "{dy:?}");
            }
        }
        // The slopes in decades: mpm (order 1) and gimp (order 2) share both axes, so
        // gimp's pixel drop per step is twice mpm's.
        let lines = polylines(&doc);
        let drop = |l: &Vec<(f64, f64)>| l[1].1 - l[0].1;
        assert!((drop(&lines[1]) / drop(&lines[0]) - 2.0).abs() < 1e-3);
        // Decades 1..100 on x: the points sit inside the frame.
        for l in &lines {
            for &(x, y) in l {
                assert!((LEFT..=WIDTH - RIGHT).contains(&x));
                assert!((TOP..=HEIGHT - BOTTOM).contains(&y));
            }
        }
        assert!(doc.contains(">10</text>") && doc.contains(">100</text>"));
    }

    #[test]
    fn reference_lines_have_their_slope_below_the_first_points() {
        let series = example();
        for slope in [-1.0, -2.0, -2.0 / 3.0] {
            let [a, b] = reference_ends(&series, slope).unwrap();
            assert_eq!((a.0, b.0), (8.0, 64.0));
            let measured = (b.1 / a.1).log10() / (b.0 / a.0).log10();
            assert!((measured - slope).abs() < 1e-12, "{measured} {slope}");
            // Half the lowest first point (mpmcg's 0.2/64 at 8 cells).
            assert!((a.1 - 0.2 / 64.0 / 2.0).abs() < 1e-15, "{a:?}");
        }
        let refs = [
            Reference {
                name: "order 1".into(),
                slope: -1.0,
            },
            Reference {
                name: "order 2".into(),
                slope: -2.0,
            },
        ];
        let doc = loglog(&Plot {
            title: "t",
            x_label: "cells",
            y_label: "e",
            series: &series,
            references: &refs,
        });
        check_xml(&doc);
        // Two dashed lines with their legend entries, inside the frame.
        let group = doc.split("<g class=\"reference\"").nth(1).unwrap();
        let group = &group[..group.find("</g>").unwrap()];
        assert_eq!(group.matches("<line ").count(), 2);
        for name in ["order 1", "order 2"] {
            assert!(doc.contains(&format!(">{name}</text>")), "{name}");
        }
        // A series with a single x has no slope to compare with.
        let one = vec![Series {
            name: "s".into(),
            points: vec![(8.0, 1e-2)],
        }];
        assert!(reference_ends(&one, -1.0).is_none());
    }

    #[test]
    fn narrow_axes_label_2_and_5_between_decades() {
        let series = example();
        let doc = loglog(&Plot {
            title: "t",
            x_label: "cells",
            y_label: "e",
            series: &series,
            references: &[],
        });
        // x spans 1–100: 2, 5, 20 and 50 labelled too; y spans 1e-5–1 (5 decades):
        // decades only.
        for label in [">2</text>", ">5</text>", ">20</text>", ">50</text>"] {
            assert!(doc.contains(label), "{label}");
        }
        assert!(doc.contains(">0.001</text>") || doc.contains("\u{2212}3</tspan>"));
        assert!(!doc.contains(">0.002</text>") && !doc.contains("2\u{00d7}10"));
    }

    #[test]
    fn unplottable_points_are_left_out_and_far_decades_use_powers() {
        let series = vec![Series {
            name: "s".into(),
            points: vec![(1e-6, 1e-9), (0.0, 1.0), (1e-5, f64::NAN), (1e-4, 1e-12)],
        }];
        let doc = loglog(&Plot {
            title: "t",
            x_label: "wall time [s]",
            y_label: "e",
            series: &series,
            references: &[],
        });
        check_xml(&doc);
        assert_eq!(polylines(&doc)[0].len(), 2);
        assert!(doc.contains("10<tspan dy=\"-7\" font-size=\"9\">\u{2212}12</tspan>"));
        // An empty series still gets its (empty) polyline and legend entry.
        let series = vec![Series {
            name: "none".into(),
            points: vec![],
        }];
        let doc = loglog(&Plot {
            title: "t",
            x_label: "x",
            y_label: "y",
            series: &series,
            references: &[],
        });
        check_xml(&doc);
        assert_eq!(polylines(&doc), vec![Vec::<(f64, f64)>::new()]);
    }
}
