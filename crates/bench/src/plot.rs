//! SVG plots of the benchmark report (plotters, SVG backend only).

use std::path::Path;

use plotters::prelude::*;

use crate::campaigns::{CampaignPoint, Strategy};
use crate::readings::{FixedComparison, ReadingPoint};

/// Errors below this are drawn at it (an exact result has no place on a log axis).
const ERROR_FLOOR: f64 = 1e-17;

type PlotResult = Result<(), Box<dyn std::error::Error>>;

/// Time per reading against actual relative error, one line per (material, geometry) over the tolerances.
pub fn reading_time_vs_error(path: &Path, points: &[ReadingPoint]) -> PlotResult {
    let root = SVGBackend::new(path, (960, 640)).into_drawing_area();
    root.fill(&WHITE)?;
    let t_max = points.iter().map(|p| p.time_us).fold(1.0, f64::max) * 2.0;
    let t_min = points
        .iter()
        .map(|p| p.time_us)
        .fold(f64::INFINITY, f64::min)
        .max(1e-3)
        / 2.0;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Simulator reading: time against actual error (tolerances 1e-2..1e-8)",
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d((ERROR_FLOOR..1.0).log_scale(), (t_min..t_max).log_scale())?;
    chart
        .configure_mesh()
        .x_desc("actual relative error vs brute-force reference")
        .y_desc("time per reading (us)")
        .draw()?;
    let mut series: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    for p in points {
        let key = format!("{} / {}", p.material, p.geometry);
        let xy = (p.rel_error.max(ERROR_FLOOR), p.time_us);
        match series.iter_mut().find(|(k, _)| *k == key) {
            Some((_, v)) => v.push(xy),
            None => series.push((key, vec![xy])),
        }
    }
    for (i, (name, xy)) in series.into_iter().enumerate() {
        draw_line(&mut chart, i, &name, xy)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

/// The fixed tensor rule's error against its time (lines) and the adaptive reading at tolerance 1e-6 (points).
pub fn adaptive_vs_fixed(path: &Path, comparisons: &[FixedComparison]) -> PlotResult {
    let root = SVGBackend::new(path, (960, 640)).into_drawing_area();
    root.fill(&WHITE)?;
    let all_t = comparisons
        .iter()
        .flat_map(|c| c.curve.iter().map(|p| p.time_us).chain([c.adaptive_time_us]));
    let (t_min, t_max) = all_t.fold((f64::INFINITY, 1.0f64), |(a, b), t| (a.min(t), b.max(t)));
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Fixed Gauss x trapezoid rule (lines) vs adaptive reading at tol 1e-6 (dots)",
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(
            ((t_min.max(1e-3)) / 2.0..t_max * 2.0).log_scale(),
            (ERROR_FLOOR..1.0).log_scale(),
        )?;
    chart
        .configure_mesh()
        .x_desc("time (us)")
        .y_desc("actual relative error")
        .draw()?;
    for (i, c) in comparisons.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        let xy: Vec<(f64, f64)> = c
            .curve
            .iter()
            .map(|p| (p.time_us, p.rel_error.max(ERROR_FLOOR)))
            .collect();
        chart
            .draw_series(LineSeries::new(xy, colour.stroke_width(2)))?
            .label(format!("{} / {}", c.material, c.geometry))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart.draw_series(std::iter::once(Circle::new(
            (c.adaptive_time_us, c.adaptive_error.max(ERROR_FLOOR)),
            6,
            colour.filled(),
        )))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

/// One material's campaign strategies: error (relative RMS, log) against points and against predicted time.
pub fn campaign(path: &Path, material: &str, points: &[CampaignPoint]) -> PlotResult {
    let root = SVGBackend::new(path, (1200, 900)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(
        &format!("{material}: BRDF error on the validation set against plan size and predicted time"),
        ("sans-serif", 22),
    )?;
    let panels = root.split_evenly((2, 2));
    let strategies = [
        Strategy::FullGrid,
        Strategy::IsotropicGrid,
        Strategy::Adaptive,
        Strategy::AdaptiveSwept,
    ];
    for (k, panel) in panels.iter().enumerate() {
        let by_time = k % 2 == 1;
        let log_metric = k >= 2;
        let xy = |p: &CampaignPoint| -> Option<(f64, f64)> {
            let x = if by_time { p.predicted_s } else { p.points as f64 };
            let y = if log_metric { Some(p.log_rms) } else { p.rel_rms }?;
            (x > 0.0).then_some((x, y.max(ERROR_FLOOR)))
        };
        let all: Vec<(f64, f64)> = points.iter().filter_map(xy).collect();
        let y_name = if log_metric {
            "log error"
        } else {
            "cos-weighted relative RMS"
        };
        let x_name = if by_time {
            "predicted instrument time (s)"
        } else {
            "points measured"
        };
        if all.is_empty() {
            panel.draw(&Text::new(
                format!("{y_name}: undefined (the reference is 0 everywhere)"),
                (40, 200),
                ("sans-serif", 16),
            ))?;
            continue;
        }
        let (xs, ys) = padded_ranges(&all);
        let mut chart = ChartBuilder::on(panel)
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(xs.log_scale(), ys.log_scale())?;
        chart.configure_mesh().x_desc(x_name).y_desc(y_name).draw()?;
        for (i, s) in strategies.iter().enumerate() {
            let line: Vec<(f64, f64)> = points
                .iter()
                .filter(|p| p.strategy == *s)
                .filter_map(xy)
                .collect();
            draw_line(&mut chart, i, s.name(), line)?;
        }
        draw_legend(&mut chart)?;
    }
    root.present()?;
    Ok(())
}

/// The x and y ranges of positive `points`, widened by a factor 1.5 each way for a log-log chart.
fn padded_ranges(points: &[(f64, f64)]) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (x0, x1, y0, y1) = points.iter().fold(
        (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64),
        |(x0, x1, y0, y1), p| (x0.min(p.0), x1.max(p.0), y0.min(p.1), y1.max(p.1)),
    );
    (x0 / 1.5..x1 * 1.5, y0 / 1.5..y1 * 1.5)
}

/// A log-log chart of an SVG.
type LogChart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<LogCoord<f64>, LogCoord<f64>>>;

/// `line` as legend entry `name` in the palette's colour `i`: a line through the points and a dot at each.
fn draw_line<'a, 'b: 'a>(
    chart: &mut LogChart<'a, 'b>,
    i: usize,
    name: &str,
    line: Vec<(f64, f64)>,
) -> PlotResult {
    if line.is_empty() {
        return Ok(());
    }
    let colour = Palette99::pick(i).to_rgba();
    chart
        .draw_series(LineSeries::new(line.clone(), colour.stroke_width(2)))?
        .label(name)
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
    chart.draw_series(line.into_iter().map(|p| Circle::new(p, 3, colour.filled())))?;
    Ok(())
}

/// The legend box, upper right.
fn draw_legend<'a, 'b: 'a>(chart: &mut LogChart<'a, 'b>) -> PlotResult {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// A named line of (x, y) points.
pub type Series = (String, Vec<(f64, f64)>);

/// A titled panel of lines.
pub type Panel = (String, Vec<Series>);

/// One material's instrument time against error, a panel per instrument file, a line per strategy.
pub fn time_vs_error(path: &Path, material: &str, panels: &[Panel]) -> PlotResult {
    let root = SVGBackend::new(path, (1200, 520)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(
        &format!("{material}: error on the in-plane validation set against instrument time"),
        ("sans-serif", 22),
    )?;
    let areas = root.split_evenly((1, panels.len().max(1)));
    for ((label, series), area) in panels.iter().zip(areas.iter()) {
        let all: Vec<(f64, f64)> = series
            .iter()
            .flat_map(|(_, l)| l.iter().copied())
            .filter(|(t, _)| *t > 0.0)
            .map(|(t, e)| (t, e.max(ERROR_FLOOR)))
            .collect();
        if all.is_empty() {
            continue;
        }
        let (xs, ys) = padded_ranges(&all);
        let mut chart = ChartBuilder::on(area)
            .caption(label, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(xs.log_scale(), ys.log_scale())?;
        chart
            .configure_mesh()
            .x_desc("instrument time (s)")
            .y_desc("cos-weighted relative RMS")
            .draw()?;
        for (i, (name, line)) in series.iter().enumerate() {
            let mut line: Vec<(f64, f64)> = line.iter().map(|(t, e)| (*t, e.max(ERROR_FLOOR))).collect();
            line.sort_by(|a, b| a.0.total_cmp(&b.0));
            draw_line(&mut chart, i, name, line)?;
        }
        draw_legend(&mut chart)?;
    }
    root.present()?;
    Ok(())
}
