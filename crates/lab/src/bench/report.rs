//! Statistics, Markdown tables and SVG line plots for the bench reports.

use anyhow::Context;
use plotters::coord::Shift;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
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
    /// Legend text, in plain words (what a reader of the plot needs, no
    /// option names).
    pub name: String,
    /// Points, in x order.
    pub points: Vec<(f64, f64)>,
    /// Colour index into a fixed palette.
    pub color: usize,
    /// Dashed (reference lines such as "ideal" or "paper", or a second
    /// family of lines such as QUIC beside TLS over TCP).
    pub dashed: bool,
}

/// How the y axis maps values.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum YScale {
    /// Evenly spaced values, from 0.
    Linear,
    /// Evenly spaced powers of ten: for series that differ by orders of
    /// magnitude (points at or below 0 are left out).
    Log,
}

impl YScale {
    /// [`YScale::Log`] when the positive y values of `series` span more than
    /// a factor of 10, else [`YScale::Linear`].
    pub fn fitting(series: &[Series]) -> YScale {
        let ys = series.iter().flat_map(|s| s.points.iter().map(|p| p.1)).filter(|&y| y > 0.0);
        let (lo, hi) = ys.fold((f64::INFINITY, 0.0f64), |(lo, hi), y| (lo.min(y), hi.max(y)));
        if hi > 10.0 * lo { YScale::Log } else { YScale::Linear }
    }
}

/// A line plot, as [`line_plot`] draws it.
pub struct Plot<'a> {
    /// Heading above the plot.
    pub title: &'a str,
    /// What the x axis counts, with its unit.
    pub x_label: &'a str,
    /// What the y axis measures, with its unit (`line_plot` adds "log scale"
    /// when it is one).
    pub y_label: &'a str,
    /// Linear or logarithmic y axis.
    pub y_scale: YScale,
    /// With names, x = 0, 1, 2, … are categories named by them.
    pub x_names: Option<&'a [&'a str]>,
    /// The lines.
    pub series: &'a [Series],
}

/// Width of the plotting part of a plot's SVG, in pixels; the legend is
/// drawn to the right of it, outside the data.
pub const PLOT_WIDTH: u32 = 640;
const HEIGHT: u32 = 480;
const LEGEND_FONT: u32 = 16;
const LEGEND_ROW: i32 = 26;

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

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// Draws `plot` as an SVG line plot with point markers into `path`: the
/// plotting area on the left with labelled axes, the legend to its right
/// (outside the data, so it never hides a line). No fonts are needed: text
/// is written as SVG `<text>` and drawn by whatever shows the file.
pub fn line_plot(path: &Path, plot: &Plot) -> anyhow::Result<()> {
    let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("cannot draw {}: {e}", path.display());
    let longest = plot.series.iter().map(|s| s.name.chars().count()).max().unwrap_or(0) as u32;
    // Room for 0.55 em per character, as wide as common sans-serif fonts run (the SVG's
    // font sizes are 1/1.24 of plotters'), so that no viewer cuts a name off.
    let legend_width = (longest * LEGEND_FONT * 55 / 124 + 60).clamp(160, 640);
    let root = SVGBackend::new(path, (PLOT_WIDTH + legend_width, HEIGHT)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let body = root.titled(plot.title, ("sans-serif", 22)).map_err(|e| err(&e))?;
    let (chart_area, legend_area) = body.split_horizontally(PLOT_WIDTH);

    let (mut x1, mut y0, mut y1) = (1.0f64, f64::INFINITY, 1.0f64);
    for &(x, y) in plot.series.iter().flat_map(|s| s.points.iter()) {
        x1 = x1.max(x);
        y1 = y1.max(y);
        if y > 0.0 {
            y0 = y0.min(y);
        }
    }
    // Categories sit on whole numbers with a margin; numbers start at 0.
    let x_range = match plot.x_names {
        Some(names) => -0.3..(names.len().max(1) - 1) as f64 + 0.3,
        None => 0.0..x1 * 1.05,
    };
    let mut builder = ChartBuilder::on(&chart_area);
    builder.margin(12).margin_right(24).x_label_area_size(54).y_label_area_size(72);
    match plot.y_scale {
        YScale::Linear => {
            let chart = builder.build_cartesian_2d(x_range, 0.0..y1 * 1.08).map_err(|e| err(&e))?;
            draw_lines(chart, plot, plot.y_label.to_string()).map_err(|e| err(&e))?;
        }
        YScale::Log => {
            let y0 = if y0.is_finite() { y0 } else { 1.0 };
            let range = (y0 / 1.5..y1 * 1.5).log_scale();
            let chart = builder.build_cartesian_2d(x_range, range).map_err(|e| err(&e))?;
            draw_lines(chart, plot, format!("{} (log scale)", plot.y_label)).map_err(|e| err(&e))?;
        }
    }
    draw_legend(&legend_area, plot.series).map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

/// The axes, the grid and the lines, on either kind of y axis.
fn draw_lines<'a, Y>(
    mut chart: ChartContext<'a, SVGBackend<'a>, Cartesian2d<RangedCoordf64, Y>>,
    plot: &Plot,
    y_label: String,
) -> Result<(), DrawingAreaErrorKind<std::io::Error>>
where
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let name_of = |x: &f64| -> String {
        match plot.x_names {
            Some(names) if (x - x.round()).abs() < 1e-6 && *x >= 0.0 => {
                names.get(x.round() as usize).map_or(String::new(), |s| s.to_string())
            }
            Some(_) => String::new(),
            None => compact(*x),
        }
    };
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(plot.x_label)
        .y_desc(y_label)
        .axis_desc_style(("sans-serif", 18))
        .label_style(("sans-serif", 15))
        .light_line_style(WHITE.mix(0.0))
        .bold_line_style(BLACK.mix(0.12))
        .x_label_formatter(&name_of)
        .y_label_formatter(&|y: &f64| compact(*y));
    if let Some(names) = plot.x_names {
        mesh.x_labels(names.len());
    }
    mesh.draw()?;
    let log = plot.y_scale == YScale::Log;
    for s in plot.series {
        let color = PALETTE[s.color % PALETTE.len()];
        let style = color.stroke_width(2);
        let points: Vec<(f64, f64)> = s.points.iter().copied().filter(|p| !log || p.1 > 0.0).collect();
        if s.dashed {
            chart.draw_series(DashedLineSeries::new(points.iter().copied(), 6, 4, style))?;
        } else {
            chart.draw_series(LineSeries::new(points.iter().copied(), style))?;
        }
        chart.draw_series(points.iter().map(|&p| Circle::new(p, 3, color.filled())))?;
    }
    Ok(())
}

/// A tick value with at most two decimals and no trailing zeros: 0.6, 2, 12.5.
fn compact(v: f64) -> String {
    let s = format!("{v:.2}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// One row per series: a sample of its line and its name.
fn draw_legend(area: &Area, series: &[Series]) -> Result<(), DrawingAreaErrorKind<std::io::Error>> {
    for (i, s) in series.iter().enumerate() {
        let y = 40 + i as i32 * LEGEND_ROW;
        let color = PALETTE[s.color % PALETTE.len()];
        let style = color.stroke_width(2);
        if s.dashed {
            for x in [4, 16, 28] {
                area.draw(&PathElement::new([(x, y), (x + 7, y)], style))?;
            }
        } else {
            area.draw(&PathElement::new([(4, y), (36, y)], style))?;
        }
        area.draw(&Circle::new((20, y), 3, color.filled()))?;
        let font = ("sans-serif", LEGEND_FONT).into_font().color(&BLACK);
        area.draw(&Text::new(s.name.as_str(), (44, y - LEGEND_FONT as i32 / 2), font))?;
    }
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

/// Writes a bench's outputs without a plot into `dir`: `STEM.json` (the
/// report) and `STEM.md`, and prints the table.
pub fn write_json_md(dir: &Path, stem: &str, report: &impl serde::Serialize, md: &str) -> anyhow::Result<()> {
    write(&dir.join(format!("{stem}.json")), &serde_json::to_string_pretty(report)?)?;
    write(&dir.join(format!("{stem}.md")), md)?;
    println!("\n{md}");
    println!("wrote {stem}.json and {stem}.md in {}", dir.display());
    Ok(())
}

/// Seconds since 1970 now, for a report's date.
pub fn unix_time() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs())
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

    /// The `x` attribute of every SVG `<text>` element whose text is `text`.
    fn text_xs(svg: &str, text: &str) -> Vec<f64> {
        svg.split("<text ")
            .skip(1)
            .filter_map(|el| {
                let (attrs, rest) = el.split_once('>')?;
                let body = rest.split("</text>").next()?.trim();
                (body == text).then(|| attr(&format!(" {attrs}"), "x")).flatten()
            })
            .collect()
    }

    fn attr(attrs: &str, name: &str) -> Option<f64> {
        attrs.split(&format!(" {name}=\"")).nth(1)?.split('"').next()?.parse().ok()
    }

    /// The `cy` of every point marker in the plotting area (not the
    /// legend's), in drawing order.
    fn marker_ys(svg: &str) -> Vec<f64> {
        svg.split("<circle ")
            .skip(1)
            .map(|el| format!(" {el}"))
            .filter(|el| attr(el, "cx").is_some_and(|x| x < PLOT_WIDTH as f64))
            .filter_map(|el| attr(&el, "cy"))
            .collect()
    }

    fn line(name: &str, points: &[(f64, f64)], dashed: bool) -> Series {
        Series { name: name.into(), points: points.to_vec(), color: 0, dashed }
    }

    #[test]
    fn plot_labels_its_axes_and_puts_every_legend_entry_outside_the_data() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.svg");
        let series = [
            line("measured speedup", &[(1.0, 1.0), (2.0, 1.9)], false),
            line("ideal (linear)", &[(1.0, 1.0), (2.0, 2.0)], true),
        ];
        let plot = Plot {
            title: "Speedup",
            x_label: "slave PCs (N)",
            y_label: "speedup (frames/s ÷ frames/s of one PC)",
            y_scale: YScale::Linear,
            x_names: None,
            series: &series,
        };
        line_plot(&p, &plot).unwrap();
        let svg = std::fs::read_to_string(&p).unwrap();
        assert!(svg.starts_with("<svg"));
        for label in [plot.x_label, plot.y_label, plot.title] {
            assert_eq!(text_xs(&svg, label).len(), 1, "axis label or title `{label}` missing");
        }
        for s in &series {
            let xs = text_xs(&svg, &s.name);
            assert_eq!(xs.len(), 1, "legend entry `{}` missing", s.name);
            assert!(
                xs[0] >= PLOT_WIDTH as f64,
                "legend entry `{}` at x = {} is inside the plot",
                s.name,
                xs[0]
            );
        }
        assert!(!svg.contains("log scale"), "a linear axis is not called logarithmic");

        let names = ["0 %", "0.1 %", "1 %"];
        line_plot(&p, &Plot { x_names: Some(&names), ..plot }).unwrap();
        let svg = std::fs::read_to_string(&p).unwrap();
        assert!(names.iter().all(|c| text_xs(&svg, c).len() == 1), "category labels missing");
    }

    #[test]
    fn a_log_axis_spaces_powers_of_ten_evenly() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.svg");
        let series = [line("frames/s", &[(0.0, 1.0), (1.0, 10.0), (2.0, 100.0)], false)];
        let plot = Plot {
            title: "t",
            x_label: "x",
            y_label: "frames per second",
            y_scale: YScale::Log,
            x_names: None,
            series: &series,
        };
        line_plot(&p, &plot).unwrap();
        let svg = std::fs::read_to_string(&p).unwrap();
        assert_eq!(
            text_xs(&svg, "frames per second (log scale)").len(),
            1,
            "the axis says it is logarithmic"
        );
        let y = marker_ys(&svg);
        assert_eq!(y.len(), 3);
        let (d1, d2) = (y[0] - y[1], y[1] - y[2]);
        assert!(d1 > 10.0 && (d1 - d2).abs() <= 1.0, "1, 10, 100 at y = {y:?}");

        line_plot(&p, &Plot { y_scale: YScale::Linear, ..plot }).unwrap();
        let y = marker_ys(&std::fs::read_to_string(&p).unwrap());
        assert!(y[1] - y[2] > 5.0 * (y[0] - y[1]), "a linear axis: 10 → 100 is 10× 1 → 10, {y:?}");
    }

    #[test]
    fn tick_values_are_short() {
        assert_eq!(compact(0.6000000000000001), "0.6");
        assert_eq!(compact(10.0), "10");
        assert_eq!(compact(0.0), "0");
        assert_eq!(compact(12.25), "12.25");
    }

    #[test]
    fn log_scale_is_chosen_for_series_an_order_of_magnitude_apart() {
        let apart = [line("a", &[(0.0, 1.5)], false), line("b", &[(0.0, 0.0), (1.0, 92.0)], false)];
        assert_eq!(YScale::fitting(&apart), YScale::Log);
        let close = [line("a", &[(0.0, 1.0), (1.0, 8.0)], false)];
        assert_eq!(YScale::fitting(&close), YScale::Linear);
        assert_eq!(YScale::fitting(&[]), YScale::Linear);
    }
}
