//! The heat maps: per incidence, the BRDF over (delta_phi, theta_o) as cells reaching halfway to their
//! neighbours, coloured on a log scale, with the colour bar that reads a colour as a value.

use super::*;

/// Width of a heat map's colour bar, its ticks and label included (pixels).
const COLOUR_BAR_W: u32 = 92;
/// Colour steps drawn in a colour bar.
const COLOUR_BAR_STEPS: usize = 64;

/// A heat-map cell: its delta_phi range and theta_o range (degrees), and its value.
type HeatCell = ((f64, f64), (f64, f64), f64);

fn viridis(t: f64) -> RGBColor {
    const STOPS: [(u8, u8, u8); 5] = [
        (68, 1, 84),
        (59, 82, 139),
        (33, 145, 140),
        (94, 201, 98),
        (253, 231, 37),
    ];
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let x = t * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    let mix = |a: u8, b: u8| (a as f64 + f * (b as f64 - a as f64)).round() as u8;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Cell edges around sorted node values: halfway to each neighbour, the ends clamped to [lo, hi].
fn edges(nodes: &[f64], lo: f64, hi: f64) -> Vec<(f64, f64)> {
    (0..nodes.len())
        .map(|j| {
            let left = if j == 0 {
                lo
            } else {
                0.5 * (nodes[j - 1] + nodes[j])
            };
            let right = if j + 1 == nodes.len() {
                hi
            } else {
                0.5 * (nodes[j] + nodes[j + 1])
            };
            (left.max(lo), right.min(hi))
        })
        .collect()
}

pub(super) fn heat_panel(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    d: &BandData,
    i: usize,
    summary: &mut PlotSummary,
) -> Result<(), ResultsError> {
    let theta: Vec<f64> = d.grid.theta_nodes().iter().map(|t| t.to_degrees()).collect();
    let dphi: Vec<f64> = d.grid.dphi_nodes().iter().map(|t| t.to_degrees()).collect();
    let ti = theta.get(i).copied().unwrap_or(0.0);
    let max_theta = theta.last().copied().unwrap_or(90.0);
    let theta_edges = edges(&theta, 0.0, (max_theta + 7.5).min(90.0));
    let dphi_edges = edges(&dphi, 0.0, 180.0);
    let mut cells: Vec<HeatCell> = Vec::new();
    for (o, te) in theta_edges.iter().enumerate() {
        if d.grid.is_pole(i) || d.grid.is_pole(o) {
            if let Some(v) = d.grid.node(i, o, 0) {
                cells.push(((0.0, 180.0), *te, v));
            }
            continue;
        }
        for (k, pe) in dphi_edges.iter().enumerate() {
            if let Some(v) = d.grid.node(i, o, k) {
                cells.push((*pe, *te, v));
            }
        }
    }
    let (lo, hi) = cells
        .iter()
        .map(|c| c.2)
        .filter(|v| *v > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    let (llo, lhi) = if hi > 0.0 {
        (lo.log10(), hi.log10())
    } else {
        (0.0, 1.0)
    };
    let span = (lhi - llo).max(1e-12);
    let caption = format!(
        "theta_i = {} deg, {} nm: BRDF {:.2e}..{:.2e} 1/sr (log colour)",
        deg_label(ti),
        d.band_nm,
        if lo.is_finite() { lo } else { 0.0 },
        hi
    );
    let (width, _) = area.dim_in_pixel();
    let (map_area, bar_area) = area.split_horizontally(width.saturating_sub(COLOUR_BAR_W));
    let mut chart = ChartBuilder::on(&map_area)
        .caption(&caption, ("sans-serif", 13))
        .margin(12)
        .x_label_area_size(32)
        .y_label_area_size(40)
        .build_cartesian_2d(0.0f64..180.0f64, 0.0f64..(max_theta + 7.5).min(90.0))
        .map_err(perr)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("phi_o - phi_i (deg)")
        .y_desc("theta_o (deg)")
        .draw()
        .map_err(perr)?;
    chart
        .draw_series(cells.iter().map(|((x0, x1), (y0, y1), v)| {
            let t = if *v > 0.0 { (v.log10() - llo) / span } else { 0.0 };
            Rectangle::new([(*x0, *y0), (*x1, *y1)], viridis(t).filled())
        }))
        .map_err(perr)?;
    if hi > 0.0 {
        colour_bar(&bar_area, llo, lhi)?;
        summary.colour_scales.push((10f64.powf(llo), 10f64.powf(lhi)));
    }
    summary.panels.push(caption);
    Ok(())
}

/// The colour scale of a heat map: viridis from `10^llo` (bottom) to `10^lhi` (top) 1/sr. The axis is linear in
/// log10 of the BRDF, its ticks labelled with the BRDF itself, so that every bar has several labels whatever
/// its span (plotters' log axis labels only whole decades).
fn colour_bar(area: &DrawingArea<SVGBackend<'_>, Shift>, llo: f64, lhi: f64) -> Result<(), ResultsError> {
    // A panel of one value still gets a readable bar: a little room either side of it.
    let (l0, l1) = if lhi - llo > 1e-9 {
        (llo, lhi)
    } else {
        (llo - 0.1, lhi + 0.1)
    };
    let mut bar = ChartBuilder::on(area)
        .margin_top(40)
        .margin_bottom(44)
        .margin_left(4)
        .right_y_label_area_size(62)
        .build_cartesian_2d(0.0f64..1.0f64, l0..l1)
        .map_err(perr)?;
    bar.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_desc("BRDF (1/sr)")
        .y_labels(6)
        .y_label_style(("sans-serif", 11))
        .axis_desc_style(("sans-serif", 11))
        .y_label_formatter(&|v: &f64| format!("{:.1e}", 10f64.powf(*v)))
        .draw()
        .map_err(perr)?;
    let step = (l1 - l0) / COLOUR_BAR_STEPS as f64;
    bar.draw_series((0..COLOUR_BAR_STEPS).map(|j| {
        let (a, b) = (l0 + j as f64 * step, l0 + (j + 1) as f64 * step);
        let t = (0.5 * (a + b) - llo) / (lhi - llo).max(1e-12);
        Rectangle::new([(0.0, a), (1.0, b)], viridis(t).filled())
    }))
    .map_err(perr)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viridis_ends_and_middle() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(0.5), RGBColor(33, 145, 140));
        assert_eq!(viridis(f64::NAN), RGBColor(68, 1, 84));
    }

    #[test]
    fn a_colour_bar_labels_values_within_its_range() {
        let mut svg = String::new();
        {
            let root = SVGBackend::with_string(&mut svg, (COLOUR_BAR_W, PANEL_H)).into_drawing_area();
            colour_bar(&root, (2.0e-3f64).log10(), (40.0f64).log10()).expect("drawn");
            root.present().expect("present");
        }
        assert!(svg.contains("BRDF (1/sr)"), "{svg}");
        let ticks: Vec<f64> = svg
            .split("</text>")
            .filter_map(|chunk| chunk.rsplit('>').next())
            .filter_map(|t| t.trim().parse::<f64>().ok())
            .collect();
        assert!(ticks.len() >= 3, "ticks {ticks:?}");
        assert!(
            ticks.iter().all(|v| (2.0e-3 * 0.999..=40.0 * 1.001).contains(v)),
            "{ticks:?}"
        );
        // The gradient: every colour step drawn.
        assert!(svg.matches("<rect").count() >= COLOUR_BAR_STEPS, "{svg}");
    }

    #[test]
    fn cell_edges_reach_halfway() {
        assert_eq!(
            edges(&[0.0, 30.0, 60.0], 0.0, 67.5),
            vec![(0.0, 15.0), (15.0, 45.0), (45.0, 67.5)]
        );
    }
}
