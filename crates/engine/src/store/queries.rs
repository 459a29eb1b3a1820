//! Reading and writing campaigns, their states, devices, calibrations and points: one statement (or one
//! transaction) per call, at the durability the campaign needs.

use gonio_results::budget::Budget;
use rusqlite::{OptionalExtension, named_params, params};

use super::schema::{INSERT_POINT, SELECT_COMMITTED_POINTS_FROM, SELECT_POINTS_FROM};

use super::{
    CalibrationRecord, CampaignId, CampaignRecord, CampaignState, InstrumentCalibrationId, NewCampaign,
    PointCompletion, PointRecord, PointValue, Store, StoreError,
};

impl Store {
    /// Store a new campaign in the `queued` state.
    pub fn create_campaign(&mut self, new: &NewCampaign) -> Result<CampaignId, StoreError> {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs_f64())
            .unwrap_or(0.0);
        self.durability_for_write(None)?;
        self.conn
            .execute(
                "INSERT INTO campaigns (name, state, campaign_toml, instrument_toml, total_points, dry_run,
                 software_version, created_unix_s, predicted_instrument_s, alignment_toml, calibration_id)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)",
                params![
                    new.name,
                    CampaignState::Queued.as_str(),
                    new.campaign_toml,
                    new.instrument_toml,
                    to_i64(new.total_points),
                    new.dry_run,
                    new.software_version,
                    now,
                    new.predicted_instrument_s,
                    new.alignment_toml,
                    new.calibration_id.map(|c| c.0)
                ],
            )
            .map_err(self.write_err())?;
        let id = CampaignId(self.conn.last_insert_rowid());
        self.dry_runs.insert(id, new.dry_run);
        Ok(id)
    }

    pub fn campaign(&self, id: CampaignId) -> Result<CampaignRecord, StoreError> {
        let record = self
            .conn
            .query_row(
                &format!("{CAMPAIGN_SELECT} WHERE c.id = ?1"),
                [id.0],
                campaign_from_row,
            )
            .optional()
            .map_err(self.read_err())?
            .ok_or(StoreError::NoSuchCampaign(id))??;
        Ok(self.overlay(record))
    }

    /// A campaign's state (cheaper than [`Store::campaign`]: no configuration texts).
    pub fn state(&self, id: CampaignId) -> Result<CampaignState, StoreError> {
        if let Some((state, _)) = self.unrecorded.get(&id) {
            return Ok(*state);
        }
        let state: String = self
            .conn
            .prepare_cached("SELECT state FROM campaigns WHERE id = ?1")
            .and_then(|mut st| st.query_row([id.0], |r| r.get(0)).optional())
            .map_err(self.read_err())?
            .ok_or(StoreError::NoSuchCampaign(id))?;
        state.parse()
    }

    /// A record with the state that could not be written, if any.
    fn overlay(&self, mut record: CampaignRecord) -> CampaignRecord {
        if let Some((state, message)) = self.unrecorded.get(&record.id) {
            record.state = *state;
            if *state == CampaignState::Completed {
                record.last_error = None;
            } else if message.is_some() {
                record.last_error.clone_from(message);
            }
        }
        record
    }

    /// All campaigns, oldest first.
    pub fn campaigns(&self) -> Result<Vec<CampaignRecord>, StoreError> {
        let mut stmt = self
            .conn
            .prepare(&format!("{CAMPAIGN_SELECT} ORDER BY c.id"))
            .map_err(self.read_err())?;
        let rows = stmt.query_map([], campaign_from_row).map_err(self.read_err())?;
        let mut out = Vec::new();
        for row in rows {
            out.push(self.overlay(row.map_err(self.read_err())??));
        }
        Ok(out)
    }

    pub fn set_state(
        &mut self,
        id: CampaignId,
        state: CampaignState,
        last_error: Option<&str>,
    ) -> Result<(), StoreError> {
        let result = self.durability_for_write(Some(id)).and_then(|()| {
            self.conn
                .prepare_cached(
                    // A completed campaign has no error left to show: a pause's reason from before its
                    // resume is cleared (it stays in the log and the events).
                    "UPDATE campaigns SET state = ?2, last_error = CASE WHEN ?2 = 'completed' THEN NULL \
                         ELSE COALESCE(?3, last_error) END WHERE id = ?1",
                )
                .and_then(|mut st| st.execute(params![id.0, state.as_str(), last_error]))
                .map_err(self.write_err())
        });
        match result {
            Ok(0) => Err(StoreError::NoSuchCampaign(id)),
            Ok(_) => {
                self.unrecorded.remove(&id);
                Ok(())
            }
            Err(e) => {
                if e.is_write_failure() {
                    // Shown from memory until a later write succeeds (module doc).
                    let message = last_error
                        .map(str::to_string)
                        .or_else(|| self.unrecorded.get(&id).and_then(|u| u.1.clone()));
                    self.unrecorded.insert(id, (state, message));
                }
                Err(e)
            }
        }
    }

    /// Set the points a campaign measures in all: an adaptive campaign that reached its target error before its
    /// budget ends with fewer points than it was submitted with.
    pub fn set_total_points(&mut self, id: CampaignId, total: u64) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        let n = self
            .conn
            .execute(
                "UPDATE campaigns SET total_points = ?2 WHERE id = ?1",
                params![id.0, to_i64(total)],
            )
            .map_err(self.write_err())?;
        if n == 0 {
            return Err(StoreError::NoSuchCampaign(id));
        }
        Ok(())
    }

    /// Cap the store file at `pages` pages (None: SQLite's own maximum); returns the cap in force. Writes that
    /// would grow the file beyond it fail as a full disk would (SQLITE_FULL). The cap lasts while this `Store`
    /// is open.
    pub fn set_max_pages(&mut self, pages: Option<u64>) -> Result<u64, StoreError> {
        // SQLite's largest page count; asking for more keeps that.
        let n = to_i64(pages.unwrap_or(u64::from(u32::MAX - 1)));
        let cap: i64 = self
            .conn
            .query_row(&format!("PRAGMA max_page_count = {n}"), [], |r| r.get(0))
            .map_err(self.write_err())?;
        Ok(from_i64(cap))
    }

    /// Pages the store file holds now.
    pub fn page_count(&self) -> Result<u64, StoreError> {
        let n: i64 = self
            .conn
            .query_row("PRAGMA page_count", [], |r| r.get(0))
            .map_err(self.read_err())?;
        Ok(from_i64(n))
    }

    /// Record the instrument time (s) at which a run of campaign `id` ended.
    pub fn set_ended_instrument_s(&mut self, id: CampaignId, t_s: f64) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        self.conn
            .execute(
                "UPDATE campaigns SET ended_instrument_s = ?1 WHERE id = ?2",
                rusqlite::params![t_s, id.0],
            )
            .map_err(self.write_err())?;
        Ok(())
    }

    pub fn set_operator_message(&mut self, id: CampaignId, message: Option<&str>) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        self.conn
            .execute(
                "UPDATE campaigns SET operator_message = ?2 WHERE id = ?1",
                params![id.0, message],
            )
            .map_err(self.write_err())?;
        Ok(())
    }

    /// Record the identity string a device reported (e.g. `*IDN?`), replacing an earlier one.
    pub fn record_device(&mut self, id: CampaignId, name: &str, identity: &str) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        self.conn
            .execute(
                "INSERT OR REPLACE INTO devices (campaign_id, name, identity) VALUES (?1, ?2, ?3)",
                params![id.0, name, identity],
            )
            .map_err(self.write_err())?;
        Ok(())
    }

    pub fn devices(&self, id: CampaignId) -> Result<Vec<(String, String)>, StoreError> {
        let mut stmt = self
            .conn
            .prepare("SELECT name, identity FROM devices WHERE campaign_id = ?1 ORDER BY name")
            .map_err(self.read_err())?;
        let rows = stmt
            .query_map([id.0], |r| Ok((r.get(0)?, r.get(1)?)))
            .map_err(self.read_err())?;
        rows.collect::<Result<_, _>>().map_err(self.read_err())
    }

    pub fn record_calibration(&mut self, id: CampaignId, cal: &CalibrationRecord) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        self.conn
            .prepare_cached(
                "INSERT INTO calibrations (campaign_id, seq, kind, band_nm, t_s, value_w, u_w)
                 VALUES (?1, (SELECT COALESCE(MAX(seq), 0) + 1 FROM calibrations WHERE campaign_id = ?1),
                         ?2, ?3, ?4, ?5, ?6)",
            )
            .and_then(|mut st| {
                st.execute(params![
                    id.0,
                    cal.kind,
                    cal.band_nm,
                    cal.t_s,
                    cal.value_w,
                    cal.u_w
                ])
            })
            .map_err(self.write_err())?;
        Ok(())
    }

    pub fn calibrations(&self, id: CampaignId) -> Result<Vec<CalibrationRecord>, StoreError> {
        let mut stmt = self
            .conn
            .prepare(
                "SELECT kind, band_nm, t_s, value_w, u_w FROM calibrations WHERE campaign_id = ?1 ORDER BY seq",
            )
            .map_err(self.read_err())?;
        let rows = stmt
            .query_map([id.0], |r| {
                Ok(CalibrationRecord {
                    kind: r.get(0)?,
                    band_nm: r.get(1)?,
                    t_s: r.get(2)?,
                    value_w: r.get(3)?,
                    u_w: r.get(4)?,
                })
            })
            .map_err(self.read_err())?;
        rows.collect::<Result<_, _>>().map_err(self.read_err())
    }

    /// Commit one point in its own transaction, as durably as its campaign asks ([`Durability`](super::Durability)). A point
    /// already committed is refused, never overwritten.
    pub fn commit_point(&mut self, id: CampaignId, p: &PointRecord) -> Result<(), StoreError> {
        let readback = serde_json::to_string(&p.readback_deg)
            .map_err(|e| StoreError::Corrupt(format!("cannot encode read-back positions: {e}")))?;
        let flags = p.flags.join(";");
        let budget = (!p.budget.entries.is_empty()).then(|| p.budget.to_compact());
        self.durability_for_write(Some(id))?;
        // Prepared once per connection (SQLite's parse and plan cost as much as the insert itself).
        let result = self.conn.prepare_cached(&INSERT_POINT).and_then(|mut st| {
            st.execute(named_params! {
                ":campaign_id": id.0,
                ":idx": to_i64(p.index),
                ":band_nm": p.band_nm,
                ":theta_i_deg": p.theta_i_deg,
                ":phi_i_deg": p.phi_i_deg,
                ":theta_o_deg": p.theta_o_deg,
                ":phi_o_deg": p.phi_o_deg,
                ":signal_w": p.signal_w,
                ":dark_w": p.dark_w,
                ":incident_w": p.incident_w,
                ":brdf_sr": p.brdf_sr,
                ":brdf_u_sr": p.brdf_u_sr,
                ":flags": flags,
                ":t_s": p.t_s,
                ":readback_json": readback,
                ":truth_point_sr": p.truth_point_sr,
                ":truth_aperture_sr": p.truth_aperture_sr,
                ":truth_effects_json": p.truth_effects_json,
                ":brdf_aperture_sr": p.brdf_aperture_sr,
                ":budget": budget,
            })
        });
        match result {
            Ok(_) => Ok(()),
            // Only the primary key means "already committed"; any other constraint is a bug, not a duplicate.
            Err(rusqlite::Error::SqliteFailure(e, _))
                if e.extended_code == rusqlite::ffi::SQLITE_CONSTRAINT_PRIMARYKEY =>
            {
                Err(StoreError::DuplicatePoint {
                    campaign: id,
                    index: p.index,
                })
            }
            Err(source) => Err(StoreError::Write {
                path: self.path.clone(),
                source,
            }),
        }
    }

    /// Records a campaign's completion (crate::budget::complete) in one transaction, replacing any earlier one
    /// of the campaign whole: per point its completed budget (its total becomes the point's `brdf_u_sr`) and,
    /// where the completion changed them, the value corrected to the nominal geometry with the aperture average
    /// it came from, and the flags. They are kept apart from the committed rows, which are never rewritten, and
    /// read in their place ([`Store::points`]). An index not stored is refused by nothing and read by nothing.
    pub fn update_completions(
        &mut self,
        id: CampaignId,
        updates: &[PointCompletion],
    ) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        let path = self.path.clone();
        let err = |source| StoreError::Write {
            path: path.clone(),
            source,
        };
        let tx = self.conn.transaction().map_err(err)?;
        tx.execute("DELETE FROM point_budgets WHERE campaign_id = ?1", [id.0])
            .map_err(err)?;
        {
            let mut st = tx
                .prepare_cached(
                    "INSERT INTO point_budgets (budget, brdf_u_sr, brdf_sr, brdf_aperture_sr, flags, \
                     campaign_id, idx) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
                )
                .map_err(err)?;
            for u in updates {
                st.execute(params![
                    u.budget.to_compact(),
                    u.budget.total_sr(),
                    u.brdf_sr,
                    u.brdf_aperture_sr,
                    u.flags.as_ref().map(|f| f.join(";")),
                    id.0,
                    to_i64(u.index)
                ])
                .map_err(err)?;
            }
        }
        tx.commit().map_err(err)
    }

    /// The first point index not yet committed: where a resumed campaign continues.
    pub fn next_index(&self, id: CampaignId) -> Result<u64, StoreError> {
        // Points are committed in index order, so the count of rows is the next index; check that the rows
        // really are 0..count so that a hole (which would mean a bug) is reported rather than skipped.
        let (count, max): (i64, Option<i64>) = self
            .conn
            .prepare_cached("SELECT COUNT(*), MAX(idx) FROM points WHERE campaign_id = ?1")
            .and_then(|mut st| st.query_row([id.0], |r| Ok((r.get(0)?, r.get(1)?))))
            .map_err(self.read_err())?;
        match max {
            None => Ok(0),
            Some(m) if m + 1 == count => Ok(from_i64(count)),
            Some(m) => Err(StoreError::Corrupt(format!(
                "campaign {id} has {count} points but the highest index is {m}: points are missing"
            ))),
        }
    }

    /// All committed points of a campaign in index order.
    pub fn points(&self, id: CampaignId) -> Result<Vec<PointRecord>, StoreError> {
        self.points_from(id, 0)
    }

    /// Committed points with index >= `from`, in index order.
    pub fn points_from(&self, id: CampaignId, from: u64) -> Result<Vec<PointRecord>, StoreError> {
        self.select_points(&SELECT_POINTS_FROM, id, from)
    }

    /// The points as they were committed, without what a completion changed (crate::budget::complete starts
    /// from these again, so that completing twice gives the same result).
    pub fn committed_points(&self, id: CampaignId) -> Result<Vec<PointRecord>, StoreError> {
        self.select_points(&SELECT_COMMITTED_POINTS_FROM, id, 0)
    }

    fn select_points(&self, sql: &str, id: CampaignId, from: u64) -> Result<Vec<PointRecord>, StoreError> {
        let mut stmt = self.conn.prepare_cached(sql).map_err(self.read_err())?;
        let rows = stmt
            .query_map(params![id.0, to_i64(from)], point_from_row)
            .map_err(self.read_err())?;
        let mut out = Vec::new();
        for row in rows {
            out.push(row.map_err(self.read_err())??);
        }
        Ok(out)
    }

    /// The geometry and BRDF of the committed points with `from <= index < to`, in index order: the columns an
    /// adaptive planner needs and no more.
    pub fn point_values(&self, id: CampaignId, from: u64, to: u64) -> Result<Vec<PointValue>, StoreError> {
        let mut stmt = self
            .conn
            .prepare(
                "SELECT idx, theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg, brdf_sr
                 FROM points WHERE campaign_id = ?1 AND idx >= ?2 AND idx < ?3 ORDER BY idx",
            )
            .map_err(self.read_err())?;
        let rows = stmt
            .query_map(params![id.0, to_i64(from), to_i64(to)], |r| {
                Ok(PointValue {
                    index: u64::try_from(r.get::<_, i64>(0)?).unwrap_or(u64::MAX),
                    theta_i_deg: r.get(1)?,
                    phi_i_deg: r.get(2)?,
                    theta_o_deg: r.get(3)?,
                    phi_o_deg: r.get(4)?,
                    brdf_sr: r.get(5)?,
                })
            })
            .map_err(self.read_err())?;
        let mut out = Vec::new();
        for row in rows {
            out.push(row.map_err(self.read_err())?);
        }
        Ok(out)
    }

    /// Campaigns that were running when the daemon last stopped, oldest first.
    pub fn interrupted_campaigns(&self) -> Result<Vec<CampaignId>, StoreError> {
        Ok(self
            .campaigns()?
            .into_iter()
            .filter(|c| c.state.was_interrupted())
            .map(|c| c.id)
            .collect())
    }
}

const CAMPAIGN_SELECT: &str = "SELECT c.id, c.name, c.state, c.campaign_toml, c.instrument_toml, c.total_points,
    (SELECT COUNT(*) FROM points p WHERE p.campaign_id = c.id), c.dry_run, c.software_version, c.created_unix_s,
    c.last_error, c.operator_message, c.predicted_instrument_s, c.alignment_toml,
    c.calibration_id, c.ended_instrument_s FROM campaigns c";

fn campaign_from_row(r: &rusqlite::Row<'_>) -> rusqlite::Result<Result<CampaignRecord, StoreError>> {
    let state: String = r.get(2)?;
    let total: i64 = r.get(5)?;
    let done: i64 = r.get(6)?;
    let record = |state| CampaignRecord {
        id: CampaignId(0),
        name: String::new(),
        state,
        campaign_toml: String::new(),
        instrument_toml: String::new(),
        total_points: from_i64(total),
        points_done: from_i64(done),
        dry_run: false,
        software_version: String::new(),
        created_unix_s: 0.0,
        last_error: None,
        operator_message: None,
        predicted_instrument_s: None,
        alignment_toml: None,
        calibration_id: None,
        ended_instrument_s: None,
    };
    let state = match state.parse::<CampaignState>() {
        Ok(s) => s,
        Err(e) => return Ok(Err(e)),
    };
    Ok(Ok(CampaignRecord {
        id: CampaignId(r.get(0)?),
        name: r.get(1)?,
        campaign_toml: r.get(3)?,
        instrument_toml: r.get(4)?,
        dry_run: r.get(7)?,
        software_version: r.get(8)?,
        created_unix_s: r.get(9)?,
        last_error: r.get(10)?,
        operator_message: r.get(11)?,
        predicted_instrument_s: r.get(12)?,
        alignment_toml: r.get(13)?,
        calibration_id: r.get::<_, Option<i64>>(14)?.map(InstrumentCalibrationId),
        ended_instrument_s: r.get(15)?,
        ..record(state)
    }))
}

/// One row of [`SELECT_POINTS_FROM`], each column by its name in the schema's list.
fn point_from_row(r: &rusqlite::Row<'_>) -> rusqlite::Result<Result<PointRecord, StoreError>> {
    let flags: String = r.get("flags")?;
    let readback: String = r.get("readback_json")?;
    let readback_deg = match serde_json::from_str(&readback) {
        Ok(v) => v,
        Err(e) => {
            return Ok(Err(StoreError::Corrupt(format!(
                "read-back positions {readback:?}: {e}"
            ))));
        }
    };
    let budget = match r.get::<_, Option<String>>("budget")? {
        None => Budget::default(),
        Some(text) => match Budget::parse_compact(&text) {
            Ok(b) => b,
            Err(e) => return Ok(Err(StoreError::Corrupt(e.to_string()))),
        },
    };
    Ok(Ok(PointRecord {
        index: from_i64(r.get("idx")?),
        band_nm: r.get("band_nm")?,
        theta_i_deg: r.get("theta_i_deg")?,
        phi_i_deg: r.get("phi_i_deg")?,
        theta_o_deg: r.get("theta_o_deg")?,
        phi_o_deg: r.get("phi_o_deg")?,
        // NULL: no reading (a failed point), stored from NaN.
        signal_w: r.get::<_, Option<f64>>("signal_w")?.unwrap_or(f64::NAN),
        dark_w: r.get::<_, Option<f64>>("dark_w")?.unwrap_or(f64::NAN),
        incident_w: r.get::<_, Option<f64>>("incident_w")?.unwrap_or(f64::NAN),
        brdf_sr: r.get("brdf_sr")?,
        brdf_u_sr: r.get("brdf_u_sr")?,
        flags: if flags.is_empty() {
            Vec::new()
        } else {
            flags.split(';').map(str::to_string).collect()
        },
        t_s: r.get("t_s")?,
        readback_deg,
        truth_point_sr: r.get("truth_point_sr")?,
        truth_aperture_sr: r.get("truth_aperture_sr")?,
        truth_effects_json: r.get("truth_effects_json")?,
        brdf_aperture_sr: r.get("brdf_aperture_sr")?,
        budget,
    }))
}

/// Counts in the store are SQLite INTEGERs (i64); ours are u64 and far below 2^63.
fn to_i64(v: u64) -> i64 {
    i64::try_from(v).unwrap_or(i64::MAX)
}

fn from_i64(v: i64) -> u64 {
    u64::try_from(v).unwrap_or(0)
}
