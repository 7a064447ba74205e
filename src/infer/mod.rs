//! The per-sample denoising pipeline, free of ROS and async: input checks → gyro correction
//! (any [`GyroCorrector`], e.g. the model's streaming form) → orientation integration.
//! The node, `replay` and the tests all drive this same [`Pipeline::push`], so what the node
//! publishes on a bag is what `replay` writes. No allocation and no I/O per sample.

mod attitude;
mod choice;
mod config;
mod corrector;
mod counters;
mod gravity_aided;
mod hindsight;
mod pipeline;
mod stamps;

pub use attitude::{INIT_TURN_RATE, TURNING_INTERVALS};
pub use choice::{choose, predict_from, trained_power_ons, Correction, ModelDomain};
pub use config::{PipelineConfig, Platform};
pub use corrector::{BiasCorrector, FullWindowCorrector, GyroCorrector, ModelCorrector, PassThrough};
pub use counters::{Counters, Dropped};
pub use gravity_aided::{GravityAidedConfig, OrientationMode, CHI2_3DOF_999};
pub use pipeline::{CorrectedImu, Pipeline};
pub use stamps::{BackwardsRun, CLOCK_JUMP_SAMPLES, RATE_FROM_GAPS};
