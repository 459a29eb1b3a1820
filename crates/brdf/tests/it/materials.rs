//! Tests of materials and presets against independent expectations: every preset loads and evaluates, material
//! files and campaign documents are read with errors naming the file, the line and the key, and a material's
//! description round-trips through its TOML.

use std::f64::consts::PI;
use std::path::Path;

use gonio_brdf::fresnel;
use gonio_brdf::{Brdf, Direction, Material, MaterialError, Wavelength};
use gonio_testkit::nm;

#[test]
fn every_preset_loads_and_evaluates() {
    let wi = Direction::from_spherical_deg(30.0, 0.0);
    let wo = Direction::from_spherical_deg(30.0, 180.0);
    for name in Material::preset_names() {
        let m = Material::preset(name).unwrap_or_else(|e| panic!("{name}: {e}"));
        for wl in (400..=700).step_by(25) {
            let f = m.eval(&wi, &wo, nm(wl as f64)).expect("inside the tables");
            assert!(f.is_finite() && f >= 0.0, "{name} {wl}: {f}");
        }
        let outside = m.at_wavelength(nm(800.0));
        if !m.is_spectrally_flat() {
            assert!(outside.is_err(), "{name}: 800 nm should be outside its tables");
        }
        // The description round-trips through TOML.
        let spec = m.spec();
        let again = Material::from_document(&spec.to_toml(), "round trip", Path::new(".")).expect("re-reads");
        assert_eq!(again.spec(), spec, "{name}");
    }
    assert!(Material::preset("mirror").expect("preset").has_delta_lobe());
    assert_eq!(
        Material::preset("mirror")
            .expect("preset")
            .eval(&wi, &wo, Wavelength::DEFAULT),
        Ok(0.0)
    );
    let r = Material::preset("mirror")
        .expect("preset")
        .delta_lobe(&Direction::NORMAL, Wavelength::DEFAULT)
        .expect("in")
        .expect("delta");
    assert!((r.reflectance - fresnel::r0_conductor(0.959, 6.687)).abs() < 1e-15);
    let spectralon = Material::preset("spectralon").expect("preset");
    let v = spectralon.eval(&wi, &wo, Wavelength::DEFAULT).expect("in");
    assert!((v - 0.99 / PI).abs() < 1e-15);
}

fn doc_error(text: &str) -> String {
    match Material::from_document(text, "test.toml", Path::new(".")) {
        Ok(m) => panic!("expected an error, got {m:?}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn material_errors_name_file_line_and_key() {
    let cases: &[(&str, &str, &str)] = &[
        // (document, expected line marker, key)
        (
            "[material]\nmodel = \"lambertian\"\nalbedo = 0.5\ncolour = 3\n",
            "line 4",
            "colour",
        ),
        ("[material]\nmodel = \"lambertian\"\n", "line 2", "albedo"),
        (
            "[material]\nmodel = \"conductor\"\ndistribution = \"ggx\"\nmasking = \"separable\"\nalpha = 0.0\neta = 1.0\nk = 2.0\n",
            "line 5",
            "alpha",
        ),
        (
            "[material]\nmodel = \"conductor\"\ndistribution = \"ggx\"\nmasking = \"separable\"\nalpha = -0.2\neta = 1.0\nk = 2.0\n",
            "line 5",
            "alpha",
        ),
        (
            "[material]\nmodel = \"lambertian\"\n\nalbedo = 1.2\n",
            "line 4",
            "albedo",
        ),
        (
            "[material]\nmodel = \"lambertian\"\nalbedo = { 450 = 0.5, 650 = 1.01 }\n",
            "line 3",
            "albedo",
        ),
        (
            "[material]\nmodel = \"mirror\"\neta = -0.3\nk = 2.0\n",
            "line 3",
            "eta",
        ),
        (
            "[material]\nmodel = \"mirror\"\neta = 1.0\nk = { 450 = -1.0 }\n",
            "line 4",
            "k",
        ),
        (
            "[material]\nmodel = \"plastic\"\ndistribution = \"ggx\"\nmasking = \"separable\"\nalpha = 0.1\nior = -1.5\nalbedo = 0.5\n",
            "line 6",
            "ior",
        ),
        (
            "[material]\nmodel = \"lambertian\"\nalbedo = { blue = 0.5 }\n",
            "line 3",
            "albedo",
        ),
        (
            "[material]\nmodel = \"lambertian\"\nalbedo = { 450 = \"high\" }\n",
            "line 3",
            "albedo",
        ),
        (
            "[material]\nmodel = \"lambertian\"\nalbedo = {}\n",
            "line 3",
            "albedo",
        ),
        (
            "[material]\nmodel = \"lambertian\"\nalbedo = \"white\"\n",
            "line 3",
            "albedo",
        ),
        (
            "[material]\nmodel = \"lambertian\"\nalbedo = 0.5\nsigma_deg = 20\n",
            "line 4",
            "sigma_deg",
        ),
        ("[material]\nmodel = \"velvet\"\n", "line 2", "model"),
        ("[material]\nalbedo = 0.5\n", "line 1", "model"),
        (
            "[material]\nmodel = \"conductor\"\ndistribution = \"ggx\"\nmasking = \"separable\"\nalpha_x = 0.1\neta = 1.0\nk = 2.0\n",
            "line 2",
            "alpha_y",
        ),
        (
            "[material]\nmodel = \"conductor\"\ndistribution = \"gauss\"\nmasking = \"separable\"\nalpha = 0.1\neta = 1.0\nk = 2.0\n",
            "line 3",
            "distribution",
        ),
        (
            "[material]\nmodel = \"phong\"\ndiffuse = 0.6\nspecular = 0.5\nexponent = 10\n",
            "line 4",
            "specular",
        ),
        (
            "[material]\nmodel = \"oren-nayar\"\nalbedo = 0.5\nsigma_deg = 120\n",
            "line 4",
            "sigma_deg",
        ),
    ];
    for (text, line, key) in cases {
        let msg = doc_error(text);
        assert!(msg.contains("test.toml"), "{msg}");
        assert!(msg.contains(line), "expected {line} in: {msg}");
        assert!(msg.contains(&format!("`{key}`")), "expected key {key} in: {msg}");
        assert!(!msg.contains('\n'), "one paragraph: {msg}");
    }
}

#[test]
fn material_inside_a_campaign_document() {
    let text = "# a campaign\n[campaign]\nname = \"test\"\n\n[material]\nmodel = \"lambertian\"\nalbedo = 0.4\n\n[instrument]\nfile = \"x.toml\"\n";
    let m = Material::from_document(text, "campaign.toml", Path::new(".")).expect("parses");
    let v = m
        .eval(&Direction::NORMAL, &Direction::NORMAL, Wavelength::DEFAULT)
        .expect("c");
    assert!((v - 0.4 / PI).abs() < 1e-16);
    let bad = text.replace("albedo = 0.4", "albedo = 4");
    let msg = doc_error(&bad);
    assert!(msg.contains("line 7") && msg.contains("`albedo`"), "{msg}");
    assert!(doc_error("[campaign]\nname = 1\n").contains("no [material] table"));
    let msg = doc_error("[material]\nmodel = \"lambertian\"\nalbedo = 0.5\nalbedo = 0.6\n");
    assert!(msg.contains("line 4") && msg.contains("TOML"), "{msg}");
}

#[test]
fn file_and_preset_errors() {
    let missing = Material::load(Path::new("/nonexistent/dir/m.toml")).expect_err("missing file");
    assert!(matches!(missing, MaterialError::Read { .. }));
    assert!(
        missing.to_string().contains("/nonexistent/dir/m.toml"),
        "{missing}"
    );
    let unknown = Material::from_file_or_preset("velvet")
        .expect_err("unknown preset")
        .to_string();
    for name in Material::preset_names() {
        assert!(unknown.contains(name), "{unknown}");
    }
    // A path ending in .toml is a file even when missing.
    assert!(matches!(
        Material::from_file_or_preset("nope.toml"),
        Err(MaterialError::Read { .. })
    ));

    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("gold-ish.toml");
    std::fs::write(&path, "[material]\nmodel = \"conductor\"\ndistribution = \"beckmann\"\nmasking = \"height-correlated\"\nalpha_x = 0.1\nalpha_y = 0.3\neta = 0.35\nk = 2.7\n").expect("write");
    let m = Material::from_file_or_preset(path.to_str().expect("utf8")).expect("loads");
    assert!(!m.is_isotropic() && m.is_spectrally_flat());
    // A measured material's data file resolves against the material file's directory.
    let path = dir.path().join("measured.toml");
    std::fs::write(&path, "[material]\nmodel = \"measured\"\nfile = \"data/none.binary\"\nformat = \"merl\"\nchannel = \"red\"\n").expect("write");
    let msg = Material::load(&path).expect_err("no data").to_string();
    assert!(msg.contains("line 3") && msg.contains("`file`"), "{msg}");
    assert!(
        msg.contains(&dir.path().join("data/none.binary").display().to_string()),
        "{msg}"
    );
}

#[test]
fn measured_material_resolves_its_file_against_the_material_directory() {
    use gonio_brdf::merl::{CELLS, MerlData};
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::create_dir(dir.path().join("data")).expect("mkdir");
    let (red, green, blue) = (vec![0.1; CELLS], vec![0.2; CELLS], vec![0.3; CELLS]);
    MerlData::from_brdf_values(&red, &green, &blue)
        .expect("valid")
        .write(&dir.path().join("data/flat.binary"))
        .expect("write");
    let path = dir.path().join("flat.toml");
    std::fs::write(
        &path,
        "[material]\nmodel = \"measured\"\nfile = \"data/flat.binary\"\nformat = \"merl\"\nchannel = \"green\"\n",
    )
    .expect("write");
    let m = Material::load(&path).expect("loads");
    let wi = Direction::from_spherical_deg(20.0, 0.0);
    let wo = Direction::from_spherical_deg(40.0, 150.0);
    let f = m.eval(&wi, &wo, Wavelength::DEFAULT).expect("flat");
    assert!((f - 0.2).abs() < 1e-12, "{f}");
    let spec = m.spec();
    assert_eq!(
        spec.file.as_deref(),
        Some(dir.path().join("data/flat.binary").as_path())
    );
    // The description, stored elsewhere, still finds the data (absolute path).
    let again = Material::from_spec(&spec, Path::new("/")).expect("reloads");
    assert_eq!(again.eval(&wi, &wo, Wavelength::DEFAULT), Ok(f));
}
