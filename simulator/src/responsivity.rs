//! The photodiode's spectral responsivity: the instrument file's (gonio_instrument::responsivity), which the
//! simulated meter and optics compute with.

pub use gonio_instrument::responsivity::Responsivity;
