//! Smooth, analytically differentiable body trajectories for the simulator.
//!
//! Every scalar signal (a position coordinate, an Euler angle, the speed or heading of a
//! vehicle) is a [`Signal`]: a sum of sinusoids, some modulated by a slow envelope, plus
//! a train of foot-impact pulses for the quadruped. A channel gives its value and its first
//! five derivatives in closed form, so angular velocity, angular acceleration and linear
//! acceleration are exact (no finite differences): they are carried through the Euler-angle
//! kinematics with forward-mode derivatives ([`Jet`]).
//!
//! Frames: world ENU (z up), body x forward, y left, z up. Attitude R = Rz(yaw) Ry(pitch)
//! Rx(roll) (`world_from_body`). Specific force f = Rᵀ (a − g_world), g_world = (0, 0, −g).
//!
//! Profiles (each seeded, reproducible):
//! - `aerial` (`mav`): a multirotor drifting around a hover point with bursts of manoeuvres
//!   (a slow envelope); it tilts into its horizontal acceleration like a thrust-vectoring
//!   vehicle (pitch ≈ a_forward/g, roll ≈ −a_left/g).
//! - `handheld`: a person walking a curving path (≈1 m/s) at ≈1.9 steps/s with a vertical
//!   bob, turning the device by tens of degrees about every axis.
//! - `car`: planar driving along the heading, speed 12 ± several m/s, turns of up to
//!   ≈0.5 rad/s; roll and pitch from the suspension (rolling out of turns, diving under
//!   braking) plus road bumps.
//! - `quadruped`: a trot at a gait frequency near 2 Hz: the body bobs, rocks and pitches at
//!   the gait frequency and each footfall adds a short vertical and angular impact pulse
//!   (a Ricker wavelet in acceleration, ≈1.5 g peak, σ = 10 ms).

use std::f64::consts::{FRAC_PI_2, TAU};
use std::ops::{Add, Mul, Neg, Sub};

use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::physics::{derive_seed, splitmix64, NOMINAL_GRAVITY};

/// A value with its first three time derivatives (forward-mode differentiation to order 3).
/// [`Jet::derivative`] shifts the orders down and marks the third as unknown (NaN), which
/// then stays confined to the third order of anything computed from it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Jet {
    pub v: f64,
    pub d1: f64,
    pub d2: f64,
    pub d3: f64,
}

impl Jet {
    pub const fn constant(v: f64) -> Jet {
        Jet { v, d1: 0.0, d2: 0.0, d3: 0.0 }
    }

    /// From a list of derivatives starting at order 0.
    pub fn from_derivs(d: &[f64]) -> Jet {
        Jet { v: d[0], d1: d[1], d2: d[2], d3: d[3] }
    }

    /// The time derivative (valid to one order less).
    pub fn derivative(self) -> Jet {
        Jet { v: self.d1, d1: self.d2, d2: self.d3, d3: f64::NAN }
    }

    pub fn sin(self) -> Jet {
        let (s, c) = self.v.sin_cos();
        let (u1, u2, u3) = (self.d1, self.d2, self.d3);
        Jet { v: s, d1: c * u1, d2: -s * u1 * u1 + c * u2, d3: -c * u1 * u1 * u1 - 3.0 * s * u1 * u2 + c * u3 }
    }

    pub fn cos(self) -> Jet {
        let (s, c) = self.v.sin_cos();
        let (u1, u2, u3) = (self.d1, self.d2, self.d3);
        Jet { v: c, d1: -s * u1, d2: -c * u1 * u1 - s * u2, d3: s * u1 * u1 * u1 - 3.0 * c * u1 * u2 - s * u3 }
    }
}

impl Add for Jet {
    type Output = Jet;
    fn add(self, o: Jet) -> Jet {
        Jet { v: self.v + o.v, d1: self.d1 + o.d1, d2: self.d2 + o.d2, d3: self.d3 + o.d3 }
    }
}

impl Sub for Jet {
    type Output = Jet;
    fn sub(self, o: Jet) -> Jet {
        self + (-o)
    }
}

impl Neg for Jet {
    type Output = Jet;
    fn neg(self) -> Jet {
        self * -1.0
    }
}

impl Mul<f64> for Jet {
    type Output = Jet;
    fn mul(self, k: f64) -> Jet {
        Jet { v: self.v * k, d1: self.d1 * k, d2: self.d2 * k, d3: self.d3 * k }
    }
}

impl Mul for Jet {
    type Output = Jet;
    /// Leibniz rule to order 3.
    fn mul(self, o: Jet) -> Jet {
        Jet {
            v: self.v * o.v,
            d1: self.d1 * o.v + self.v * o.d1,
            d2: self.d2 * o.v + 2.0 * self.d1 * o.d1 + self.v * o.d2,
            d3: self.d3 * o.v + 3.0 * self.d2 * o.d1 + 3.0 * self.d1 * o.d2 + self.v * o.d3,
        }
    }
}

/// Number of derivatives a [`Signal`] provides (orders 0..=5).
pub const ORDERS: usize = 6;

/// A · sin(ω t + φ).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Sine {
    pub amplitude: f64,
    /// Angular frequency, rad/s.
    pub omega: f64,
    /// Phase, rad.
    pub phase: f64,
}

impl Sine {
    /// Hz → the sinusoid.
    pub fn hz(amplitude: f64, hz: f64, phase: f64) -> Sine {
        Sine { amplitude, omega: TAU * hz, phase }
    }

    /// Value and derivatives: dⁿ/dtⁿ A sin(ωt + φ) = A ωⁿ sin(ωt + φ + nπ/2).
    fn derivs(&self, t: f64) -> [f64; ORDERS] {
        std::array::from_fn(|n| self.amplitude * self.omega.powi(n as i32) * (self.omega * t + self.phase + n as f64 * FRAC_PI_2).sin())
    }
}

/// A slow envelope m + a sin(Ω t + ψ) that multiplies a channel's modulated sinusoids.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    pub mean: f64,
    pub sine: Sine,
}

/// Foot impacts: at t_k = first + k·period (k ≥ 0), a pulse whose second derivative is a
/// Ricker wavelet A_k (1 − x²) e^{−x²/2}, x = (t − t_k)/σ. Its value, −A_k σ² e^{−x²/2}, and
/// its first derivative vanish away from the impact: no net change of position or velocity.
/// A_k = amplitude (1 + variation·u_k) (−1)^k if alternating, u_k ∈ [−1, 1] hashed from
/// (seed, k).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pulses {
    pub first_s: f64,
    pub period_s: f64,
    pub sigma_s: f64,
    /// Peak second derivative (m/s² or rad/s²).
    pub amplitude: f64,
    pub variation: f64,
    pub alternate: bool,
    pub seed: u64,
}

impl Pulses {
    fn amplitude_of(&self, k: i64) -> f64 {
        let u = (splitmix64(self.seed ^ (k as u64)) >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0;
        let sign = if self.alternate && k % 2 == 1 { -1.0 } else { 1.0 };
        sign * self.amplitude * (1.0 + self.variation * u)
    }

    fn derivs(&self, t: f64) -> [f64; ORDERS] {
        let mut out = [0.0; ORDERS];
        let reach = 8.0 * self.sigma_s;
        let k0 = (((t - self.first_s - reach) / self.period_s).ceil() as i64).max(0);
        let k1 = ((t - self.first_s + reach) / self.period_s).floor() as i64;
        for k in k0..=k1 {
            let s = self.sigma_s;
            let x = (t - (self.first_s + k as f64 * self.period_s)) / s;
            let g = (-0.5 * x * x).exp();
            // Probabilists' Hermite polynomials: dⁿ/dxⁿ e^{−x²/2} = (−1)ⁿ Heₙ(x) e^{−x²/2}.
            let x2 = x * x;
            let he = [1.0, x, x2 - 1.0, x * (x2 - 3.0), x2 * x2 - 6.0 * x2 + 3.0, x * (x2 * x2 - 10.0 * x2 + 15.0)];
            let scale = -self.amplitude_of(k) * s * s;
            for (n, h) in he.iter().enumerate() {
                out[n] += scale * (-1.0 / s).powi(n as i32) * h * g;
            }
        }
        out
    }
}

/// One scalar signal of a trajectory, with exact derivatives.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Signal {
    pub offset: f64,
    /// Linear trend, per second.
    pub slope: f64,
    pub sines: Vec<Sine>,
    /// Sinusoids multiplied by `envelope` (ignored without one).
    pub modulated: Vec<Sine>,
    pub envelope: Option<Envelope>,
    pub pulses: Option<Pulses>,
}

impl Signal {
    pub fn constant(offset: f64) -> Signal {
        Signal { offset, ..Default::default() }
    }

    /// Value and derivatives of orders 0..=5 at t (s).
    pub fn derivs(&self, t: f64) -> [f64; ORDERS] {
        let mut out = [0.0; ORDERS];
        out[0] = self.offset + self.slope * t;
        out[1] = self.slope;
        let add = |out: &mut [f64; ORDERS], d: [f64; ORDERS]| out.iter_mut().zip(d).for_each(|(o, x)| *o += x);
        for s in &self.sines {
            add(&mut out, s.derivs(t));
        }
        if let Some(env) = &self.envelope {
            let mut e = env.sine.derivs(t);
            e[0] += env.mean;
            let mut m = [0.0; ORDERS];
            for s in &self.modulated {
                add(&mut m, s.derivs(t));
            }
            // Leibniz: (e m)⁽ⁿ⁾ = Σ C(n, k) e⁽ᵏ⁾ m⁽ⁿ⁻ᵏ⁾.
            for n in 0..ORDERS {
                let mut binom = 1.0;
                for k in 0..=n {
                    out[n] += binom * e[k] * m[n - k];
                    binom = binom * (n - k) as f64 / (k + 1) as f64;
                }
            }
        }
        if let Some(p) = &self.pulses {
            add(&mut out, p.derivs(t));
        }
        out
    }

    /// Jet of the n-th derivative (orders n..n+3), n ≤ 2.
    pub fn jet(&self, t: f64, n: usize) -> Jet {
        Jet::from_derivs(&self.derivs(t)[n..n + 4])
    }
}

/// How the body moves through space.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Translation {
    /// x, y, z as channels of time, m.
    Cartesian([Signal; 3]),
    /// A vehicle moving along its heading at `speed` (m/s) in the plane, at `height` (m).
    Planar { heading: Signal, speed: Signal, height: Signal },
}

/// The simulated motions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Profile {
    /// A multirotor: hover and manoeuvres in 3D (`mav` also accepted).
    #[serde(alias = "mav")]
    #[value(alias = "mav")]
    Aerial,
    /// A walking person holding the sensor.
    Handheld,
    /// A car driving on a road.
    Car,
    /// A legged robot trotting.
    Quadruped,
}

impl Profile {
    pub const ALL: [Profile; 4] = [Profile::Aerial, Profile::Handheld, Profile::Car, Profile::Quadruped];

    pub fn name(self) -> &'static str {
        match self {
            Profile::Aerial => "aerial",
            Profile::Handheld => "handheld",
            Profile::Car => "car",
            Profile::Quadruped => "quadruped",
        }
    }
}

impl std::fmt::Display for Profile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Profile {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "mav" => Ok(Profile::Aerial),
            _ => Profile::ALL
                .into_iter()
                .find(|p| p.name() == s)
                .ok_or_else(|| format!("unknown profile `{s}`, expected one of: {} (or mav)", Profile::ALL.map(|p| p.name()).join(", "))),
        }
    }
}

/// The true motion at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KinematicState {
    pub world_from_body: UnitQuaternion<f64>,
    /// Angular velocity of the body in the body frame, rad/s.
    pub omega_in_body: Vector3<f64>,
    /// Angular acceleration of the body in the body frame, rad/s².
    pub alpha_in_body: Vector3<f64>,
    /// Velocity in the world, m/s.
    pub velocity_in_world: Vector3<f64>,
    /// Acceleration in the world, m/s².
    pub accel_in_world: Vector3<f64>,
}

impl KinematicState {
    /// Standing still, level (set the attitude).
    pub fn at_rest() -> Self {
        KinematicState {
            world_from_body: UnitQuaternion::identity(),
            omega_in_body: Vector3::zeros(),
            alpha_in_body: Vector3::zeros(),
            velocity_in_world: Vector3::zeros(),
            accel_in_world: Vector3::zeros(),
        }
    }

    /// What an ideal accelerometer reads: f = Rᵀ (a − g_world), g_world = (0, 0, −g).
    pub fn specific_force_in_body(&self, gravity: f64) -> Vector3<f64> {
        self.world_from_body.inverse_transform_vector(&(self.accel_in_world + Vector3::z() * gravity))
    }
}

/// A body trajectory: Euler angles and translation as analytic channels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Trajectory {
    pub profile: Profile,
    pub roll: Signal,
    pub pitch: Signal,
    /// Yaw; for a planar translation, added to the heading.
    pub yaw: Signal,
    pub translation: Translation,
    /// Tilt into the acceleration: roll += gains[0]·a_left/g, pitch += gains[1]·a_forward/g,
    /// with the world acceleration expressed in the yawed (heading) frame.
    pub tilt_gains: [f64; 2],
}

impl Trajectory {
    /// The trajectory of `profile`, its random choices drawn from `seed`.
    pub fn new(profile: Profile, seed: u64) -> Trajectory {
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(derive_seed(seed, "trajectory", 0));
        let rng = &mut rng;
        match profile {
            Profile::Aerial => aerial(rng),
            Profile::Handheld => handheld(rng),
            Profile::Car => car(rng),
            Profile::Quadruped => quadruped(rng, seed),
        }
    }

    /// Euler angles (roll, pitch, yaw) as jets valid to order 2, and the world acceleration
    /// and velocity.
    fn angles_and_motion(&self, t: f64) -> ([Jet; 3], Vector3<f64>, Vector3<f64>) {
        let (accel, velocity, yaw) = match &self.translation {
            Translation::Cartesian(p) => {
                let a = [p[0].jet(t, 2), p[1].jet(t, 2), p[2].jet(t, 2)];
                let v = Vector3::new(p[0].jet(t, 1).v, p[1].jet(t, 1).v, p[2].jet(t, 1).v);
                (a, v, self.yaw.jet(t, 0))
            }
            Translation::Planar { heading, speed, height } => {
                let h = heading.jet(t, 0);
                let s = speed.jet(t, 0);
                let vx = s * h.cos();
                let vy = s * h.sin();
                let vz = height.jet(t, 1);
                let v = Vector3::new(vx.v, vy.v, vz.v);
                ([vx.derivative(), vy.derivative(), vz.derivative()], v, h + self.yaw.jet(t, 0))
            }
        };
        let (c, s) = (yaw.cos(), yaw.sin());
        let a_forward = c * accel[0] + s * accel[1];
        let a_left = c * accel[1] - s * accel[0];
        let roll = self.roll.jet(t, 0) + a_left * (self.tilt_gains[0] / NOMINAL_GRAVITY);
        let pitch = self.pitch.jet(t, 0) + a_forward * (self.tilt_gains[1] / NOMINAL_GRAVITY);
        ([roll, pitch, yaw], Vector3::new(accel[0].v, accel[1].v, accel[2].v), velocity)
    }

    /// The true motion at `t` s.
    pub fn state(&self, t: f64) -> KinematicState {
        let ([roll, pitch, yaw], accel_in_world, velocity_in_world) = self.angles_and_motion(t);
        let (droll, dpitch, dyaw) = (roll.derivative(), pitch.derivative(), yaw.derivative());
        // ZYX Euler rates → body rates: ω = (φ̇ − ψ̇ sθ, θ̇ cφ + ψ̇ cθ sφ, −θ̇ sφ + ψ̇ cθ cφ).
        let (sr, cr, sp, cp) = (roll.sin(), roll.cos(), pitch.sin(), pitch.cos());
        let wx = droll - dyaw * sp;
        let wy = dpitch * cr + dyaw * cp * sr;
        let wz = dyaw * cp * cr - dpitch * sr;
        KinematicState {
            world_from_body: UnitQuaternion::from_euler_angles(roll.v, pitch.v, yaw.v),
            omega_in_body: Vector3::new(wx.v, wy.v, wz.v),
            alpha_in_body: Vector3::new(wx.d1, wy.d1, wz.d1),
            velocity_in_world,
            accel_in_world,
        }
    }

    /// Positions at increasing times `t` (s, from 0). Cartesian: exact. Planar: the velocity
    /// integrated from t = 0 (origin) with 3-point Gauss–Legendre on steps of at most 5 ms
    /// (error far below a micrometre over minutes).
    pub fn positions(&self, times: &[f64]) -> Vec<Vector3<f64>> {
        match &self.translation {
            Translation::Cartesian(p) => {
                times.iter().map(|&t| Vector3::new(p[0].derivs(t)[0], p[1].derivs(t)[0], p[2].derivs(t)[0])).collect()
            }
            Translation::Planar { heading, speed, height } => {
                let planar_velocity = |t: f64| {
                    let (h, v) = (heading.derivs(t)[0], speed.derivs(t)[0]);
                    Vector3::new(v * h.cos(), v * h.sin(), 0.0)
                };
                let nodes = [(-(0.6f64).sqrt(), 5.0 / 9.0), (0.0, 8.0 / 9.0), ((0.6f64).sqrt(), 5.0 / 9.0)];
                let mut xy = Vector3::zeros();
                let mut t_prev = 0.0;
                times
                    .iter()
                    .map(|&t| {
                        let steps = ((t - t_prev).abs() / 5e-3).ceil().max(1.0) as usize;
                        let h = (t - t_prev) / steps as f64;
                        for k in 0..steps {
                            let mid = t_prev + (k as f64 + 0.5) * h;
                            for (x, w) in nodes {
                                xy += planar_velocity(mid + 0.5 * h * x) * (0.5 * h * w);
                            }
                        }
                        t_prev = t;
                        Vector3::new(xy.x, xy.y, height.derivs(t)[0])
                    })
                    .collect()
            }
        }
    }
}

fn uniform(rng: &mut impl Rng, lo: f64, hi: f64) -> f64 {
    rng.gen_range(lo..hi)
}

/// `n` sinusoids with amplitudes in [a0, a1) and frequencies in [f0, f1) Hz, random phases.
fn sines(rng: &mut impl Rng, n: usize, (a0, a1): (f64, f64), (f0, f1): (f64, f64)) -> Vec<Sine> {
    (0..n).map(|_| Sine::hz(uniform(rng, a0, a1), uniform(rng, f0, f1), uniform(rng, 0.0, TAU))).collect()
}

fn aerial(rng: &mut impl Rng) -> Trajectory {
    // Manoeuvre intensity: between 0.1 (hovering) and 1, period 15–25 s.
    let envelope = Envelope { mean: 0.55, sine: Sine::hz(0.45, 1.0 / uniform(rng, 15.0, 25.0), uniform(rng, 0.0, TAU)) };
    let mut axis = |offset: f64, amp: (f64, f64), n: usize| Signal {
        offset,
        modulated: sines(rng, n, amp, (0.05, 0.25)),
        envelope: Some(envelope),
        // Position-hold jitter, always there.
        sines: sines(rng, 2, (0.005, 0.02), (0.3, 0.8)),
        ..Default::default()
    };
    let translation = Translation::Cartesian([axis(0.0, (0.3, 1.5), 3), axis(0.0, (0.3, 1.5), 3), axis(1.5, (0.1, 0.5), 2)]);
    Trajectory {
        profile: Profile::Aerial,
        roll: Signal { sines: sines(rng, 2, (0.005, 0.02), (0.5, 2.0)), ..Default::default() },
        pitch: Signal { sines: sines(rng, 2, (0.005, 0.02), (0.5, 2.0)), ..Default::default() },
        yaw: Signal {
            offset: uniform(rng, -3.0, 3.0),
            slope: uniform(rng, -0.1, 0.1),
            sines: sines(rng, 2, (0.3, 1.0), (0.02, 0.1)),
            ..Default::default()
        },
        translation,
        tilt_gains: [-1.0, 1.0],
    }
}

fn handheld(rng: &mut impl Rng) -> Trajectory {
    let step_hz = uniform(rng, 1.7, 2.1);
    let speed = Signal {
        offset: 1.0,
        sines: [sines(rng, 2, (0.1, 0.25), (0.02, 0.08)), vec![Sine::hz(0.1, step_hz, uniform(rng, 0.0, TAU))]].concat(),
        ..Default::default()
    };
    let heading = Signal {
        offset: uniform(rng, -3.0, 3.0),
        slope: uniform(rng, -0.05, 0.05),
        sines: sines(rng, 3, (0.5, 1.5), (0.01, 0.05)),
        ..Default::default()
    };
    let height = Signal {
        offset: 1.3,
        sines: [sines(rng, 1, (0.05, 0.1), (0.05, 0.15)), vec![Sine::hz(0.025, step_hz, uniform(rng, 0.0, TAU))]].concat(),
        ..Default::default()
    };
    let hand = |rng: &mut _, a: (f64, f64)| Signal {
        sines: [sines(rng, 3, a, (0.1, 0.9)), vec![Sine::hz(0.02, step_hz, uniform(rng, 0.0, TAU))]].concat(),
        ..Default::default()
    };
    Trajectory {
        profile: Profile::Handheld,
        roll: hand(rng, (0.05, 0.25)),
        pitch: hand(rng, (0.05, 0.25)),
        yaw: hand(rng, (0.1, 0.35)),
        translation: Translation::Planar { heading, speed, height },
        tilt_gains: [0.0, 0.0],
    }
}

fn car(rng: &mut impl Rng) -> Trajectory {
    let heading = Signal {
        offset: uniform(rng, -3.0, 3.0),
        slope: uniform(rng, -0.02, 0.02),
        sines: sines(rng, 3, (0.3, 1.5), (0.01, 0.05)),
        ..Default::default()
    };
    let speed = Signal { offset: 12.0, sines: sines(rng, 3, (1.0, 2.5), (0.01, 0.05)), ..Default::default() };
    let bumps = |rng: &mut _, a: (f64, f64)| Signal { sines: sines(rng, 3, a, (0.8, 2.5)), ..Default::default() };
    Trajectory {
        profile: Profile::Car,
        roll: bumps(rng, (0.001, 0.005)),
        pitch: bumps(rng, (0.001, 0.005)),
        yaw: Signal::default(),
        translation: Translation::Planar { heading, speed, height: Signal { offset: 0.5, ..bumps(rng, (0.001, 0.006)) } },
        // ≈4°/g roll out of turns, ≈2°/g nose dive under braking.
        tilt_gains: [0.07, -0.035],
    }
}

fn quadruped(rng: &mut impl Rng, seed: u64) -> Trajectory {
    let gait_hz = uniform(rng, 1.8, 2.2);
    let period = 1.0 / gait_hz;
    let bob_phase = uniform(rng, 0.0, TAU);
    // Footfalls at the bottom of the bob: 2π f t + φ = −π/2 (mod 2π).
    let first = ((-FRAC_PI_2 - bob_phase) / TAU).rem_euclid(1.0) * period;
    let pulses = |amplitude: f64, alternate: bool, concern: &str| Pulses {
        first_s: first,
        period_s: period,
        sigma_s: 0.01,
        amplitude,
        variation: 0.25,
        alternate,
        seed: derive_seed(seed, concern, 0),
    };
    let heading = Signal { offset: uniform(rng, -3.0, 3.0), sines: sines(rng, 2, (0.5, 1.5), (0.01, 0.04)), ..Default::default() };
    let speed = Signal {
        offset: 0.8,
        sines: [sines(rng, 1, (0.1, 0.3), (0.02, 0.05)), vec![Sine::hz(0.05, gait_hz, bob_phase)]].concat(),
        ..Default::default()
    };
    let height = Signal {
        offset: 0.35,
        sines: vec![Sine::hz(0.012, gait_hz, bob_phase)],
        pulses: Some(pulses(15.0, false, "footfall_z")),
        ..Default::default()
    };
    Trajectory {
        profile: Profile::Quadruped,
        // Rocking from one diagonal pair to the other at half the footfall rate.
        roll: Signal {
            sines: vec![Sine::hz(0.03, gait_hz / 2.0, uniform(rng, 0.0, TAU))],
            pulses: Some(pulses(20.0, true, "footfall_roll")),
            ..Default::default()
        },
        pitch: Signal {
            sines: [vec![Sine::hz(0.015, gait_hz, uniform(rng, 0.0, TAU))], sines(rng, 1, (0.01, 0.03), (0.05, 0.2))].concat(),
            pulses: Some(pulses(10.0, false, "footfall_pitch")),
            ..Default::default()
        },
        yaw: Signal { sines: vec![Sine::hz(0.02, gait_hz / 2.0, uniform(rng, 0.0, TAU))], ..Default::default() },
        translation: Translation::Planar { heading, speed, height },
        tilt_gains: [0.0, 0.0],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::ImuSample;
    use crate::so3;

    fn central(f: impl Fn(f64) -> f64, t: f64, h: f64) -> f64 {
        (f(t + h) - f(t - h)) / (2.0 * h)
    }

    #[test]
    fn channel_derivatives_match_finite_differences() {
        let c = Signal {
            offset: 0.3,
            slope: 0.1,
            sines: vec![Sine::hz(0.5, 0.7, 0.2)],
            modulated: vec![Sine::hz(1.0, 0.3, 1.0), Sine::hz(0.2, 1.1, -0.4)],
            envelope: Some(Envelope { mean: 0.6, sine: Sine::hz(0.4, 0.05, 0.3) }),
            pulses: Some(Pulses { first_s: 0.2, period_s: 0.5, sigma_s: 0.05, amplitude: 3.0, variation: 0.2, alternate: true, seed: 4 }),
        };
        for t in [0.0, 0.21, 0.7, 1.234, 5.0] {
            let d = c.derivs(t);
            for n in 0..ORDERS - 1 {
                let fd = central(|s| c.derivs(s)[n], t, 1e-5);
                assert!((fd - d[n + 1]).abs() < 1e-5 * (1.0 + d[n + 1].abs()), "t {t} order {}: {fd} vs {}", n + 1, d[n + 1]);
            }
        }
    }

    #[test]
    fn pulse_leaves_no_net_velocity_or_position() {
        let p = Pulses { first_s: 1.0, period_s: 10.0, sigma_s: 0.01, amplitude: 15.0, variation: 0.0, alternate: false, seed: 0 };
        let before = p.derivs(0.5);
        let after = p.derivs(1.5);
        assert!(before.iter().chain(after.iter()).all(|x| x.abs() < 1e-12));
        let peak = p.derivs(1.0);
        assert!((peak[2] - 15.0).abs() < 1e-12, "Ricker peak {}", peak[2]);
    }

    #[test]
    fn jet_sin_matches_finite_differences() {
        let u = |t: f64| 0.3 + 1.2 * t + 0.4 * t * t - 0.1 * t * t * t;
        let jet = |t: f64| Jet { v: u(t), d1: 1.2 + 0.8 * t - 0.3 * t * t, d2: 0.8 - 0.6 * t, d3: -0.6 };
        let t = 0.7;
        let j = (jet(t).sin() * jet(t).cos()) * 2.0; // = sin 2u
        let f = |t: f64| (2.0 * u(t)).sin();
        assert!((j.v - f(t)).abs() < 1e-12);
        assert!((j.d1 - central(f, t, 1e-5)).abs() < 1e-7);
        assert!((j.d2 - central(|s| (jet(s).sin() * jet(s).cos() * 2.0).d1, t, 1e-5)).abs() < 1e-6);
        assert!((j.d3 - central(|s| (jet(s).sin() * jet(s).cos() * 2.0).d2, t, 1e-5)).abs() < 1e-5);
    }

    #[test]
    fn angular_velocity_and_acceleration_match_the_attitude() {
        for profile in Profile::ALL {
            let traj = Trajectory::new(profile, 5);
            for t in [0.3, 7.1, 23.45] {
                let h = 1e-5;
                let s = traj.state(t);
                // ω from the attitude: Log(R(t−h)ᵀ R(t+h)) / 2h, in the body frame.
                let q = |t: f64| traj.state(t).world_from_body;
                let omega_fd = so3::log(&(q(t - h).inverse() * q(t + h))) / (2.0 * h);
                assert!(
                    (omega_fd - s.omega_in_body).norm() < 1e-6 * (1.0 + s.omega_in_body.norm()),
                    "{profile} t {t}: {omega_fd:?} vs {:?}",
                    s.omega_in_body
                );
                let alpha_fd = (traj.state(t + h).omega_in_body - traj.state(t - h).omega_in_body) / (2.0 * h);
                assert!(
                    (alpha_fd - s.alpha_in_body).norm() < 1e-4 * (1.0 + s.alpha_in_body.norm()),
                    "{profile} t {t}: {alpha_fd:?} vs {:?}",
                    s.alpha_in_body
                );
                let accel_fd = (traj.state(t + h).velocity_in_world - traj.state(t - h).velocity_in_world) / (2.0 * h);
                assert!((accel_fd - s.accel_in_world).norm() < 1e-4 * (1.0 + s.accel_in_world.norm()), "{profile} t {t}");
            }
        }
    }

    #[test]
    fn integrating_the_exact_gyro_reproduces_the_attitude() {
        // 60 s at 200 Hz. Each step's rotation is composed from 8 midpoint sub-steps of the
        // exact ω (so the check is on ω, not on the first-order integrator).
        for profile in Profile::ALL {
            let traj = Trajectory::new(profile, 11);
            let dt = 5e-3;
            let n = 12_001;
            let imu: Vec<ImuSample> =
                (0..n).map(|k| ImuSample { stamp_ns: k as i64 * 5_000_000, gyro: Vector3::zeros(), accel: Vector3::zeros() }).collect();
            let path = so3::integrate_gyro(&imu, traj.state(0.0).world_from_body, |k| {
                let sub = 8;
                let h = dt / sub as f64;
                let mut r = UnitQuaternion::identity();
                for j in 0..sub {
                    r *= so3::exp(&(traj.state(k as f64 * dt + (j as f64 + 0.5) * h).omega_in_body * h));
                }
                so3::log(&r) / dt
            });
            let worst = (0..n)
                .step_by(100)
                .map(|k| so3::angle_deg(&(path[k].inverse() * traj.state(k as f64 * dt).world_from_body)))
                .fold(0.0, f64::max);
            eprintln!("{profile}: worst attitude error {worst:.1e}° over 60 s");
            assert!(worst < 0.01, "{profile}: {worst}°");
        }
    }

    #[test]
    fn double_integrating_the_acceleration_gives_the_positions() {
        for profile in Profile::ALL {
            let traj = Trajectory::new(profile, 2);
            // Simpson on 1 ms steps: v(T) = v(0) + ∫a, p(T) = p(0) + ∫v.
            let (dt, n) = (1e-3, 20_000);
            let times: Vec<f64> = (0..=n).map(|k| k as f64 * dt).collect();
            let states: Vec<_> = times.iter().map(|&t| traj.state(t)).collect();
            let simpson = |f: &dyn Fn(usize) -> Vector3<f64>, a: usize, b: usize| -> Vector3<f64> {
                (a..b).step_by(2).map(|k| (f(k) + f(k + 1) * 4.0 + f(k + 2)) * (dt / 3.0)).sum()
            };
            let dv = simpson(&|k| states[k].accel_in_world, 0, n);
            let v_end = states[n].velocity_in_world;
            assert!((states[0].velocity_in_world + dv - v_end).norm() < 1e-6, "{profile}: velocity");
            let positions = traj.positions(&[0.0, times[n]]);
            let dp = simpson(&|k| states[k].velocity_in_world, 0, n);
            assert!((positions[0] + dp - positions[1]).norm() < 1e-6, "{profile}: position {:?} vs {:?}", positions[0] + dp, positions[1]);
        }
    }

    #[test]
    fn profiles_move_as_described() {
        let stats = |profile: Profile| {
            let traj = Trajectory::new(profile, 1);
            let states: Vec<_> = (0..6000).map(|k| traj.state(k as f64 * 0.01)).collect();
            let max_w = states.iter().map(|s| s.omega_in_body.amax()).fold(0.0, f64::max);
            let max_a = states.iter().map(|s| s.accel_in_world.norm()).fold(0.0, f64::max);
            let max_tilt = states.iter().map(|s| so3::euler_zyx(&s.world_from_body).xy().amax()).fold(0.0, f64::max);
            let min_speed = states.iter().map(|s| s.velocity_in_world.xy().norm()).fold(f64::INFINITY, f64::min);
            (max_w, max_a, max_tilt, min_speed)
        };
        let (w, a, tilt, _) = stats(Profile::Aerial);
        assert!(w > 0.1 && w < 3.0 && a > 0.5 && a < 15.0 && tilt < 0.8, "aerial {w} {a} {tilt}");
        let (w, a, tilt, v) = stats(Profile::Car);
        assert!(w < 1.0 && a > 0.5 && tilt < 0.1 && v > 1.0, "car {w} {a} {tilt} {v}");
        let (w, _, tilt, _) = stats(Profile::Handheld);
        assert!(w > 0.5 && w < 6.0 && tilt > 0.2 && tilt < 1.2, "handheld {w} {tilt}");
        let (w, a, tilt, v) = stats(Profile::Quadruped);
        assert!(w > 0.1 && a > 10.0 && tilt < 0.2 && v > 0.2, "quadruped {w} {a} {tilt} {v}");
    }

    #[test]
    fn seeded_and_reproducible() {
        assert_eq!(Trajectory::new(Profile::Handheld, 3), Trajectory::new(Profile::Handheld, 3));
        assert_ne!(Trajectory::new(Profile::Handheld, 3), Trajectory::new(Profile::Handheld, 4));
    }
}
