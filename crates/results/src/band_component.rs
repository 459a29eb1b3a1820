//! The finite filter band's part of a point's value and budget ([`crate::budget::components::BAND`]).
//!
//! **The centre.** A band's value is the sample's reflectance averaged over the filter's passband and quoted at
//! the band's nominal centre, but the filter's true centre is off its nominal one by up to its catalogue
//! tolerance (the instrument file's `centre_u_nm`, a standard uncertainty). The value moves by the sample's
//! spectral slope times that offset: `u = |df/dlambda| u_lambda`, the slope estimated from the bands measured
//! at the same geometry (the data, not a model of the sample): the slope at the band of the monotone cubic
//! through them (gonio_brdf::spectrum::monotone_cubic_slope: the weighted harmonic mean of the secants on either
//! side, zero at a peak or a trough, a shape-preserving three-point estimate at the ends). Why not a central
//! difference: bands are far apart (100 nm) next to a spectrum's edges, and a difference across an edge is the
//! edge's rise, not the slope at the band. Construction paper (0.06, 0.07, 0.52 at 450, 550, 650 nm) has a slope
//! of about 4e-4 per nm at 550 (its table's own cubic); the central difference said 2.3e-3, the cubic through the
//! three bands says 2e-4. Measured with `gonio-bench --accuracy` (2,000 geometries per material, 16 instruments
//! of realistic.toml, after bring-up): with the central difference paper, coloured plastic and gold were covered
//! at 99-100 % (k = 2, rms z 0.4-0.6), the whole set at 98.4 % (rms z 0.69); with the cubic's slope and the
//! passband below, 96.4 % (rms z 0.83); `gonio fit`'s albedo at 550 nm (ACCURACY.md's fits) within k = 2 on
//! 15 of 16 instruments for paper (rms z 1.18) and 12 of 16 for coloured plastic (1.59: its edge between 500 and
//! 550 nm is finer than three bands resolve), at 450 and 650 nm on all of them. Bands closer than
//! [`crate::run::BAND_TOLERANCE_NM`] are one band. A geometry measured in one band has no spectral information
//! of its own: it borrows its spectrum's shape from the nearest geometries measured in several bands, the
//! probes ([`borrow`]: the campaign's own, or its points for its sweep readings), the borrowed shape's
//! uncertainty added; without a probe its points get no band component.
//!
//! **The leak, corrected.** A filter passes a fraction `L` of light from outside its band (the file's blocking,
//! the source's colour temperature and the detector's responsivity: gonio_instrument::leakage), spread over the
//! detector's range as the source's spectrum times the responsivity ([`LeakSpectrum`], mostly red and near
//! infrared). The direct beam through the same filter carries the same fraction, so a band's measured value is
//! `m = (f + L fbar) / (1 + L)`, `fbar` the sample's value averaged over the leak's spectrum. A grey sample
//! cancels it; a blue band on gold or paper reads several per cent high, on a blue plastic low. The completion
//! solves for `f = m + L (m - fbar)`, with `fbar` from the bands measured at the same geometry, corrected
//! themselves (the sample's spectrum taken as linear between the bands and flat beyond the first and the last:
//! the same rule the simulator's material tables follow beyond their ends, and the one thing a lab cannot
//! measure without a band further out). The correction's uncertainty:
//! - the spectrum beyond the measured bands: within one band step of the outermost band's value (rectangular,
//!   `|f_n - f_n-1| / sqrt 3`), times the share of the leak out there;
//! - the leaked fraction itself: `L` is reckoned against the band's width, so its relative uncertainty is the
//!   width's (`bandwidth_u_nm / bandwidth_nm`); a real passband's shoulders, which the file's top-hat band
//!   leaves out, are well inside it (about 5 % for a three-cavity filter).
//!
//! **The centroid.** The light through a filter is centred a little above its centre (a lamp and a silicon
//! photodiode both favour the red: 0.07-0.24 nm through 10 nm filters from 650 to 450 nm,
//! gonio_instrument::passband), and the value is the sample's spectrum there. Counted with the centre's
//! tolerance, `u = |f'| sqrt(u_lambda^2 + delta^2)`, not corrected: a correction `-f' delta` needs the slope at
//! the band, and at the outermost bands the cubic's end slope is an extrapolation (coloured plastic peaks at
//! its 450 nm band, where the cubic through 450, 550 and 650 says -5e-3 per nm: corrected, its blue values moved
//! 0.26 % the wrong way, and construction paper's curves in BENCHMARKS.md section 7 lost a tenth of their
//! accuracy on realistic.toml, 8.2e-3 to 9.0e-3). A tenth to a quarter of the 1 nm tolerance either way.
//!
//! **The passband.** A band's value is the spectrum averaged over the filter's passband, not its value at the
//! centre: about `f'' sigma^2 / 2` apart, `sigma^2` the passband's variance (gonio_instrument::passband, from
//! the file's `bandwidth_nm`) and `f''` the spectrum's curvature at the band, taken from the monotone cubic through
//! the bands (the larger of its two sides: at the foot of an edge the spectrum is flat on one side of the band
//! and bends on the other). Not corrected, because bands 100 nm apart see an edge's curvature only roughly
//! (paper at 550 nm, worked out by hand from its material table: the cubic through the bands bends by 1.3e-4
//! per nm^2 on its red side, paper's own spectrum by about 3.9e-4, a bias of +1.7 % that the estimate puts at
//! 1.1 %): it is the component's size.
//! Without it, with the cubic's slope alone, `gonio-bench --accuracy` found the 550 nm band's shared error
//! outside its k = 2 interval on a third of paper's instruments (rms z 1.6).
//!
//! The band's error is the filter's, the same for every point of the band: the component is shared by the
//! band's points (group `band-<nm>`).
//!
//! Both estimates are only as good as the band spacing allows: a band between (the wheel's 500 and 600 nm) or
//! further out resolves an edge the cubic through three bands 100 nm apart only guesses at. Measured with
//! `gonio-bench --accuracy --bands 450,500,550,600,650` (all five of the wheel's bands, the whole table; not the
//! one kept in ACCURACY.md): coloured plastic's fitted albedo at 550 nm within k = 2 on 15 of 16 instruments of
//! realistic.toml, without and after bring-up (12 of 16 in three bands), and every fit after bring-up within
//! its targets; but the points' intervals too wide: after bring-up construction paper covered at 100 % (rms z
//! 0.62, the band component 1.45 % of the value against a median error of 0.76 %), coloured plastic at 99.0 %
//! (0.66; the component 0.48 %, 0.27 % in three bands) and gold at 99.3 % (0.71; 0.34 %, 0.20 %),
//! realistic.toml's coverage over the target's 97 % (97.7 % without bring-up, 98.4 % after, rms z 0.76); and on
//! the ideal
//! instrument, whose bands have no width, the coloured plastic's alpha, ior and 450 nm albedo within k = 2 on
//! only 12-14 of 16 (rms z 1.27-1.42), not yet understood. Bands 50 nm apart see more of a spectrum's bend
//! than three do, and the larger side's curvature then counts more of it than the passband averages.
//! Where paper's width comes from there (six instruments of realistic.toml without bring-up, 150 geometries
//! each, the component's parts printed by a build made for it: by hand, not a command in the repository;
//! `gonio-bench --accuracy --bands 450,500,550,600,650 --materials construction-paper` gives the totals):
//! - at 450 and 500 nm, the leak's correction: the filters pass 1.6 % and 0.7 % of those bands' light from
//!   outside them, where paper reflects about seven times its blue value; the spectrum beyond 650 nm (within a
//!   band step of 650 nm's value) is 2.3 % and 1.1 % of the value, the leaked fraction's own uncertainty 1.0 %
//!   and 0.5 %. Errors at 450 nm -1.4 to +2.4 % (rms z 0.1-0.8): wide, but what lies beyond the last band is
//!   not known to the data, and the prior is one band step;
//! - at 550 nm, the passband: the larger side's curvature gives 3.5 % of the value against a bias of about
//!   +2 % (errors +0.4 to +2.9 %, rms z 0.15-0.8). Paper's edge starts at the band: its spectrum bends on the
//!   red side only, and a symmetric passband averages the flat side with the bent one, half the larger side's
//!   bend. The mean of the two sides' signed curvature instead (tried by hand): rms z 0.27-1.43 at 550 nm in
//!   five bands, but 0.38-2.0 in three (the cubic through bands 100 nm apart bends a third as much as paper's
//!   spectrum there, and the larger side is what covered that). Not adopted: in five bands the cubic through
//!   the bands is, on the seed materials, the simulator's own spectrum (their tables are monotone cubics
//!   through nodes 50 nm apart, at the bands), so the mean's good showing there is the simulation's
//!   coincidence, not evidence that a real spectrum between the bands would give the same.

use crate::points::Point;
use crate::run::BAND_TOLERANCE_NM;

/// What the instrument file says of one band's filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterBand {
    pub band_nm: f64,
    /// Standard uncertainty of the filter's centre wavelength (nm).
    pub centre_u_nm: f64,
    /// The light the filter leaks outside its band, relative to the band's own (gonio_instrument::leakage).
    pub leakage: f64,
    /// The relative standard uncertainty of `leakage` (the band width's).
    pub leakage_u_rel: f64,
    /// The variance of the filter's passband about its centre (nm^2): what the band's value averages the
    /// sample's spectrum over (gonio_instrument::passband::variance_nm2); 0 for a band that is a single
    /// wavelength.
    pub passband_variance_nm2: f64,
    /// How far above the filter's centre the light through it is centred (nm; gonio_instrument::passband):
    /// where the band's value is the sample's spectrum, counted with the centre's tolerance.
    pub centroid_offset_nm: f64,
}

/// Where the leaked light falls: `(nm, share)` samples of the source's spectrum times the detector's
/// responsivity, the shares summing to 1 (gonio_instrument::leakage::leak_spectrum).
#[derive(Debug, Clone, PartialEq)]
pub struct LeakSpectrum {
    samples: Vec<(f64, f64)>,
}

/// How the leak divides among the wavelengths a sample was measured at ([`LeakSpectrum::weights`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LeakWeights {
    /// One weight per node, the flat ends included; they sum to 1.
    pub nodes: Vec<f64>,
    /// The leak's share below the first node and above the last: where the spectrum is extrapolated.
    pub below: f64,
    pub above: f64,
}

impl LeakSpectrum {
    /// From `(nm, share)` samples in ascending wavelength (normalised here to a sum of 1); `None` when they do
    /// not sum to a finite positive number.
    pub fn new(mut samples: Vec<(f64, f64)>) -> Option<LeakSpectrum> {
        let total: f64 = samples.iter().map(|s| s.1).sum();
        if !(total.is_finite() && total > 0.0) {
            return None;
        }
        for s in &mut samples {
            s.1 /= total;
        }
        Some(LeakSpectrum { samples })
    }

    /// The weights that average a spectrum known at `nodes_nm` (ascending) over the leak, the spectrum taken
    /// as linear between the nodes and flat beyond them; `None` for no nodes or nodes out of order.
    pub fn weights(&self, nodes_nm: &[f64]) -> Option<LeakWeights> {
        let (&first, &last) = (nodes_nm.first()?, nodes_nm.last()?);
        if nodes_nm
            .windows(2)
            .any(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater))
        {
            return None;
        }
        let n = nodes_nm.len();
        let mut out = LeakWeights {
            nodes: vec![0.0; n],
            below: 0.0,
            above: 0.0,
        };
        for &(nm, w) in &self.samples {
            if nm <= first {
                out.nodes[0] += w;
                out.below += w;
            } else if nm >= last {
                out.nodes[n - 1] += w;
                out.above += w;
            } else {
                // Between nodes k and k + 1: the hat functions of linear interpolation.
                let k = nodes_nm.partition_point(|&x| x <= nm) - 1;
                let t = (nm - nodes_nm[k]) / (nodes_nm[k + 1] - nodes_nm[k]);
                out.nodes[k] += w * (1.0 - t);
                out.nodes[k + 1] += w * t;
            }
        }
        Some(out)
    }
}

/// A point's band estimate: the leak's correction to its value (`value + shift_sr`) and the band component of
/// the corrected value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandEstimate {
    /// What the leak correction adds to the point's value (1/sr).
    pub shift_sr: f64,
    /// How the correction scales the value's own errors (`1 + L`).
    pub scale: f64,
    /// The band component of the corrected value (1/sr, k = 1).
    pub u_sr: f64,
}

/// Geometries closer than this (degrees) are the same geometry seen in another band.
const SAME_GEOMETRY_DEG: f64 = 1e-6;

/// Iterations of the leak's correction: each shrinks what is left by the leaked fraction (a few per cent).
const LEAK_ITERATIONS: usize = 8;

fn same_geometry(a: &Point, b: &Point) -> bool {
    (a.theta_i_deg - b.theta_i_deg).abs() < SAME_GEOMETRY_DEG
        && (a.phi_i_deg - b.phi_i_deg).abs() < SAME_GEOMETRY_DEG
        && (a.theta_o_deg - b.theta_o_deg).abs() < SAME_GEOMETRY_DEG
        && (a.phi_o_deg - b.phi_o_deg).abs() < SAME_GEOMETRY_DEG
}

/// The valid points grouped by geometry, in index order within each group: a point joins the first group (in
/// creation order) whose first point is at its geometry.
fn geometry_groups(points: &[Point]) -> Vec<Vec<usize>> {
    // The groups are found through buckets of theta_o one tolerance wide (a group at this geometry sits in this
    // bucket or a neighbour), so a campaign of thousands of points is not compared with every group
    // (quadratic: a fifth of a 6,000-point completion's time).
    let bucket = |p: &Point| (p.theta_o_deg / SAME_GEOMETRY_DEG).floor() as i64;
    let mut by_bucket: std::collections::HashMap<i64, Vec<usize>> = std::collections::HashMap::new();
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for (i, p) in points.iter().enumerate() {
        if p.value().is_none() {
            continue;
        }
        let b = bucket(p);
        let found = (b.saturating_sub(1)..=b.saturating_add(1))
            .filter_map(|k| by_bucket.get(&k))
            .flatten()
            .copied()
            .filter(|&g| same_geometry(&points[groups[g][0]], p))
            .min();
        match found {
            Some(g) => groups[g].push(i),
            None => {
                by_bucket.entry(b).or_default().push(groups.len());
                groups.push(vec![i]);
            }
        }
    }
    groups
}

/// One band at one geometry: its wavelength, the mean of its values and the points they came from.
struct Band {
    nm: f64,
    mean: f64,
    members: Vec<usize>,
}

/// The bands of each geometry of `points` (valid values only), each geometry's ascending in wavelength, repeats
/// averaged; with the geometry's first point.
fn spectra(points: &[Point]) -> Vec<(usize, Vec<Band>)> {
    geometry_groups(points)
        .into_iter()
        .map(|g| {
            let mut bands: Vec<Band> = Vec::new();
            for &i in &g {
                let p = &points[i];
                let f = p.value().unwrap_or(f64::NAN);
                match bands
                    .iter_mut()
                    .find(|b| (b.nm - p.band_nm).abs() <= BAND_TOLERANCE_NM)
                {
                    Some(b) => {
                        b.mean += f;
                        b.members.push(i);
                    }
                    None => bands.push(Band {
                        nm: p.band_nm,
                        mean: f,
                        members: vec![i],
                    }),
                }
            }
            for b in &mut bands {
                b.mean /= b.members.len() as f64;
            }
            bands.sort_by(|a, b| a.nm.total_cmp(&b.nm));
            (g[0], bands)
        })
        .collect()
}

/// One band's solution at one geometry: the band component (1/sr, k = 1), the leak's mean of the spectrum
/// (1/sr; NaN when there is no leak spectrum, and then nothing is corrected) and the band's leaked fraction.
#[derive(Debug, Clone, Copy)]
struct Solved {
    u_sr: f64,
    fbar: f64,
    leakage: f64,
}

/// The leak's weights for a set of bands, worked out once per set (the same at most geometries).
struct WeightsCache<'a> {
    leak: Option<&'a LeakSpectrum>,
    known: Vec<(Vec<f64>, Option<LeakWeights>)>,
}

impl WeightsCache<'_> {
    fn get(&mut self, nodes: &[f64]) -> Option<LeakWeights> {
        if let Some((_, w)) = self.known.iter().find(|(n, _)| n == nodes) {
            return w.clone();
        }
        let w = self.leak.and_then(|l| l.weights(nodes));
        self.known.push((nodes.to_vec(), w.clone()));
        w
    }
}

/// The band component and the leak's mean of each of `measured` (`(nm, value)` ascending, at least two) at one
/// geometry (module doc); `None` for a band the filters do not describe or whose component is not finite.
fn solve(
    measured: &[(f64, f64)],
    filter: &impl Fn(f64) -> Option<FilterBand>,
    weights: &mut WeightsCache<'_>,
) -> Vec<Option<Solved>> {
    let filters: Vec<Option<FilterBand>> = measured.iter().map(|b| filter(b.0)).collect();
    let nodes: Vec<f64> = measured.iter().map(|b| b.0).collect();
    let weights = weights.get(&nodes);
    let leaked = |k: usize| filters[k].map_or(0.0, |f| f.leakage);
    let values: Vec<f64> = measured.iter().map(|b| b.1).collect();
    // The spectrum net of the leak and the leak's mean of it, solved by iteration (module doc).
    let (spectrum, fbar) = match &weights {
        Some(w) => {
            let mut f = values.clone();
            let mut fbar = 0.0;
            for _ in 0..LEAK_ITERATIONS {
                fbar = w.nodes.iter().zip(&f).map(|(w, f)| w * f).sum::<f64>();
                for (k, fk) in f.iter_mut().enumerate() {
                    *fk = values[k] + leaked(k) * (values[k] - fbar);
                }
            }
            (f, Some(fbar))
        }
        None => (values.clone(), None),
    };
    let nm_spectrum: Vec<(f64, f64)> = nodes.iter().copied().zip(spectrum.iter().copied()).collect();
    // The leak's mean beyond the measured bands: within one band step of the outermost value.
    let n = spectrum.len();
    let fbar_u = weights.as_ref().map(|w| {
        let step = |a: usize, b: usize| (spectrum[a] - spectrum[b]).abs() / 3f64.sqrt();
        (w.above * step(n - 1, n - 2)).hypot(w.below * step(0, 1))
    });
    (0..n)
        .map(|k| {
            let filter = filters[k]?;
            // Where the value's wavelength may be: the filter's centre within its tolerance, and the light's
            // centroid off it (module doc).
            let centre = slope(&nm_spectrum, k).abs() * filter.centre_u_nm.hypot(filter.centroid_offset_nm);
            let passband = if filter.passband_variance_nm2 > 0.0 {
                0.5 * curvature(&nm_spectrum, k) * filter.passband_variance_nm2
            } else {
                0.0
            };
            let filter_u = centre.hypot(passband);
            let l = filter.leakage;
            let (u_sr, fbar) = match (fbar, fbar_u) {
                (Some(fbar), Some(fbar_u)) => {
                    let of_l = l * filter.leakage_u_rel * (values[k] - fbar).abs();
                    (filter_u.hypot(of_l).hypot(l * fbar_u), fbar)
                }
                _ => {
                    // No spectrum for the leak: bounded by the largest relative difference from this band's
                    // value among the bands measured.
                    let value = values[k];
                    let far = values
                        .iter()
                        .map(|f| (f / value - 1.0).abs())
                        .fold(0.0f64, f64::max);
                    (filter_u.hypot(value.abs() * l * far), f64::NAN)
                }
            };
            u_sr.is_finite().then_some(Solved {
                u_sr,
                fbar,
                leakage: l,
            })
        })
        .collect()
}

/// The band estimates of a band's `members` from its solution: each value corrected for the leak by its own
/// value against the leak's mean.
fn estimate_members(points: &[Point], members: &[usize], s: Solved, out: &mut [Option<BandEstimate>]) {
    for &i in members {
        let shift_sr = if s.fbar.is_finite() {
            s.leakage * (points[i].value().unwrap_or(f64::NAN) - s.fbar)
        } else {
            0.0
        };
        if shift_sr.is_finite() {
            out[i] = Some(BandEstimate {
                shift_sr,
                scale: if s.fbar.is_finite() { 1.0 + s.leakage } else { 1.0 },
                u_sr: s.u_sr,
            });
        }
    }
}

/// The band estimate of each point (module doc), `None` where it cannot be made (no valid value, a band the
/// filters do not describe, or one band at the geometry and no probe to borrow a spectrum from). `probes`:
/// points measured in several bands that a geometry measured in one band borrows its spectrum's shape from
/// ([`borrow`]; the campaign's own points, or a campaign's points for its sweep readings); `filter` looks a
/// band up in the instrument file; `leak` is where the filters' leaked light falls (`None`: no correction, the
/// leak only bounded by the measured bands' spread).
pub fn band_estimates(
    points: &[Point],
    probes: &[Point],
    filter: impl Fn(f64) -> Option<FilterBand>,
    leak: Option<&LeakSpectrum>,
) -> Vec<Option<BandEstimate>> {
    let mut out = vec![None; points.len()];
    let mut weights = WeightsCache {
        leak,
        known: Vec::new(),
    };
    let mut lender: Option<borrow::Lender> = None;
    for (first, bands) in spectra(points) {
        if let [band] = &bands[..] {
            if !band.members.iter().all(|&i| borrow::significant(&points[i])) {
                continue;
            }
            let lender = lender.get_or_insert_with(|| borrow::Lender::new(probes));
            if let Some(s) = lender.solve(&points[first], band.nm, band.mean, &filter, &mut weights) {
                estimate_members(points, &band.members, s, &mut out);
            }
            continue;
        }
        let measured: Vec<(f64, f64)> = bands.iter().map(|b| (b.nm, b.mean)).collect();
        for (band, solved) in bands.iter().zip(solve(&measured, &filter, &mut weights)) {
            if let Some(s) = solved {
                estimate_members(points, &band.members, s, &mut out);
            }
        }
    }
    out
}

/// The larger magnitude of the monotone cubic's second derivative (per nm^2) at `spectrum[k]`, from the pieces
/// on either side of it (the cubic's curvature jumps at a band: at the foot of an edge it is flat on one side
/// and bends on the other, and a passband averages both); NaN where the slopes are unknown.
fn curvature(spectrum: &[(f64, f64)], k: usize) -> f64 {
    // A cubic Hermite piece from (x0, y0, d0) to (x1, y1, d1), h = x1 - x0, has second derivative
    // 6 (y1 - y0) / h^2 - (4 d0 + 2 d1) / h at x0 and -6 (y1 - y0) / h^2 + (2 d0 + 4 d1) / h at x1.
    let piece = |a: usize, at_start: bool| {
        let ((x0, y0), (x1, y1)) = (spectrum[a], spectrum[a + 1]);
        let (h, d0, d1) = (x1 - x0, slope(spectrum, a), slope(spectrum, a + 1));
        let chord = 6.0 * (y1 - y0) / (h * h);
        if at_start {
            chord - (4.0 * d0 + 2.0 * d1) / h
        } else {
            -chord + (2.0 * d0 + 4.0 * d1) / h
        }
    };
    let right = (k + 1 < spectrum.len()).then(|| piece(k, true).abs());
    let left = (k > 0 && k < spectrum.len()).then(|| piece(k - 1, false).abs());
    match (left, right) {
        (Some(l), Some(r)) => l.max(r),
        (Some(c), None) | (None, Some(c)) => c,
        (None, None) => f64::NAN,
    }
}

/// The spectral slope (per nm) at `spectrum[k]`: the monotone cubic's through the bands (module doc); NaN
/// where it has none (the caller's bands are ascending and at least two, so never in practice).
fn slope(spectrum: &[(f64, f64)], k: usize) -> f64 {
    gonio_brdf::spectrum::monotone_cubic_slope(spectrum, k).unwrap_or(f64::NAN)
}

mod borrow;

#[cfg(test)]
mod tests;
