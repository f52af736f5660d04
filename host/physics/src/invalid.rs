//! The one error the physics gives for a value it does not take: which input, and
//! what is wrong with it, in the words the CLI and the service use
//! (`passes 0: must be 1-10000`). Callers answer it as bad input (an exit with the
//! message, a 400, a `ValueError`), never as the program failing.

/// A value outside what the physics accepts.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct Invalid {
    /// The input at fault, as its caller named it (`passes`, `--colors`, `rings`, `leds`).
    pub field: String,
    /// What is wrong, the field and the value named.
    pub message: String,
}

impl Invalid {
    /// `field` is wrong, as `message` says.
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            message: message.into(),
        }
    }
}
