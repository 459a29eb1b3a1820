//! Latitude coordinates on the part of a cone above the horizon, with maps onto a narrow lobe.

use std::f64::consts::{FRAC_PI_2, PI};

use gonio_brdf::Direction;

use super::gauss_legendre;

mod adapt;
#[cfg(test)]
mod tests;

/// The part of a cone above the horizon in latitude coordinates.
///
/// The elevation runs from the cone's top `e_axis + beta` (sigma = 0) down as `e = e_axis + beta cos(sigma)` to
/// the horizon at `sigma_max = acos(-e_axis / beta)`. At each elevation the cone spans the azimuths
/// `phi_axis +- W(sigma)`, the half-width from the haversine law in a product form free of cancellation,
/// `sin^2(W/2) = sin(beta cos^2(sigma/2)) sin(beta sin^2(sigma/2)) / (cos(e) cos(e_axis))`, and
/// `phi = phi_axis + W tau`, tau in [-1, 1]. Then `d omega = cos(e) beta sin(sigma) W d sigma d tau` and the
/// integrand is `f(w) sin(e) cos(e) beta sin(sigma) W`.
///
/// The horizon is the coordinate line sigma = sigma_max and cos(theta) = sin(e) vanishes linearly there: the
/// integrand is smooth on the closed rectangle, no kink left for the rules to resolve. The substitution
/// `theta = theta_axis - beta cos(sigma)` also removes the square-root behaviour of W at the cone's top and bottom
/// (W is analytic in sigma), and a kink along a circle of latitude (Oren-Nayar's theta_o = theta_i) is a
/// coordinate line too, cut exactly. (Polar coordinates about the axis clipped per azimuth, rho up to the
/// horizon, would be smooth as well, but when the axis lies near the horizon the clipped
/// `rho_max(phi) ~ e_axis / cos(phi)` has a pole just off the range of phi, and the rules converge slowly there:
/// with the axis 0.01 beta above the horizon, 64 Gauss-Legendre nodes in phi still leave 2e-5 of the clipped
/// part's projected solid angle, which the latitude rule gets to rounding with 48 in sigma.)
///
/// A lobe narrower than the aperture gets maps (the Cauchy substitution, which turns a GGX lobe
/// `1 / (1 + x^2)^2` into the smooth `cos^2`). In each row, `phi = phi_peak + g tan(u)` with `g` the lobe's width
/// across over `cos(e)`, u mapped linearly onto tau: near grazing incidence a microfacet lobe is
/// `1 / cos(theta_i)` times narrower across the plane of incidence than in it. In sigma, `sigma = c + s tan(t)`
/// onto each place where the row integral changes on a scale shorter than the aperture (a [`Focus`]): the lobe's
/// own row, and the rows where its ridge crosses the cone's rim, where the row integral goes from the whole
/// ridge to none of it within the ridge's width. Each focus gets a piece of sigma of its own, and the rules run
/// over the pieces laid end to end in one variable v: all maps are smooth, so the rules still see a smooth
/// integrand.
///
/// [`Focus`]: adapt::Focus
#[derive(Debug, Clone, Copy)]
pub(super) struct Latitude {
    beta: f64,
    /// Elevation of the axis above the horizon (rad, in (-beta, pi/2 - beta)).
    elevation: f64,
    cos_elevation: f64,
    /// Azimuth of the axis (rad).
    azimuth: f64,
    /// sigma at the horizon; pi when the whole cone is above it.
    pub(super) sigma_max: f64,
    /// The smooth pieces of sigma in order, with their maps; v runs over them end to end.
    pieces: [Piece; MAX_PIECES],
    piece_count: usize,
    /// The azimuth map onto a lobe's ridge; None: `phi = phi_axis + W tau`.
    ridge: Option<Ridge>,
    /// A kink along a meridian, its azimuth relative to the axis: each row that contains it is cut there,
    /// at tau = 0.
    kink_offset: Option<f64>,
}

/// Enough for every piece the features make: one per focus (the lobe's row, two rim crossings), cut at the kinks
/// (a latitude, and a meridian's two rim crossings), 6 in all.
const MAX_PIECES: usize = 8;

/// `(centre, scale)`: `sigma = centre + scale tan(t)`.
type CauchyMap = (f64, f64);

/// A piece of sigma, the rules' variable over it, and where it starts in v.
#[derive(Debug, Clone, Copy, Default)]
struct Piece {
    /// `sigma = centre + scale tan(t)` when Some((centre, scale)); else `sigma = t`.
    map: Option<CauchyMap>,
    /// The range of t.
    t: [f64; 2],
    /// v at `t[0]`.
    v_start: f64,
}

impl Piece {
    fn new(lo: f64, hi: f64, map: Option<CauchyMap>) -> Piece {
        let t_of = |sigma: f64| match map {
            None => sigma,
            Some((centre, scale)) => ((sigma - centre) / scale).atan(),
        };
        Piece {
            map,
            t: [t_of(lo), t_of(hi)],
            v_start: 0.0,
        }
    }

    fn v_end(&self) -> f64 {
        self.v_start + (self.t[1] - self.t[0])
    }
}

/// The meridian of a lobe's peak and its widths.
#[derive(Debug, Clone, Copy)]
struct Ridge {
    /// Azimuth of the peak relative to the axis, in [-pi, pi).
    offset: f64,
    /// Elevation of the peak.
    elevation: f64,
    /// As in [`Peak`].
    ///
    /// [`Peak`]: super::Peak
    width: f64,
    across: (f64, f64),
}

impl Ridge {
    /// The map's scale in azimuth in a row at elevation e: the lobe's width across there, widened by the
    /// distance from the peak along the meridian, over cos(e).
    fn gamma(&self, sin_e: f64, cos_e: f64) -> f64 {
        let e = sin_e.atan2(cos_e);
        // Floored so that the map's tangent stays well conditioned at grazing incidence (cos theta_i -> 0).
        let across = (self.across.0 + self.across.1 * sin_e.max(0.0)).max(1e-9);
        across * (1.0 + ((e - self.elevation) / self.width).powi(2)).sqrt() / cos_e
    }
}

/// The quantities of one sigma: everything but the azimuth.
#[derive(Debug, Clone, Copy)]
pub(super) struct Row {
    sin_e: f64,
    cos_e: f64,
    /// W(sigma): the azimuthal half-width (rad).
    half_width: f64,
    /// `sin(e) cos(e) beta sin(sigma)`, which times `d phi / d tau` multiplies f (0 outside the open range).
    pub(super) weight: f64,
    /// The range of the map's parameter s over the row, [lo, at tau = 0, hi]: tau in [-1, 0] and [0, 1] map
    /// linearly onto its two parts. The middle is the kink's s when the row contains one, else the midpoint.
    s: [f64; 3],
    map: RowMap,
}

/// s to the azimuth relative to the axis, in one row.
#[derive(Debug, Clone, Copy)]
enum RowMap {
    /// `s`.
    Linear,
    /// `offset + gamma tan(s)`.
    Ridge { offset: f64, gamma: f64 },
}

impl RowMap {
    /// s at the azimuth `dphi` relative to the axis.
    fn s_of(&self, dphi: f64) -> f64 {
        match *self {
            RowMap::Linear => dphi,
            RowMap::Ridge { offset, gamma } => ((dphi - offset) / gamma).atan(),
        }
    }
}

/// An angle in [-pi, pi).
fn wrap(angle: f64) -> f64 {
    (angle + PI).rem_euclid(2.0 * PI) - PI
}

impl Latitude {
    /// The part above the horizon of the cone of half-angle `beta` about the axis at `elevation` above the
    /// horizon and `azimuth`, no maps; None unless the cone crosses the horizon and misses the zenith.
    pub(super) fn new(beta: f64, elevation: f64, azimuth: f64) -> Option<Latitude> {
        let across = beta > 0.0 && beta < FRAC_PI_2 && elevation + beta > 0.0 && elevation + beta < FRAC_PI_2;
        if !across || elevation - beta >= 0.0 {
            return None;
        }
        let sigma_max = (-elevation / beta).clamp(-1.0, 1.0).acos();
        let mut lat = Latitude {
            beta,
            elevation,
            cos_elevation: elevation.cos(),
            azimuth,
            sigma_max,
            pieces: [Piece::default(); MAX_PIECES],
            piece_count: 0,
            ridge: None,
            kink_offset: None,
        };
        lat.set_pieces(&[], &[]);
        Some(lat)
    }

    fn pieces_in_use(&self) -> &[Piece] {
        &self.pieces[..self.piece_count]
    }

    /// (sigma, d sigma / d v) at v.
    pub(super) fn sigma(&self, v: f64) -> (f64, f64) {
        let pieces = self.pieces_in_use();
        let piece = pieces.iter().rev().find(|p| p.v_start <= v).or(pieces.first());
        let Some(p) = piece else {
            return (v, 1.0);
        };
        let t = p.t[0] + (v - p.v_start);
        match p.map {
            None => (t, 1.0),
            Some((centre, scale)) => {
                let tan = t.tan();
                (centre + scale * tan, scale * (1.0 + tan * tan))
            }
        }
    }

    pub(super) fn row(&self, sigma: f64) -> Row {
        let sin_sigma = sigma.sin();
        let (hs, hc) = (0.5 * sigma).sin_cos();
        let e = self.elevation + self.beta * sigma.cos();
        let (sin_e, cos_e) = e.sin_cos();
        let num = (self.beta * hc * hc).sin() * (self.beta * hs * hs).sin();
        let den = cos_e * self.cos_elevation;
        let hav = if den > 0.0 {
            (num / den).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let half_width = 2.0 * hav.sqrt().asin();
        let weight = sin_e * cos_e * self.beta * sin_sigma;
        let map = match self.ridge {
            Some(ridge) if cos_e > 0.0 => RowMap::Ridge {
                offset: ridge.offset,
                gamma: ridge.gamma(sin_e, cos_e),
            },
            _ => RowMap::Linear,
        };
        let (lo, hi) = (map.s_of(-half_width), map.s_of(half_width));
        let middle = match self.kink_offset {
            Some(k) if k.abs() < half_width => map.s_of(k),
            _ => 0.5 * (lo + hi),
        };
        Row {
            sin_e,
            cos_e,
            half_width,
            s: [lo, middle, hi],
            weight: if weight > 0.0 && half_width > 0.0 {
                weight
            } else {
                0.0
            },
            map,
        }
    }

    /// The direction at tau in a row and `d phi / d tau` there.
    pub(super) fn point(&self, row: &Row, tau: f64) -> Option<(Direction, f64)> {
        let [lo, middle, hi] = row.s;
        let ds = if tau < 0.0 { middle - lo } else { hi - middle };
        let s = middle + ds * tau;
        let (dphi, jacobian) = match row.map {
            RowMap::Linear => (s, ds),
            RowMap::Ridge { offset, gamma } => {
                let t = s.tan();
                (offset + gamma * t, gamma * ds * (1.0 + t * t))
            }
        };
        let (sp, cp) = (self.azimuth + dphi).sin_cos();
        Direction::new(row.cos_e * cp, row.cos_e * sp, row.sin_e).map(|d| (d, jacobian))
    }

    /// sigma at elevation `e`, clamped to the cone (0 above its top, pi below its bottom).
    fn sigma_at(&self, e: f64) -> f64 {
        ((e - self.elevation) / self.beta).clamp(-1.0, 1.0).acos()
    }

    /// The intervals of v that the rules treat as smooth pieces, end to end.
    pub(super) fn pieces(&self) -> Vec<[f64; 2]> {
        self.pieces_in_use()
            .iter()
            .map(|p| [p.v_start, p.v_end()])
            .collect()
    }

    /// True when rows may be cut at tau = 0 (a kink along a meridian): the rules in tau must not cross 0.
    pub(super) fn rows_cut(&self) -> bool {
        self.kink_offset.is_some()
    }

    /// `∫ cos(theta) d omega` over the part above the horizon, with an error estimate. The tau integral of a
    /// constant is 2W, leaving a 1-D integral of an analytic function: Gauss-Legendre on two halves, 16 and 24
    /// nodes (the 24-node result converges to rounding for every cone this class takes, by far).
    pub(super) fn projected_solid_angle(&self) -> (f64, f64) {
        let rule = |n: usize| -> f64 {
            let half = 0.25 * self.sigma_max;
            let mut sum = 0.0;
            for mid in [half, 3.0 * half] {
                for &(x, w) in gauss_legendre(n) {
                    let row = self.row(mid + half * x);
                    sum += w * row.weight * 2.0 * row.half_width;
                }
            }
            half * sum
        };
        let (coarse, fine) = (rule(16), rule(24));
        let error = (fine - coarse).abs().max(64.0 * f64::EPSILON * fine.abs());
        (fine, error)
    }

    /// The starting rectangles of the adaptive rule in (v, tau), as cuts: the pieces each halved, and cut at
    /// their focus when it lies inside, and tau halved.
    pub(super) fn initial_partition(&self) -> (Vec<f64>, Vec<f64>) {
        let mut v_cuts = Vec::with_capacity(4 * self.piece_count + 1);
        for p in self.pieces_in_use() {
            let (lo, hi) = (p.v_start, p.v_end());
            v_cuts.extend([lo, 0.5 * (lo + hi), hi]);
            if p.map.is_some() && p.t[0] < 0.0 && p.t[1] > 0.0 {
                // t = 0 is the focus.
                v_cuts.push(p.v_start - p.t[0]);
            }
        }
        let (lo, hi) = (
            v_cuts.first().copied().unwrap_or(0.0),
            self.pieces_in_use().last().map_or(0.0, Piece::v_end),
        );
        v_cuts.retain(|c| c.is_finite() && *c >= lo && *c <= hi);
        v_cuts.sort_by(f64::total_cmp);
        v_cuts.dedup_by(|x, y| (*x - *y).abs() <= 1e-12 * (hi - lo));
        (v_cuts, vec![-1.0, 0.0, 1.0])
    }
}
