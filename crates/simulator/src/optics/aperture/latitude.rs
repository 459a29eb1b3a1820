//! Latitude coordinates on the part of a cone above the horizon, with maps onto a narrow lobe.

use std::f64::consts::{FRAC_PI_2, PI};

use gonio_brdf::Direction;

use super::{Features, Peak, gauss_legendre};

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

/// Where the row integral changes fast in sigma, and on what scale (rad of sigma).
#[derive(Debug, Clone, Copy)]
struct Focus {
    sigma: f64,
    scale: f64,
}

/// The meridian of a lobe's peak and its widths.
#[derive(Debug, Clone, Copy)]
struct Ridge {
    /// Azimuth of the peak relative to the axis, in [-pi, pi).
    offset: f64,
    /// Elevation of the peak.
    elevation: f64,
    /// As in [`Peak`].
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

    /// The same part of the cone with its maps onto `features.peak` when the lobe is narrower than the
    /// aperture, and cut at the kinks: `features.kink_theta` in sigma, `features.kink_azimuth` in each row and
    /// in sigma where it crosses the rim (there the rows start or stop containing it).
    pub(super) fn adapted_to(mut self, features: &Features) -> Latitude {
        let mut cuts: Vec<f64> = features
            .kink_theta
            .filter(|t| t.is_finite())
            .map(|t| self.sigma_at(FRAC_PI_2 - t))
            .into_iter()
            .collect();
        if let Some(azimuth) = features.kink_azimuth.filter(|a| a.is_finite()) {
            // Rows that do not reach the meridian are not cut (`row`), nor is sigma where it misses the rim.
            let offset = wrap(azimuth - self.azimuth);
            self.kink_offset = Some(offset);
            cuts.extend(self.rim_crossings_of(offset).into_iter().map(|(sigma, _)| sigma));
        }
        let mut foci = Vec::with_capacity(3);
        let ok = |w: f64| w > 0.0 && w.is_finite();
        if let Some(p) = features
            .peak
            .filter(|p| ok(p.width) && p.across.0 >= 0.0 && p.across.1 >= 0.0)
        {
            self.map_onto(&p, &mut foci);
        }
        self.set_pieces(&foci, &cuts);
        self
    }

    /// Set the ridge map onto a lobe and collect its foci in sigma.
    fn map_onto(&mut self, p: &Peak, foci: &mut Vec<Focus>) {
        let d = &p.direction;
        let e_peak = d.z().atan2(d.sin_theta());
        let offset = wrap(d.phi() - self.azimuth);
        let (e_top, e_bottom) = (self.elevation + self.beta, (self.elevation - self.beta).max(0.0));
        // The width across at the lowest elevation of the part above the horizon, where it is narrowest.
        let across = p.across.0 + p.across.1 * e_bottom.sin();
        if !(across > 0.0 && across.is_finite()) {
            return;
        }
        // How far the peak lies outside the part above the horizon, in elevation and across (roughly). Seen from
        // a distance the lobe is wider: a GGX lobe `(alpha^2 + s_along^2 + s_across^2)^-2` in the half vector's
        // slopes, at a distance g along, is `hypot(1, g / width)` times wider across, and conversely.
        let gap_e = (e_peak - e_top).max(e_bottom - e_peak).max(0.0);
        let gap_a = (offset.abs() * e_peak.cos() - self.beta).max(0.0);
        let along = p.width * (1.0 + (gap_e / p.width).powi(2) + (gap_a / across).powi(2)).sqrt();
        if along < self.beta {
            let centre = self.sigma_at(e_peak).min(self.sigma_max);
            // An angle w along the meridian is w / (beta sin sigma) in sigma; near the cone's top or bottom, where
            // the elevation is quadratic in sigma, sqrt(2 w / beta).
            let scale = (along / (self.beta * centre.sin())).min((2.0 * along / self.beta).sqrt());
            foci.push(Focus { sigma: centre, scale });
        }
        let wide = across * (1.0 + (gap_e / p.width).powi(2)).sqrt();
        // Farther than 1e4 widths the map's tangent would lose digits, and the tail is smooth anyway.
        if wide < self.beta && offset.abs() < 1e4 * wide {
            let ridge = Ridge {
                offset,
                elevation: e_peak,
                width: p.width,
                across: p.across,
            };
            self.ridge = Some(ridge);
            foci.extend(self.rim_crossings(&ridge));
        }
    }

    /// Where the ridge's meridian crosses the cone's rim above the horizon: there the row integral goes from
    /// the whole ridge to none of it as W(sigma) passes |offset|, over `gamma / |W'(sigma)|` in sigma (or
    /// `sqrt(2 gamma / |W''|)` where the meridian grazes the rim).
    ///
    /// The meridian at azimuth `phi_axis + offset` meets the rim where `w . axis = cos(beta)`:
    /// `cos(e) cos(e_axis) cos(offset) + sin(e) sin(e_axis) = cos(beta)`, i.e. `R cos(e - delta) = cos(beta)`.
    fn rim_crossings(&self, ridge: &Ridge) -> Vec<Focus> {
        let mut foci = Vec::with_capacity(2);
        for (sigma, e) in self.rim_crossings_of(ridge.offset) {
            let h = 1e-4 * sigma.min(self.sigma_max - sigma).min(0.01);
            let w = |s: f64| self.row(s).half_width;
            let (w0, wp, wm) = (w(sigma), w(sigma + h), w(sigma - h));
            let slope = ((wp - wm) / (2.0 * h)).abs();
            let curvature = ((wp - 2.0 * w0 + wm) / (h * h)).abs();
            let (sin_e, cos_e) = e.sin_cos();
            let gamma = ridge.gamma(sin_e, cos_e);
            let scale = (gamma / slope).min((2.0 * gamma / curvature).sqrt());
            // Only a transition inside the part above needs a map: one that reaches the cone's top or the
            // horizon is damped there by the row weight (sin(sigma), sin(e) -> 0), and a crossing at the very
            // top is the ridge through the top point (offset 0 up to rounding), no transition at all.
            if scale > 0.0 && scale < sigma.min(self.sigma_max - sigma) {
                foci.push(Focus { sigma, scale });
            }
        }
        foci
    }

    /// (sigma, elevation) where the meridian at `offset` from the axis's crosses the rim strictly inside the
    /// part above the horizon (not at the cone's top, not on the horizon, where it bounds the part anyway).
    fn rim_crossings_of(&self, offset: f64) -> Vec<(f64, f64)> {
        let a = self.cos_elevation * offset.cos();
        let b = self.elevation.sin();
        let (r, delta) = (a.hypot(b), b.atan2(a));
        let c = self.beta.cos() / r;
        if c.is_nan() || c >= 1.0 {
            return Vec::new();
        }
        let spread = c.acos();
        [delta + spread, delta - spread]
            .into_iter()
            .map(|e| (self.sigma_at(e), e))
            .filter(|&(sigma, _)| sigma > 1e-9 * self.sigma_max && sigma < self.sigma_max * (1.0 - 1e-9))
            .collect()
    }

    /// Lay out the pieces: each focus in a piece of its own, mapped onto it, the pieces meeting where the maps'
    /// node densities `scale / (sigma - centre)^2` are equal; each piece cut again at the kinks' sigmas.
    fn set_pieces(&mut self, foci: &[Focus], cuts: &[f64]) {
        let mut foci = foci.to_vec();
        foci.sort_by(|a, b| a.sigma.total_cmp(&b.sigma));
        let mut spans: Vec<(f64, f64, Option<CauchyMap>)> = Vec::with_capacity(MAX_PIECES);
        let mut lo = 0.0;
        for (k, f) in foci.iter().enumerate() {
            let hi = match foci.get(k + 1) {
                Some(g) => {
                    let (ra, rb) = (f.scale.sqrt(), g.scale.sqrt());
                    f.sigma + (g.sigma - f.sigma) * ra / (ra + rb)
                }
                None => self.sigma_max,
            };
            spans.push((lo, hi, Some((f.sigma, f.scale))));
            lo = hi;
        }
        if spans.is_empty() {
            spans.push((0.0, self.sigma_max, None));
        }
        let inside = |s: f64| s > 1e-9 * self.sigma_max && s < self.sigma_max * (1.0 - 1e-9);
        self.piece_count = 0;
        let mut v = 0.0;
        for (lo, hi, map) in spans {
            let mut bounds = vec![lo];
            bounds.extend(cuts.iter().copied().filter(|&c| inside(c) && c > lo && c < hi));
            bounds.push(hi);
            bounds.sort_by(f64::total_cmp);
            for w in bounds.windows(2) {
                if w[1] <= w[0] {
                    continue;
                }
                if self.piece_count == MAX_PIECES {
                    // More pieces than the features can make (module docs); should it happen, the last piece
                    // stretches to the end: any of the maps spans any range, and no part of the cone is lost.
                    let last = &mut self.pieces[MAX_PIECES - 1];
                    last.t[1] = Piece::new(w[0], w[1], last.map).t[1];
                    continue;
                }
                let mut piece = Piece::new(w[0], w[1], map);
                piece.v_start = v;
                v = piece.v_end();
                self.pieces[self.piece_count] = piece;
                self.piece_count += 1;
            }
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latitude_rows_span_the_cone_exactly() {
        // The row at sigma lies at elevation e_axis + beta cos(sigma), its ends (tau = +-1) on the rim, its
        // middle inside; the horizon row is at elevation 0. Cones above, on and below the horizon, at any azimuth,
        // with and without the maps onto a lobe.
        for (beta, frac, phi) in [
            (0.01, 0.5, 0.3),
            (0.1, 0.0, 2.0),
            (0.3, -0.7, -1.0),
            (0.05, 0.99, 3.1),
        ] {
            let axis = Direction::from_spherical(FRAC_PI_2 - frac * beta, phi);
            let lat = Latitude::new(beta, frac * beta, phi).expect("across the horizon");
            let horizon = lat.point(&lat.row(lat.sigma_max), 0.0).map(|(d, _)| d.z());
            assert!(horizon.is_none_or(|z| z.abs() < 1e-15), "{horizon:?}");
            let peak = Peak {
                direction: Direction::from_spherical(FRAC_PI_2 - 0.2 * beta, phi + 0.1 * beta),
                width: 0.05 * beta,
                across: (0.01 * beta, 0.0),
            };
            let features = Features {
                peak: Some(peak),
                kink_theta: None,
                kink_azimuth: None,
            };
            for lat in [lat, lat.adapted_to(&features)] {
                for k in 1..20 {
                    let sigma = lat.sigma_max * k as f64 / 20.0;
                    let row = lat.row(sigma);
                    let e = frac * beta + beta * sigma.cos();
                    for (tau, inside) in [(-1.0, false), (1.0, false), (0.3, true)] {
                        let (d, jacobian) = lat.point(&row, tau).expect("a direction");
                        assert!((d.z() - e.sin()).abs() < 1e-15, "elevation at sigma {sigma}");
                        assert!(jacobian > 0.0);
                        let rho = d.angle_to(&axis);
                        if inside {
                            assert!(rho < beta, "sigma {sigma}: inside at {rho}");
                        } else {
                            assert!(
                                (rho - beta).abs() < 1e-12 * beta.max(1.0),
                                "sigma {sigma}: {rho} vs {beta}"
                            );
                        }
                    }
                }
            }
        }
    }

    /// v runs over [0, total] continuously: sigma is continuous and increasing across the pieces, from 0 to
    /// sigma_max, with each focus where its map puts it.
    fn assert_pieces_cover_sigma(lat: &Latitude) {
        let pieces = lat.pieces();
        assert_eq!(pieces[0][0], 0.0);
        for w in pieces.windows(2) {
            assert_eq!(w[0][1], w[1][0], "{pieces:?}");
            let (below, _) = lat.sigma(w[0][1] - 1e-12);
            let (above, _) = lat.sigma(w[1][0] + 1e-12);
            assert!((above - below).abs() < 1e-9, "{below} {above}");
        }
        let last = pieces[pieces.len() - 1][1];
        assert!(lat.sigma(0.0).0.abs() < 1e-12);
        assert!((lat.sigma(last).0 - lat.sigma_max).abs() < 1e-12 * lat.sigma_max);
        let mut previous = -1.0;
        for k in 0..=1000 {
            let (sigma, jacobian) = lat.sigma(last * k as f64 / 1000.0);
            assert!(sigma > previous && jacobian > 0.0, "{sigma} after {previous}");
            previous = sigma;
        }
    }

    #[test]
    fn a_ridge_crossing_the_rim_gets_a_piece_mapped_onto_the_crossing() {
        // A narrow ridge (0.001 rad across) on the meridian 0.016 rad from the axis's, peak above the cone's top;
        // the axis 0.042 rad below the horizon, half-angle 0.05 rad: the meridian leaves the part above through
        // the rim at one elevation, where the map centres a piece.
        let (beta, elevation, azimuth) = (0.05, -0.0424, 0.656);
        let lat = Latitude::new(beta, elevation, azimuth).expect("across");
        let peak = Peak {
            direction: Direction::from_spherical(FRAC_PI_2 - 0.0239, azimuth - 0.016),
            width: 0.06,
            across: (0.0007, 0.03),
        };
        let features = Features {
            peak: Some(peak),
            kink_theta: Some(FRAC_PI_2 - 0.002),
            kink_azimuth: None,
        };
        let mapped = lat.adapted_to(&features);
        assert_pieces_cover_sigma(&mapped);
        let foci: Vec<(f64, f64)> = mapped.pieces_in_use().iter().filter_map(|p| p.map).collect();
        assert!(!foci.is_empty(), "{mapped:?}");
        // Every focus is a rim crossing: W(sigma) = |offset| there.
        for (sigma, scale) in &foci {
            let w = mapped.row(*sigma).half_width;
            assert!((w - 0.016).abs() < 1e-9, "W {w} at {sigma}");
            assert!(*scale > 0.0 && *scale < 0.1 * mapped.sigma_max, "{scale}");
        }
        // The kink's row is a cut too: two pieces with the same map.
        assert_eq!(mapped.pieces().len(), 2, "{mapped:?}");
        // Without a ridge (a lobe as wide as the cone), one piece and no map.
        let wide = Features {
            peak: Some(Peak {
                across: (0.2, 0.0),
                width: 0.2,
                ..peak
            }),
            kink_theta: None,
            kink_azimuth: None,
        };
        let plain = lat.adapted_to(&wide);
        assert_pieces_cover_sigma(&plain);
        assert_eq!(plain.pieces().len(), 1);
    }

    #[test]
    fn a_kink_along_a_meridian_cuts_the_rows_at_tau_zero_and_sigma_where_it_meets_the_rim() {
        // The axis 0.02 rad below the horizon, half-angle 0.05: the meridian 0.02 rad from the axis's crosses
        // the rim once above the horizon. Rows wider than 0.02 have the kink at tau = 0; narrower rows are
        // linear in tau; sigma is cut where W(sigma) = 0.02, with and without a lobe's maps.
        let (beta, elevation, azimuth) = (0.05, -0.02, 1.0);
        let lat = Latitude::new(beta, elevation, azimuth).expect("across");
        let kink = Features {
            peak: None,
            kink_theta: None,
            kink_azimuth: Some(azimuth + 0.02),
        };
        let lobe = Features {
            peak: Some(Peak {
                direction: Direction::from_spherical(FRAC_PI_2 - 0.01, azimuth - 0.01),
                width: 0.02,
                across: (0.002, 0.0),
            }),
            ..kink
        };
        for features in [kink, lobe] {
            let cut = lat.adapted_to(&features);
            assert!(cut.rows_cut());
            assert_pieces_cover_sigma(&cut);
            let bounds: Vec<f64> = cut.pieces().iter().map(|p| cut.sigma(p[0]).0).collect();
            let crossings: Vec<f64> = bounds
                .iter()
                .copied()
                .filter(|&s| (cut.row(s).half_width - 0.02).abs() < 1e-9)
                .collect();
            assert_eq!(crossings.len(), 1, "{bounds:?}");
            for k in 1..40 {
                let sigma = cut.sigma_max * k as f64 / 40.0;
                let row = cut.row(sigma);
                let (d, _) = cut.point(&row, 0.0).expect("a direction");
                let dphi = wrap(d.phi() - azimuth);
                if row.half_width > 0.02 {
                    assert!((dphi - 0.02).abs() < 1e-12, "sigma {sigma}: the kink at {dphi}");
                } else if features.peak.is_none() {
                    assert!(dphi.abs() < 1e-12, "sigma {sigma}: the middle at {dphi}");
                }
                // The two halves still span the row, rim to rim.
                for tau in [-1.0, 1.0] {
                    let (d, _) = cut.point(&row, tau).expect("a direction");
                    assert!((wrap(d.phi() - azimuth).abs() - row.half_width).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn more_pieces_than_room_still_cover_the_whole_range() {
        let mut lat = Latitude::new(0.1, 0.02, 0.0).expect("across");
        let m = lat.sigma_max;
        let foci: Vec<Focus> = (1..=5)
            .map(|k| Focus {
                sigma: m * k as f64 / 6.0,
                scale: 0.01,
            })
            .collect();
        let cuts: Vec<f64> = (1..=5).map(|k| m * (k as f64 + 0.5) / 6.0).collect();
        lat.set_pieces(&foci, &cuts);
        assert_eq!(lat.pieces().len(), MAX_PIECES);
        assert_pieces_cover_sigma(&lat);
    }
}
