//! A measured material: a MERL channel or an RGL file, behind one [`Brdf`] implementation.

use super::*;

/// A measured material: the table, shared (it is large), and where it came from.
#[derive(Debug, Clone)]
pub struct MeasuredMaterial {
    pub(super) table: MeasuredTable,
    pub(super) file: PathBuf,
}

/// The data of a measured material, by format.
#[derive(Debug, Clone)]
pub enum MeasuredTable {
    /// One channel of a MERL table.
    Merl {
        brdf: Arc<MeasuredBrdf>,
        channel: MerlChannel,
    },
    /// An RGL file (spectral).
    Rgl(Arc<RglBrdf>),
}

impl MeasuredMaterial {
    pub fn table(&self) -> &MeasuredTable {
        &self.table
    }
    /// The data file, resolved against the directory of the description it came from.
    pub fn file(&self) -> &Path {
        &self.file
    }
}

macro_rules! measured_dispatch {
    ($self:expr, $b:ident => $e:expr) => {
        match &$self.table {
            MeasuredTable::Merl { brdf, .. } => {
                let $b: &MeasuredBrdf = brdf;
                $e
            }
            MeasuredTable::Rgl(rgl) => {
                let $b: &RglBrdf = rgl;
                $e
            }
        }
    };
}

impl Brdf for MeasuredMaterial {
    fn eval(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Result<f64, SpectrumError> {
        measured_dispatch!(self, b => b.eval(wi, wo, wavelength))
    }
    fn is_isotropic(&self) -> bool {
        measured_dispatch!(self, b => b.is_isotropic())
    }
    fn is_spectrally_flat(&self) -> bool {
        measured_dispatch!(self, b => b.is_spectrally_flat())
    }
    fn delta_lobe(&self, wi: &Direction, wavelength: Wavelength) -> Result<Option<DeltaLobe>, SpectrumError> {
        measured_dispatch!(self, b => b.delta_lobe(wi, wavelength))
    }
    fn has_delta_lobe(&self) -> bool {
        measured_dispatch!(self, b => b.has_delta_lobe())
    }
    fn sample(
        &self,
        wi: &Direction,
        u: [f64; 2],
        wavelength: Wavelength,
    ) -> Result<Option<DirectionSample>, SpectrumError> {
        measured_dispatch!(self, b => b.sample(wi, u, wavelength))
    }
    fn lobe_width(&self) -> Option<f64> {
        measured_dispatch!(self, b => b.lobe_width())
    }
}
