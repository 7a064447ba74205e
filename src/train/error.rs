//! The trainer's errors: what a run refuses (a config, data or checkpoint it cannot train from,
//! said in full) and what failed under it (a model file, a recording, an evaluation, the disk).

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// A config, dataset, checkpoint or run the trainer will not go on with, and why.
    #[error("{0}")]
    Refused(String),
    #[error(transparent)]
    Model(#[from] crate::model::ModelError),
    #[error(transparent)]
    Data(#[from] super::data::DataError),
    #[error(transparent)]
    Eval(#[from] crate::eval::EvalError),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Stopped on request at an epoch's end, its checkpoint written.
    #[error(transparent)]
    Stopped(#[from] super::fit::Stopped),
    /// libtorch refused an operation (a file it cannot read, a tensor it cannot convert).
    #[error("{0}")]
    Torch(String),
}

impl TrainError {
    /// `what: e` as a refusal (context for an error of another kind).
    pub fn refused(what: impl std::fmt::Display, e: impl std::fmt::Display) -> Self {
        TrainError::Refused(format!("{what}: {e}"))
    }
}

/// `return Err(TrainError::Refused(format!(…)))`.
macro_rules! refuse {
    ($($arg:tt)*) => {
        return Err($crate::train::error::TrainError::Refused(format!($($arg)*)))
    };
}
pub(crate) use refuse;

impl From<tch::TchError> for TrainError {
    fn from(e: tch::TchError) -> Self {
        TrainError::Torch(crate::model::torch_message(&e))
    }
}

/// What a failure was doing, said before it (`.context("reading x")`, as a refusal).
pub(crate) trait Context<T> {
    fn context(self, what: impl std::fmt::Display) -> Result<T, TrainError>;
    fn with_context<S: std::fmt::Display>(self, what: impl FnOnce() -> S) -> Result<T, TrainError>;
}

impl<T, E: std::fmt::Display> Context<T> for Result<T, E> {
    fn context(self, what: impl std::fmt::Display) -> Result<T, TrainError> {
        self.map_err(|e| TrainError::refused(what, e))
    }
    fn with_context<S: std::fmt::Display>(self, what: impl FnOnce() -> S) -> Result<T, TrainError> {
        self.map_err(|e| TrainError::refused(what(), e))
    }
}

impl<T> Context<T> for Option<T> {
    fn context(self, what: impl std::fmt::Display) -> Result<T, TrainError> {
        self.ok_or_else(|| TrainError::Refused(what.to_string()))
    }
    fn with_context<S: std::fmt::Display>(self, what: impl FnOnce() -> S) -> Result<T, TrainError> {
        self.ok_or_else(|| TrainError::Refused(what().to_string()))
    }
}
