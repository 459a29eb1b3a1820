//! Sweep readings: a campaign's sweeps (`[[plan.sweeps]]`) store their readings a segment (one sweep of one arc
//! in one band) at a time, the segment's row and all its readings in one transaction. A segment is therefore
//! complete in the store or absent: resuming restarts the first segment not committed, and never stores a
//! reading twice (the primary key (campaign, segment, reading) refuses it). The completion (crate::budget's
//! `sweep_completions`) is kept beside each reading (`completed_*`), never over it: completing again starts
//! from the readings as committed. Readers get the completed value, and the committed one as the aperture
//! average it was corrected from. A reading is
//! `gonio_results::sweeps::SweepReading`, stored column for column.

use rusqlite::{OptionalExtension, named_params, params};
use serde::{Deserialize, Serialize};

use gonio_results::sweeps::SweepReading;

use super::{CampaignId, Store, StoreError};

/// The tables, created with a new store and added by the migration to version 11 (`timing_u_s` by the one to
/// version 12).
pub(super) const SWEEP_TABLES: &str = "CREATE TABLE sweep_segments (
                campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
                segment INTEGER NOT NULL,
                band_nm REAL,
                started_s REAL NOT NULL,
                ended_s REAL NOT NULL,
                readings INTEGER NOT NULL,
                timing_u_s REAL,
                PRIMARY KEY (campaign_id, segment)
            );
            CREATE TABLE sweep_readings (
                campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
                segment INTEGER NOT NULL,
                k INTEGER NOT NULL,
                band_nm REAL NOT NULL,
                t_s REAL NOT NULL,
                integration_s REAL NOT NULL,
                theta_i_deg REAL NOT NULL,
                phi_i_deg REAL NOT NULL,
                theta_o_deg REAL NOT NULL,
                phi_o_deg REAL NOT NULL,
                arc_from_deg REAL NOT NULL,
                arc_to_deg REAL NOT NULL,
                signal_w REAL,
                incident_w REAL,
                brdf_sr REAL,
                brdf_u_sr REAL,
                flags TEXT NOT NULL,
                truth_point_sr REAL,
                completed_brdf_sr REAL,
                completed_u_sr REAL,
                completed_flags TEXT,
                PRIMARY KEY (campaign_id, segment, k)
            );";

/// One committed sweep segment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepSegmentRecord {
    /// Index of the sweep in the campaign's sweep schedule.
    pub segment: u32,
    pub band_nm: Option<f64>,
    /// Instrument time (s from the campaign's start) at which the sweep's motion started and ended.
    pub started_s: f64,
    pub ended_s: f64,
    pub readings: u32,
    /// How well the time of each reading is known for placing it along its arc (s, standard uncertainty): the
    /// meter's exchange and the windows in which the controller took its position reports; None for segments
    /// stored before it was kept (the completion then takes the meter's exchange alone).
    #[serde(default)]
    pub timing_u_s: Option<f64>,
}

impl Store {
    /// Commit one sweep segment with its readings in one transaction; a segment already committed is refused.
    pub fn commit_sweep_segment(
        &mut self,
        id: CampaignId,
        segment: &SweepSegmentRecord,
        readings: &[SweepReading],
    ) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        let path = self.path.clone();
        let write = |source| StoreError::Write {
            path: path.clone(),
            source,
        };
        let tx = self.conn.transaction().map_err(write)?;
        let inserted = tx.execute(
            "INSERT INTO sweep_segments (campaign_id, segment, band_nm, started_s, ended_s, readings, timing_u_s)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
            params![
                id.0,
                segment.segment,
                segment.band_nm,
                segment.started_s,
                segment.ended_s,
                segment.readings,
                segment.timing_u_s
            ],
        );
        if let Err(rusqlite::Error::SqliteFailure(e, _)) = &inserted
            && e.extended_code == rusqlite::ffi::SQLITE_CONSTRAINT_PRIMARYKEY
        {
            return Err(StoreError::Corrupt(format!(
                "campaign {id}: sweep segment {} is already committed",
                segment.segment
            )));
        }
        inserted.map_err(write)?;
        {
            let mut st = tx
                .prepare_cached(
                    "INSERT INTO sweep_readings (campaign_id, segment, k, band_nm, t_s, integration_s, theta_i_deg,
                     phi_i_deg, theta_o_deg, phi_o_deg, arc_from_deg, arc_to_deg, signal_w, incident_w, brdf_sr,
                     brdf_u_sr, flags, truth_point_sr)
                     VALUES (:campaign_id, :segment, :k, :band_nm, :t_s, :integration_s, :theta_i_deg, :phi_i_deg,
                     :theta_o_deg, :phi_o_deg, :arc_from_deg, :arc_to_deg, :signal_w, :incident_w, :brdf_sr, :brdf_u_sr, :flags,
                     :truth_point_sr)",
                )
                .map_err(write)?;
            for r in readings {
                st.execute(named_params! {
                    ":campaign_id": id.0,
                    ":segment": r.segment,
                    ":k": r.k,
                    ":band_nm": r.band_nm,
                    ":t_s": r.t_s,
                    ":integration_s": r.integration_s,
                    ":theta_i_deg": r.theta_i_deg,
                    ":phi_i_deg": r.phi_i_deg,
                    ":theta_o_deg": r.theta_o_deg,
                    ":phi_o_deg": r.phi_o_deg,
                    ":arc_from_deg": r.arc_from_deg,
                    ":arc_to_deg": r.arc_to_deg,
                    ":signal_w": r.signal_w,
                    ":incident_w": r.incident_w,
                    ":brdf_sr": r.brdf_sr,
                    ":brdf_u_sr": r.brdf_u_sr,
                    ":flags": r.flags.join(";"),
                    ":truth_point_sr": r.truth_point_sr,
                })
                .map_err(write)?;
            }
        }
        tx.commit().map_err(write)
    }

    /// Segments committed for a campaign: the sweeps run resumes at this index (segments commit in order).
    pub fn sweep_segments_done(&self, id: CampaignId) -> Result<u32, StoreError> {
        let n: Option<i64> = self
            .conn
            .query_row(
                "SELECT MAX(segment) + 1 FROM sweep_segments WHERE campaign_id = ?1",
                params![id.0],
                |r| r.get(0),
            )
            .optional()
            .map_err(self.read_err())?
            .flatten();
        Ok(n.and_then(|n| u32::try_from(n).ok()).unwrap_or(0))
    }

    /// Every committed segment of a campaign, in order.
    pub fn sweep_segments(&self, id: CampaignId) -> Result<Vec<SweepSegmentRecord>, StoreError> {
        let mut st = self
            .conn
            .prepare_cached(
                "SELECT segment, band_nm, started_s, ended_s, readings, timing_u_s FROM sweep_segments
                 WHERE campaign_id = ?1 ORDER BY segment",
            )
            .map_err(self.read_err())?;
        let rows = st
            .query_map(params![id.0], |r| {
                Ok(SweepSegmentRecord {
                    segment: r.get(0)?,
                    band_nm: r.get(1)?,
                    started_s: r.get(2)?,
                    ended_s: r.get(3)?,
                    readings: r.get(4)?,
                    timing_u_s: r.get(5)?,
                })
            })
            .map_err(self.read_err())?;
        rows.collect::<Result<Vec<_>, _>>().map_err(self.read_err())
    }

    /// Every sweep reading of a campaign, segment by segment, completed (module doc).
    pub fn sweep_readings(&self, id: CampaignId) -> Result<Vec<SweepReading>, StoreError> {
        self.read_sweep_readings(id, true)
    }

    /// Every sweep reading of a campaign as committed, without its completion: what a completion starts from.
    pub fn committed_sweep_readings(&self, id: CampaignId) -> Result<Vec<SweepReading>, StoreError> {
        self.read_sweep_readings(id, false)
    }

    fn read_sweep_readings(&self, id: CampaignId, completed: bool) -> Result<Vec<SweepReading>, StoreError> {
        let mut st = self
            .conn
            .prepare_cached(
                "SELECT segment, k, band_nm, t_s, integration_s, theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg,
                 arc_from_deg, arc_to_deg, signal_w, brdf_sr, brdf_u_sr, flags, truth_point_sr, completed_brdf_sr,
                 completed_u_sr, completed_flags, incident_w
                 FROM sweep_readings WHERE campaign_id = ?1 ORDER BY segment, k",
            )
            .map_err(self.read_err())?;
        let rows = st
            .query_map(params![id.0], |r| {
                let committed_flags: String = r.get(14)?;
                let completed_flags: Option<String> = if completed { r.get(18)? } else { None };
                let flags = completed_flags.unwrap_or(committed_flags);
                let committed_brdf: Option<f64> = r.get(12)?;
                let completed_brdf: Option<f64> = if completed { r.get(16)? } else { None };
                let completed_u: Option<f64> = if completed { r.get(17)? } else { None };
                Ok(SweepReading {
                    segment: r.get(0)?,
                    k: r.get(1)?,
                    band_nm: r.get(2)?,
                    t_s: r.get(3)?,
                    integration_s: r.get(4)?,
                    theta_i_deg: r.get(5)?,
                    phi_i_deg: r.get(6)?,
                    theta_o_deg: r.get(7)?,
                    phi_o_deg: r.get(8)?,
                    arc_from_deg: r.get(9)?,
                    arc_to_deg: r.get(10)?,
                    signal_w: r.get(11)?,
                    incident_w: r.get(19)?,
                    brdf_sr: completed_brdf.or(committed_brdf),
                    brdf_u_sr: match completed_u {
                        Some(u) => Some(u),
                        None => r.get(13)?,
                    },
                    // The committed value is the aperture average when the completion corrected it.
                    brdf_aperture_sr: completed_brdf
                        .and(committed_brdf)
                        .filter(|a| Some(*a) != completed_brdf),
                    flags: flags
                        .split(';')
                        .filter(|f| !f.is_empty())
                        .map(str::to_string)
                        .collect(),
                    truth_point_sr: r.get(15)?,
                })
            })
            .map_err(self.read_err())?;
        rows.collect::<Result<Vec<_>, _>>().map_err(self.read_err())
    }

    /// The completion of a campaign's sweep readings ([`SweepCompletion`] each), in one transaction, in place of
    /// any earlier one.
    pub fn update_sweep_completions(
        &mut self,
        id: CampaignId,
        completions: &[SweepCompletion],
    ) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        let path = self.path.clone();
        let write = |source| StoreError::Write {
            path: path.clone(),
            source,
        };
        let tx = self.conn.transaction().map_err(write)?;
        {
            let mut st = tx
                .prepare_cached(
                    "UPDATE sweep_readings SET completed_brdf_sr = ?1, completed_u_sr = ?2, completed_flags = ?3
                     WHERE campaign_id = ?4 AND segment = ?5 AND k = ?6",
                )
                .map_err(write)?;
            for c in completions {
                st.execute(params![
                    c.brdf_sr,
                    c.brdf_u_sr,
                    c.flags.as_ref().map(|f| f.join(";")),
                    id.0,
                    c.segment,
                    c.k
                ])
                .map_err(write)?;
            }
        }
        tx.commit().map_err(write)
    }
}

/// What the completion sets for one sweep reading (crate::budget::sweep_completions).
#[derive(Debug, Clone, PartialEq)]
pub struct SweepCompletion {
    pub segment: u32,
    pub k: u32,
    /// The value at the nominal geometry (the committed one when not corrected).
    pub brdf_sr: Option<f64>,
    pub brdf_u_sr: Option<f64>,
    /// The flags, when the completion changed them.
    pub flags: Option<Vec<String>>,
}

#[cfg(test)]
mod tests;
