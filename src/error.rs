//! The one error type the binary maps to exit code 2 ("bad usage or bad input").
//!
//! Library modules keep their own `thiserror` enums; the command layer wraps the
//! ones caused by the user's input in [`InputError`] so `main` can tell a bad file
//! (exit 2) from a failure of the work (exit 1).

/// Bad input or bad usage: the message names the file and what is wrong with it.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct InputError(pub String);

impl InputError {
    pub fn new(message: impl Into<String>) -> Self {
        InputError(message.into())
    }
}
