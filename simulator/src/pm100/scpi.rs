//! SCPI program headers and data: matching a header against the command tree (short and long forms,
//! optional nodes, numeric suffix 1), the `MIN`/`MAX` numeric arguments, and the NR3 number format.

use super::function::Function;

/// SCPI commands the meter knows (the common `*` commands are matched apart).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Cmd {
    SystSensIdn,
    SystErr,
    SystVers,
    Wavelength,
    RangeAuto,
    Range,
    CurrentRangeAuto,
    CurrentRange,
    Unit,
    Average,
    BeamDiameter,
    Responsivity,
    Conf(Function),
    ConfQuery,
    Meas(Function),
    Read,
    Fetch,
    Init,
    Abort,
    QuesCond,
    QuesEvent,
    QuesEnable,
    OperCond,
    OperEvent,
    OperEnable,
    StatPreset,
}

/// Command tree patterns: nodes separated by ':', `[...]` optional, upper-case part = short form. The first
/// match wins, so a longer pattern comes before its prefix.
const PATTERNS: &[(&str, Cmd)] = &[
    ("SYSTem:SENSor:IDN", Cmd::SystSensIdn),
    ("SYSTem:ERRor[:NEXT]", Cmd::SystErr),
    ("SYSTem:VERSion", Cmd::SystVers),
    ("[SENSe]:CORRection:WAVelength", Cmd::Wavelength),
    ("[SENSe]:CORRection:BEAMdiameter", Cmd::BeamDiameter),
    ("[SENSe]:CORRection:POWer[:PDIOde][:RESPonse]", Cmd::Responsivity),
    ("[SENSe]:POWer[:DC]:RANGe:AUTO", Cmd::RangeAuto),
    ("[SENSe]:POWer[:DC]:RANGe[:UPPer]", Cmd::Range),
    ("[SENSe]:CURRent[:DC]:RANGe:AUTO", Cmd::CurrentRangeAuto),
    ("[SENSe]:CURRent[:DC]:RANGe[:UPPer]", Cmd::CurrentRange),
    ("[SENSe]:POWer[:DC]:UNIT", Cmd::Unit),
    ("[SENSe]:AVERage[:COUNt]", Cmd::Average),
    ("CONFigure[:SCALar]:POWer", Cmd::Conf(Function::Power)),
    ("CONFigure[:SCALar]:CURRent[:DC]", Cmd::Conf(Function::Current)),
    ("CONFigure[:SCALar]:PDENsity", Cmd::Conf(Function::PowerDensity)),
    ("CONFigure[:SCALar]:FREQuency", Cmd::Conf(Function::Frequency)),
    ("CONFigure[:SCALar]:VOLTage[:DC]", Cmd::Conf(Function::Voltage)),
    ("CONFigure[:SCALar]:ENERgy", Cmd::Conf(Function::Energy)),
    ("CONFigure[:SCALar]:EDENsity", Cmd::Conf(Function::EnergyDensity)),
    ("CONFigure[:SCALar]:RESistance", Cmd::Conf(Function::Resistance)),
    ("CONFigure[:SCALar]:TEMPerature", Cmd::Conf(Function::Temperature)),
    ("CONFigure", Cmd::ConfQuery),
    ("MEASure[:SCALar]:POWer", Cmd::Meas(Function::Power)),
    ("MEASure[:SCALar]:CURRent[:DC]", Cmd::Meas(Function::Current)),
    ("MEASure[:SCALar]:PDENsity", Cmd::Meas(Function::PowerDensity)),
    ("MEASure[:SCALar]:FREQuency", Cmd::Meas(Function::Frequency)),
    ("MEASure[:SCALar]:VOLTage[:DC]", Cmd::Meas(Function::Voltage)),
    ("MEASure[:SCALar]:ENERgy", Cmd::Meas(Function::Energy)),
    ("MEASure[:SCALar]:EDENsity", Cmd::Meas(Function::EnergyDensity)),
    ("MEASure[:SCALar]:RESistance", Cmd::Meas(Function::Resistance)),
    ("MEASure[:SCALar]:TEMPerature", Cmd::Meas(Function::Temperature)),
    ("MEASure", Cmd::Meas(Function::Power)),
    ("READ", Cmd::Read),
    ("FETCh", Cmd::Fetch),
    ("INITiate[:IMMediate]", Cmd::Init),
    ("ABORt", Cmd::Abort),
    ("STATus:QUEStionable:CONDition", Cmd::QuesCond),
    ("STATus:QUEStionable[:EVENt]", Cmd::QuesEvent),
    ("STATus:QUEStionable:ENABle", Cmd::QuesEnable),
    ("STATus:OPERation:CONDition", Cmd::OperCond),
    ("STATus:OPERation[:EVENt]", Cmd::OperEvent),
    ("STATus:OPERation:ENABle", Cmd::OperEnable),
    ("STATus:PRESet", Cmd::StatPreset),
];

/// A numeric parameter: a number or one of the SCPI keywords for the limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Num {
    Value(f64),
    Min,
    Max,
    Default,
}

/// Parse a numeric parameter; errors are SCPI (code, text).
pub(super) fn parse_num(arg: &str) -> Result<Num, (i32, &'static str)> {
    let a = arg.trim();
    if a.is_empty() {
        return Err((-109, "Missing parameter"));
    }
    match a.to_ascii_uppercase().as_str() {
        "MIN" | "MINIMUM" => return Ok(Num::Min),
        "MAX" | "MAXIMUM" => return Ok(Num::Max),
        "DEF" | "DEFAULT" => return Ok(Num::Default),
        _ => {}
    }
    a.parse::<f64>()
        .ok()
        .filter(|x| x.is_finite())
        .map(Num::Value)
        .ok_or((-104, "Data type error"))
}

/// The argument of a query that takes `MIN`/`MAX`: none (the current value), or a limit.
pub(super) fn query_limit(arg: &str) -> Result<Option<Num>, (i32, &'static str)> {
    if arg.trim().is_empty() {
        return Ok(None);
    }
    match parse_num(arg)? {
        Num::Value(_) => Err((-224, "Illegal parameter value")),
        n => Ok(Some(n)),
    }
}

/// Does `word` name the node `long` (short form = its upper-case prefix), with an optional numeric suffix 1?
fn node_matches(word: &str, long: &str) -> bool {
    let word = word.strip_suffix('1').filter(|w| !w.is_empty()).unwrap_or(word);
    let short: String = long.chars().take_while(|c| c.is_ascii_uppercase()).collect();
    word.eq_ignore_ascii_case(&short) || word.eq_ignore_ascii_case(long)
}

fn match_pattern(words: &[&str], nodes: &[(&str, bool)]) -> bool {
    match (words.first(), nodes.first()) {
        (None, None) => true,
        (None, Some(_)) => nodes.iter().all(|(_, optional)| *optional),
        (Some(_), None) => false,
        (Some(w), Some((long, optional))) => {
            (node_matches(w, long) && match_pattern(&words[1..], &nodes[1..]))
                || (*optional && match_pattern(words, &nodes[1..]))
        }
    }
}

pub(super) fn match_header(header: &str) -> Option<Cmd> {
    let header = header.strip_prefix(':').unwrap_or(header);
    let words: Vec<&str> = header.split(':').collect();
    if words.iter().any(|w| w.is_empty()) {
        return None;
    }
    PATTERNS.iter().find_map(|(pattern, cmd)| {
        let nodes: Vec<(&str, bool)> = pattern
            .split(':')
            .filter(|n| !n.is_empty())
            .map(|n| {
                let optional = n.starts_with('[') || n.ends_with(']');
                (n.trim_matches(|c| c == '[' || c == ']'), optional)
            })
            .collect();
        // "[:NEXT]" splits as "[" + "NEXT]": the filter above drops the empty piece.
        match_pattern(&words, &nodes).then_some(*cmd)
    })
}

/// SCPI NR3 format: `d.dddddde±XX`.
pub(super) fn sci(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return "0.000000E+00".into();
    }
    let exp = x.abs().log10().floor() as i32;
    let mut mant = x / 10f64.powi(exp);
    let mut exp = exp;
    if (mant.abs() * 1e6).round() >= 1e7 {
        mant /= 10.0;
        exp += 1;
    }
    format!("{mant:.6}E{}{:02}", if exp < 0 { '-' } else { '+' }, exp.abs())
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scpi_headers_match_short_and_long_forms_case_insensitively() {
        assert_eq!(match_header("SENS:CORR:WAV"), Some(Cmd::Wavelength));
        assert_eq!(match_header("sense:correction:wavelength"), Some(Cmd::Wavelength));
        assert_eq!(match_header("CORR:WAV"), Some(Cmd::Wavelength));
        assert_eq!(match_header(":SENS1:POW:DC:RANG:AUTO"), Some(Cmd::RangeAuto));
        assert_eq!(match_header("SENS:POW:RANG"), Some(Cmd::Range));
        assert_eq!(match_header("POW:RANG:UPP"), Some(Cmd::Range));
        assert_eq!(match_header("MEAS:POW"), Some(Cmd::Meas(Function::Power)));
        assert_eq!(match_header("meas:scal:pow"), Some(Cmd::Meas(Function::Power)));
        assert_eq!(match_header("SYST:ERR"), Some(Cmd::SystErr));
        assert_eq!(match_header("SYST:ERR:NEXT"), Some(Cmd::SystErr));
        assert_eq!(match_header("SYST:SENS:IDN"), Some(Cmd::SystSensIdn));
        // Neither short nor long form.
        assert_eq!(match_header("SENS:CORR:WAVE"), None);
        assert_eq!(match_header("CORRE:WAV"), None);
        assert_eq!(match_header("SENS::WAV"), None);
    }

    #[test]
    fn nr3_format() {
        assert_eq!(sci(633.0), "6.330000E+02");
        assert_eq!(sci(1.234e-7), "1.234000E-07");
        assert_eq!(sci(9.9999999e-5), "1.000000E-04");
        assert_eq!(sci(0.0), "0.000000E+00");
    }

    #[test]
    fn longer_patterns_win_and_functions_are_told_apart() {
        assert_eq!(match_header("MEAS:CURR"), Some(Cmd::Meas(Function::Current)));
        assert_eq!(match_header("MEAS:CURR:DC"), Some(Cmd::Meas(Function::Current)));
        assert_eq!(match_header("MEAS:PDEN"), Some(Cmd::Meas(Function::PowerDensity)));
        assert_eq!(match_header("MEAS"), Some(Cmd::Meas(Function::Power)));
        assert_eq!(match_header("CONF:POW"), Some(Cmd::Conf(Function::Power)));
        assert_eq!(match_header("CONF"), Some(Cmd::ConfQuery));
        assert_eq!(match_header("STAT:QUES:COND"), Some(Cmd::QuesCond));
        assert_eq!(match_header("STAT:QUES"), Some(Cmd::QuesEvent));
        assert_eq!(match_header("status:questionable:event"), Some(Cmd::QuesEvent));
        assert_eq!(match_header("SENS:CURR:RANG"), Some(Cmd::CurrentRange));
        assert_eq!(match_header("SENS:CORR:BEAM"), Some(Cmd::BeamDiameter));
    }

    #[test]
    fn numeric_parameters_and_limit_keywords() {
        assert_eq!(parse_num("633"), Ok(Num::Value(633.0)));
        assert_eq!(parse_num("min"), Ok(Num::Min));
        assert_eq!(parse_num("MAXIMUM"), Ok(Num::Max));
        assert_eq!(parse_num(""), Err((-109, "Missing parameter")));
        assert_eq!(parse_num("abc"), Err((-104, "Data type error")));
        assert_eq!(query_limit(""), Ok(None));
        assert_eq!(query_limit("MAX"), Ok(Some(Num::Max)));
        assert_eq!(query_limit("5"), Err((-224, "Illegal parameter value")));
    }
}
