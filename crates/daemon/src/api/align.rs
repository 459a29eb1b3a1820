//! The alignment and the calibrations ([`crate::service`]'s `align` and `calibration`):
//!
//! - `POST /api/align` `{}` or `{"mirror": "mirror", "material": "coloured-plastic", "simulate_operator": false,
//!   "characterise": true, "sample_alignment": false, "warmup_watch_s": 1800}` (dry-runs: the simulated operator's
//!   alignment mirror and sample, presets; false: each operator step waits for a person's confirmation; the
//!   procedures as `gonio align --steps` and `--warmup-watch-s`, the characterisation on by default) -> 202
//!   with the status; 409 naming the campaign while one holds the instrument, or while an alignment runs
//! - `GET /api/align` -> the alignment in progress or how the last one ended: `state` (`idle`, `running`,
//!   `waiting-operator`, `completed`, `failed`), `step`, `operator_message`, `calibration_id`, `error`, ...
//! - `POST /api/align/confirm` -> the operator did what a waiting alignment asked; `POST /api/align/abort` ends
//!   the wait (409 when the alignment is not waiting)
//! - `GET /api/calibrations` -> every stored calibration (oldest first), which is current, which are made for
//!   this instrument file
//! - `GET /api/calibrations/{id}` -> the calibration file (`application/toml`), as `gonio align` writes it
//! - `GET /api/calibrations/{id}/report.json` -> the alignment's whole report (404 for one given as a file)
//!
//! Starting, confirming and aborting are logged with who sent them (the token holder, or loopback).

use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;

use super::console::{parse_body, who};
use super::{ApiError, AppState};
use crate::service::AlignProcedures;
use gonio_engine::store::InstrumentCalibrationId;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AlignBody {
    #[serde(default)]
    mirror: Option<String>,
    /// Dry-runs: the sample the simulated operator mounts (a preset).
    #[serde(default)]
    material: Option<String>,
    /// Dry-runs: false makes each operator step wait for a person's confirmation.
    #[serde(default = "yes")]
    simulate_operator: bool,
    /// The detector's and the source's characterisation (default true).
    #[serde(default = "yes")]
    characterise: bool,
    /// The alignment on the sample's own specular lobe (default false).
    #[serde(default)]
    sample_alignment: bool,
    /// The characterisation's warm-up watch (s of instrument time).
    #[serde(default)]
    warmup_watch_s: Option<f64>,
}

fn yes() -> bool {
    true
}

pub(super) async fn align_start(State(state): State<AppState>, body: Bytes) -> Result<Response, ApiError> {
    let body: AlignBody = parse_body(
        &body,
        r#"{} or {"mirror": "mirror", "material": "coloured-plastic", "simulate_operator": false, "characterise": true, "sample_alignment": false, "warmup_watch_s": 1800}"#,
    )?;
    let defaults = AlignProcedures::default();
    let procedures = AlignProcedures {
        characterise: body.characterise,
        on_sample: body.sample_alignment,
        warmup_watch_s: body.warmup_watch_s.unwrap_or(defaults.warmup_watch_s),
        material: body.material,
    };
    let status = state.service.start_alignment(
        who(&state),
        body.mirror.as_deref(),
        body.simulate_operator,
        procedures,
    )?;
    Ok((StatusCode::ACCEPTED, axum::Json(status)).into_response())
}

pub(super) async fn align_status(State(state): State<AppState>) -> Response {
    axum::Json(state.service.alignment_status()).into_response()
}

pub(super) async fn align_action(
    State(state): State<AppState>,
    Path(action): Path<String>,
) -> Result<Response, ApiError> {
    let status = match action.as_str() {
        "confirm" => state.service.confirm_alignment(who(&state))?,
        "abort" => state.service.abort_alignment(who(&state))?,
        other => {
            return Err(ApiError::new(
                StatusCode::NOT_FOUND,
                format!("no alignment action {other:?}: confirm or abort"),
            ));
        }
    };
    Ok(axum::Json(status).into_response())
}

pub(super) async fn calibrations(State(state): State<AppState>) -> Result<Response, ApiError> {
    Ok(axum::Json(state.service.calibrations()?).into_response())
}

fn parse_calibration_id(raw: &str) -> Result<InstrumentCalibrationId, ApiError> {
    raw.parse::<i64>().map(InstrumentCalibrationId).map_err(|_| {
        ApiError::new(
            StatusCode::NOT_FOUND,
            format!("no calibration with id {raw:?}: ids are integers"),
        )
    })
}

pub(super) async fn calibration(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let text = state.service.calibration_toml(parse_calibration_id(&id)?)?;
    Ok(([(header::CONTENT_TYPE, "application/toml; charset=utf-8")], text).into_response())
}

pub(super) async fn calibration_report(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let id = parse_calibration_id(&id)?;
    match state.service.calibration_report(id)? {
        Some(json) => Ok(([(header::CONTENT_TYPE, "application/json")], json).into_response()),
        None => Err(ApiError::new(
            StatusCode::NOT_FOUND,
            format!("calibration {id} has no alignment report: it was given as a file"),
        )),
    }
}
