//! Errors that name the file, the line, the key and what was expected.

use gonio_scheduler::plan::PlanError;

/// A campaign file that did not validate. The message names file, line, key and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct CampaignError(pub String);

/// Where a campaign's text came from, for messages: the origin (a path, or `<stored campaign 3>`) and the text
/// whose lines they name.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Located<'a> {
    pub origin: &'a str,
    pub text: &'a str,
}

impl Located<'_> {
    /// `origin:LINE` of `key` in `[table]` (or of the table's header), else the origin alone.
    pub fn at(&self, table: &str, key: Option<&str>) -> String {
        match line_of(self.text, table, key) {
            Some(l) => format!("{}:{l}", self.origin),
            None => self.origin.to_string(),
        }
    }

    /// `origin:LINE: [table] key: message`.
    pub fn err(&self, table: &str, key: &str, message: impl std::fmt::Display) -> CampaignError {
        CampaignError(format!(
            "{}: [{table}] {key}: {message}",
            self.at(table, Some(key))
        ))
    }

    /// `origin: message`.
    pub fn plain(&self, message: impl std::fmt::Display) -> CampaignError {
        CampaignError(format!("{}: {message}", self.origin))
    }

    /// A scheduler error with the file and line of its key.
    pub fn plan(&self, e: &PlanError) -> CampaignError {
        CampaignError(match e {
            PlanError::Parse { message, .. } => format!("{}: {}", self.origin, message.trim()),
            PlanError::Invalid { table, key, message } => {
                let t = format!("plan{table}");
                // Keys may be dotted or indexed ("grid.theta_i_deg"); look up the first component.
                let k = key.split(['.', '[']).next().unwrap_or(key);
                format!("{}: [{t}] {key}: {message}", self.at(&t, Some(k)))
            }
        })
    }

    /// The `:LINE` of the first line that opens top-level table or key `key`, or nothing.
    pub fn top_level_line(&self, key: &str) -> String {
        self.text
            .lines()
            .position(|l| {
                let l = l.trim();
                l.starts_with(&format!("[{key}"))
                    || l.starts_with(&format!("{key} "))
                    || l.starts_with(&format!("{key}="))
                    || l.starts_with(&format!("{key}."))
            })
            .map(|i| format!(":{}", i + 1))
            .unwrap_or_default()
    }
}

/// The 1-based line of the first `key = ` inside `[table]` (dotted tables like `plan.grid` allowed), else the
/// table header's line, else None.
pub fn line_of(text: &str, table: &str, key: Option<&str>) -> Option<usize> {
    let mut current = String::new();
    let mut header = None;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if let Some(rest) = line.strip_prefix('[') {
            let name = rest
                .trim_start_matches('[')
                .split(']')
                .next()
                .unwrap_or("")
                .trim()
                .to_string();
            current = name;
            if current == table && header.is_none() {
                header = Some(i + 1);
            }
            continue;
        }
        if current == table
            && let Some(k) = key
            && let Some(rest) = line.strip_prefix(k)
            && (rest.trim_start().starts_with('=') || rest.trim_start().starts_with('.'))
        {
            return Some(i + 1);
        }
    }
    header
}
