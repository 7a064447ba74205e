//! imu-fsda: few-shot domain-adapted IMU gyroscope denoising for ROS 2.
//!
//! Data flows one way: bags / datasets → samples → model → corrected samples →
//! metrics / bags / topics. See ARCHITECTURE.md for the layers.

pub mod adapt;
pub mod bag;
pub mod bias_memory;
pub mod core;
pub mod dataset;
pub mod diagnose;
pub mod embed;
pub mod eval;
pub mod figures;
pub mod frozen_ground_truth;
pub mod ground_truth_frame;
pub mod infer;
pub mod model;
pub mod motion_bias;
pub mod msg;
pub mod node;
pub mod physics;
pub mod plot;
pub mod resample;
pub mod setting;
pub mod sim;
pub mod so3;
pub mod standstill;
pub mod student_t;
pub mod train;
pub mod tsne;
