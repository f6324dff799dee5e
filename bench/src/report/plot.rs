//! The scaling plot of `docs/bench/` (plotters, bundled DejaVu Sans).

use std::path::Path;

use anyhow::{Context, Result};
use plotters::prelude::*;

use super::ScalingPoint;

/// Registers the bundled DejaVu Sans as plotters' `sans-serif` (plotters draws text with
/// `ab_glyph` from registered fonts only; no system font is needed).
///
/// # Errors
/// When the font cannot be parsed.
pub fn register_fonts() -> Result<()> {
    plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular())
        .map_err(|_| anyhow::anyhow!("DejaVu Sans is not a valid font"))?;
    plotters::style::register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold())
        .map_err(|_| anyhow::anyhow!("DejaVu Sans Bold is not a valid font"))?;
    Ok(())
}

struct Panel<'a> {
    axis: &'a str,
    title: &'a str,
    log_x: bool,
}

/// Draws the four scaling panels (time per frame against M, D, N, E; log time axis; log₂ M and
/// E axes) into a PNG at `path`.
///
/// # Errors
/// When a panel has no measured point, or drawing or writing fails.
pub fn plot_scaling(points: &[ScalingPoint], path: &Path) -> Result<()> {
    register_fonts()?;
    let root = BitMapBackend::new(path, (1400, 1000)).into_drawing_area();
    root.fill(&WHITE)?;
    let (top, rest) = root.split_vertically(50);
    top.draw(&Text::new(
        "stjpdacf Tracker::step on the host, time per frame (median, 95 % CI of the median)",
        (20, 14),
        ("sans-serif", 24).into_font(),
    ))?;
    let panels = [
        Panel {
            axis: "M",
            title: "M: points per frame (dense: first M used; adversarial: M points)",
            log_x: true,
        },
        Panel {
            axis: "D",
            title: "D: lane slots (D lanes present, 256 points)",
            log_x: false,
        },
        Panel {
            axis: "N",
            title: "N: index points (61 rows, rank follows N)",
            log_x: false,
        },
        Panel {
            axis: "E",
            title: "E: events per row (adversarial frames)",
            log_x: true,
        },
    ];
    let areas = rest.split_evenly((2, 2));
    for (area, panel) in areas.iter().zip(panels.iter()) {
        let on_axis: Vec<&ScalingPoint> = points
            .iter()
            .filter(|p| p.input.axis == panel.axis)
            .collect();
        let mut names: Vec<&str> = Vec::new();
        for p in &on_axis {
            if !names.contains(&p.input.series.as_str()) {
                names.push(&p.input.series);
            }
        }
        let curves: Vec<(&str, Vec<Pt>)> = names
            .iter()
            .map(|n| {
                (
                    *n,
                    on_axis
                        .iter()
                        .filter(|p| p.input.series == *n)
                        .filter_map(|p| {
                            p.time.map(|e| {
                                (
                                    p.input.value as f64,
                                    e.median_ns / 1e3,
                                    e.median_lo_ns / 1e3,
                                    e.median_hi_ns / 1e3,
                                    p.input.reference,
                                )
                            })
                        })
                        .collect(),
                )
            })
            .collect();
        let pts: Vec<Pt> = curves.iter().flat_map(|c| c.1.iter().copied()).collect();
        anyhow::ensure!(
            !pts.is_empty(),
            "no measured point on the {} axis",
            panel.axis
        );
        let xmin = pts.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
        let xmax = pts.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
        let ymin = pts.iter().map(|p| p.2).fold(f64::INFINITY, f64::min);
        let ymax = pts.iter().map(|p| p.3).fold(f64::NEG_INFINITY, f64::max);
        let (ylo, yhi) = (ymin / 1.5, ymax * 1.5);
        let mut b = ChartBuilder::on(area);
        b.caption(panel.title, ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(70);
        // M and E: log₂ of the value on a linear axis, labelled with the value.
        let tx = |v: f64| if panel.log_x { v.log2() } else { v };
        let curves: Vec<(&str, Vec<Pt>)> = curves
            .into_iter()
            .map(|(n, c)| {
                (
                    n,
                    c.into_iter()
                        .map(|p| (tx(p.0), p.1, p.2, p.3, p.4))
                        .collect(),
                )
            })
            .collect();
        let (xmin, xmax) = (tx(xmin), tx(xmax));
        let pad = (xmax - xmin).max(1.0) * 0.08;
        let mut chart = b.build_cartesian_2d(xmin - pad..xmax + pad, (ylo..yhi).log_scale())?;
        let log_x = panel.log_x;
        let xlabel = move |v: &f64| {
            if log_x {
                format!("{:.0}", v.exp2())
            } else {
                format!("{v:.0}")
            }
        };
        chart
            .configure_mesh()
            .x_desc(if log_x {
                format!("{} (log scale)", panel.axis)
            } else {
                panel.axis.to_string()
            })
            .y_desc("µs per frame (log scale)")
            .x_labels(((xmax - xmin).round() as usize + 1).clamp(2, 12))
            .x_label_formatter(&xlabel)
            .y_label_formatter(&|v| format!("{v:.0}"))
            .label_style(("sans-serif", 15))
            .draw()?;
        for (i, (n, c)) in curves.iter().enumerate() {
            series(&mut chart, n, i, c)?;
        }
        legend(&mut chart)?;
    }
    root.present()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// (value, median µs, CI low, CI high, reference configuration).
type Pt = (f64, f64, f64, f64, bool);

const COLORS: [RGBColor; 3] = [
    RGBColor(31, 119, 180),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
];

fn series<'a, X, Y>(
    chart: &mut ChartContext<'a, BitMapBackend<'a>, Cartesian2d<X, Y>>,
    name: &str,
    index: usize,
    pts: &[Pt],
) -> Result<()>
where
    X: plotters::coord::ranged1d::Ranged<ValueType = f64>,
    Y: plotters::coord::ranged1d::Ranged<ValueType = f64>,
{
    let blue = COLORS[index % COLORS.len()];
    chart
        .draw_series(LineSeries::new(
            pts.iter().map(|p| (p.0, p.1)),
            blue.stroke_width(2),
        ))?
        .label(format!("{name} frames"))
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], blue.stroke_width(2)));
    chart.draw_series(
        pts.iter()
            .map(|p| PathElement::new(vec![(p.0, p.2), (p.0, p.3)], blue.stroke_width(2))),
    )?;
    chart.draw_series(pts.iter().map(|p| {
        let style = if p.4 { RED.filled() } else { blue.filled() };
        Circle::new((p.0, p.1), if p.4 { 7 } else { 5 }, style)
    }))?;
    chart.draw_series(pts.iter().map(|p| {
        let label = if p.1 >= 1000.0 {
            format!("{:.2} ms", p.1 / 1e3)
        } else {
            format!("{:.0} µs", p.1)
        };
        EmptyElement::at((p.0, p.1)) + Text::new(label, (8, -20), ("sans-serif", 14).into_font())
    }))?;
    Ok(())
}

fn legend<'a, X, Y>(
    chart: &mut ChartContext<'a, BitMapBackend<'a>, Cartesian2d<X, Y>>,
) -> Result<()>
where
    X: plotters::coord::ranged1d::Ranged<ValueType = f64>,
    Y: plotters::coord::ranged1d::Ranged<ValueType = f64>,
{
    chart
        .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())?
        .label("red dot: reference configuration")
        .legend(|(x, y)| Circle::new((x + 10, y), 5, RED.filled()));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .label_font(("sans-serif", 14))
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}
