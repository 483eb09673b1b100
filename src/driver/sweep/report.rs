//! The sweep's tables: one [`Row`] per run, `results.csv`, the observed convergence
//! orders and `report.md`. Pure functions of the rows; nothing here runs the solver.

use std::fmt::Write as _;

/// What a run produced, read from its `summary.json`.
#[derive(Clone, Debug, PartialEq)]
pub struct Stats {
    pub particles: u64,
    pub steps: u64,
    pub wall_seconds: f64,
    pub particle_updates_per_second: f64,
    /// Maximum over the run of the volume-weighted particle L2 norms (NaN if absent).
    pub displacement_l2: f64,
    pub velocity_l2: f64,
}

/// One run of the sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    pub gradient: String,
    /// Cells along the first axis (the sweep's resolution parameter `n`).
    pub cells: usize,
    pub ranks: usize,
    pub threads: usize,
    /// `completed`, `unstable` (the run's own status) or `failed` (no summary).
    pub status: String,
    /// Why the run was unstable or failed.
    pub message: Option<String>,
    /// `None` when the run failed before writing a summary.
    pub stats: Option<Stats>,
}

impl Row {
    pub fn completed(&self) -> bool {
        self.status == "completed"
    }
}

pub const CSV_HEADER: &str = "gradient,cells,particles,ranks,threads,steps,wall_seconds,\
particle_updates_per_second,status,displacement_l2,velocity_l2";

/// `results.csv`: the header and one line per row; floats in shortest round-trip
/// exponent form, empty fields where a failed run has no value.
pub fn csv(rows: &[Row]) -> String {
    let mut s = String::from(CSV_HEADER);
    s.push('\n');
    for r in rows {
        let _ = write!(s, "{},{},", r.gradient, r.cells);
        match &r.stats {
            Some(st) => {
                let _ = write!(s, "{},", st.particles);
                let _ = write!(s, "{},{},", r.ranks, r.threads);
                let _ = write!(
                    s,
                    "{},{:e},{:e},{},{:e},{:e}",
                    st.steps,
                    st.wall_seconds,
                    st.particle_updates_per_second,
                    r.status,
                    st.displacement_l2,
                    st.velocity_l2
                );
            }
            None => {
                let _ = write!(s, ",{},{},,,,{},,", r.ranks, r.threads, r.status);
            }
        }
        s.push('\n');
    }
    s
}

/// Observed convergence orders `log(e_coarse/e_fine) / log(n_fine/n_coarse)` for points
/// sorted by increasing `n`. Entry `i` compares point `i` with the nearest earlier
/// usable point; points whose error is `None`, non-finite or not positive are skipped
/// and get `None`, as does the first usable point.
pub fn orders(points: &[(usize, Option<f64>)]) -> Vec<Option<f64>> {
    let usable = |e: Option<f64>| e.filter(|e| e.is_finite() && *e > 0.0);
    let mut prev: Option<(usize, f64)> = None;
    points
        .iter()
        .map(|&(n, e)| {
            let e = usable(e)?;
            let order = prev
                .filter(|&(pn, _)| pn < n)
                .map(|(pn, pe)| (pe / e).ln() / (n as f64 / pn as f64).ln());
            prev = Some((n, e));
            order
        })
        .collect()
}

/// The rows of one gradient, in the order given (the sweep sorts by `cells`).
pub fn rows_of<'a>(rows: &'a [Row], gradient: &str) -> Vec<&'a Row> {
    rows.iter().filter(|r| r.gradient == gradient).collect()
}

/// Error norms of usable (completed) runs, for [`orders`].
fn norm_points(rows: &[&Row], norm: fn(&Stats) -> f64) -> Vec<(usize, Option<f64>)> {
    rows.iter()
        .map(|r| {
            let e = r.stats.as_ref().filter(|_| r.completed()).map(norm);
            (r.cells, e)
        })
        .collect()
}

fn cell<T>(x: Option<T>, f: impl Fn(T) -> String) -> String {
    x.map_or_else(|| "–".to_string(), f)
}

/// Everything `report.md` says besides the rows.
pub struct ReportHeader<'a> {
    pub scene: &'a str,
    /// The command line that produced the sweep.
    pub command: &'a str,
    /// Further lines under the header (scene facts: grids, particles per cell).
    pub notes: &'a [String],
}

/// `report.md`: a short header, then per gradient (in `gradients` order) a table of the
/// runs with the observed order of each error norm against the previous resolution.
pub fn markdown(head: &ReportHeader, gradients: &[&str], rows: &[Row]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Speed against error: `{}`\n", head.scene);
    let _ = writeln!(s, "Produced by:\n\n    {}\n", head.command);
    for n in head.notes {
        let _ = writeln!(s, "- {n}");
    }
    let _ = writeln!(
        s,
        "- Errors: volume-weighted particle L2 norms, maximum over the run. Order: \
         `log(e_coarse/e_fine) / log(n_fine/n_coarse)` against the previous completed \
         resolution.\n- Plots: `error_vs_cells.svg`, `error_vs_wall_time.svg`; data: \
         `results.csv`.\n"
    );
    for g in gradients {
        let rs = rows_of(rows, g);
        let ou = orders(&norm_points(&rs, |s| s.displacement_l2));
        let ov = orders(&norm_points(&rs, |s| s.velocity_l2));
        let _ = writeln!(s, "## {g}\n");
        let _ = writeln!(
            s,
            "| cells | particles | ranks | threads | steps | wall_seconds | \
             particle_updates_per_second | status | displacement_l2 | order | velocity_l2 | order |"
        );
        let _ = writeln!(
            s,
            "|---:|---:|---:|---:|---:|---:|---:|:---|---:|---:|---:|---:|"
        );
        for (i, r) in rs.iter().enumerate() {
            let st = r.stats.as_ref();
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                r.cells,
                cell(st, |s| s.particles.to_string()),
                r.ranks,
                r.threads,
                cell(st, |s| s.steps.to_string()),
                cell(st, |s| format!("{:.3e}", s.wall_seconds)),
                cell(st, |s| format!("{:.3e}", s.particle_updates_per_second)),
                r.status,
                cell(st, |s| format!("{:.4e}", s.displacement_l2)),
                cell(ou[i], |o| format!("{o:.2}")),
                cell(st, |s| format!("{:.4e}", s.velocity_l2)),
                cell(ov[i], |o| format!("{o:.2}")),
            );
        }
        let notes: Vec<_> = rs
            .iter()
            .filter_map(|r| r.message.as_ref().map(|m| (r, m)))
            .collect();
        if !notes.is_empty() {
            s.push('\n');
            for (r, m) in notes {
                let _ = writeln!(s, "- {} cells, {}: {}", r.cells, r.status, m.trim());
            }
        }
        s.push('\n');
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(g: &str, n: usize, status: &str, e: f64) -> Row {
        Row {
            gradient: g.into(),
            cells: n,
            ranks: 1,
            threads: 2,
            status: status.into(),
            message: (status != "completed").then(|| format!("{status} at step 7")),
            stats: Some(Stats {
                particles: 2 * n as u64,
                steps: 10 * n as u64,
                wall_seconds: 1e-3 * n as f64,
                particle_updates_per_second: 1.5e6,
                displacement_l2: e,
                velocity_l2: 3.0 * e,
            }),
        }
    }

    #[test]
    fn errors_proportional_to_n_power_give_that_order() {
        let pts: Vec<_> = [8usize, 16, 32, 64]
            .iter()
            .map(|&n| (n, Some(7.0 * (n as f64).powi(-2))))
            .collect();
        let o = orders(&pts);
        assert_eq!(o[0], None);
        for x in &o[1..] {
            assert!((x.unwrap() - 2.0).abs() < 1e-12, "{o:?}");
        }
        // Unequal ratios and a fractional order.
        let pts: Vec<_> = [10usize, 30, 70]
            .iter()
            .map(|&n| (n, Some(0.3 * (n as f64).powf(-1.5))))
            .collect();
        for x in &orders(&pts)[1..] {
            assert!((x.unwrap() - 1.5).abs() < 1e-12);
        }
    }

    #[test]
    fn orders_skip_unusable_points_and_use_the_real_ratio() {
        let e = |n: usize| Some((n as f64).powi(-2));
        let pts = vec![
            (8, e(8)),
            (16, None),
            (32, e(32)),
            (64, Some(f64::NAN)),
            (128, Some(0.0)),
        ];
        let o = orders(&pts);
        assert_eq!(o.len(), 5);
        assert_eq!(o[0], None);
        assert_eq!(o[1], None);
        // 32 against 8: a ratio of 4 in n, 16 in error.
        assert!((o[2].unwrap() - 2.0).abs() < 1e-12);
        assert_eq!(o[3], None);
        assert_eq!(o[4], None);
        // A stalled error gives order 0, a growing one a negative order.
        let o = orders(&[(8, Some(1e-3)), (16, Some(1e-3)), (32, Some(2e-3))]);
        assert_eq!(o[1], Some(0.0));
        assert!((o[2].unwrap() + 1.0).abs() < 1e-12);
    }

    #[test]
    fn csv_has_the_exact_header_and_round_trips_values() {
        let failed = Row {
            stats: None,
            message: Some("cannot run on 4 ranks".into()),
            ..row("gimp", 4, "failed", 0.0)
        };
        let rows = vec![
            row("mpm", 8, "completed", 1.234_567_890_123e-4),
            row("mpm", 16, "unstable", f64::NAN),
            failed,
        ];
        let text = csv(&rows);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[0],
            "gradient,cells,particles,ranks,threads,steps,wall_seconds,\
             particle_updates_per_second,status,displacement_l2,velocity_l2"
        );
        assert_eq!(lines.len(), 4);
        assert!(text.ends_with('\n'));
        for (line, r) in lines[1..].iter().zip(&rows) {
            let f: Vec<&str> = line.split(',').collect();
            assert_eq!(f.len(), 11, "{line}");
            assert_eq!(f[0], r.gradient);
            assert_eq!(f[1].parse::<usize>().unwrap(), r.cells);
            assert_eq!(f[3].parse::<usize>().unwrap(), r.ranks);
            assert_eq!(f[4].parse::<usize>().unwrap(), r.threads);
            assert_eq!(f[8], r.status);
            match &r.stats {
                Some(st) => {
                    assert_eq!(f[2].parse::<u64>().unwrap(), st.particles);
                    assert_eq!(f[5].parse::<u64>().unwrap(), st.steps);
                    assert_eq!(f[6].parse::<f64>().unwrap(), st.wall_seconds);
                    assert_eq!(f[7].parse::<f64>().unwrap(), st.particle_updates_per_second);
                    let (u, v) = (f[9].parse::<f64>().unwrap(), f[10].parse::<f64>().unwrap());
                    if st.displacement_l2.is_nan() {
                        assert!(u.is_nan() && v.is_nan());
                    } else {
                        assert_eq!(u, st.displacement_l2);
                        assert_eq!(v, st.velocity_l2);
                    }
                }
                None => {
                    for k in [2, 5, 6, 7, 9, 10] {
                        assert_eq!(f[k], "", "field {k} of {line}");
                    }
                }
            }
        }
    }

    #[test]
    fn report_has_a_table_per_gradient_with_orders() {
        let rows = vec![
            row("mpm", 8, "completed", 1e-2),
            row("mpm", 16, "completed", 2.5e-3),
            row("mpm", 32, "unstable", 9.0),
            row("mpmcg", 8, "completed", 4e-3),
            row("mpmcg", 16, "completed", 2e-3),
        ];
        let head = ReportHeader {
            scene: "bar",
            command: "mpmcg sweep bar.toml --cells 8,16,32",
            notes: &["Grids: 8 → [8]".to_string()],
        };
        let md = markdown(&head, &["mpm", "mpmcg"], &rows);
        assert!(md.contains("mpmcg sweep bar.toml --cells 8,16,32"));
        assert_eq!(md.matches("\n## ").count(), 2);
        let table = |g: &str| -> Vec<Vec<String>> {
            let start = md.find(&format!("## {g}\n")).unwrap();
            md[start..]
                .lines()
                .skip_while(|l| !l.starts_with("| cells"))
                .skip(2)
                .take_while(|l| l.starts_with('|'))
                .map(|l| l.split('|').map(|c| c.trim().to_string()).collect())
                .collect()
        };
        let mpm = table("mpm");
        assert_eq!(mpm.len(), 3);
        // Columns: "", cells, particles, ranks, threads, steps, wall, pups, status, u,
        // order_u, v, order_v, "".
        assert_eq!(mpm[0][1], "8");
        assert_eq!(mpm[0][10], "–");
        assert_eq!(mpm[1][10], "2.00");
        assert_eq!(mpm[1][12], "2.00");
        assert_eq!(mpm[2][8], "unstable");
        assert_eq!(mpm[2][10], "–");
        assert!(md.contains("- 32 cells, unstable: unstable at step 7"));
        let cg = table("mpmcg");
        assert_eq!(cg.len(), 2);
        assert_eq!(cg[1][10], "1.00");
    }
}
