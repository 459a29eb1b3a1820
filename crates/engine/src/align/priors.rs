//! What an instrument's geometry is uncertain by before any alignment: each parameter of the geometric model
//! (crate::align::model) with the standard uncertainty the instrument file states for how the lab set it up.
//! A campaign run without an alignment carries them in its pointing budget, each through the model as one
//! error shared by the campaign (crate::budget::positioning), where three offsets of theta_i, theta_o and the
//! azimuth could not describe a tilted sample or a beam beside the axis; an alignment's file falls back on
//! them for a parameter it fitted but could not observe and has no observed combination for
//! (crate::align::file).
//!
//! - the beam's direction (`beam_deg`, the light arm's zero against the beam included): the file's
//!   `alignment_u_deg`, the zeros as set by eye;
//! - its elevation: `[instrument.source] pointing_u_deg` (else `alignment_u_deg`); its offsets beside and
//!   above the axis: `offset_u_mm`;
//! - the detector's and the tilt's zeros: `alignment_u_deg`; the sample's tilt on its holder:
//!   `[instrument.sample_holder] tilt_u_deg` (else `alignment_u_deg`);
//! - the sample's surface off the arms' axis (both components): `[instrument.sample_holder] centring_u_mm`;
//! - the encoders' cyclic errors: none (no file figure states them; an alignment bounds them).

use gonio_instrument::Instrument;

use super::model::{N_PARAMS, PARAM_NAMES};

/// Each parameter's prior standard uncertainty on `instrument` (module doc), in [`PARAM_NAMES`] order.
pub fn prior_u(instrument: &Instrument) -> [f64; N_PARAMS] {
    let zero = instrument.alignment_u_deg();
    let pointing = instrument.source.pointing_u_or(zero);
    let offset = instrument.source.offset_u_or_default();
    let centring = instrument.sample_holder.centring_u_mm();
    let tilt = instrument.sample_holder.tilt_u_or(zero);
    let mut u = [0.0; N_PARAMS];
    for (k, (name, _)) in PARAM_NAMES.iter().enumerate() {
        u[k] = match *name {
            "beam_deg" | "detector_zero_deg" | "tilt_zero_deg" => zero,
            "sample_tilt_x_deg" | "sample_tilt_y_deg" => tilt,
            "beam_elevation_deg" => pointing,
            "beam_lateral_mm" | "beam_vertical_mm" => offset,
            "eccentricity_x_mm" | "eccentricity_y_mm" => centring,
            _ => 0.0,
        };
    }
    u
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_instrument::InstrumentFile;

    #[test]
    fn each_parameter_takes_the_file_figure_for_how_it_was_set() {
        let mut inst = InstrumentFile::simulated().instrument;
        inst.alignment_u_deg = Some(0.05);
        inst.source.pointing_u_deg = Some(0.01);
        inst.source.offset_u_mm = Some(0.07);
        inst.sample_holder.centring_u_mm = Some(0.2);
        inst.sample_holder.tilt_u_deg = Some(0.03);
        let u = prior_u(&inst);
        let of = |name: &str| {
            u[PARAM_NAMES
                .iter()
                .position(|(n, _)| *n == name)
                .expect("a parameter")]
        };
        assert_eq!(of("beam_deg"), 0.05);
        assert_eq!(of("detector_zero_deg"), 0.05);
        assert_eq!(of("sample_tilt_y_deg"), 0.03);
        assert_eq!(of("beam_elevation_deg"), 0.01);
        assert_eq!(of("beam_vertical_mm"), 0.07);
        assert_eq!(of("eccentricity_x_mm"), 0.2);
        assert_eq!(of("light_encoder_sin_deg"), 0.0);
    }
}
