//! The offline trainer (`imu-fsda train`): the paper's FSDA-F (MAML on the Embedding), FSDA
//! (the framework without meta-learning) and the DIGDL baseline, on EuRoC / TUM-VI sequence
//! folders or MCAP bags, with TorchScript export. See docs/training.md.
//!
//! Files: [`config`] (the YAML), [`data`] (recordings → checked tasks, windows,
//! normalisation), [`optim`] (Adam with saveable state), [`power_on`] (each recording's power-on bias taken out, on request), [`checkpoint`], [`report`] (the
//! run's JSON), [`curves`] (its figure), [`fit`] (datasets, evaluation, the strategies'
//! steps), [`run`] (one run as an object with steps: start, epochs, finish), [`seeds`] (restarts: the best of
//! several seeds by validation score), [`error`].

pub mod checkpoint;
pub mod config;
pub mod curves;
pub mod data;
pub mod error;
pub mod fit;
pub mod optim;
pub mod power_on;
pub mod report;
pub mod run;
pub mod seeds;

pub use config::TrainConfig;
pub use fit::{RunOptions, Stopped};
pub use run::train;
