//! Fitting the latitude coordinates to what the BRDF looks like: maps onto a lobe narrower than the aperture (its
//! peak in sigma, its ridge in azimuth and where the ridge crosses the rim), cuts at the kinks, and the layout of
//! the smooth pieces of sigma that the rules run over end to end. The rules then see a smooth integrand.

use std::f64::consts::FRAC_PI_2;

use super::super::{Features, Peak};
use super::{CauchyMap, Latitude, MAX_PIECES, Piece, Ridge, wrap};

/// Where the row integral changes fast in sigma, and on what scale (rad of sigma).
#[derive(Debug, Clone, Copy)]
pub(super) struct Focus {
    pub(super) sigma: f64,
    pub(super) scale: f64,
}

impl Latitude {
    /// The same part of the cone with its maps onto `features.peak` when the lobe is narrower than the
    /// aperture, and cut at the kinks: `features.kink_theta` in sigma, `features.kink_azimuth` in each row and
    /// in sigma where it crosses the rim (there the rows start or stop containing it).
    pub(in crate::optics::aperture) fn adapted_to(mut self, features: &Features) -> Latitude {
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
    pub(super) fn set_pieces(&mut self, foci: &[Focus], cuts: &[f64]) {
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
}
