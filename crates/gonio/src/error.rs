//! The binary's error: a message for a person, and the exit code scripts can test.

use std::process::ExitCode;

#[derive(Debug, thiserror::Error)]
pub enum CliError {
    /// The user's input (a file, a flag, a line on stdin) is wrong; the message says what and where.
    #[error("{0}")]
    Input(String),
    /// A check found a broken physical law (not a program failure): exit code 1 with the report printed.
    #[error("{0}")]
    CheckFailed(String),
    /// Reading or writing failed.
    #[error("{context}: {source}")]
    Io { context: String, source: std::io::Error },
    /// A run stopped before its end (interrupted, paused by a fault); the message says how to resume.
    #[error("{0}")]
    Interrupted(String),
}

impl CliError {
    pub fn input(message: impl Into<String>) -> CliError {
        CliError::Input(message.into())
    }

    pub fn io(context: impl Into<String>, source: std::io::Error) -> CliError {
        CliError::Io {
            context: context.into(),
            source,
        }
    }

    pub fn exit_code(&self) -> ExitCode {
        match self {
            CliError::CheckFailed(_) => ExitCode::from(1),
            CliError::Input(_) => ExitCode::from(2),
            CliError::Io { .. } => ExitCode::from(3),
            CliError::Interrupted(_) => ExitCode::from(4),
        }
    }
}
