//! Where a campaign's materials come from, and the rule on which files it may make gonio read.
//!
//! A campaign names materials in two places: `[material]` (the simulated sample of a dry-run: a table, possibly
//! `model = "measured"` with a data `file`, or `preset = "<name>"`) and `[calibration] reference` (the relative
//! method's reference sample: a preset name or a material file, which may itself name a measured data file).
//! [`Sources`] says how those names resolve:
//! - [`Sources::Local`] (`gonio run` on a file): relative paths resolve against the campaign file's directory
//!   (made absolute), any readable file may be named;
//! - [`Sources::Confined`] (a campaign submitted to the daemon over HTTP): presets, or files inside the daemon's
//!   data directory only. Paths are canonicalized (symbolic links followed) and must stay inside the canonical
//!   data directory; `..` components are refused outright; nothing outside is opened or even probed;
//! - [`Sources::Stored`] (a campaign read back from the store): no name is resolved again. The materials come
//!   from the `[resolved]` table that submission appended to the stored text ([`resolved_trailer`]); only a
//!   measured material's data file is read again, by the absolute path resolved at submission.
//!
//! The `[resolved]` table holds each material's full description (`Material::spec`), so a run is reproducible
//! from the store alone and resuming never depends on the current directory or on files that changed since.

use std::path::{Component, Path, PathBuf};

use gonio_brdf::material::{Material, MaterialSpec};
use gonio_scheduler::sweep::ArcProfile;
use serde::{Deserialize, Serialize};

/// How material and reference names in a campaign resolve (module doc).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Sources {
    /// A local campaign file: relative paths against this directory; any readable file.
    Local(PathBuf),
    /// Submitted to the daemon: presets or files inside this data directory only.
    Confined(PathBuf),
    /// Read back from the store: materials from the `[resolved]` table.
    Stored,
}

/// The `[resolved]` table appended to a stored campaign text.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Resolved {
    /// The simulated sample (`[material]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material: Option<MaterialSpec>,
    /// The relative method's reference sample (`[calibration] reference`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<MaterialSpec>,
    /// The speed profiles of sweeps that follow the BRDF, read from their first pass.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sweep_profiles: Vec<ArcProfile>,
}

#[derive(Serialize)]
struct Trailer<'a> {
    resolved: &'a Resolved,
}

/// The text appended to a campaign file when it is stored: a comment and the `[resolved]` table. Empty when
/// there is nothing to resolve. Appending keeps every line of the original where it was (messages about the
/// stored text keep their line numbers) and is valid TOML after any document, since `[resolved]` may not appear
/// in a campaign a person writes.
pub fn resolved_trailer(r: &Resolved) -> String {
    if r.material.is_none() && r.reference.is_none() && r.sweep_profiles.is_empty() {
        return String::new();
    }
    let table = toml::to_string(&Trailer { resolved: r }).unwrap_or_default();
    format!(
        "\n\n# ---- Added by gonio when this campaign was stored: the materials and first passes it names, resolved \
         once (presets and files read at submission), so that resuming never reads them again. ----\n{table}"
    )
}

/// Rebuild a material from its stored description. A measured material's `file` is absolute (resolved at
/// submission); `/` is only the base of a relative path written by hand.
pub fn material_from_stored(spec: &MaterialSpec) -> Result<Material, gonio_brdf::material::MaterialError> {
    Material::from_spec(spec, Path::new("/"))
}

/// A path named in a campaign, checked against the policy: the file to read.
/// `relative_to` is the directory a relative name resolves against (the campaign file's or, for a file named in
/// a reference material file, that file's directory).
pub(crate) fn file_path(sources: &Sources, relative_to: &Path, name: &str) -> Result<PathBuf, String> {
    match sources {
        Sources::Local(_) | Sources::Stored => {
            let p = Path::new(name);
            Ok(if p.is_absolute() {
                p.to_path_buf()
            } else {
                relative_to.join(p)
            })
        }
        Sources::Confined(root) => confine(root, relative_to, name),
    }
}

/// The directory relative names resolve against at the top of a campaign: absolute, so that what is stored
/// (measured data files) does not depend on the current directory later.
pub(crate) fn base_dir(sources: &Sources) -> Result<PathBuf, String> {
    match sources {
        Sources::Local(dir) => {
            let dir = if dir.as_os_str().is_empty() {
                Path::new(".")
            } else {
                dir.as_path()
            };
            Ok(dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf()))
        }
        Sources::Confined(root) => canonical_root(root),
        Sources::Stored => Ok(PathBuf::from("/")),
    }
}

fn canonical_root(root: &Path) -> Result<PathBuf, String> {
    root.canonicalize()
        .map_err(|e| format!("cannot resolve the data directory {}: {e}", root.display()))
}

/// `name` (relative to `relative_to`, or absolute) as a canonical path inside `root`, or why not. The error says
/// what the rule is and never where a link outside leads.
pub(crate) fn confine(root: &Path, relative_to: &Path, name: &str) -> Result<PathBuf, String> {
    let root = canonical_root(root)?;
    let rule = format!(
        "a campaign submitted to the daemon may only name material presets or files inside its data directory {}",
        root.display()
    );
    let p = Path::new(name);
    if name.is_empty() {
        return Err(format!("expected a preset name or a file name; {rule}"));
    }
    if p.components().any(|c| matches!(c, Component::ParentDir)) {
        return Err(format!("{name:?} contains `..`; {rule}"));
    }
    let joined = if p.is_absolute() {
        // Lexically outside: refuse before touching the file system there.
        if !p.starts_with(&root) {
            return Err(format!("{name:?} is outside the data directory; {rule}"));
        }
        p.to_path_buf()
    } else {
        relative_to.join(p)
    };
    let canonical = joined
        .canonicalize()
        .map_err(|e| format!("{name:?}: no such file in the data directory ({e}); {rule}"))?;
    if !canonical.starts_with(&root) {
        return Err(format!(
            "{name:?} leads outside the data directory (through a symbolic link); {rule}"
        ));
    }
    if !canonical.is_file() {
        return Err(format!("{name:?} is not a file; {rule}"));
    }
    Ok(canonical)
}

/// The `file` key of a document's `[material]` table, when it is a string (a measured material's data file).
pub fn material_data_file(text: &str) -> Option<String> {
    let doc: toml::Table = toml::from_str(text).ok()?;
    doc.get("material")?
        .as_table()?
        .get("file")?
        .as_str()
        .map(str::to_string)
}

/// True when `name` is a built-in material preset.
pub fn is_preset(name: &str) -> bool {
    Material::preset_names().contains(&name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn confinement_refuses_parent_dirs_absolute_paths_and_escaping_links() {
        let data = tempfile::tempdir().expect("tempdir");
        let outside = tempfile::tempdir().expect("tempdir");
        std::fs::write(data.path().join("ref.toml"), "x").expect("write");
        std::fs::create_dir(data.path().join("sub")).expect("mkdir");
        std::fs::write(data.path().join("sub/inner.toml"), "x").expect("write");
        std::fs::write(outside.path().join("secret.toml"), "x").expect("write");
        let root = data.path();
        let canon = root.canonicalize().expect("canon");

        assert_eq!(
            confine(root, root, "ref.toml").expect("inside"),
            canon.join("ref.toml")
        );
        assert_eq!(
            confine(root, &canon.join("sub"), "inner.toml").expect("inside, relative to a subdirectory"),
            canon.join("sub/inner.toml")
        );
        let abs = canon.join("ref.toml").display().to_string();
        assert!(confine(root, root, &abs).is_ok());

        let e = confine(root, root, "../x.toml").expect_err("parent dir");
        assert!(e.contains("`..`") && e.contains("data directory"), "{e}");
        let e = confine(root, root, "sub/../ref.toml").expect_err("parent dir even when harmless");
        assert!(e.contains("`..`"), "{e}");
        let secret = outside.path().join("secret.toml").display().to_string();
        let e = confine(root, root, &secret).expect_err("absolute outside");
        assert!(e.contains("outside the data directory"), "{e}");
        let e = confine(root, root, "missing.toml").expect_err("missing");
        assert!(e.contains("no such file"), "{e}");
        let e = confine(root, root, "sub").expect_err("a directory");
        assert!(e.contains("not a file"), "{e}");

        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(outside.path().join("secret.toml"), root.join("link.toml"))
                .expect("symlink");
            let e = confine(root, root, "link.toml").expect_err("link out");
            assert!(e.contains("symbolic link"), "{e}");
            assert!(
                !e.contains("secret"),
                "the message must not reveal the target: {e}"
            );
            std::os::unix::fs::symlink(root.join("ref.toml"), root.join("inner-link.toml")).expect("symlink");
            assert_eq!(
                confine(root, root, "inner-link.toml").expect("a link inside stays inside"),
                canon.join("ref.toml")
            );
        }
    }

    #[test]
    fn the_trailer_round_trips_the_material_descriptions() {
        let gold = Material::preset("gold").expect("gold");
        let r = Resolved {
            material: Some(gold.spec()),
            reference: Some(Material::preset("spectralon").expect("spectralon").spec()),
            sweep_profiles: vec![ArcProfile {
                entry: 1,
                held_deg: 30.0,
                plane_phi_deg: 0.0,
                pieces: vec![gonio_scheduler::sweep::follow::FollowPiece {
                    from_deg: -80.0,
                    to_deg: 12.5,
                    speed_deg_s: 5.656854249492381,
                    smearing_rel: 1.25e-4,
                }],
            }],
        };
        let doc = format!("[campaign]\nid = \"x\"{}", resolved_trailer(&r));
        #[derive(Deserialize)]
        struct Doc {
            resolved: Resolved,
        }
        let back: Doc = toml::from_str(&doc).expect("valid TOML");
        assert_eq!(back.resolved, r);
        let m = material_from_stored(back.resolved.material.as_ref().expect("material")).expect("rebuilt");
        let wi = gonio_brdf::Direction::from_spherical_deg(30.0, 0.0);
        let wo = gonio_brdf::Direction::from_spherical_deg(40.0, 180.0);
        let wl = gonio_brdf::Wavelength::from_nm(550.0).expect("wl");
        use gonio_brdf::Brdf;
        assert_eq!(
            m.eval(&wi, &wo, wl).expect("eval").to_bits(),
            gold.eval(&wi, &wo, wl).expect("eval").to_bits()
        );
        assert_eq!(resolved_trailer(&Resolved::default()), "");
    }
}
