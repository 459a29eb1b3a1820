//! `gonio brdf eval`: evaluate a material's BRDF, or a measured run's interpolant (`--run`), for geometries
//! read on stdin.
//!
//! Input: one geometry per line, `theta_i phi_i theta_o phi_o` in degrees, separated by whitespace; blank lines
//! and lines starting with `#` (after optional whitespace) are skipped. Output: one line per geometry, f in 1/sr
//! (no cosine factor), printed with the shortest representation that round-trips as f64. A direction at or
//! below the horizon gives 0; with `--run`, a pair the run did not measure gives `NaN`. A malformed line stops the run with an error naming its line number.
//!
//! Streaming and speed: input is read through a 1 MiB buffer and lines are parsed in place (a line split across
//! two refills is assembled in one reused buffer), output goes through
//! a 1 MiB buffer, angles are parsed from bytes (Clinger fast path, exact), numbers are formatted with `ryu` into
//! a stack buffer, and the material is resolved once at
//! the wavelength (`Material::at_wavelength`), so the loop allocates nothing and memory stays constant.

use std::io::{BufRead, BufReader, BufWriter, Write};

use gonio_brdf::{Brdf, Direction, Material, Wavelength};

use crate::CliError;

const BUFFER_BYTES: usize = 1 << 20;

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// A material TOML file with a [material] table, or a preset name (e.g. gold, spectralon).
    #[arg(long, required_unless_present = "run", conflicts_with = "run")]
    pub material: Option<String>,
    /// Instead of a material: a measured run (a run directory or its points CSV), evaluated with gonio's
    /// interpolant of its points (the one every resampling export uses); `nan` where it was not measured.
    /// `--wavelength` picks the band (default: the run's only band).
    #[arg(long)]
    pub run: Option<std::path::PathBuf>,
    /// Wavelength in nm (default 550).
    #[arg(long)]
    pub wavelength: Option<f64>,
}

/// What is evaluated at a pair of directions (both above the horizon): f in 1/sr, NaN where there is no value.
type Evaluator<'a> = dyn Fn(&Direction, &Direction) -> Result<f64, String> + 'a;

pub fn run(args: EvalArgs) -> Result<(), CliError> {
    if let Some(path) = &args.run {
        return run_interpolant(path, args.wavelength);
    }
    let name = args.material.unwrap_or_default();
    let material = Material::from_file_or_preset(&name).map_err(|e| CliError::input(e.to_string()))?;
    let wavelength = Wavelength::from_nm(args.wavelength.unwrap_or(Wavelength::DEFAULT.nm()))
        .map_err(|e| CliError::input(format!("--wavelength: {e}")))?;
    let resolved = material
        .resolved(wavelength)
        .map_err(|e| CliError::input(format!("{name}: {e}")))?;
    if resolved.has_delta_lobe() {
        eprintln!(
            "gonio: note: material {name} is a delta (mirror-like) reflector: its specular reflection has no pointwise \
             value, so eval prints only the non-delta part (0 for an ideal mirror)"
        );
    }
    let f = |wi: &Direction, wo: &Direction| resolved.eval(wi, wo, wavelength).map_err(|e| e.to_string());
    stream_stdio(&f)
}

/// `--run`: the run's interpolant for one band.
fn run_interpolant(path: &std::path::Path, wavelength: Option<f64>) -> Result<(), CliError> {
    let run = gonio_results::Run::load(path).map_err(|e| CliError::input(e.to_string()))?;
    let bands = run.bands_nm();
    let band = match (wavelength, bands.as_slice()) {
        (Some(nm), _) => run.band(nm).map_err(|e| CliError::input(e.to_string()))?,
        (None, [only]) => *only,
        (None, _) => {
            return Err(CliError::input(format!(
                "{}: give --wavelength, one of the run's bands: {}",
                run.origin,
                gonio_results::run::list_nm(&bands)
            )));
        }
    };
    let points: Vec<gonio_results::iso::IsoPoint> = run
        .points
        .iter()
        .filter(|p| (p.band_nm - band).abs() <= gonio_results::run::BAND_TOLERANCE_NM)
        .filter_map(gonio_results::iso::IsoPoint::from_point)
        .collect();
    let grid = gonio_results::iso::IsoGrid::build(&points);
    let f = |wi: &Direction, wo: &Direction| {
        Ok(gonio_results::hemispherical::covered_value(&grid, wi, wo).unwrap_or(f64::NAN))
    };
    stream_stdio(&f)
}

/// Streams stdin to stdout through `f`.
fn stream_stdio(f: &Evaluator) -> Result<(), CliError> {
    let stdin = std::io::stdin();
    let stdout = std::io::stdout();
    let input = BufReader::with_capacity(BUFFER_BYTES, stdin.lock());
    let mut output = BufWriter::with_capacity(BUFFER_BYTES, stdout.lock());
    let result = eval_stream(f, input, &mut output);
    // Flush whatever was computed before an error too: the lines before a malformed one are valid results.
    let flushed = output.flush().map_err(|e| CliError::io("writing to stdout", e));
    result.and(flushed)
}

/// Evaluates every geometry line of `input`, writing one value per line to `output`.
///
/// Lines are taken in place from the reader's buffer (no copy), except a line split across two refills, which is
/// assembled in `carry`.
fn eval_stream(f: &Evaluator, mut input: impl BufRead, output: &mut impl Write) -> Result<(), CliError> {
    let mut carry: Vec<u8> = Vec::with_capacity(256);
    let mut number = ryu::Buffer::new();
    let mut line_no: u64 = 0;
    loop {
        let buf = input.fill_buf().map_err(|e| CliError::io("reading stdin", e))?;
        if buf.is_empty() {
            if !carry.is_empty() {
                line_no += 1;
                eval_line(f, &carry, line_no, &mut number, output)?;
            }
            return Ok(());
        }
        let len = buf.len();
        let mut start = 0;
        while let Some(offset) = buf[start..].iter().position(|&b| b == b'\n') {
            let end = start + offset + 1;
            line_no += 1;
            if carry.is_empty() {
                eval_line(f, &buf[start..end], line_no, &mut number, output)?;
            } else {
                carry.extend_from_slice(&buf[start..end]);
                eval_line(f, &carry, line_no, &mut number, output)?;
                carry.clear();
            }
            start = end;
        }
        carry.extend_from_slice(&buf[start..]);
        input.consume(len);
    }
}

/// One input line: its value on a line of `output`, nothing for a blank or comment line, or the error.
fn eval_line(
    f: &Evaluator,
    line: &[u8],
    line_no: u64,
    number: &mut ryu::Buffer,
    output: &mut impl Write,
) -> Result<(), CliError> {
    let Some(angles) =
        parse_line(line).map_err(|why| CliError::input(format!("stdin line {line_no}: {why}")))?
    else {
        return Ok(());
    };
    let wi = Direction::from_spherical_deg(angles[0], angles[1]);
    let wo = Direction::from_spherical_deg(angles[2], angles[3]);
    let value = if wi.is_above_horizon() && wo.is_above_horizon() {
        f(&wi, &wo).map_err(|e| CliError::input(format!("stdin line {line_no}: {e}")))?
    } else {
        0.0
    };
    output
        .write_all(number.format(value).as_bytes())
        .map_err(|e| CliError::io("writing to stdout", e))?;
    output
        .write_all(b"\n")
        .map_err(|e| CliError::io("writing to stdout", e))
}

/// The four angles of a data line; `None` for a blank or comment line; an error saying what is wrong otherwise.
/// Works on bytes: the line is never validated or copied as a whole.
fn parse_line(raw: &[u8]) -> Result<Option<[f64; 4]>, String> {
    let text = raw.trim_ascii();
    if text.is_empty() || text.first() == Some(&b'#') {
        return Ok(None);
    }
    const NAMES: [&str; 4] = ["theta_i", "phi_i", "theta_o", "phi_o"];
    let count_error = |what: &str| {
        format!(
            "expected 4 numbers `theta_i phi_i theta_o phi_o` in degrees, found {what} in {:?}",
            String::from_utf8_lossy(text)
        )
    };
    let mut angles = [0.0; 4];
    let mut fields = text.split(|b| b.is_ascii_whitespace()).filter(|f| !f.is_empty());
    for (slot, name) in angles.iter_mut().zip(NAMES) {
        let field = fields.next().ok_or_else(|| count_error("too few"))?;
        let v = parse_f64(field)
            .ok_or_else(|| format!("{name} {:?} is not a number", String::from_utf8_lossy(field)))?;
        if !v.is_finite() {
            return Err(format!(
                "{name} {:?} is not a finite angle",
                String::from_utf8_lossy(field)
            ));
        }
        *slot = v;
    }
    if fields.next().is_some() {
        return Err(count_error("more"));
    }
    Ok(Some(angles))
}

/// Parses a decimal number. Plain decimals of at most 15 digits (`-12.375`, the usual angle) take Clinger's
/// fast path: the digits form an integer below 2^53 and the divisor a power of ten below 10^22, both exact in
/// f64, so one IEEE division gives the correctly rounded result, identical to `str::parse`. Anything else
/// (exponents, long mantissas, `inf`) goes to `str::parse`.
fn parse_f64(field: &[u8]) -> Option<f64> {
    const POW10: [f64; 16] = [
        1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
    ];
    let (negative, body) = match field.first() {
        Some(b'-') => (true, &field[1..]),
        Some(b'+') => (false, &field[1..]),
        _ => (false, field),
    };
    let mut mantissa: u64 = 0;
    let mut digits = 0usize;
    let mut fraction_digits = 0usize;
    let mut seen_point = false;
    let mut fast = !body.is_empty();
    for &b in body {
        match b {
            b'0'..=b'9' if digits < 15 => {
                mantissa = mantissa * 10 + u64::from(b - b'0');
                digits += 1;
                if seen_point {
                    fraction_digits += 1;
                }
            }
            b'.' if !seen_point => seen_point = true,
            _ => {
                fast = false;
                break;
            }
        }
    }
    if fast && digits > 0 {
        let v = mantissa as f64 / POW10[fraction_digits];
        return Some(if negative { -v } else { v });
    }
    std::str::from_utf8(field).ok()?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_data_comment_and_blank_lines() {
        assert_eq!(parse_line(b"10 20 30 40\n"), Ok(Some([10.0, 20.0, 30.0, 40.0])));
        assert_eq!(
            parse_line(b"  \t1.5\t-2e1   3 4  \r\n"),
            Ok(Some([1.5, -20.0, 3.0, 4.0]))
        );
        assert_eq!(parse_line(b"   \n"), Ok(None));
        assert_eq!(parse_line(b"  # a comment 1 2 3 4\n"), Ok(None));
        assert!(parse_line(b"1 2 3\n").is_err());
        assert!(parse_line(b"1 2 3 4 5\n").is_err());
        assert!(parse_line(b"1 2 x 4\n").expect_err("bad").contains("theta_o"));
        assert!(parse_line(b"1 2 inf 4\n").is_err());
        assert!(parse_line(b"1 2 NaN 4\n").is_err());
        assert!(parse_line(b"1 2 - 4\n").is_err());
        assert!(parse_line(b"1 2 . 4\n").is_err());
        assert!(parse_line(b"1 2 1.2.3 4\n").is_err());
    }

    #[test]
    fn fast_number_parsing_agrees_with_the_standard_library() {
        let cases = [
            "0",
            "-0",
            "+1",
            "1.",
            ".5",
            "-.5",
            "90",
            "89.999999999",
            "0.1",
            "0.3",
            "12.345678901234",
            "123456789012345",
            "1234567890123456789",
            "0.000000000000001",
            "1e-3",
            "-2.5E2",
            "33.333333333333333333",
            "inf",
            "-inf",
            "NaN",
            "1_0",
            "0x10",
            "",
            "-",
            "+",
            ".",
            "1.2.3",
            "45.0000000000001",
            "179.99999999999997",
        ];
        for case in cases {
            let expect = case.parse::<f64>().ok();
            let got = parse_f64(case.as_bytes());
            assert_eq!(
                got.map(f64::to_bits),
                expect.map(f64::to_bits),
                "{case:?}: {got:?} vs {expect:?}"
            );
        }
        // A sweep of typical angle strings.
        for i in 0..20_000 {
            let s = format!("{:.4}", (i as f64) * 0.0137 - 91.0);
            assert_eq!(
                parse_f64(s.as_bytes()).map(f64::to_bits),
                s.parse::<f64>().ok().map(f64::to_bits),
                "{s}"
            );
        }
    }

    #[test]
    fn lines_split_across_buffer_refills_give_the_same_output() {
        let material = Material::preset("gold").expect("preset");
        let f = |wi: &Direction, wo: &Direction| {
            material
                .eval(wi, wo, Wavelength::DEFAULT)
                .map_err(|e| e.to_string())
        };
        let text = b"# header\n10 20 30 200\n\n  45.5 0 60 180.25\r\n0 0 0 0\n80 359.9 1 3";
        let whole = {
            let mut out = Vec::new();
            eval_stream(&f, &text[..], &mut out).expect("valid");
            out
        };
        assert_eq!(String::from_utf8_lossy(&whole).lines().count(), 4);
        for capacity in 1..text.len() + 2 {
            let mut out = Vec::new();
            let reader = std::io::BufReader::with_capacity(capacity, &text[..]);
            eval_stream(&f, reader, &mut out).expect("valid");
            assert_eq!(out, whole, "buffer of {capacity} bytes");
        }
        // The line number of an error counts lines across refills too.
        let bad = b"1 2 3 4\n5 6 7 8\n# c\n1 2 x 4\n";
        let err = eval_stream(
            &f,
            std::io::BufReader::with_capacity(3, &bad[..]),
            &mut Vec::new(),
        )
        .expect_err("line 4 is malformed");
        assert!(err.to_string().contains("stdin line 4"), "{err}");
    }

    #[test]
    fn stream_stops_at_the_first_bad_line_and_names_it() {
        let material = Material::preset("spectralon").expect("preset");
        let f = |wi: &Direction, wo: &Direction| {
            material
                .eval(wi, wo, Wavelength::DEFAULT)
                .map_err(|e| e.to_string())
        };
        let mut out = Vec::new();
        let err =
            eval_stream(&f, &b"# header\n0 0 0 0\n\n1 2 3\n"[..], &mut out).expect_err("line 4 is malformed");
        assert!(err.to_string().contains("stdin line 4"), "{err}");
        assert_eq!(String::from_utf8(out).expect("utf8").lines().count(), 1);
    }
}
