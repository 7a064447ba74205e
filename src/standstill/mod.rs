//! Standstill detection and the gyro bias measured there: this power-on's turn-on constant.
//!
//! A MEMS gyro's bias is drawn anew at every power-on (a consumer part: up to a few °/s), far
//! more than a learned model can tell from motion; at rest the gyro reads that bias alone. The
//! stream is cut into windows of short blocks; a window is still when
//! - the block means of every gyro axis span less than `max_gyro_spread` and those of every
//!   accelerometer axis less than `max_accel_spread` or, where larger, `vibration_sigmas` σ of
//!   a block mean from the scatter inside the blocks (block means, not samples: a standing
//!   robot's motors or engine vibrate; what a vibration leaves in a block mean grows with it);
//! - its mean specific force is gravity (within `max_gravity_error`);
//! - its mean rate is a plausible bias (≤ `max_bias`): faster is a turn;
//! - gravity has not turned in the body since the standstill began (≤ `max_tilt_change`): a
//!   slow turn about a horizontal axis tilts it, and a standstill that tilts is dropped whole,
//!   unless it was level for at least two windows first (a rest that ended in a slow turn:
//!   that rest is kept, its variance widened by the turn rate its tilt allows);
//! - after an earlier standstill, its mean is within `max_bias_change` (plus 5 σ) of the
//!   estimate: a steady turn about gravity reads like a bias to one IMU, and it is at least not
//!   mixed into a bias already measured.
//!
//! Consecutive still windows are one standstill; its mean is fused with what earlier
//! standstills measured (their variance grown by the bias's random walk since). After a hole in
//! the input of `new_power_on_gap_s` (or a clock that went back), a standstill that contradicts
//! the estimate is a new power-on's (the IMU power-cycled under the node). A steady turn
//! about gravity slower than `max_bias` at the *first* standstill cannot be told from a bias by
//! an IMU alone: that is the stated limit (docs/poweron.md). Per sample: no allocation.
//!
//! Files: `config.rs` (the settings), `window.rs` (a window and its judgement),
//! `run.rs` (the standstill in progress), `estimate.rs` (the estimate, the prediction from
//! earlier power-ons, their fusion), `power_on.rs` (the streaming detector, [`PowerOnBias`]),
//! `steady_rate.rs` (a still body read at a steady rate above `max_bias`: said, not removed),
//! `track.rs` (over a whole recording, [`BiasTrack`]).

mod config;
mod estimate;
mod power_on;
mod run;
mod steady_rate;
mod track;
mod window;

pub use config::{InMotion, StandstillConfig, MAX_BLOCKS};
pub use estimate::{BiasEstimate, BiasPrediction};
pub use power_on::PowerOnBias;
pub use steady_rate::RateAboveMaxBias;
pub use track::BiasTrack;
pub use window::{NotStill, StandstillCounters, WindowVerdict};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::{ImuSample, STANDARD_GRAVITY};
    use nalgebra::Vector3;
    use proptest::prelude::*;

    /// A 200-Hz stream: `rate(t)` the true body rate, a bias, white noise σ (a seeded LCG), the
    /// specific force `accel(t)`.
    fn stream(
        seconds: f64,
        bias: Vector3<f64>,
        sigma: f64,
        rate: impl Fn(f64) -> Vector3<f64>,
        accel: impl Fn(f64) -> Vector3<f64>,
    ) -> Vec<ImuSample> {
        let mut state: u64 = 12345;
        let mut noise = move || {
            // Sum of 4 uniforms: roughly normal, unit variance.
            (0..4)
                .map(|_| {
                    state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                })
                .sum::<f64>()
                * 3f64.sqrt()
        };
        (0..(seconds * 200.0) as usize)
            .map(|k| {
                let t = k as f64 * 0.005;
                let n = Vector3::new(noise(), noise(), noise()) * sigma;
                ImuSample { stamp_ns: 1_000_000_000 + k as i64 * 5_000_000, gyro: rate(t) + bias + n, accel: accel(t) }
            })
            .collect()
    }

    fn level(_: f64) -> Vector3<f64> {
        Vector3::new(0.0, 0.0, STANDARD_GRAVITY)
    }

    /// A body turning about x at `w` rad/s from level, gravity turning in it, no bias.
    fn turning_about_x(seconds: f64, w: f64, sigma: f64) -> Vec<ImuSample> {
        stream(
            seconds,
            Vector3::zeros(),
            sigma,
            |_| Vector3::new(w, 0.0, 0.0),
            |t| Vector3::new(0.0, (w * t).sin(), (w * t).cos()) * STANDARD_GRAVITY,
        )
    }

    /// An accelerometer's white noise of `sigma` per axis, a function of the stamp alone.
    fn accel_noise(t: f64, sigma: f64) -> Vector3<f64> {
        let u = |k: f64| ((t * 7919.0 + k) * 12.9898).sin() * 43758.5453 % 1.0;
        Vector3::new(u(1.0), u(2.0), u(3.0)) * (sigma * 3f64.sqrt())
    }

    fn run(imu: &[ImuSample]) -> PowerOnBias {
        let mut p = PowerOnBias::new(StandstillConfig::default());
        for s in imu {
            p.push(s);
        }
        p
    }

    #[test]
    fn a_rest_measures_the_bias_and_its_variance_covers_the_error() {
        let bias = Vector3::new(0.03, -0.05, 0.08);
        let imu = stream(5.0, bias, 0.005, |_| Vector3::zeros(), level);
        let p = run(&imu);
        let e = p.estimate().expect("a rest");
        let err = e.bias - bias;
        assert!(err.amax() < 1e-3, "{err}");
        for i in 0..3 {
            assert!(err[i].abs() < 4.0 * e.variance[i].sqrt(), "axis {i}: error {} σ {}", err[i], e.variance[i].sqrt());
        }
        assert!(e.still_s > 4.0, "{}", e.still_s);
    }

    #[test]
    fn a_standing_robots_vibration_is_a_rest() {
        // ±0.05 rad/s and ±2 m/s²: at 30 Hz (three cycles a 0.1-s block) the block means stay
        // put; at 17–47 Hz a residue of up to a fifth of the amplitude is left in each mean,
        // which the fixed 0.2 m/s² spread alone refuses, and the scatter inside the blocks allows.
        let bias = Vector3::new(0.01, 0.0, -0.02);
        for f in [17.0, 23.0, 27.0, 30.0, 33.0, 47.0] {
            let shake = move |t: f64| (2.0 * std::f64::consts::PI * f * t).sin();
            let imu = stream(
                4.0,
                bias,
                0.01,
                |t| Vector3::new(0.05, 0.025, 0.015) * shake(t),
                |t| level(t) + Vector3::new(2.0, 1.0, 2.0) * shake(t),
            );
            // At 100 Hz too (a wheeled robot's IMU): ten samples a block still show the scatter.
            let at100: Vec<ImuSample> = imu.iter().step_by(2).copied().collect();
            for (hz, imu) in [(200, &imu), (100, &at100)] {
                let e = *run(imu).estimate().unwrap_or_else(|| panic!("{f} Hz at {hz} Hz: a vibrating rest is a rest"));
                assert!((e.bias - bias).amax() < 2e-3, "{f} Hz at {hz} Hz: {}", e.bias);
                assert!(e.still_s >= 3.0, "{f} Hz at {hz} Hz: {} s", e.still_s);
            }
            if f != 30.0 {
                let fixed = run_with(&imu, StandstillConfig { vibration_sigmas: 0.0, ..Default::default() });
                assert!(fixed.estimate().is_none(), "{f} Hz: the fixed limit alone found a rest");
            }
        }
    }

    #[test]
    fn a_vibrating_body_that_turns_slowly_is_not_a_rest() {
        // The wider accelerometer limit lets the vibration through, not the turn: gravity still
        // turns in the body (0.03 rad/s about x, under ±2 m/s² at 27 Hz).
        let w = 0.03;
        let shake = |t: f64| (2.0 * std::f64::consts::PI * 27.0 * t).sin();
        let imu = stream(
            5.0,
            Vector3::zeros(),
            0.001,
            |t| Vector3::new(w, 0.0, 0.0) + Vector3::new(0.05, 0.025, 0.015) * shake(t),
            |t| Vector3::new(0.0, (w * t).sin(), (w * t).cos()) * STANDARD_GRAVITY + Vector3::new(2.0, 1.0, 2.0) * shake(t),
        );
        let p = run(&imu);
        assert!(p.counters().tilting_windows > 0, "{:?}", p.counters());
        let kept = p.estimate().map_or(0.0, |e| e.still_s);
        assert!(kept <= 1.0, "{kept} s kept of a slow turn");
    }

    #[test]
    fn a_bias_beyond_max_bias_is_said_and_gravity_tells_it_from_a_turn() {
        // A part whose zero-rate offset on x is 0.25 rad/s (above max_bias 0.15), at rest: no
        // standstill, but gravity did not turn where a turn across it would have turned it.
        let bias = Vector3::new(0.25, 0.01, -0.02);
        let imu = stream(5.0, bias, 0.01, |_| Vector3::zeros(), level);
        let p = run(&imu);
        assert!(p.estimate().is_none());
        let r = p.rate_above_max_bias().expect("a steady rate above max_bias is said");
        assert!((r.rate - bias).amax() < 5e-3 && r.seconds >= 4.0, "{r:?}");
        assert!(r.across_is_bias(), "{}", r.says());
        assert!(r.says().contains("is this IMU's bias"), "{}", r.says());
        // Raised as it says, the rest measures it.
        let raised = run_with(&imu, StandstillConfig { max_bias: 0.3, ..Default::default() });
        assert!((raised.estimate().expect("a rest").bias - bias).amax() < 2e-3);
        assert!(raised.rate_above_max_bias().is_none());

        // A turn in place about gravity at 0.3 rad/s: said, and not called a bias.
        let turn = stream(5.0, Vector3::zeros(), 0.01, |_| Vector3::new(0.0, 0.0, 0.3), level);
        let r = run(&turn).rate_above_max_bias().expect("said");
        assert!(!r.across_is_bias() && (r.about_gravity - 0.3).abs() < 5e-3, "{r:?}");
        assert!(r.says().contains("one IMU cannot tell"), "{}", r.says());

        // A turn across gravity at 0.2 rad/s turns gravity: never said to be a bias.
        let p = run(&turning_about_x(5.0, 0.2, 0.01));
        assert!(p.rate_above_max_bias().is_none_or(|r| !r.across_is_bias()), "{:?}", p.rate_above_max_bias());
        assert!(p.estimate().is_none());
    }

    #[test]
    fn a_slow_turn_about_a_horizontal_axis_is_not_a_rest() {
        // 0.03 rad/s about x: gravity turns in the body, 0.15 rad in 5 s.
        let p = run(&turning_about_x(5.0, 0.03, 0.001));
        assert!(p.counters().tilting_windows > 0, "{:?}", p.counters());
        // At most the first windows, before gravity had turned by max_tilt_change.
        let e = p.estimate().map_or(0.0, |e| e.still_s);
        assert!(e <= 1.0, "{e}");
        // Slower turns pass as level for longer: what is kept of them states the turn as σ
        // (an accelerometer with a consumer part's noise: the turn must stand out of it).
        for w in [0.01, 0.005, 0.002] {
            let imu = stream(
                20.0,
                Vector3::zeros(),
                0.001,
                |_| Vector3::new(w, 0.0, 0.0),
                |t| Vector3::new(0.0, (w * t).sin(), (w * t).cos()) * STANDARD_GRAVITY + accel_noise(t, 0.03),
            );
            if let Some(e) = run(&imu).estimate() {
                assert!(e.bias[0].abs() < 3.0 * e.variance[0].sqrt(), "{w} rad/s read as a bias {} ± {}", e.bias[0], e.variance[0].sqrt());
            }
        }
    }

    /// A rest of 10 s, then a turn at 0.03 rad/s about x from rest (a robot that starts to lean,
    /// a device lifted slowly): the turn's first windows pass the spreads and tilt the
    /// standstill, but what came before them was a rest and is kept, its bias unbiased by the
    /// turn.
    #[test]
    fn a_rest_that_ends_in_a_slow_turn_keeps_its_rest() {
        let (bias, w, t_turn) = (Vector3::new(0.01, -0.02, 0.03), 0.03, 10.0);
        let tilt = |t: f64| w * (t - t_turn).max(0.0);
        let imu = stream(
            16.0,
            bias,
            0.002,
            |t| if t < t_turn { Vector3::zeros() } else { Vector3::new(w, 0.0, 0.0) },
            |t| Vector3::new(0.0, tilt(t).sin(), tilt(t).cos()) * STANDARD_GRAVITY + accel_noise(t, 0.03),
        );
        let p = run(&imu);
        assert!(p.counters().tilting_windows > 0, "{:?}", p.counters());
        let e = p.estimate().expect("the rest before the turn");
        assert!(e.still_s >= 8.0, "{}", e.still_s);
        let err = e.bias - bias;
        assert!(err.amax() < 1e-3, "{err}");
        for i in 0..3 {
            assert!(err[i].abs() < 4.0 * e.variance[i].sqrt(), "axis {i}: error {} σ {}", err[i], e.variance[i].sqrt());
        }
    }

    #[test]
    fn a_turn_faster_than_any_bias_is_not_a_rest() {
        let imu = stream(3.0, Vector3::zeros(), 0.001, |_| Vector3::new(0.0, 0.0, 0.3), level);
        let p = run(&imu);
        assert!(p.estimate().is_none());
        assert!(p.counters().turning_windows >= 4, "{:?}", p.counters());
    }

    #[test]
    fn a_slow_turn_about_gravity_after_a_rest_is_not_mixed_in() {
        let bias = Vector3::new(0.0, 0.0, 0.02);
        let mut imu = stream(3.0, bias, 0.002, |_| Vector3::zeros(), level);
        // Then it moves, then stands turning at 0.06 rad/s about z (reads as a bias of 0.08).
        let moving = stream(3.0, bias, 0.002, |t| Vector3::new(0.5 * (3.0 * t).sin(), 0.0, 0.0), level);
        let turning = stream(5.0, bias, 0.002, |_| Vector3::new(0.0, 0.0, 0.06), level);
        let t_end = imu.last().unwrap().stamp_ns;
        for (k, s) in moving.iter().chain(&turning).enumerate() {
            imu.push(ImuSample { stamp_ns: t_end + (k as i64 + 1) * 5_000_000, ..*s });
        }
        let p = run(&imu);
        let e = p.estimate().unwrap();
        assert!((e.bias - bias).amax() < 1e-3, "{}", e.bias);
        assert!(p.counters().inconsistent_windows >= 8, "{:?}", p.counters());
    }

    #[test]
    fn a_later_rest_refines_the_estimate() {
        let bias = Vector3::new(0.02, 0.01, -0.01);
        let first = stream(1.0, bias, 0.01, |_| Vector3::zeros(), level);
        let moving = stream(5.0, bias, 0.01, |t| Vector3::new(0.0, 0.8 * (2.0 * t).sin(), 0.0), level);
        let later = stream(10.0, bias, 0.01, |_| Vector3::zeros(), level);
        let mut imu = first.clone();
        for (k, s) in moving.iter().chain(&later).enumerate() {
            imu.push(ImuSample { stamp_ns: first.last().unwrap().stamp_ns + (k as i64 + 1) * 5_000_000, ..*s });
        }
        let after_first = run(&first).estimate().copied().unwrap();
        let p = run(&imu);
        let e = p.estimate().unwrap();
        assert_eq!(p.counters().standstills, 1, "the first ended; the later one is in progress");
        assert!(e.variance.max() < after_first.variance.max() / 3.0, "{} vs {}", e.variance, after_first.variance);
        assert!((e.bias - bias).amax() < 1e-3);
    }

    #[test]
    fn a_bump_or_a_clock_jump_breaks_the_rest_and_keeps_what_was_measured() {
        let bias = Vector3::new(0.0, 0.04, 0.0);
        let mut imu = stream(6.0, bias, 0.002, |_| Vector3::zeros(), level);
        // A bump at 2 s: 0.05 s of a 1-rad/s knock and 5 m/s².
        for s in imu.iter_mut().skip(400).take(10) {
            s.gyro.x += 1.0;
            s.accel.x += 5.0;
        }
        // A clock that goes back 1 s at 4 s.
        for s in imu.iter_mut().skip(800) {
            s.stamp_ns -= 1_000_000_000;
        }
        let p = run(&imu);
        let c = p.counters();
        assert!(c.moving_windows >= 1 && c.interrupted_windows >= 1, "{c:?}");
        let e = p.estimate().unwrap();
        assert!((e.bias - bias).amax() < 1e-3, "{}", e.bias);
    }

    #[test]
    fn a_rest_hold_rate_integrates_the_window_to_zero() {
        let imu = stream(1.2, Vector3::new(0.01, 0.02, 0.03), 0.003, |_| Vector3::zeros(), level);
        let mut p = PowerOnBias::new(StandstillConfig::default());
        let mut found = None;
        for s in &imu {
            if let Some(WindowVerdict::Still { start_ns, end_ns, hold_rate }) = p.push(s) {
                found = Some((start_ns, end_ns, hold_rate));
                break;
            }
        }
        let (a, b, m) = found.expect("a still window");
        let turn: Vector3<f64> = imu
            .windows(2)
            .filter(|w| w[0].stamp_ns >= a && w[1].stamp_ns <= b)
            .map(|w| (w[0].gyro - m) * ((w[1].stamp_ns - w[0].stamp_ns) as f64 * 1e-9))
            .sum();
        assert!(turn.amax() < 1e-12, "{turn}");
    }

    #[test]
    fn the_offline_track_holds_a_rest_and_removes_the_bias_after_it() {
        let bias = Vector3::new(0.02, -0.01, 0.05);
        let mut imu = stream(2.0, bias, 0.002, |_| Vector3::zeros(), level);
        let t_end = imu.last().unwrap().stamp_ns;
        for (k, s) in stream(2.0, bias, 0.002, |t| Vector3::new(0.0, 0.0, 0.4 * t.sin()), level).iter().enumerate() {
            imu.push(ImuSample { stamp_ns: t_end + (k as i64 + 1) * 5_000_000, ..*s });
        }
        let track = BiasTrack::over(&imu, &StandstillConfig::default());
        assert_eq!(track.still.len(), 4, "{:?}", track.still);
        assert!(track.bias[0].norm() == 0.0 && (track.bias[imu.len() - 1] - bias).amax() < 1e-3);
        let g = track.corrected_gyro(&imu);
        let q = crate::so3::integrate_gyro(&imu, nalgebra::UnitQuaternion::identity(), |n| g[n]);
        // Held over the rest (the body did not turn), then integrated with the bias removed.
        let at_rest_end = track.still.last().unwrap().1;
        assert!(q[at_rest_end].angle() < 1e-7, "{}", q[at_rest_end].angle());
        assert!(track.note().contains("power-on bias"));
    }

    #[test]
    fn retake_forgets_the_estimate() {
        let mut p = run(&stream(2.0, Vector3::new(0.05, 0.0, 0.0), 0.001, |_| Vector3::zeros(), level));
        assert!(p.estimate().is_some());
        p.retake();
        assert!(p.estimate().is_none());
        assert_eq!(p.bias(), Vector3::zeros());
    }

    /// The IMU power-cycled under the node: a rest, a hole in the input, a rest at another
    /// turn-on bias. After a hole of `new_power_on_gap_s` the second rest is a new power-on's;
    /// after a shorter one it is refused as inconsistent; the same bias after a long hole is
    /// the same power-on's, fused.
    #[test]
    fn a_standstill_after_a_hole_that_contradicts_the_bias_is_a_new_power_on() {
        let first = Vector3::new(0.05, -0.02, 0.01);
        let second = Vector3::new(-0.03, 0.04, 0.02);
        let after = |hole_s: f64, bias: Vector3<f64>| {
            let a = stream(3.0, first, 0.005, |_| Vector3::zeros(), level);
            let shift = a.last().unwrap().stamp_ns + (hole_s * 1e9) as i64;
            let b = stream(3.0, bias, 0.005, |_| Vector3::zeros(), level);
            let b = b.iter().map(|s| ImuSample { stamp_ns: s.stamp_ns - b[0].stamp_ns + shift, ..*s });
            run(&a.iter().copied().chain(b).collect::<Vec<_>>())
        };
        let p = after(3.0, second);
        let e = p.estimate().expect("the new power-on's rest");
        assert!((e.bias - second).amax() < 2e-3 && e.still_s < 3.5, "{e:?}");
        assert_eq!(p.counters().new_power_ons, 1);

        // Between the hole and the next standstill the old bias stays, stated with a new
        // turn-on bias's σ; a standstill that agrees takes that back.
        let a = stream(3.0, first, 0.005, |_| Vector3::zeros(), level);
        let mut p = run(&a);
        let calm = p.in_force(0).unwrap().variance.max();
        let t = a.last().unwrap().stamp_ns + 3_000_000_000;
        p.push(&ImuSample { stamp_ns: t, ..a[0] });
        let e = p.in_force(t).unwrap();
        assert!(e.bias == p.estimate().unwrap().bias && e.variance.min() >= 0.1f64.powi(2) && calm < 1e-6, "{e:?}");

        let p = after(0.5, second);
        assert!((p.estimate().unwrap().bias - first).amax() < 2e-3);
        assert!(p.counters().inconsistent_windows > 0 && p.counters().new_power_ons == 0, "{:?}", p.counters());

        let p = after(3.0, first);
        let e = p.estimate().unwrap();
        assert!((e.bias - first).amax() < 2e-3 && e.still_s > 4.0, "{e:?}");
        assert_eq!(p.counters().new_power_ons, 0);
        assert!(p.in_force(0).unwrap().variance.max() < 1e-6, "the agreeing standstill takes the widening back");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        /// Whatever the bias (within the limit) and noise, a rest's stated σ covers its error.
        #[test]
        fn the_stated_variance_covers_the_error(
            bx in -0.1f64..0.1, by in -0.1f64..0.1, bz in -0.1f64..0.1,
            sigma in 0.0005f64..0.02, seconds in 1.0f64..8.0,
        ) {
            let bias = Vector3::new(bx, by, bz);
            let p = run(&stream(seconds, bias, sigma, |_| Vector3::zeros(), level));
            let e = p.estimate().expect("a rest");
            let z = (e.bias - bias).component_div(&e.variance.map(f64::sqrt));
            prop_assert!(z.amax() < 5.0, "z {z}, σ {}", e.variance.map(f64::sqrt));
        }
    }

    #[test]
    fn earlier_power_ons_hold_until_the_first_standstill() {
        let bias = Vector3::new(0.002, -0.03, 0.08);
        let remembered = BiasPrediction {
            bias: Vector3::new(0.0, -0.031, 0.079),
            variance: Vector3::new(0.08f64.powi(2), 4e-6, 4e-6),
            applied: [false, true, true],
            power_ons: 5,
        };
        let cfg = StandstillConfig { remembered: Some(remembered), ..StandstillConfig::default() };
        // Moving for 5 s (a turn about x faster than any bias), then standing.
        let turning = stream(5.0, bias, 0.002, |t| Vector3::new(0.6 * (t * 2.0).sin(), 0.0, 0.0), level);
        let mut p = PowerOnBias::new(cfg);
        for s in &turning {
            p.push(s);
        }
        assert_eq!(p.source(), "memory");
        let e = p.in_force(turning.last().unwrap().stamp_ns).unwrap();
        assert_eq!(e.bias, remembered.bias);
        assert_eq!(e.variance, remembered.variance, "the prediction's own variance, x's the unremoved mean's");
        let still = stream(3.0, bias, 0.002, |_| Vector3::zeros(), level);
        let last = turning.last().unwrap().stamp_ns;
        for s in &still {
            p.push(&ImuSample { stamp_ns: last + s.stamp_ns, ..*s });
        }
        assert_eq!(p.source(), "standstill");
        assert!((p.bias() - bias).amax() < 2e-3, "{:?}", p.bias());
        // What the standstill measured is within the prediction; another IMU's is not.
        assert_eq!(remembered.contradicted_by(p.estimate().unwrap()), None);
        let other = BiasEstimate { bias: Vector3::new(0.0, -0.031, 0.02), variance: Vector3::repeat(1e-8), at_ns: 0, still_s: 1.0 };
        let said = remembered.contradicted_by(&other).unwrap();
        assert!(said.contains("z 0.02000 against 0.07900"), "{said}");
        // A prediction that applies to no axis is not in force.
        let none = BiasPrediction { applied: [false; 3], bias: Vector3::zeros(), ..remembered };
        let p = run_with(&turning, StandstillConfig { remembered: Some(none), ..StandstillConfig::default() });
        assert_eq!(p.source(), "");
        assert!(p.in_force(0).is_none());
    }

    fn run_with(imu: &[ImuSample], cfg: StandstillConfig) -> PowerOnBias {
        let mut p = PowerOnBias::new(cfg);
        for s in imu {
            p.push(s);
        }
        p
    }
}
