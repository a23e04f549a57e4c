//! The run's pictures: its training curve and line charts of named series
//! (utilisation, bench results), drawn with plotters into PNG files.

use std::path::Path;

use crate::{RecordsError, Result};
use plotters::prelude::*;

/// The face every plot's text is drawn with, built into the binary: plots
/// need no fonts installed on the machine (a bare GPU server has none).
static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// Registers [`FONT`] as plotters' "sans-serif", once per process.
pub fn font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The bytes are a fixed, valid TrueType file; a failure is a build defect.
        if plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).is_err() {
            tracing::warn!("the built-in font could not be read; plots will lack text");
        }
    });
}

/// A plotters error as this crate's error.
pub fn plot_err<E: std::fmt::Display>(e: E) -> RecordsError {
    RecordsError::Plot(e.to_string())
}

/// Draws rolling episode reward against wall time, with the threshold, and
/// below it the greedy validation success of each evaluation (the kept
/// result marked), so that a policy that got worse after its peak shows.
pub fn reward_plot(
    points: &[(f64, f64)],
    threshold: f64,
    validation: &[(f64, f64)],
    result_at: Option<f64>,
    out: &Path,
) -> Result<()> {
    font();
    let root = BitMapBackend::new(out, (800, 640)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let (top, bottom) = root.split_vertically(400);
    let tmax = points.iter().chain(validation).map(|p| p.0).fold(1.0f64, f64::max);
    let lo = points.iter().map(|p| p.1).fold(-110.0f64, f64::min);
    let hi = points.iter().map(|p| p.1).fold(threshold + 50.0, f64::max);
    let mut chart = ChartBuilder::on(&top)
        .caption("rolling episode reward", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(35)
        .y_label_area_size(45)
        .build_cartesian_2d(0f64..tmax, lo..hi)
        .map_err(plot_err)?;
    chart.configure_mesh().x_desc("wall time (s)").y_desc("reward").draw().map_err(plot_err)?;
    chart
        .draw_series(LineSeries::new(points.iter().copied(), BLUE.stroke_width(2)))
        .map_err(plot_err)?;
    chart
        .draw_series(LineSeries::new([(0.0, threshold), (tmax, threshold)], RED.mix(0.6)))
        .map_err(plot_err)?;
    let mut val = ChartBuilder::on(&bottom)
        .caption("greedy validation success (%); ring: the run's result", ("sans-serif", 16))
        .margin(12)
        .x_label_area_size(35)
        .y_label_area_size(45)
        .build_cartesian_2d(0f64..tmax, 0f64..100f64)
        .map_err(plot_err)?;
    val.configure_mesh().x_desc("wall time (s)").y_desc("%").draw().map_err(plot_err)?;
    let pct = || validation.iter().map(|(t, s)| (*t, s * 100.0));
    val.draw_series(LineSeries::new(pct(), GREEN.stroke_width(2))).map_err(plot_err)?;
    val.draw_series(pct().map(|p| Circle::new(p, 3, GREEN.filled()))).map_err(plot_err)?;
    if let Some(p) = result_at.and_then(|t| pct().find(|p| p.0 == t)) {
        val.draw_series([Circle::new(p, 7, RED.stroke_width(2))]).map_err(plot_err)?;
    }
    root.present().map_err(plot_err)?;
    Ok(())
}

/// The colour of series `i`: the ten of matplotlib's `tab10`, then
/// plotters' 99-colour palette, so that no two of a plot's series share one.
fn series_color(i: usize) -> RGBColor {
    const TAB10: [(u8, u8, u8); 10] = [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
        (188, 189, 34),
        (23, 190, 207),
    ];
    match TAB10.get(i) {
        Some(&(r, g, b)) => RGBColor(r, g, b),
        None => {
            let c = Palette99::pick(i - TAB10.len()).to_rgba();
            RGBColor(c.0, c.1, c.2)
        }
    }
}

/// A part of a picture being drawn.
type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// The plot's area and, beside it on the right, a panel with the legend
/// (a legend inside the plot covers the curves).
fn with_legend_panel<'a>(out: &'a Path, names: &[&str]) -> Result<(Area<'a>, Area<'a>)> {
    let widest = names.iter().map(|n| n.chars().count()).max().unwrap_or(0) as u32;
    let panel = (widest * 8 + 50).clamp(80, 320);
    let root = BitMapBackend::new(out, (800 + panel, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let (plot, legend) = root.split_horizontally(800);
    for (i, name) in names.iter().enumerate() {
        let y = 40 + 22 * i as i32;
        let c = series_color(i);
        legend
            .draw(&PathElement::new(vec![(6, y), (30, y)], c.stroke_width(3)))
            .map_err(plot_err)?;
        legend
            .draw(&Text::new(name.to_string(), (36, y - 8), ("sans-serif", 15)))
            .map_err(plot_err)?;
    }
    Ok((plot, legend))
}

/// One arm's curve over seeds: (x, middle, low, high), e.g. the IQM with
/// the 25th and 75th percentiles.
pub type Band = (String, Vec<(f64, f64, f64, f64)>);

/// Curves with shaded bands, one per arm (`hive bench seeds`).
pub fn band_plot(
    title: &str,
    x_desc: &str,
    y_desc: &str,
    bands: &[Band],
    y_range: (f64, f64),
    out: &Path,
) -> Result<()> {
    font();
    let names: Vec<&str> = bands.iter().map(|b| b.0.as_str()).collect();
    let (root, legend) = with_legend_panel(out, &names)?;
    let xmax = bands.iter().flat_map(|b| b.1.iter().map(|p| p.0)).fold(1.0f64, f64::max);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(35)
        .y_label_area_size(55)
        .build_cartesian_2d(0f64..xmax, y_range.0..y_range.1)
        .map_err(plot_err)?;
    chart.configure_mesh().x_desc(x_desc).y_desc(y_desc).draw().map_err(plot_err)?;
    for (i, (_, pts)) in bands.iter().enumerate() {
        let c = series_color(i);
        let area: Vec<(f64, f64)> =
            pts.iter().map(|p| (p.0, p.3)).chain(pts.iter().rev().map(|p| (p.0, p.2))).collect();
        chart.draw_series([Polygon::new(area, c.mix(0.15).filled())]).map_err(plot_err)?;
        chart
            .draw_series(LineSeries::new(pts.iter().map(|p| (p.0, p.1)), c.stroke_width(2)))
            .map_err(plot_err)?;
    }
    root.present().map_err(plot_err)?;
    legend.present().map_err(plot_err)?;
    Ok(())
}

/// A line chart of several named series (e.g. milliseconds against agents).
pub fn lines_plot(
    title: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[(String, Vec<(f64, f64)>)],
    out: &Path,
) -> Result<()> {
    font();
    let names: Vec<&str> = series.iter().map(|s| s.0.as_str()).collect();
    let (root, legend) = with_legend_panel(out, &names)?;
    let pts = || series.iter().flat_map(|s| s.1.iter().copied());
    let xmax = pts().map(|p| p.0).fold(1.0f64, f64::max);
    let ymax = pts().map(|p| p.1).fold(1e-3f64, f64::max) * 1.1;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(35)
        .y_label_area_size(55)
        .build_cartesian_2d(0f64..xmax, 0f64..ymax)
        .map_err(plot_err)?;
    chart.configure_mesh().x_desc(x_desc).y_desc(y_desc).draw().map_err(plot_err)?;
    for (i, (_, s)) in series.iter().enumerate() {
        let c = series_color(i);
        chart
            .draw_series(LineSeries::new(s.iter().copied(), c.stroke_width(2)))
            .map_err(plot_err)?;
        chart.draw_series(s.iter().map(|p| Circle::new(*p, 3, c.filled()))).map_err(plot_err)?;
    }
    root.present().map_err(plot_err)?;
    legend.present().map_err(plot_err)?;
    Ok(())
}
