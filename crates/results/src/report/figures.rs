//! The report's own pictures (the BRDF plots are [`crate::plot`]'s): where on the hemisphere the run
//! measured, and the normalisation readings over the run's time.

use plotters::prelude::*;

use crate::error::ResultsError;
use crate::points::Point;
use crate::provenance::CalibrationReading;
use crate::run::{BAND_TOLERANCE_NM, Run};

const DISC_PANEL: u32 = 300;
const DISC_COLUMNS: usize = 4;
/// Incidences closer than this (degrees) share a disc.
const INCIDENCE_TOLERANCE_DEG: f64 = 0.5;

fn perr(e: impl std::fmt::Display) -> ResultsError {
    ResultsError::Plot {
        message: e.to_string(),
    }
}

/// The run's distinct incidence angles (degrees), ascending.
pub fn incidences_deg(points: &[Point]) -> Vec<f64> {
    let mut all: Vec<f64> = points
        .iter()
        .map(|p| p.theta_i_deg)
        .filter(|t| t.is_finite())
        .collect();
    all.sort_by(f64::total_cmp);
    let mut out: Vec<f64> = Vec::new();
    for t in all {
        if out.last().is_none_or(|last| t - last > INCIDENCE_TOLERANCE_DEG) {
            out.push(t);
        }
    }
    out
}

/// What the coverage picture shows, for its caption and the tests.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CoverageSummary {
    /// One disc per incidence angle (degrees).
    pub discs_deg: Vec<f64>,
    /// Outgoing directions drawn as measured (a valid value in some band) and as not measured (flagged or failed
    /// in every band).
    pub measured: usize,
    pub not_measured: usize,
}

/// The hemisphere of outgoing directions per incidence angle, seen from above the sample: the radius is
/// theta_o (the rim is 90 degrees), the angle is phi_o - phi_i with the source's azimuth to the left, so the
/// specular direction lies to the right. Filled dots: directions with a valid value in at least one band;
/// red crosses: directions whose every reading was flagged or failed.
pub fn coverage_svg(run: &Run) -> Result<(String, CoverageSummary), ResultsError> {
    let discs = incidences_deg(&run.points);
    let rows = discs.len().div_ceil(DISC_COLUMNS).max(1);
    let columns = discs.len().clamp(1, DISC_COLUMNS);
    let mut summary = CoverageSummary {
        discs_deg: discs.clone(),
        ..CoverageSummary::default()
    };
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (DISC_PANEL * columns as u32, DISC_PANEL * rows as u32))
            .into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let areas = root.split_evenly((rows, columns));
        for (area, &ti) in areas.iter().zip(&discs) {
            disc(area, run, ti, &mut summary)?;
        }
        root.present().map_err(perr)?;
    }
    Ok((svg, summary))
}

/// One outgoing direction with whether any band measured it.
struct Direction {
    theta_o_deg: f64,
    dphi_deg: f64,
    valid: bool,
}

fn directions_at(run: &Run, ti: f64) -> Vec<Direction> {
    let mut out: Vec<Direction> = Vec::new();
    for p in run
        .points
        .iter()
        .filter(|p| (p.theta_i_deg - ti).abs() <= INCIDENCE_TOLERANCE_DEG)
    {
        let dphi = (p.phi_o_deg - p.phi_i_deg).rem_euclid(360.0);
        let same = out.iter_mut().find(|d| {
            (d.theta_o_deg - p.theta_o_deg).abs() < 1e-6 && {
                let diff = (d.dphi_deg - dphi).abs();
                diff.min(360.0 - diff) < 1e-6 || p.theta_o_deg.abs() < 1e-9
            }
        });
        match same {
            Some(d) => d.valid |= p.is_valid(),
            None => out.push(Direction {
                theta_o_deg: p.theta_o_deg,
                dphi_deg: dphi,
                valid: p.is_valid(),
            }),
        }
    }
    out
}

fn disc(
    area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    run: &Run,
    ti: f64,
    summary: &mut CoverageSummary,
) -> Result<(), ResultsError> {
    let (w, h) = area.dim_in_pixel();
    let (cx, cy) = (w as i32 / 2, h as i32 / 2 + 10);
    let radius = (w.min(h) as f64 / 2.0 - 28.0).max(10.0);
    let to_xy = |theta_deg: f64, dphi_deg: f64| -> (i32, i32) {
        let r = radius * (theta_deg / 90.0);
        // dphi = 180 (the specular side) to the right, 0 (the source's side) to the left.
        let a = (180.0 - dphi_deg).to_radians();
        (
            cx + (r * a.cos()).round() as i32,
            cy - (r * a.sin()).round() as i32,
        )
    };
    let grey = RGBColor(200, 200, 200);
    for ring in [30.0, 60.0, 90.0] {
        area.draw(&Circle::new(
            (cx, cy),
            (radius * ring / 90.0).round() as i32,
            ShapeStyle::from(&grey).stroke_width(1),
        ))
        .map_err(perr)?;
    }
    area.draw(&PathElement::new(
        vec![(cx - radius as i32, cy), (cx + radius as i32, cy)],
        ShapeStyle::from(&grey).stroke_width(1),
    ))
    .map_err(perr)?;
    let caption = format!("theta_i = {} deg", super::html::deg(ti));
    area.draw_text(&caption, &("sans-serif", 15).into_text_style(area), (8, 6))
        .map_err(perr)?;
    // The source's direction on the left, the specular direction on the right.
    let source = to_xy(ti, 0.0);
    let specular = to_xy(ti, 180.0);
    area.draw(&Circle::new(
        source,
        6,
        ShapeStyle::from(&RGBColor(230, 160, 0)).filled(),
    ))
    .map_err(perr)?;
    area.draw(&Circle::new(specular, 7, ShapeStyle::from(&BLUE).stroke_width(2)))
        .map_err(perr)?;
    let label = ("sans-serif", 11).into_text_style(area);
    area.draw_text("source", &label, (source.0 - 14, source.1 + 9))
        .map_err(perr)?;
    area.draw_text("specular", &label, (specular.0 - 22, specular.1 + 10))
        .map_err(perr)?;
    for d in directions_at(run, ti) {
        let (x, y) = to_xy(d.theta_o_deg, d.dphi_deg);
        if d.valid {
            summary.measured += 1;
            area.draw(&Circle::new((x, y), 3, ShapeStyle::from(&BLACK).filled()))
                .map_err(perr)?;
        } else {
            summary.not_measured += 1;
            area.draw(&Cross::new((x, y), 4, ShapeStyle::from(&RED).stroke_width(2)))
                .map_err(perr)?;
        }
    }
    Ok(())
}

/// The normalisation readings (direct beam or reference) over the run's instrument time, each band relative
/// to its first reading: what the drift model interpolated between. `None` when there are fewer than two.
pub fn drift_svg(calibrations: &[CalibrationReading]) -> Result<Option<String>, ResultsError> {
    let norm: Vec<&CalibrationReading> = calibrations
        .iter()
        .filter(|c| c.kind != "dark" && c.value_w.is_finite() && c.t_s.is_finite())
        .collect();
    if norm.len() < 2 {
        return Ok(None);
    }
    let mut bands: Vec<f64> = Vec::new();
    for c in &norm {
        let b = c.band_nm.unwrap_or(0.0);
        if !bands.iter().any(|x| (x - b).abs() <= BAND_TOLERANCE_NM) {
            bands.push(b);
        }
    }
    let series: Vec<(f64, Vec<(f64, f64)>)> = bands
        .iter()
        .map(|&b| {
            let readings: Vec<&&CalibrationReading> = norm
                .iter()
                .filter(|c| (c.band_nm.unwrap_or(0.0) - b).abs() <= BAND_TOLERANCE_NM)
                .collect();
            let first = readings.first().map(|c| c.value_w).unwrap_or(1.0);
            let pts = readings
                .iter()
                .filter(|_| first != 0.0)
                .map(|c| (c.t_s, (c.value_w / first - 1.0) * 100.0))
                .collect();
            (b, pts)
        })
        .collect();
    let (t_max, mut lo, mut hi) = series
        .iter()
        .flat_map(|(_, s)| s)
        .fold((1.0f64, -0.01f64, 0.01f64), |(t, lo, hi), &(x, y)| {
            (t.max(x), lo.min(y), hi.max(y))
        });
    let pad = 0.1 * (hi - lo);
    lo -= pad;
    hi += pad;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (760, 320)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "normalisation readings relative to each band's first",
                ("sans-serif", 16),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..t_max * 1.02, lo..hi)
            .map_err(perr)?;
        chart
            .configure_mesh()
            .x_desc("instrument time (s)")
            .y_desc("change (%)")
            .draw()
            .map_err(perr)?;
        for (k, (band, pts)) in series.iter().enumerate() {
            let colour = Palette99::pick(k).to_rgba();
            chart
                .draw_series(LineSeries::new(pts.iter().copied(), colour.stroke_width(2)))
                .map_err(perr)?
                .label(format!("{band} nm"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
            chart
                .draw_series(pts.iter().map(|&(x, y)| Circle::new((x, y), 3, colour.filled())))
                .map_err(perr)?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(perr)?;
        root.present().map_err(perr)?;
    }
    Ok(Some(svg))
}
