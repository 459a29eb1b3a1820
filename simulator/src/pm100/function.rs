//! [`Function`]: the meter's measurement function, which `CONFigure` and `MEASure` name, the meter's settings
//! keep, and `READ?` and `FETCh?` measure.
//!
//! Its own module because the command tree ([`super::scpi`], which parses it out of a header) and the command set
//! (`super::commands`, which acts on it) both speak it and neither should reach into the other for it.

/// The measurement function chosen by `CONFigure` or `MEASure`, read by `READ?` and `FETCh?`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Function {
    Power,
    Current,
    PowerDensity,
    Frequency,
    Voltage,
    Energy,
    EnergyDensity,
    Resistance,
    Temperature,
}

impl Function {
    /// The name `CONF?` answers.
    pub(super) fn name(self) -> &'static str {
        match self {
            Function::Power => "POW",
            Function::Current => "CURR",
            Function::PowerDensity => "PDEN",
            Function::Frequency => "FREQ",
            Function::Voltage => "VOLT",
            Function::Energy => "ENER",
            Function::EnergyDensity => "EDEN",
            Function::Resistance => "RES",
            Function::Temperature => "TEMP",
        }
    }

    /// Can a photodiode head measure it? (Voltage is a thermopile's, energy a pyroelectric head's,
    /// resistance and temperature a thermistor's.)
    pub(super) fn photodiode(self) -> bool {
        matches!(
            self,
            Function::Power | Function::Current | Function::PowerDensity | Function::Frequency
        )
    }
}
