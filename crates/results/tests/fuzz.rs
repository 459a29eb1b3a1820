//! Whatever a points CSV holds (any finite numbers, negative or absurd angles and values, flags, missing
//! fields), reading it and every operation on the run (exports of every format included) return a value or an
//! error: never a panic.

use gonio_results::export::{self, ExportContext};
use gonio_results::fit::{self, FitModel, FitOptions, Loss};
use gonio_results::iso::{IsoGrid, IsoPoint};
use gonio_results::plot::{self, PlotOptions};
use gonio_results::points::parse_points_csv;
use gonio_results::run::Run;
use gonio_results::{astm, rgl, zemax};
use proptest::prelude::*;

const HEADER: &str = "index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,incident_w,\
                      brdf_sr,brdf_u_sr,flags,t_s,light_deg";

fn number() -> impl Strategy<Value = String> {
    prop_oneof![
        (-400.0f64..400.0).prop_map(|v| v.to_string()),
        (0.0f64..90.0).prop_map(|v| v.to_string()),
        (-1e300f64..1e300).prop_map(|v| v.to_string()),
        Just(String::new()),
        Just("NaN".to_string()),
        Just("0".to_string()),
        Just("-0".to_string()),
    ]
}

/// A finite angle, often a sensible one.
fn angle() -> impl Strategy<Value = String> {
    prop_oneof![
        3 => (0.0f64..90.0).prop_map(|v| v.to_string()),
        1 => (-400.0f64..400.0).prop_map(|v| v.to_string()),
        1 => Just("90".to_string()),
        1 => Just("0".to_string()),
    ]
}

fn row() -> impl Strategy<Value = String> {
    (
        0u64..50,
        prop_oneof![
            Just("450".to_string()),
            Just("550".to_string()),
            Just("650.2".to_string())
        ],
        proptest::collection::vec(angle(), 4),
        proptest::collection::vec(number(), 4),
        // An uncertainty is never negative (the reader refuses one, as tested in points.rs).
        prop_oneof![
            (0.0f64..1e3).prop_map(|v| v.to_string()),
            Just(String::new()),
            Just("NaN".to_string())
        ],
        prop_oneof![
            Just(String::new()),
            Just("overfilled".to_string()),
            Just("a;b".to_string())
        ],
        number(),
        number(),
    )
        .prop_map(|(i, band, angles, values, u, flags, t, axis)| {
            format!(
                "{i},{band},{},{},{},{},{},{},{},{},{u},{flags},{t},{axis}",
                angles[0], angles[1], angles[2], angles[3], values[0], values[1], values[2], values[3]
            )
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn every_operation_survives_arbitrary_rows(rows in proptest::collection::vec(row(), 0..30)) {
        let text = format!("{HEADER}\n{}\n", rows.join("\n"));
        // Required fields are always well-formed here, so the reader accepts every case.
        let table = parse_points_csv(&text, "fuzz.csv");
        prop_assert!(table.is_ok(), "{:?}", table.err());
        let Ok(table) = table else { return Ok(()) };
        let run = Run::from_parts("fuzz".into(), "fuzz".into(), table, None);
        let ctx = ExportContext { exported_by: "test".into(), resolved: None, setup: None };
        let csv = export::to_csv(&run, &ctx);
        // The export's table reads back.
        let back: String = csv.lines().filter(|l| !l.starts_with('#')).map(|l| format!("{l}\n")).collect();
        prop_assert!(parse_points_csv(&back, "export").is_ok());
        let _ = export::to_json(&run, &ctx);
        for band in run.bands_nm() {
            let pts: Vec<IsoPoint> = run
                .points
                .iter()
                .filter(|p| p.band_nm == band)
                .filter_map(IsoPoint::from_point)
                .collect();
            let grid = IsoGrid::build(&pts);
            for p in &pts {
                if let Some(v) = grid.eval(&p.angles) {
                    prop_assert!(v.is_finite());
                }
            }
        }
        let _ = astm::write(&run, "test", None);
        if let Ok(e) = rgl::to_rgl(&run) {
            let bytes = e.to_bytes("fuzz");
            prop_assert!(gonio_brdf::rgl::RglBrdf::from_bytes(&bytes).is_ok(), "the export reads back");
        }
        // The Zemax export integrates per incidence (up to a million evaluations each): a few points suffice.
        let mut small = run.clone();
        small.points.truncate(5);
        for band in small.bands_nm() {
            if let Ok(z) = zemax::to_zemax(&small, band) {
                for b in &z.blocks {
                    prop_assert!(b.integrals.reflectance.value.is_finite());
                }
                let _ = zemax::write(&z, &small, "test", None);
            }
        }
        let _ = plot::render(&run, &PlotOptions::default());
        let mut opts = FitOptions::new(FitModel::Lambertian);
        opts.loss = Loss::Huber;
        let _ = fit::fit(&run, &opts);
    }
}
