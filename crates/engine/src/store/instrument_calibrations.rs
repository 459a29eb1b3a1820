//! The instrument's calibrations (`gonio align` files) kept in the store: added, listed, fetched, and the latest
//! one made for an instrument file found. Rows are never overwritten or deleted (the schema's triggers refuse
//! it), so every campaign's `calibration_id` keeps naming what it was given.

use rusqlite::{OptionalExtension, named_params};

use super::{InstrumentCalibration, InstrumentCalibrationId, NewInstrumentCalibration, Store, StoreError};

const SELECT: &str =
    "SELECT id, stored_unix_s, instrument, instrument_sha256, created_utc, software, method, source,
    calibration_toml, report_json FROM instrument_calibrations";

fn from_row(r: &rusqlite::Row<'_>) -> rusqlite::Result<InstrumentCalibration> {
    Ok(InstrumentCalibration {
        id: InstrumentCalibrationId(r.get(0)?),
        stored_unix_s: r.get(1)?,
        instrument: r.get(2)?,
        instrument_sha256: r.get(3)?,
        created_utc: r.get(4)?,
        software: r.get(5)?,
        method: r.get(6)?,
        source: r.get(7)?,
        calibration_toml: r.get(8)?,
        report_json: r.get(9)?,
    })
}

impl Store {
    /// Keep a new instrument calibration (at the strictest durability: it belongs to no campaign).
    pub fn add_instrument_calibration(
        &mut self,
        new: &NewInstrumentCalibration,
    ) -> Result<InstrumentCalibrationId, StoreError> {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs_f64())
            .unwrap_or(0.0);
        self.durability_for_write(None)?;
        self.conn
            .execute(
                "INSERT INTO instrument_calibrations (stored_unix_s, instrument, instrument_sha256, created_utc,
                 software, method, source, calibration_toml, report_json)
                 VALUES (:now, :instrument, :sha, :created, :software, :method, :source, :toml, :report)",
                named_params! {
                    ":now": now,
                    ":instrument": new.instrument,
                    ":sha": new.instrument_sha256,
                    ":created": new.created_utc,
                    ":software": new.software,
                    ":method": new.method,
                    ":source": new.source,
                    ":toml": new.calibration_toml,
                    ":report": new.report_json,
                },
            )
            .map_err(self.write_err())?;
        Ok(InstrumentCalibrationId(self.conn.last_insert_rowid()))
    }

    /// Every stored instrument calibration, oldest first (in the order they were stored).
    pub fn instrument_calibrations(&self) -> Result<Vec<InstrumentCalibration>, StoreError> {
        let mut st = self
            .conn
            .prepare_cached(&format!("{SELECT} ORDER BY id"))
            .map_err(self.read_err())?;
        let rows = st.query_map([], from_row).map_err(self.read_err())?;
        rows.collect::<Result<Vec<_>, _>>().map_err(self.read_err())
    }

    pub fn instrument_calibration(
        &self,
        id: InstrumentCalibrationId,
    ) -> Result<InstrumentCalibration, StoreError> {
        self.conn
            .query_row(&format!("{SELECT} WHERE id = ?1"), [id.0], from_row)
            .optional()
            .map_err(self.read_err())?
            .ok_or(StoreError::NoSuchCalibration(id))
    }

    /// The calibration made last (by its `created_utc`, then the order stored) for the instrument file with
    /// SHA-256 `instrument_sha256`; None when there is none.
    pub fn latest_instrument_calibration(
        &self,
        instrument_sha256: &str,
    ) -> Result<Option<InstrumentCalibration>, StoreError> {
        self.conn
            .query_row(
                &format!("{SELECT} WHERE instrument_sha256 = ?1 ORDER BY created_utc DESC, id DESC LIMIT 1"),
                [instrument_sha256],
                from_row,
            )
            .optional()
            .map_err(self.read_err())
    }

    /// The stored calibration whose text is exactly `calibration_toml` (the first stored), if any: the same file
    /// given again (`gonio daemon --calibration` at every start) is kept once.
    pub fn instrument_calibration_with_text(
        &self,
        calibration_toml: &str,
    ) -> Result<Option<InstrumentCalibration>, StoreError> {
        self.conn
            .query_row(
                &format!("{SELECT} WHERE calibration_toml = ?1 ORDER BY id LIMIT 1"),
                [calibration_toml],
                from_row,
            )
            .optional()
            .map_err(self.read_err())
    }
}

#[cfg(test)]
mod tests;
