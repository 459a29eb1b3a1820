//! The sample holder: how large a sample it takes, and how repeatably a sample sits in it.

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SampleHolder {
    /// Radius of the largest sample the holder takes (mm); a campaign may state a smaller sample.
    pub max_sample_radius_mm: f64,
    /// How differently the sample sits each time it goes back into the holder (after a direct-beam reading,
    /// or a reference's turn): the standard uncertainty of each of the two components of its normal's tilt
    /// (degrees), the holder's repeatability. No alignment measures it: it is in every value's budget
    /// (`re-seating`). Absent: [`DEFAULT_RESEAT_U_DEG`].
    #[serde(default)]
    pub reseat_u_deg: Option<f64>,
    /// How well the sample's surface was brought onto the arms' axis (mm, standard uncertainty of each of its
    /// two components): without an alignment, what the pointing budget takes for the eccentricity. Absent:
    /// [`DEFAULT_CENTRING_U_MM`].
    #[serde(default)]
    pub centring_u_mm: Option<f64>,
    /// How well the sample's normal is known on the holder without an alignment (degrees, standard uncertainty
    /// of each tilt component: the holder's squareness to the rotation axis and the sample's own wedge).
    /// Absent: the instrument's `alignment_u_deg`.
    #[serde(default)]
    pub tilt_u_deg: Option<f64>,
}

/// How well a sample's surface is on the arms' axis when the instrument file does not say (mm per component):
/// brought there with a dial gauge or a laser, about a tenth of a millimetre.
pub const DEFAULT_CENTRING_U_MM: f64 = 0.1;

/// A holder's re-seating repeatability when the instrument file does not state it (deg per tilt component): a
/// sample pressed back by hand against the same reference face, about a hundredth of a degree (a kinematic
/// mount repeats to microradians; state it).
pub const DEFAULT_RESEAT_U_DEG: f64 = 0.01;

impl SampleHolder {
    /// Each tilt component's re-seating standard uncertainty (deg): the file's, else [`DEFAULT_RESEAT_U_DEG`].
    pub fn reseat_u_deg(&self) -> f64 {
        self.reseat_u_deg.unwrap_or(DEFAULT_RESEAT_U_DEG)
    }

    /// Each tilt component's standard uncertainty without an alignment (deg): the file's, else
    /// `alignment_u_deg` (the instrument's angles as known without an alignment).
    pub fn tilt_u_or(&self, alignment_u_deg: f64) -> f64 {
        self.tilt_u_deg.unwrap_or(alignment_u_deg)
    }

    /// Each component's centring standard uncertainty (mm): the file's, else [`DEFAULT_CENTRING_U_MM`].
    pub fn centring_u_mm(&self) -> f64 {
        self.centring_u_mm.unwrap_or(DEFAULT_CENTRING_U_MM)
    }
}
