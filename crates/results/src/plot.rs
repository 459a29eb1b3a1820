//! SVG plots of a run (plotters, SVG backend): pictures a person looks at.
//!
//! One SVG, panels in rows of three:
//! - per band, the in-plane slices as a polar plot: one curve per incidence angle; the polar angle is the
//!   signed theta_o (positive on the specular side, delta_phi = 180 degrees; negative towards the source,
//!   delta_phi = 0), the radius is log10 of the BRDF over [`DECADES`] decades below the panel's largest value;
//!   the source's direction is marked on the rim by a dot of the curve's colour;
//! - per incidence angle known at two or more outgoing directions, a heat map of the BRDF over
//!   (delta_phi = phi_o - phi_i, theta_o) for one band
//!   (default: the band nearest 550 nm), log colour scale, each measured node a cell reaching halfway to its
//!   neighbours, and beside it the colour scale: a bar from the panel's smallest to its largest value with
//!   labelled ticks (BRDF in 1/sr), so that a colour reads as a value;
//! - with a model (a fitted material file), its curves in the polar plots (lines over each slice's measured
//!   range, the measurements then as dots) and a panel of measured against model values (log-log, with the 1:1 line).
//!
//! The data are those of the interpolant's nodes ([`crate::iso::IsoGrid`]): repeated measurements averaged and
//! reciprocity used, so that an incidence curve also shows the points measured with source and detector
//! swapped. Every curve is a legend entry and every panel has a caption, so that the SVG's text says what it
//! shows (the tests read it).

use std::f64::consts::PI;

use gonio_brdf::geometry::Direction;
use gonio_brdf::material::Material;
use gonio_brdf::{Brdf, Wavelength};
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::error::ResultsError;
use crate::iso::{IsoGrid, IsoPoint, NODE_TOLERANCE_RAD, directions};
use crate::run::{BAND_TOLERANCE_NM, Run, list_nm};

mod heat;
use heat::heat_panel;

/// Decades of BRDF shown below a panel's largest value.
pub const DECADES: f64 = 3.0;

/// The fewest measured cells an incidence's heat map needs.
const MIN_HEAT_CELLS: usize = 2;

const PANEL_W: u32 = 520;
const PANEL_H: u32 = 460;
const COLUMNS: usize = 3;

/// What to plot besides the run.
#[derive(Debug, Clone, Default)]
pub struct PlotOptions {
    /// The band of the heat maps (nm); default: the band nearest 550 nm.
    pub heat_band_nm: Option<f64>,
    /// A model to compare with, and its name for the captions (e.g. the material file).
    pub model: Option<(Material, String)>,
}

/// What the plot holds: panel captions and curve labels, in drawing order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PlotSummary {
    pub panels: Vec<String>,
    pub series: Vec<String>,
    /// Each heat map's colour scale: the BRDF (1/sr) at its bottom and top colour.
    pub colour_scales: Vec<(f64, f64)>,
}

fn perr(e: impl std::fmt::Display) -> ResultsError {
    ResultsError::Plot {
        message: e.to_string(),
    }
}

/// One band's grid.
struct BandData {
    band_nm: f64,
    grid: IsoGrid,
}

/// A point of an in-plane slice: signed theta_o (degrees) and value.
type SlicePoint = (f64, f64);

/// The in-plane slice at incidence node `i`: (signed theta_o in degrees, value), sorted.
fn in_plane_slice(grid: &IsoGrid, i: usize) -> Vec<SlicePoint> {
    let theta = grid.theta_nodes();
    let dphi = grid.dphi_nodes();
    let near = |target: f64| dphi.iter().position(|d| (d - target).abs() <= NODE_TOLERANCE_RAD);
    let (back, forward) = (near(0.0), near(PI));
    let mut out = Vec::new();
    for (o, t) in theta.iter().enumerate() {
        let deg = t.to_degrees();
        if grid.is_pole(i) || grid.is_pole(o) {
            // No azimuth at the pole: the value belongs to every plane.
            if let Some(v) = grid.node(i, o, 0) {
                if grid.is_pole(o) {
                    out.push((0.0, v));
                } else {
                    out.push((deg, v));
                    out.push((-deg, v));
                }
            }
            continue;
        }
        if let Some(v) = forward.and_then(|k| grid.node(i, o, k)) {
            out.push((deg, v));
        }
        if let Some(v) = back.and_then(|k| grid.node(i, o, k)) {
            out.push((-deg, v));
        }
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    out
}

fn deg_label(v: f64) -> String {
    let r = (v * 10.0).round() / 10.0;
    if r == r.trunc() {
        format!("{}", r as i64)
    } else {
        format!("{r}")
    }
}

/// Renders the plot (module doc) to SVG text.
pub fn render(run: &Run, opts: &PlotOptions) -> Result<(String, PlotSummary), ResultsError> {
    let bands = run.bands_nm();
    if bands.is_empty() {
        return Err(ResultsError::NoData {
            origin: run.origin.clone(),
            message: "no valid points to plot".into(),
        });
    }
    let data: Vec<BandData> = bands
        .iter()
        .map(|&band_nm| {
            let pts: Vec<IsoPoint> = run
                .points
                .iter()
                .filter(|p| (p.band_nm - band_nm).abs() <= BAND_TOLERANCE_NM)
                .filter_map(IsoPoint::from_point)
                .collect();
            BandData {
                band_nm,
                grid: IsoGrid::build(&pts),
            }
        })
        .collect();
    let heat_band = match opts.heat_band_nm {
        Some(nm) => run.band(nm)?,
        None => bands
            .iter()
            .copied()
            .min_by(|a, b| (a - 550.0).abs().total_cmp(&(b - 550.0).abs()))
            .unwrap_or(550.0),
    };
    let heat = data
        .iter()
        .find(|d| d.band_nm == heat_band)
        .ok_or_else(|| ResultsError::Invalid(format!("no band {heat_band} nm in {}", list_nm(&bands))))?;
    // A heat map per incidence with something to map: an incidence known at one outgoing direction only (a
    // sweep's readings seen through reciprocity, each its own incidence) would be a panel of one cell.
    let grid = &heat.grid;
    let cells = |i: usize| {
        (0..grid.theta_nodes().len())
            .flat_map(|o| (0..grid.dphi_nodes().len()).map(move |k| (o, k)))
            .filter(|&(o, k)| grid.node(i, o, k).is_some())
            .take(MIN_HEAT_CELLS)
            .count()
    };
    let incidences: Vec<usize> = (0..grid.theta_nodes().len())
        .filter(|&i| cells(i) >= MIN_HEAT_CELLS)
        .collect();
    let panels = data.len() + incidences.len() + usize::from(opts.model.is_some());
    let rows = panels.div_ceil(COLUMNS);
    let mut svg = String::new();
    let mut summary = PlotSummary::default();
    {
        let root = SVGBackend::with_string(&mut svg, (PANEL_W * COLUMNS as u32, PANEL_H * rows as u32))
            .into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let areas = root.split_evenly((rows, COLUMNS));
        let mut next = areas.iter();
        for d in &data {
            if let Some(area) = next.next() {
                polar_panel(area, run, d, opts, &mut summary)?;
            }
        }
        for &i in &incidences {
            if let Some(area) = next.next() {
                heat_panel(area, heat, i, &mut summary)?;
            }
        }
        if let Some((model, name)) = &opts.model
            && let Some(area) = next.next()
        {
            model_panel(area, run, &bands, model, name, &mut summary)?;
        }
        root.present().map_err(perr)?;
    }
    Ok((svg, summary))
}

fn polar_panel(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    run: &Run,
    d: &BandData,
    opts: &PlotOptions,
    summary: &mut PlotSummary,
) -> Result<(), ResultsError> {
    let theta = d.grid.theta_nodes();
    let slices: Vec<(f64, Vec<SlicePoint>)> = (0..theta.len())
        .map(|i| (theta[i].to_degrees(), in_plane_slice(&d.grid, i)))
        // A curve needs two points: an incidence seen at one direction only (through reciprocity) is not one.
        .filter(|(_, s)| s.len() >= 2)
        .collect();
    let wl = Wavelength::from_nm(d.band_nm).map_err(|e| ResultsError::Invalid(e.to_string()))?;
    let model_curves: Vec<(f64, Vec<SlicePoint>)> = match &opts.model {
        Some((m, _)) => slices
            .iter()
            .map(|(ti, slice)| {
                // Over the measured range of the slice only: the model is compared, not extrapolated.
                let lo = slice.first().map_or(0.0, |p| p.0);
                let hi = slice.last().map_or(0.0, |p| p.0);
                let steps = ((hi - lo) / 0.5).ceil().max(1.0) as usize;
                let curve = (0..=steps)
                    .filter_map(|j| {
                        let to = lo + (hi - lo) * j as f64 / steps as f64;
                        let wi = Direction::from_spherical_deg(*ti, 180.0);
                        let wo = Direction::from_spherical_deg(to.abs(), if to >= 0.0 { 0.0 } else { 180.0 });
                        m.eval(&wi, &wo, wl).ok().map(|v| (to, v))
                    })
                    .collect();
                (*ti, curve)
            })
            .collect(),
        None => Vec::new(),
    };
    let fmax = slices
        .iter()
        .chain(&model_curves)
        .flat_map(|(_, s)| s.iter().map(|(_, v)| *v))
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    // The rim is a little above the largest value; rings at whole decades.
    let top = if fmax > 0.0 { (1.2 * fmax).log10() } else { 0.0 };
    let bottom = top - DECADES;
    let radius = |v: f64| -> f64 {
        if v > 0.0 {
            ((v.log10() - bottom) / DECADES).clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    let xy = |deg: f64, r: f64| (r * deg.to_radians().sin(), r * deg.to_radians().cos());
    let caption = format!("in-plane slices, {} nm ({})", d.band_nm, run.name);
    let mut chart = ChartBuilder::on(area)
        .caption(&caption, ("sans-serif", 16))
        .margin(12)
        // Equal scales on both axes (the semicircle stays round); the space below the horizon holds the legend.
        .build_cartesian_2d(-1.15f64..1.15f64, -0.76f64..1.12f64)
        .map_err(perr)?;
    summary.panels.push(caption.clone());
    let grey = RGBColor(200, 200, 200);
    // Rings at each decade, spokes every 15 degrees.
    let rim: Vec<(f64, f64)> = (-90..=90).map(|a| xy(f64::from(a), 1.0)).collect();
    chart
        .draw_series(LineSeries::new(rim, grey.stroke_width(1)))
        .map_err(perr)?;
    for dec in (bottom.ceil() as i32)..=(top.floor() as i32) {
        let r = (f64::from(dec) - bottom) / DECADES;
        let ring: Vec<(f64, f64)> = (-90..=90).map(|a| xy(f64::from(a), r)).collect();
        chart
            .draw_series(LineSeries::new(ring, grey.stroke_width(1)))
            .map_err(perr)?;
        chart
            .draw_series(std::iter::once(Text::new(
                format!("1e{dec}"),
                (-r, -0.05),
                ("sans-serif", 10),
            )))
            .map_err(perr)?;
    }
    for a in (-90..=90).step_by(15) {
        let a = f64::from(a);
        chart
            .draw_series(LineSeries::new(
                vec![(0.0, 0.0), xy(a, 1.0)],
                grey.stroke_width(1),
            ))
            .map_err(perr)?;
        if a.abs() < 90.0 {
            chart
                .draw_series(std::iter::once(Text::new(
                    deg_label(a),
                    xy(a, 1.06),
                    ("sans-serif", 10),
                )))
                .map_err(perr)?;
        }
    }
    let has_model = !model_curves.is_empty();
    for (n, (ti, slice)) in slices.iter().enumerate() {
        let colour = Palette99::pick(n).to_rgba();
        let label = format!("theta_i = {} deg", deg_label(*ti));
        let points: Vec<(f64, f64)> = slice.iter().map(|(a, v)| xy(*a, radius(*v))).collect();
        let series = if has_model {
            chart
                .draw_series(points.iter().map(|p| Circle::new(*p, 3, colour.filled())))
                .map_err(perr)?
        } else {
            chart
                .draw_series(points.iter().map(|p| Circle::new(*p, 2, colour.filled())))
                .map_err(perr)?;
            chart
                .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))
                .map_err(perr)?
        };
        series
            .label(label.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2)));
        summary.series.push(format!("{caption}: {label}"));
        // The source's direction on the rim (it lies on the side opposite the specular direction).
        chart
            .draw_series(std::iter::once(Circle::new(xy(-ti, 1.0), 4, colour.filled())))
            .map_err(perr)?;
    }
    // Model curves: lines in the colour of their incidence; one legend entry for all of them.
    for (n, (ti, curve)) in model_curves.iter().enumerate() {
        let colour = Palette99::pick(n).to_rgba();
        let points: Vec<(f64, f64)> = curve
            .iter()
            .filter(|(_, v)| *v > 0.0)
            .map(|(a, v)| xy(*a, radius(*v)))
            .collect();
        let drawn = chart
            .draw_series(LineSeries::new(points, colour.stroke_width(1)))
            .map_err(perr)?;
        if n == 0 {
            drawn
                .label("model (lines)")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(1)));
        }
        summary
            .series
            .push(format!("{caption}: model, theta_i = {} deg", deg_label(*ti)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .label_font(("sans-serif", 10))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(perr)?;
    Ok(())
}

fn model_panel(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    run: &Run,
    bands: &[f64],
    model: &Material,
    name: &str,
    summary: &mut PlotSummary,
) -> Result<(), ResultsError> {
    let mut series: Vec<(f64, Vec<(f64, f64)>)> = Vec::new();
    for &b in bands {
        let Ok(wl) = Wavelength::from_nm(b) else { continue };
        let pts: Vec<(f64, f64)> = run
            .valid_points()
            .filter(|p| (p.band_nm - b).abs() <= BAND_TOLERANCE_NM)
            .filter_map(|p| {
                let f = p.value()?;
                let (wi, wo) = directions(p);
                let m = model.eval(&wi, &wo, wl).ok()?;
                (m > 0.0 && f > 0.0).then_some((m, f))
            })
            .collect();
        series.push((b, pts));
    }
    let all = series
        .iter()
        .flat_map(|(_, s)| s.iter().flat_map(|(a, b)| [*a, *b]));
    let (lo, hi) = all.fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    let (lo, hi) = if hi > 0.0 && lo.is_finite() {
        (lo / 1.5, hi * 1.5)
    } else {
        (1e-3, 1.0)
    };
    let caption = format!("measured vs model ({name})");
    let mut chart = ChartBuilder::on(area)
        .caption(&caption, ("sans-serif", 14))
        .margin(12)
        .x_label_area_size(32)
        .y_label_area_size(48)
        .build_cartesian_2d((lo..hi).log_scale(), (lo..hi).log_scale())
        .map_err(perr)?;
    chart
        .configure_mesh()
        .x_desc("model (1/sr)")
        .y_desc("measured (1/sr)")
        .draw()
        .map_err(perr)?;
    chart
        .draw_series(LineSeries::new(vec![(lo, lo), (hi, hi)], BLACK.stroke_width(1)))
        .map_err(perr)?
        .label("1:1")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(1)));
    summary.series.push(format!("{caption}: 1:1"));
    for (n, (b, pts)) in series.iter().enumerate() {
        let colour = Palette99::pick(n).to_rgba();
        let label = format!("{b} nm");
        chart
            .draw_series(pts.iter().map(|p| Circle::new(*p, 3, colour.filled())))
            .map_err(perr)?
            .label(label.clone())
            .legend(move |(x, y)| Circle::new((x + 8, y), 3, colour.filled()));
        summary.series.push(format!("{caption}: {label}"));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .label_font(("sans-serif", 11))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(perr)?;
    summary.panels.push(caption);
    Ok(())
}
