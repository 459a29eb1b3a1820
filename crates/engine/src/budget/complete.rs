//! The budget's parts that need the campaign's other points, added once it has completed: today the finite
//! band (gonio_results::band_component: the sample's spectral slope from the bands measured at the same
//! geometry, times each filter's centre uncertainty from the instrument file). Each point's budget gains the component, shared by its band's points, and its `brdf_u_sr`
//! becomes the new total, all in one transaction; running it again gives the same budgets (a resumed
//! campaign that completes runs it over every point).

use gonio_instrument::Instrument;
use gonio_results::band_component::{FilterBand, band_components};
use gonio_results::budget::{components, groups};
use gonio_results::run::BAND_TOLERANCE_NM;

use crate::store::{CampaignId, Store, StoreError};

/// Completes the budgets of campaign `id` measured on `instrument`; the number of points whose budget changed.
pub fn complete(store: &mut Store, id: CampaignId, instrument: &Instrument) -> Result<usize, StoreError> {
    let record = store.campaign(id)?;
    let stored = store.points(id)?;
    let table = crate::export::points_table(&record, &stored);
    let filter = |nm: f64| {
        instrument
            .filter_wheel
            .as_ref()?
            .positions
            .iter()
            .find(|p| p.band_nm.is_some_and(|b| (b - nm).abs() <= BAND_TOLERANCE_NM))
            .map(|p| FilterBand {
                band_nm: nm,
                centre_u_nm: p.centre_u_nm(),
            })
    };
    let bands = band_components(&table.points, filter);
    let mut updates = Vec::new();
    for (p, u) in stored.iter().zip(bands) {
        let Some(u) = u else { continue };
        let mut budget = p.budget.clone();
        budget.set(components::BAND, u, Some(groups::band(p.band_nm)));
        if budget != p.budget {
            updates.push((p.index, budget));
        }
    }
    store.update_budgets(id, &updates)?;
    Ok(updates.len())
}
