//! Alignment: the instrument's geometric errors measured from its own readings (issue 27, first part).
//!
//! The procedure (what an operator does by hand with a mirror and a power meter, automated):
//! 1. **Sample out** (the operator empties the holder): the detector arm is scanned through the direct beam at
//!    a few light-arm angles where both arms can face each other. Each scan's centre is where the detector's
//!    aperture sits on the beam's line.
//! 2. **Mirror in** (the operator mounts a flat mirror on the holder): at several incidence angles on both sides
//!    of the normal and several rotations of the stage, the detector is scanned through the reflection, then,
//!    holding the detector at that centre, the tilt is scanned through it.
//! 3. The centres (each the mid-point of its profile's half-height edges: `centre`) are fitted with the
//!    geometric model (`model`, `fit`); what the observations cannot determine is reported as such. The beam is
//!    seen only along its line as the detector meets it, in and across the arms' plane: applying a calibration
//!    splits each line between the beam's direction and its offset by the instrument file's priors
//!    (`beam_split`), and the same priors (`priors`) are what the geometry is uncertain by without an
//!    alignment.
//!
//! The tilt's zero is its true angle at nominal 0 (its encoder's cyclic error there included: over the few
//! tenths of a degree the tilt scans cover, the two are one offset). The arms' zeros and their encoders' cyclic
//! errors are fitted together; over the arcs the scans cover they are strongly correlated, so each alone is
//! uncertain while their sum at any angle in those arcs ([`AlignmentReport::detector_error_deg`]) is known well.
//!
//! With the holder still empty after step 1, the characterisation (crate::characterise: the meter's ranges, the
//! instrument signature, the source's warm-up) runs when [`AlignOptions::characterise`] asks for it.
//!
//! Not measured yet: the encoders' cyclic errors of the tilt and rotation, the rotation's zero (an isotropic
//! mirror cannot show it: it turns the tilt vector, which absorbs it), and the re-seating of a sample other than
//! the mirror.

pub mod beam_split;
pub mod centre;
pub mod correction;
pub mod file;
pub mod fit;
mod keys;
pub mod model;
pub mod priors;
pub mod sample_tilt;
pub(crate) mod scan;

use std::future::Future;
use std::pin::Pin;

use gonio_driver::{DetectorConfig, PowerRange};
use gonio_instrument::AxisRole;
use gonio_scheduler::kinematics::Pose;
use serde::Serialize;

use crate::characterise::{
    CharacterisationReport, CharacteriseError, CharacteriseOptions, Meter, finish, read_empty_holder,
    sample_overlaps,
};
use crate::motion::{Device, Motion, MotionError};
use crate::rig::Held;
pub use centre::CentreError;
use fit::{GeometryFit, Observed};
use model::{Dimensions, N_PARAMS, Observation, PARAM_NAMES};
use scan::{DETECTOR_HALF_WIDTH_DEG, scan, tilt_half_width_deg};

/// What the operator must put in the holder before a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Placement {
    /// Nothing: the direct beam reaches the detector.
    Empty,
    /// A flat front-surface mirror, its face where a sample's face goes.
    Mirror,
    /// The sample to be measured (the characterisation reads its reflection).
    Sample,
}

impl Placement {
    /// What a dry-run's alignment holder (crate::rig::Rig::alignment_holder) holds for this placement: the
    /// mirror in its first place, the sample in its second.
    pub fn held(self) -> Held {
        match self {
            Placement::Empty => Held::Empty,
            Placement::Mirror => Held::Sample,
            Placement::Sample => Held::Reference,
        }
    }

    /// The instruction to the operator.
    pub fn instruction(self) -> &'static str {
        match self {
            Placement::Empty => {
                "remove everything from the sample holder (the direct beam must reach the detector)"
            }
            Placement::Mirror => {
                "mount the alignment mirror on the sample holder, its face where a sample's face goes"
            }
            Placement::Sample => {
                "mount the sample to be measured on the holder (its reflection gives the meter's smallest ranges \
                 their levels)"
            }
        }
    }
}

/// An operator step's answer: done, or why not. A future, so that a caller can wait for a person (the daemon
/// waits for a confirmation through its API) without holding a thread; `Send`, so that the procedure's future
/// is (the daemon runs it in a task of its own).
pub type OperatorStep<'a> = Pin<Box<dyn Future<Output = Result<(), String>> + Send + 'a>>;

/// Why the alignment stopped.
#[derive(Debug, thiserror::Error)]
pub enum AlignError {
    #[error(transparent)]
    Motion(#[from] MotionError),
    #[error(transparent)]
    Characterise(#[from] CharacteriseError),
    /// A scan could not see what it needs: which scan, and why.
    #[error("{scan}: {cause}")]
    Scan { scan: String, cause: CentreError },
    /// A reading at or over the meter's full scale on its largest range.
    #[error(
        "{scan}: the detector is saturated ({power_w:.3e} W at or over its largest range): attenuate the beam"
    )]
    Saturated { scan: String, power_w: f64 },
    /// The instrument cannot make the poses the procedure needs.
    #[error("{0}")]
    Instrument(String),
    /// The operator did not do a step.
    #[error("operator step not done: {0}")]
    Operator(String),
}

/// The beam's direction against its line through the arms' axis, which no scan here sees (deg, standard
/// uncertainty): an assumption, a 0.2 mm lateral offset of the beam over the 250 mm to a typical detector.
const BEAM_DIRECTION_UNSEEN_DEG: f64 = 0.05;
/// Incidence of the scans of the sample's own lobe (deg).
const LOBE_INCIDENCE_DEG: f64 = 30.0;
/// Incidence of the characterisation's overlaps on the sample (deg): near grazing a glossy sample's lobe is at its
/// brightest, which the second-smallest range needs.
const SAMPLE_INCIDENCE_DEG: f64 = 60.0;
/// Direct-beam light angles tried, then kept where both arms (with the scan) stay inside their travel.
const DIRECT_LIGHT_DEG: [f64; 4] = [-90.0, -85.0, 85.0, 90.0];
/// Incidence angles of the mirror scans (deg from the normal), on both sides.
const INCIDENCE_DEG: [f64; 4] = [15.0, 30.0, 45.0, 60.0];
/// Stage rotations at every incidence, and the extra ones at the first (to see the normal's wobble).
const ROTATIONS_DEG: [f64; 2] = [0.0, 180.0];
const WOBBLE_ROTATIONS_DEG: [f64; 2] = [90.0, -90.0];

/// The observations the procedure makes (the mirror's tilt scans with `detector_deg` 0 until measured), for
/// direct-beam light angles `direct`.
/// `order` is the sign of (detector - light) the arms keep: they cannot pass each other, so every pose keeps the
/// order homing left them in.
pub fn plan_observations(direct: &[f64], order: f64) -> Vec<Observation> {
    let mut out: Vec<Observation> = direct
        .iter()
        .map(|&light_deg| Observation::DirectBeam { light_deg })
        .collect();
    for (k, theta) in INCIDENCE_DEG.iter().enumerate() {
        {
            let light_deg = -order.signum() * theta;
            let mut rotations = ROTATIONS_DEG.to_vec();
            if k == 1 {
                rotations.extend(WOBBLE_ROTATIONS_DEG);
            }
            for rotation_deg in rotations {
                out.push(Observation::MirrorDetector {
                    light_deg,
                    tilt_deg: 0.0,
                    rotation_deg,
                });
                out.push(Observation::MirrorTilt {
                    light_deg,
                    detector_deg: 0.0,
                    rotation_deg,
                });
            }
        }
    }
    out
}

/// One fitted value for the report: `K` and `K_u`, and whether the observations determine it.
#[derive(Debug, Clone, Serialize)]
pub struct Estimate {
    pub name: String,
    pub unit: String,
    pub value: f64,
    pub u: f64,
    pub observable: bool,
}

/// One scan's centre, for the report.
#[derive(Debug, Clone, Serialize)]
pub struct ScanRecord {
    pub observation: Observation,
    pub centre_deg: f64,
    pub centre_u_deg: f64,
    pub residual_deg: f64,
    pub readings: usize,
}

/// What the alignment found.
#[derive(Debug, Clone, Serialize)]
pub struct AlignmentReport {
    pub instrument: String,
    pub dry_run: bool,
    pub band_nm: f64,
    pub estimates: Vec<Estimate>,
    /// What could not be estimated, and why.
    pub unobservable: Vec<String>,
    pub reduced_chi2: f64,
    /// The fitted parameters' covariance, in the order of the first [`N_PARAMS`] estimates.
    pub covariance: Vec<Vec<f64>>,
    pub scans: Vec<ScanRecord>,
    /// Instrument time the procedure took (s).
    pub instrument_s: f64,
    /// The detector's and the source's characterisation, when it ran.
    pub characterisation: Option<CharacterisationReport>,
}

/// What `run_alignment` does besides the geometric alignment.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AlignOptions {
    /// Characterise the detector and the source with the holder empty (crate::characterise).
    pub characterise: Option<CharacteriseOptions>,
    /// Align on the sample's own specular lobe too (crate::align::sample_tilt): its tilt as it sits, used in
    /// place of the mirror's.
    pub on_sample: bool,
}

impl AlignmentReport {
    /// The estimate named `name`.
    pub fn get(&self, name: &str) -> Option<&Estimate> {
        self.estimates.iter().find(|e| e.name == name)
    }

    /// The fitted geometry as the model's parameters.
    pub fn params(&self) -> model::GeometryParams {
        let v: Vec<f64> = self.estimates.iter().take(N_PARAMS).map(|e| e.value).collect();
        model::GeometryParams::from_slice(&v)
    }

    /// The detector arm's true angle minus its nominal one at nominal `detector_deg` (its zero and its encoder's
    /// cyclic error together: what a pose really gets), with its standard uncertainty. The zero and the cyclic
    /// error are correlated over the arcs the scans cover; their sum is known far better than either.
    pub fn detector_error_deg(&self, detector_deg: f64) -> (f64, f64) {
        let p = self.params();
        let (s, c) = detector_deg.to_radians().sin_cos();
        let value = p.detector_zero_deg + p.detector_encoder_sin_deg * s + p.detector_encoder_cos_deg * c;
        let mut g = [0.0; N_PARAMS];
        g[4] = 1.0;
        g[12] = s;
        g[13] = c;
        (value, self.combination_u(&g))
    }

    /// Standard uncertainty of `sum g_k x_k` over the fitted parameters.
    fn combination_u(&self, g: &[f64; N_PARAMS]) -> f64 {
        let c = &self.covariance;
        let mut var = 0.0;
        for i in 0..N_PARAMS {
            for j in 0..N_PARAMS {
                var += g[i] * g[j] * c.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0.0);
            }
        }
        var.max(0.0).sqrt()
    }
}

/// Run the alignment (module doc). `operator` is asked to make each placement; its step ends when it is done.
pub async fn run_alignment<'a>(
    motion: &mut Motion<'_>,
    operator: &'a (dyn Fn(Placement) -> OperatorStep<'a> + Sync),
    options: AlignOptions,
) -> Result<AlignmentReport, AlignError> {
    let rig = motion.rig();
    let file = rig.file().clone();
    let inst = &file.instrument;
    let clock = motion.clock();
    let t0 = clock.now_s();
    for role in [AxisRole::LightArm, AxisRole::DetectorArm] {
        if inst.axis(role).is_none() {
            return Err(AlignError::Instrument(format!(
                "alignment needs a {role:?} axis; this instrument has none"
            )));
        }
    }
    motion.reference_all().await?;
    let band_nm = put_band_in_beam(motion).await?;
    let det = rig.detector();
    let averaging = inst.detector.averaging;
    let config = DetectorConfig {
        wavelength_nm: band_nm,
        averaging,
        range: PowerRange::Auto,
    };
    motion
        .device(Device::Detector, "configure the meter", || det.configure(config))
        .await?;
    let within = |role: AxisRole, deg: f64, margin: f64| {
        inst.axis(role)
            .is_none_or(|a| deg - margin >= a.min_deg && deg + margin <= a.max_deg)
    };
    let direct = direct_beam_light_angles(motion)?;
    let order = arms_order(motion);
    let has_tilt = inst.axis(AxisRole::SampleTilt).is_some();
    let rotations_ok = |r: f64| {
        r == 0.0
            || inst
                .axis(AxisRole::SampleRotation)
                .is_some_and(|a| within(AxisRole::SampleRotation, r, 0.0) && a.max_deg > a.min_deg)
    };
    let plan: Vec<Observation> = plan_observations(&direct, order)
        .into_iter()
        .filter(|o| match o {
            Observation::MirrorTilt { rotation_deg, .. } => has_tilt && rotations_ok(*rotation_deg),
            Observation::MirrorDetector { rotation_deg, .. } => rotations_ok(*rotation_deg),
            Observation::DirectBeam { .. } => true,
        })
        .collect();

    let mut observed: Vec<Observed> = Vec::new();
    let mut readings = Vec::new();
    operator(Placement::Empty).await.map_err(AlignError::Operator)?;
    for o in plan
        .iter()
        .filter(|o| matches!(o, Observation::DirectBeam { .. }))
    {
        let Observation::DirectBeam { light_deg } = *o else {
            continue;
        };
        let name = format!("direct beam, light arm at {light_deg} deg");
        tracing::info!("alignment: {name}");
        let at = |x: f64| Pose::new(light_deg, x, 0.0, 0.0);
        let profile = scan(
            motion,
            &name,
            AxisRole::DetectorArm,
            model::wrap_deg(light_deg + 180.0),
            DETECTOR_HALF_WIDTH_DEG,
            &at,
        )
        .await?;
        let (c, n) = (profile.centre, profile.readings);
        observed.push(Observed {
            what: *o,
            value_deg: c.value,
            u_deg: c.u,
        });
        readings.push(n);
    }
    let first_direct = observed.iter().find_map(|o| match o.what {
        Observation::DirectBeam { light_deg } => Some((light_deg, o.value_deg)),
        _ => None,
    });
    let mut meter = Meter::default();
    let characterise_from = clock.now_s();
    let empty = match (options.characterise, first_direct) {
        (Some(opts), Some((light_deg, facing_deg))) => {
            tracing::info!("characterisation with the holder empty");
            let e = read_empty_holder(motion, &mut meter, light_deg, facing_deg, opts, t0).await?;
            put_band_in_beam(motion).await?;
            motion
                .device(Device::Detector, "configure the meter", || det.configure(config))
                .await?;
            Some(e)
        }
        _ => None,
    };
    let mut characterise_s = clock.now_s() - characterise_from;
    operator(Placement::Mirror).await.map_err(AlignError::Operator)?;
    let mut last_detector = std::collections::BTreeMap::new();
    for o in plan.iter() {
        match *o {
            Observation::MirrorDetector {
                light_deg,
                tilt_deg,
                rotation_deg,
            } => {
                let name =
                    format!("mirror, detector scan, light {light_deg} deg, rotation {rotation_deg} deg");
                tracing::info!("alignment: {name}");
                let at = |x: f64| Pose::new(light_deg, x, tilt_deg, rotation_deg);
                let profile = scan(
                    motion,
                    &name,
                    AxisRole::DetectorArm,
                    -light_deg,
                    DETECTOR_HALF_WIDTH_DEG,
                    &at,
                )
                .await?;
                let (c, n) = (profile.centre, profile.readings);
                last_detector.insert((light_deg.to_bits(), rotation_deg.to_bits()), c.value);
                observed.push(Observed {
                    what: *o,
                    value_deg: c.value,
                    u_deg: c.u,
                });
                readings.push(n);
            }
            Observation::MirrorTilt {
                light_deg,
                rotation_deg,
                ..
            } => {
                let Some(&detector_deg) = last_detector.get(&(light_deg.to_bits(), rotation_deg.to_bits()))
                else {
                    continue;
                };
                let name = format!("mirror, tilt scan, light {light_deg} deg, rotation {rotation_deg} deg");
                tracing::info!("alignment: {name}");
                let at = |x: f64| Pose::new(light_deg, detector_deg, x, rotation_deg);
                let profile = scan(
                    motion,
                    &name,
                    AxisRole::SampleTilt,
                    0.0,
                    tilt_half_width_deg(light_deg.abs()),
                    &at,
                )
                .await?;
                let (c, n) = (profile.centre, profile.readings);
                let what = Observation::MirrorTilt {
                    light_deg,
                    detector_deg,
                    rotation_deg,
                };
                observed.push(Observed {
                    what,
                    value_deg: c.value,
                    u_deg: c.u,
                });
                readings.push(n);
            }
            Observation::DirectBeam { .. } => {}
        }
    }
    let dims = Dimensions {
        detector_distance_mm: inst.detector.distance_mm,
    };
    let nominal = model::Model {
        p: model::GeometryParams::default(),
        dims,
    };
    if let Some(o) = observed.iter().find(|o| nominal.predict(&o.what).is_none()) {
        return Err(AlignError::Instrument(format!(
            "the instrument's nominal geometry cannot produce the scan {:?}",
            o.what
        )));
    }
    let fitted = fit::fit(&observed, dims).ok_or_else(|| {
        AlignError::Instrument(
            "the scan centres do not fit the instrument's geometry (the fit left the model's range)".into(),
        )
    })?;
    // With the sample back in the holder: its own lobe (when asked), then the characterisation's last step.
    let mut on_sample = Vec::new();
    if options.on_sample || empty.is_some() {
        operator(Placement::Sample).await.map_err(AlignError::Operator)?;
    }
    let light_deg = -order.signum() * SAMPLE_INCIDENCE_DEG;
    if options.on_sample {
        let model = model::Model {
            p: fitted.params,
            dims,
        };
        on_sample = sample_tilt::align_on_sample(
            motion,
            &model,
            -order.signum() * LOBE_INCIDENCE_DEG,
            &rotations_ok,
        )
        .await?;
    }
    let characterisation = match empty {
        Some(e) => {
            let from = clock.now_s();
            let position = inst.filter_wheel.as_ref().and_then(|w| {
                w.positions
                    .iter()
                    .find(|p| !p.blank && p.band_nm == Some(e.overlap_nm))
                    .map(|p| p.position)
            });
            let sample =
                sample_overlaps(motion, &mut meter, light_deg, -light_deg, e.overlap_nm, position).await?;
            characterise_s += clock.now_s() - from;
            Some(finish(e, sample, inst, characterise_s))
        }
        None => None,
    };
    let run = RunFacts {
        instrument: inst.name.clone(),
        dry_run: rig.is_dry_run(),
        band_nm,
        instrument_s: clock.now_s() - t0,
    };
    let mut out = report(run, &observed, &readings, &fitted, dims);
    out.estimates.extend(on_sample);
    if let (Some(mut c), Some((_, facing_deg))) = (characterisation, first_direct) {
        // Each signature point's angle from the beam is known to the detector's error there and the beam's
        // line, and to what the scans cannot see: the beam's direction against its line (a lateral offset).
        let (_, detector_u) = out.detector_error_deg(facing_deg);
        let line_u = out.get("beam_line_deg").map_or(0.0, |e| e.u);
        let u_alpha = detector_u.hypot(line_u).hypot(BEAM_DIRECTION_UNSEEN_DEG);
        for s in &mut c.detector.signature {
            s.widen_for_angle(u_alpha);
        }
        out.characterisation = Some(c);
    }
    Ok(out)
}

/// The sign of (detector - light) the arms keep: they cannot pass each other, so every pose keeps the order
/// homing left them in.
pub(crate) fn arms_order(motion: &Motion<'_>) -> f64 {
    let here = *motion.current();
    if here.detector_deg >= here.light_deg {
        1.0
    } else {
        -1.0
    }
}

/// The light-arm angles of [`DIRECT_LIGHT_DEG`] at which the detector arm can face the source (with a scan's
/// width) within both arms' travel and without the arms passing each other.
pub(crate) fn direct_beam_light_angles(motion: &Motion<'_>) -> Result<Vec<f64>, AlignError> {
    let inst = &motion.rig().file().instrument;
    let within = |role: AxisRole, deg: f64, margin: f64| {
        inst.axis(role)
            .is_none_or(|a| deg - margin >= a.min_deg && deg + margin <= a.max_deg)
    };
    let direct: Vec<f64> = DIRECT_LIGHT_DEG
        .iter()
        .copied()
        .filter(|&l| {
            within(AxisRole::LightArm, l, 0.0)
                && within(
                    AxisRole::DetectorArm,
                    model::wrap_deg(l + 180.0),
                    DETECTOR_HALF_WIDTH_DEG + 0.5,
                )
        })
        .collect();
    if direct.is_empty() {
        return Err(AlignError::Instrument(
            "no light-arm angle lets the detector arm face the source within both arms' travel".into(),
        ));
    }
    let order = arms_order(motion);
    let direct: Vec<f64> = direct
        .into_iter()
        .filter(|&l| (model::wrap_deg(l + 180.0) - l) * order > 0.0)
        .collect();
    if direct.is_empty() {
        return Err(AlignError::Instrument(
            "no light-arm angle lets the detector arm face the source without the arms passing each other"
                .into(),
        ));
    }
    Ok(direct)
}

/// What the report says of the run itself.
struct RunFacts {
    instrument: String,
    dry_run: bool,
    band_nm: f64,
    instrument_s: f64,
}

fn report(
    run: RunFacts,
    observed: &[Observed],
    readings: &[usize],
    f: &GeometryFit,
    dims: Dimensions,
) -> AlignmentReport {
    let RunFacts {
        instrument,
        dry_run,
        band_nm,
        instrument_s,
    } = run;
    let values = f.params.to_vec();
    let mut estimates = (0..N_PARAMS)
        .map(|k| Estimate {
            name: PARAM_NAMES[k].0.to_string(),
            unit: PARAM_NAMES[k].1.to_string(),
            value: values[k],
            u: f.u[k],
            observable: f.observable[k],
        })
        .collect::<Vec<_>>();
    for (name, (line, line_u)) in [
        ("beam_line_deg", f.beam_line_deg(dims)),
        ("beam_elevation_line_deg", f.beam_elevation_line_deg(dims)),
    ] {
        estimates.push(Estimate {
            name: name.into(),
            unit: "deg".into(),
            value: line,
            u: line_u,
            observable: line_u < 0.05,
        });
    }
    let mut unobservable: Vec<String> = estimates
        .iter()
        .filter(|e| !e.observable)
        .map(|e| {
            format!(
                "{}: the scans leave it near its prior ({:.3} {} standard uncertainty)",
                e.name, e.u, e.unit
            )
        })
        .collect();
    unobservable.push(
        "the whole instrument's rotation about the arms' axis: nothing on it can see it; the lab frame is defined by \
         the stage's rotation axis"
            .into(),
    );
    unobservable.push(
        "rotation_zero_deg: an isotropic mirror looks the same at every rotation; the sample tilt vector is given at \
         the nominal rotation angles and absorbs it"
            .into(),
    );
    let scans = observed
        .iter()
        .zip(readings)
        .zip(&f.residuals_deg)
        .map(|((o, n), r)| ScanRecord {
            observation: o.what,
            centre_deg: o.value_deg,
            centre_u_deg: o.u_deg,
            residual_deg: *r,
            readings: *n,
        })
        .collect();
    AlignmentReport {
        instrument,
        dry_run,
        band_nm,
        estimates,
        unobservable,
        reduced_chi2: f.reduced_chi2,
        covariance: f.covariance.clone(),
        scans,
        instrument_s,
        characterisation: None,
    }
}

/// The first band of the wheel (or of the detector's table) into the beam; its wavelength.
pub(crate) async fn put_band_in_beam(motion: &Motion<'_>) -> Result<f64, AlignError> {
    let rig = motion.rig();
    let inst = &rig.file().instrument;
    let Some(wheel) = &inst.filter_wheel else {
        return Ok(inst.bands_nm().first().copied().unwrap_or(550.0));
    };
    let Some((position, nm)) = wheel.positions.iter().find_map(|p| {
        p.band_nm
            .filter(|_| !p.blank && p.transmission > 0.0)
            .map(|nm| (p.position, nm))
    }) else {
        return Err(AlignError::Instrument(
            "the filter wheel has no open band to align with".into(),
        ));
    };
    if let Some(w) = rig.wheel() {
        motion
            .device(Device::Wheel, "the alignment band into the beam", || {
                w.go_to(position)
            })
            .await?;
    }
    Ok(nm)
}
