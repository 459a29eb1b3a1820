//! Built-in materials. They are data, not code: the TOML files in config/materials/, compiled in so that the
//! binary works from any directory. Each file says what it represents and that its parameters are
//! representative, not measurements.

/// Preset names, in the order they are listed to users.
pub const NAMES: &[&str] = &[
    "mirror",
    "white-styrofoam",
    "construction-paper",
    "coloured-plastic",
    "gold",
    "spectralon",
];

/// The TOML text of a preset, `None` for an unknown name.
pub fn preset_text(name: &str) -> Option<&'static str> {
    Some(match name {
        "mirror" => include_str!("../../../config/materials/mirror.toml"),
        "white-styrofoam" => include_str!("../../../config/materials/white-styrofoam.toml"),
        "construction-paper" => include_str!("../../../config/materials/construction-paper.toml"),
        "coloured-plastic" => include_str!("../../../config/materials/coloured-plastic.toml"),
        "gold" => include_str!("../../../config/materials/gold.toml"),
        "spectralon" => include_str!("../../../config/materials/spectralon.toml"),
        _ => return None,
    })
}
