//! Statistics, Markdown tables and SVG line plots for the bench reports.

use anyhow::Context;
use plotters::prelude::*;
use std::path::Path;

/// The `q`-quantile (0 ≤ q ≤ 1) of `v` by the nearest-rank method; 0 when empty.
pub fn quantile(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let rank = (q.clamp(0.0, 1.0) * s.len() as f64).ceil() as usize;
    s[rank.clamp(1, s.len()) - 1]
}

/// The median of `v` (the lower middle value for even lengths); 0 when empty.
pub fn median(v: &[f64]) -> f64 {
    quantile(v, 0.5)
}

/// A Markdown table.
pub fn table(header: &[&str], rows: &[Vec<String>]) -> String {
    let mut out = format!("| {} |\n|{}\n", header.join(" | "), "---|".repeat(header.len()));
    for r in rows {
        out.push_str(&format!("| {} |\n", r.join(" | ")));
    }
    out
}

/// One line of a plot.
pub struct Series {
    /// Legend text.
    pub name: String,
    /// Points, in x order.
    pub points: Vec<(f64, f64)>,
    /// Colour index into a fixed palette.
    pub color: usize,
    /// Dashed (reference lines such as "ideal" or "paper").
    pub dashed: bool,
}

const PALETTE: [RGBColor; 8] = [
    RGBColor(0x1f, 0x77, 0xb4),
    RGBColor(0xd6, 0x27, 0x28),
    RGBColor(0x2c, 0xa0, 0x2c),
    RGBColor(0xff, 0x7f, 0x0e),
    RGBColor(0x94, 0x67, 0xbd),
    RGBColor(0x8c, 0x56, 0x4b),
    RGBColor(0x7f, 0x7f, 0x7f),
    RGBColor(0x17, 0xbe, 0xcf),
];

/// Draws `series` as an SVG line plot with point markers (no fonts needed:
/// text is written as SVG `<text>` and drawn by whatever shows the file).
/// With `x_names`, x = 0, 1, 2, … are categories named by it.
pub fn line_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    x_names: Option<&[&str]>,
) -> anyhow::Result<()> {
    let pts = series.iter().flat_map(|s| s.points.iter());
    let (mut x1, mut y1) = (1.0f64, 1.0f64);
    for &(x, y) in pts {
        x1 = x1.max(x);
        y1 = y1.max(y);
    }
    // Categories sit on whole numbers with a margin; numbers start at 0.
    let x_range = match x_names {
        Some(names) => -0.3..(names.len().max(1) - 1) as f64 + 0.3,
        None => 0.0..x1 * 1.05,
    };
    let root = SVGBackend::new(path, (760, 480)).into_drawing_area();
    let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("cannot draw {}: {e}", path.display());
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(x_range, 0.0..y1 * 1.08)
        .map_err(|e| err(&e))?;
    let name_of = |x: &f64| -> String {
        match x_names {
            Some(names) if (x - x.round()).abs() < 1e-6 && *x >= 0.0 => {
                names.get(x.round() as usize).map_or(String::new(), |s| s.to_string())
            }
            Some(_) => String::new(),
            None => format!("{x}"),
        }
    };
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(x_label).y_desc(y_label).light_line_style(WHITE.mix(0.0)).x_label_formatter(&name_of);
    if let Some(names) = x_names {
        mesh.x_labels(names.len());
    }
    mesh.draw().map_err(|e| err(&e))?;
    for s in series {
        let color = PALETTE[s.color % PALETTE.len()];
        let style = color.stroke_width(2);
        let drawn = if s.dashed {
            chart.draw_series(DashedLineSeries::new(s.points.iter().copied(), 6, 4, style))
        } else {
            chart.draw_series(LineSeries::new(s.points.iter().copied(), style))
        }
        .map_err(|e| err(&e))?;
        drawn.label(s.name.as_str()).legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], style));
        if !s.dashed {
            chart
                .draw_series(s.points.iter().map(|&p| Circle::new(p, 3, color.filled())))
                .map_err(|e| err(&e))?;
        }
    }
    chart
        .configure_series_labels()
        .position(if x_names.is_some() {
            SeriesLabelPosition::UpperRight
        } else {
            SeriesLabelPosition::UpperLeft
        })
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

/// Writes a bench's outputs into `dir`: `STEM.json` (the report, when
/// `json`; a redraw from `--from-json` skips it), `STEM.md` and `STEM.svg`
/// (drawn by `plot`), and prints the table.
pub fn write_outputs(
    dir: &Path,
    stem: &str,
    report: &impl serde::Serialize,
    json: bool,
    md: &str,
    plot: impl FnOnce(&Path) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    if json {
        write(&dir.join(format!("{stem}.json")), &serde_json::to_string_pretty(report)?)?;
    }
    write(&dir.join(format!("{stem}.md")), md)?;
    plot(&dir.join(format!("{stem}.svg")))?;
    println!("\n{md}");
    println!("wrote {stem}.json, {stem}.md and {stem}.svg in {}", dir.display());
    Ok(())
}

/// Writes `text` to `path`, creating the directory.
pub fn write(path: &Path, text: &str) -> anyhow::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_by_nearest_rank() {
        let v = [5.0, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(median(&v), 3.0);
        assert_eq!(quantile(&v, 0.95), 5.0);
        assert_eq!(quantile(&v, 0.0), 1.0);
        assert_eq!(median(&[]), 0.0);
        let hundred: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&hundred, 0.99), 99.0);
    }

    #[test]
    fn markdown_table_has_a_separator_per_column() {
        let t = table(&["a", "b"], &[vec!["1".into(), "2".into()]]);
        assert_eq!(t, "| a | b |\n|---|---|\n| 1 | 2 |\n");
    }

    #[test]
    fn plot_writes_an_svg_with_every_series_named() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.svg");
        let series = vec![
            Series { name: "measured".into(), points: vec![(1.0, 1.0), (2.0, 1.9)], color: 0, dashed: false },
            Series { name: "ideal".into(), points: vec![(1.0, 1.0), (2.0, 2.0)], color: 6, dashed: true },
        ];
        line_plot(&p, "t", "x", "y", &series, None).unwrap();
        line_plot(&p, "t", "x", "y", &series, Some(&["zero", "first", "second"])).unwrap();
        let svg = std::fs::read_to_string(&p).unwrap();
        assert!(["zero", "first", "second"].iter().all(|c| svg.contains(c)), "category labels missing");
        let svg = std::fs::read_to_string(&p).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("measured") && svg.contains("ideal"));
    }
}
