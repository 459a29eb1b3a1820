//! The MERL binary format and the measured BRDF: byte layout, bit-exact round trip, the documented binning
//! checked against indices computed by hand, typed errors for bad files, and the lookup's properties.

use std::f64::consts::{FRAC_PI_2, PI};
use std::path::Path;

use gonio_brdf::checks::reciprocity_residual;
use gonio_brdf::measured::{Interpolation, MeasuredBrdf};
use gonio_brdf::merl::{
    self, CELLS, FILE_BYTES, MerlChannel, MerlData, MerlError, cell_centre, cell_index, phi_d_index,
    theta_d_index, theta_h_index,
};
use gonio_brdf::{Brdf, Direction, HalfDiff, Wavelength};

const WL: Wavelength = Wavelength::DEFAULT;

/// A synthetic table whose values are awkward f64 bit patterns (not round decimals), distinct per cell and
/// channel, with a few invalid (negative) cells.
fn synthetic() -> MerlData {
    let channel = |c: f64| -> Vec<f64> {
        (0..CELLS)
            .map(|i| {
                if i % 9973 == 17 {
                    -1.0
                } else {
                    ((i as f64) * 0.618_033_988_749_894_9 + c).sin().abs() * 1e3 / 3.0
                }
            })
            .collect()
    };
    MerlData::from_stored(channel(0.1), channel(0.2), channel(0.3)).expect("valid table")
}

#[test]
fn layout_is_the_documented_one() {
    let data = synthetic();
    let bytes = data.to_bytes();
    assert_eq!(bytes.len(), FILE_BYTES);
    assert_eq!(FILE_BYTES, 12 + 3 * 1_458_000 * 8);
    // Header: three little-endian int32 90, 90, 180.
    assert_eq!(&bytes[..12], &[90, 0, 0, 0, 90, 0, 0, 0, 180, 0, 0, 0]);
    // Channel-major: the first green value sits right after all red values, little-endian f64.
    let green0 = f64::from_le_bytes(
        bytes[12 + CELLS * 8..12 + CELLS * 8 + 8]
            .try_into()
            .expect("8 bytes"),
    );
    assert_eq!(green0.to_bits(), data.stored(MerlChannel::Green)[0].to_bits());
    let blue_last = f64::from_le_bytes(bytes[FILE_BYTES - 8..].try_into().expect("8 bytes"));
    assert_eq!(
        blue_last.to_bits(),
        data.stored(MerlChannel::Blue)[CELLS - 1].to_bits()
    );
}

#[test]
fn write_then_read_round_trips_bit_exactly() {
    let data = synthetic();
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("synthetic.binary");
    data.write(&path).expect("write");
    let back = MerlData::read(&path).expect("read");
    for ch in [MerlChannel::Red, MerlChannel::Green, MerlChannel::Blue] {
        let (a, b) = (data.stored(ch), back.stored(ch));
        assert!(
            a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()),
            "{ch:?} differs"
        );
    }
    // Scaled values: stored times the documented factor.
    let m = MeasuredBrdf::from_merl_file(&path, MerlChannel::Blue).expect("read");
    assert_eq!(m.values()[5], data.stored(MerlChannel::Blue)[5] * 1.66 / 1500.0);
    assert_eq!(m.values()[17], -1.0, "invalid cells stay marked");
}

#[test]
fn scale_factors_are_the_documented_ones() {
    assert_eq!(MerlChannel::Red.scale(), 1.0 / 1500.0);
    assert_eq!(MerlChannel::Green.scale(), 1.15 / 1500.0);
    assert_eq!(MerlChannel::Blue.scale(), 1.66 / 1500.0);
}

#[test]
fn binning_matches_hand_computed_indices() {
    // theta_h: floor(sqrt(theta_h / (pi/2)) * 90). theta_h = pi/8 -> sqrt(1/4) * 90 = 45.
    assert_eq!(theta_h_index(PI / 8.0 + 1e-12), 45);
    // theta_h = 0.1 rad -> sqrt(0.063662) * 90 = 22.708 -> 22.
    assert_eq!(theta_h_index(0.1), 22);
    assert_eq!(theta_h_index(0.0), 0);
    assert_eq!(theta_h_index(FRAC_PI_2), 89, "clamped");
    // theta_d: floor(theta_d / (pi/2) * 90): 30 deg -> 30, 0.5 rad -> 28.64 -> 28.
    assert_eq!(theta_d_index(30.5f64.to_radians()), 30);
    assert_eq!(theta_d_index(0.5), 28);
    assert_eq!(theta_d_index(FRAC_PI_2), 89, "clamped");
    // phi_d: +pi if negative, floor(phi_d / pi * 180): 1 rad -> 57.29 -> 57; -1 rad -> pi - 1 -> 122.7 -> 122.
    assert_eq!(phi_d_index(1.0), 57);
    assert_eq!(phi_d_index(-1.0), 122);
    assert_eq!(phi_d_index(PI), 0, "phi_d = pi is the same cell as phi_d = 0");
    // Flat index: phi_d + 180 theta_d + 180*90 theta_h.
    assert_eq!(cell_index(22, 28, 57), 57 + 180 * 28 + 16_200 * 22);
}

#[test]
fn lookup_of_known_geometries_hits_the_hand_computed_cell() {
    // A table whose value is its own cell index: the lookup reveals which cell a geometry lands in.
    let table: Vec<f64> = (0..CELLS).map(|i| i as f64).collect();
    let m = MeasuredBrdf::from_table(table)
        .expect("valid")
        .with_interpolation(Interpolation::Nearest);
    // Geometry 1: wi = wo = normal. h = n: theta_h = 0; d = wi: theta_d = 0, phi_d = 0 -> cell 0.
    assert_eq!(m.eval(&Direction::NORMAL, &Direction::NORMAL, WL), Ok(0.0));
    // Geometry 2: specular pair at 40 deg: theta_h = 0, theta_d = 40 deg -> 40; phi_d = 0 (wi at phi 0 lies
    // in the x-z plane of the half-vector frame) -> cell 180 * 40 = 7200.
    let wi = Direction::from_spherical_deg(40.3, 0.0);
    let wo = Direction::from_spherical_deg(40.3, 180.0);
    assert_eq!(m.eval(&wi, &wo, WL), Ok(7200.0));
    // Geometry 3: in the plane of incidence on the same side, wi at 55.5 deg and wo at 4.5 deg (phi 0): h is
    // the bisector at 30 deg = pi/6 -> theta_h bin floor(sqrt(1/3) * 90) = floor(51.96) = 51; rotating wi by
    // -30 deg about y leaves it at 25.5 deg in the x-z plane: theta_d bin 25, phi_d = 0 -> bin 0.
    // Cell 0 + 180 * 25 + 16200 * 51 = 830700.
    let wi = Direction::from_spherical_deg(55.5, 0.0);
    let wo = Direction::from_spherical_deg(4.5, 0.0);
    assert_eq!(m.eval(&wi, &wo, WL), Ok(830_700.0));
    // Geometry 4: from half/difference angles, through the documented inverse transform.
    let hd = HalfDiff {
        theta_h: 0.1,
        phi_h: 0.4,
        theta_d: 0.5,
        phi_d: 1.0,
    };
    let (wi, wo) = hd.to_directions();
    assert_eq!(m.eval(&wi, &wo, WL), Ok(cell_index(22, 28, 57) as f64));
    // Reciprocity: the swapped pair has phi_d + pi, the same cell.
    assert_eq!(m.eval(&wo, &wi, WL), Ok(cell_index(22, 28, 57) as f64));
}

#[test]
fn trilinear_reproduces_cell_values_at_centres_and_stays_reciprocal() {
    let data = synthetic();
    let m = MeasuredBrdf::from_merl(&data, MerlChannel::Red);
    assert_eq!(m.interpolation(), Interpolation::Trilinear);
    for (h, d, p) in [(0, 0, 0), (10, 20, 30), (45, 60, 179), (89, 89, 90)] {
        let cell = cell_index(h, d, p);
        let value = m.values()[cell];
        let got = m.lookup(&cell_centre(h, d, p));
        assert!(
            (got - value).abs() <= 1e-9 * value.max(1.0),
            "cell ({h}, {d}, {p}): {got} vs {value}"
        );
    }
    let residual = reciprocity_residual(&m, WL).expect("flat");
    assert!(residual.max_relative < 1e-9, "{residual:?}");
    // Invalid cells give 0 (cell 17 is invalid: its centre looks it up).
    let (h, d, p) = merl::split_index(17);
    assert_eq!(m.lookup(&cell_centre(h, d, p)), 0.0);
}

#[test]
fn tabulated_lambertian_is_looked_up_as_constant_and_zero_below_horizon() {
    let rho_over_pi = 0.7 / PI;
    let m = MeasuredBrdf::from_table(vec![rho_over_pi; CELLS]).expect("valid");
    for (ti, pi, to, po) in [
        (0.0, 0.0, 0.0, 0.0),
        (30.0, 10.0, 60.0, 200.0),
        (89.9, 0.0, 89.9, 180.0),
        (70.0, 0.0, 5.0, 90.0),
    ] {
        let v = m
            .eval(
                &Direction::from_spherical_deg(ti, pi),
                &Direction::from_spherical_deg(to, po),
                WL,
            )
            .expect("flat");
        assert!((v - rho_over_pi).abs() < 1e-15, "{v}");
    }
    let below = Direction::from_spherical_deg(100.0, 0.0);
    assert_eq!(m.eval(&below, &Direction::NORMAL, WL), Ok(0.0));
    assert_eq!(m.eval(&Direction::NORMAL, &below, WL), Ok(0.0));
    let horizon = Direction::from_spherical_deg(90.0, 0.0);
    assert_eq!(m.eval(&horizon, &Direction::NORMAL, WL), Ok(0.0));
}

fn write_bytes(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("write");
    path
}

#[test]
fn bad_files_give_typed_errors_naming_the_file() {
    let dir = tempfile::tempdir().expect("temp dir");
    let good = synthetic().to_bytes();

    let truncated = write_bytes(dir.path(), "truncated.binary", &good[..good.len() - 1000]);
    let err = MerlData::read(&truncated).expect_err("truncated");
    assert!(matches!(err, MerlError::WrongSize { actual_bytes, .. } if actual_bytes == FILE_BYTES - 1000));
    let msg = err.to_string();
    assert!(
        msg.contains("truncated.binary") && msg.contains("truncated"),
        "{msg}"
    );

    let tiny = write_bytes(dir.path(), "tiny.binary", &good[..7]);
    assert!(matches!(MerlData::read(&tiny), Err(MerlError::WrongSize { .. })));

    let mut header = good.clone();
    header[8] = 90; // 90 90 90
    let bad_header = write_bytes(dir.path(), "header.binary", &header);
    let err = MerlData::read(&bad_header).expect_err("bad header");
    assert!(
        matches!(
            err,
            MerlError::BadHeader {
                found: [90, 90, 90],
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("header.binary"));

    let mut garbled = good.clone();
    let at = 12 + (CELLS + 5) * 8; // green channel, cell 5
    garbled[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
    let nan_file = write_bytes(dir.path(), "nan.binary", &garbled);
    let err = MerlData::read(&nan_file).expect_err("NaN");
    assert!(
        matches!(
            err,
            MerlError::NonFinite {
                channel: "green",
                cell: 5,
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("nan.binary"));

    let mut longer = good;
    longer.push(0);
    let long_file = write_bytes(dir.path(), "long.binary", &longer);
    assert!(matches!(
        MerlData::read(&long_file),
        Err(MerlError::WrongSize { .. })
    ));

    let missing = dir.path().join("missing.binary");
    let err = MeasuredBrdf::from_merl_file(&missing, MerlChannel::Red).expect_err("missing");
    assert!(matches!(err, MerlError::Io { .. }) && err.to_string().contains("missing.binary"));

    assert!(matches!(
        MeasuredBrdf::from_table(vec![0.0; 10]),
        Err(MerlError::WrongLength { actual: 10, .. })
    ));
    let mut with_inf = vec![0.1; CELLS];
    with_inf[3] = f64::INFINITY;
    assert!(matches!(
        MeasuredBrdf::from_table(with_inf),
        Err(MerlError::NonFinite { cell: 3, .. })
    ));
}

#[test]
fn tabulating_a_smooth_model_and_looking_it_up_approximates_it() {
    // Tabulate a smooth reciprocal, isotropic function and compare the interpolated lookup with it.
    #[derive(Debug)]
    struct Smooth;
    impl Brdf for Smooth {
        fn eval(
            &self,
            wi: &Direction,
            wo: &Direction,
            _w: Wavelength,
        ) -> Result<f64, gonio_brdf::SpectrumError> {
            if wi.z() <= 0.0 || wo.z() <= 0.0 {
                return Ok(0.0);
            }
            Ok(0.2 + 0.1 * wi.z() * wo.z() + 0.05 * (wi.x() * wo.x() + wi.y() * wo.y()))
        }
        fn is_isotropic(&self) -> bool {
            true
        }
        fn is_spectrally_flat(&self) -> bool {
            true
        }
    }
    let m = MeasuredBrdf::tabulate(&Smooth, WL).expect("flat");
    for (ti, to, dphi) in [(10.0, 20.0, 30.0), (45.0, 45.0, 180.0), (60.0, 30.0, 90.0)] {
        let wi = Direction::from_spherical_deg(ti, 0.0);
        let wo = Direction::from_spherical_deg(to, dphi);
        let exact = Smooth.eval(&wi, &wo, WL).expect("flat");
        let got = m.eval(&wi, &wo, WL).expect("flat");
        assert!(
            (got - exact).abs() < 2e-3 * exact,
            "({ti}, {to}, {dphi}): {got} vs {exact}"
        );
    }
}
