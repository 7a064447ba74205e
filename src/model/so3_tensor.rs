//! SO(3) on batched tensors for the orientation-increment loss (paper §III-A "Loss function",
//! `δR_{i,i+j} = Π_k exp(ω_k dt)`; DIGDL §IV): exp/log maps, quaternion products, and
//! increments over `j` samples by log-depth products.
//!
//! Rotations are Hamilton unit quaternions `[..., 4] = (w, x, y, z)`, the convention of
//! `crate::so3` (`R(t_{n+1}) = R(t_n) · Exp(ω_n dt_n)`, `dt_n = t_{n+1} − t_n`).
//!
//! Gradients stay finite at zero rotation: near θ = 0 both maps switch to Taylor series,
//! and the branch not taken is evaluated on a harmless input (θ² replaced by 1), because
//! `where` masks values, not gradients (the untaken branch would otherwise give 0·∞ = NaN).

use tch::{Kind, Tensor};

/// Below this squared angle (rad²) the series are used: at θ = 1e-3 their truncation error
/// is below 1e-16 relative.
const SMALL_ANGLE_SQ: f64 = 1e-6;

/// Exp: rotation vector `[..., 3]` (rad) → unit quaternion `[..., 4]`.
pub fn quat_exp(phi: &Tensor) -> Tensor {
    let theta_sq = phi.square().sum_dim_intlist(-1, true, None);
    let small = theta_sq.lt(SMALL_ANGLE_SQ);
    let theta = theta_sq.where_self(&small.logical_not(), &Tensor::ones_like(&theta_sq)).sqrt();
    let half = &theta * 0.5;
    // w = cos(θ/2), k = sin(θ/2)/θ; series: w ≈ 1 − θ²/8 + θ⁴/384, k ≈ 1/2 − θ²/48 + θ⁴/3840.
    let t4 = theta_sq.square();
    let w_series = &theta_sq / -8.0 + &t4 / 384.0 + 1.0;
    let k_series = &theta_sq / -48.0 + &t4 / 3840.0 + 0.5;
    let w = w_series.where_self(&small, &half.cos());
    let k = k_series.where_self(&small, &(half.sin() / &theta));
    Tensor::cat(&[w, phi * k], -1)
}

/// Log: quaternion `[..., 4]` → rotation vector `[..., 3]` with angle in [0, π]. Normalises
/// first, so products that drifted off the unit sphere are fine.
pub fn quat_log(q: &Tensor) -> Tensor {
    let q = q / q.square().sum_dim_intlist(-1, true, None).sqrt();
    // q and −q are the same rotation: take w ≥ 0 (a sign flip, no gradient of its own).
    let sign = q.narrow(-1, 0, 1).lt(0.0).to_kind(q.kind()) * -2.0 + 1.0;
    let q = q * sign;
    let w = q.narrow(-1, 0, 1);
    let v = q.narrow(-1, 1, 3);
    let s_sq = v.square().sum_dim_intlist(-1, true, None);
    let small = s_sq.lt(SMALL_ANGLE_SQ);
    // Large: θ/s with θ = 2·atan2(s, w). Small (w ≈ 1): 2·atan(x)/x / w with x = s/w,
    // atan(x)/x ≈ 1 − x²/3 + x⁴/5.
    let ones = Tensor::ones_like(&s_sq);
    let s = s_sq.where_self(&small.logical_not(), &ones).sqrt();
    let w_safe = w.where_self(&small, &ones);
    let x_sq = &s_sq / w_safe.square();
    let series = (&x_sq / -3.0 + x_sq.square() / 5.0 + 1.0) * 2.0 / &w_safe;
    let factor = series.where_self(&small, &(s.atan2(&w) * 2.0 / &s));
    v * factor
}

/// Hamilton product `a ⊗ b`, broadcasting over leading dimensions.
pub fn quat_mul(a: &Tensor, b: &Tensor) -> Tensor {
    let c = |t: &Tensor, i: i64| t.narrow(-1, i, 1);
    let (aw, ax, ay, az) = (c(a, 0), c(a, 1), c(a, 2), c(a, 3));
    let (bw, bx, by, bz) = (c(b, 0), c(b, 1), c(b, 2), c(b, 3));
    Tensor::cat(
        &[
            &aw * &bw - &ax * &bx - &ay * &by - &az * &bz,
            &aw * &bx + &ax * &bw + &ay * &bz - &az * &by,
            &aw * &by - &ax * &bz + &ay * &bw + &az * &bx,
            &aw * &bz + &ax * &by - &ay * &bx + &az * &bw,
        ],
        -1,
    )
}

/// Conjugate (the inverse of a unit quaternion).
pub fn quat_conj(q: &Tensor) -> Tensor {
    let sign = Tensor::from_slice(&[1.0, -1.0, -1.0, -1.0]).to_kind(q.kind()).to_device(q.device());
    q * sign
}

/// The identity rotation with the kind, device and leading shape of `like` (`[..., 4]`).
pub fn quat_identity_like(like: &Tensor) -> Tensor {
    let mut shape = like.size();
    let last = shape.len() - 1;
    shape[last] = 1;
    let ones = Tensor::ones(shape.as_slice(), (like.kind(), like.device()));
    let zeros = Tensor::zeros([3], (like.kind(), like.device())).expand(like.narrow(-1, 0, 3).size(), false);
    Tensor::cat(&[ones, zeros], -1)
}

/// Rotation matrix `[..., 3, 3]` of a unit quaternion `[..., 4]`.
pub fn quat_to_rotation_matrix(q: &Tensor) -> Tensor {
    let c = |i: i64| q.narrow(-1, i, 1);
    let (w, x, y, z) = (c(0), c(1), c(2), c(3));
    let rows = [
        [(&y * &y + &z * &z) * -2.0 + 1.0, (&x * &y - &w * &z) * 2.0, (&x * &z + &w * &y) * 2.0],
        [(&x * &y + &w * &z) * 2.0, (&x * &x + &z * &z) * -2.0 + 1.0, (&y * &z - &w * &x) * 2.0],
        [(&x * &z - &w * &y) * 2.0, (&y * &z + &w * &x) * 2.0, (&x * &x + &y * &y) * -2.0 + 1.0],
    ];
    let rows: Vec<Tensor> = rows.into_iter().map(|r| Tensor::cat(&r, -1).unsqueeze(-2)).collect();
    Tensor::cat(&rows, -2)
}

/// Products of consecutive blocks of `j` quaternions along dim 1:
/// `q: [B, M·j, 4]` → `[B, M, 4]`, entry m = `q_{mj} ⊗ … ⊗ q_{mj+j−1}`. A pairwise tree,
/// ⌈log₂ j⌉ batched products deep (order preserved: left factors are earlier samples).
pub fn block_products(q: &Tensor, j: i64) -> Tensor {
    let (b, t) = (q.size()[0], q.size()[1]);
    assert!(j >= 1 && t % j == 0, "block_products: length {t} is not a multiple of {j}");
    let mut x = q.reshape([b, t / j, j, 4]);
    let mut len = j;
    while len > 1 {
        if len % 2 == 1 {
            // Pad with the identity at the end so every factor has a partner.
            let id = quat_identity_like(&x.narrow(2, 0, 1));
            x = Tensor::cat(&[x, id], 2);
            len += 1;
        }
        let pairs = x.reshape([b, t / j, len / 2, 2, 4]);
        x = quat_mul(&pairs.select(3, 0), &pairs.select(3, 1));
        len /= 2;
    }
    x.squeeze_dim(2)
}

/// Inclusive prefix products along dim 1, `[B, T, 4]` → `[B, T, 4]`, entry n =
/// `q_0 ⊗ … ⊗ q_n`: a Hillis–Steele scan, ⌈log₂ T⌉ batched products (for open-loop
/// integration in tensors; its rounding grows with T, so the loss uses [`block_products`]).
pub fn prefix_products(q: &Tensor) -> Tensor {
    let t = q.size()[1];
    let mut y = q.shallow_clone();
    let mut s = 1;
    while s < t {
        let head = y.narrow(1, 0, s);
        let tail = quat_mul(&y.narrow(1, 0, t - s), &y.narrow(1, s, t - s));
        y = Tensor::cat(&[head, tail], 1);
        s *= 2;
    }
    y
}

/// Number of non-overlapping `j`-sample increments in a sequence of `t` samples: the
/// increment m spans samples `mj … (m+1)j`, so it needs `(m+1)j ≤ t − 1`.
pub fn num_increments(t: i64, j: i64) -> i64 {
    if t < 1 {
        0
    } else {
        (t - 1) / j
    }
}

/// Estimated increments `δR̂_{mj,(m+1)j} = Π_{k=mj}^{(m+1)j−1} Exp(ω_k dt_k)`:
/// `omega: [B, T, 3]` (rad/s), `dt: [B, T]` (s, `dt_k = t_{k+1} − t_k`; the last entry is not
/// used) → `[B, M, 4]`, M = [`num_increments`]`(T, j)`.
pub fn increments_from_gyro(omega: &Tensor, dt: &Tensor, j: i64) -> Tensor {
    let m = num_increments(omega.size()[1], j);
    let used = m * j;
    let phi = omega.narrow(1, 0, used) * dt.narrow(1, 0, used).unsqueeze(-1);
    block_products(&quat_exp(&phi), j)
}

/// Ground-truth increments `δR_{mj,(m+1)j} = R_{mj}ᵀ R_{(m+1)j}` from attitudes
/// `q: [B, T, 4]` (`world_from_body` at the IMU stamps) → `[B, M, 4]`.
pub fn increments_from_attitudes(q: &Tensor, j: i64) -> Tensor {
    let m = num_increments(q.size()[1], j);
    let ends = q.slice(1, 0, m * j + 1, j); // [B, M + 1, 4]
    quat_mul(&quat_conj(&ends.narrow(1, 0, m)), &ends.narrow(1, 1, m))
}

/// The residual rotation vector `Log(δR_gt δR̂ᵀ)` of two increment tensors `[..., 4]`.
pub fn increment_residual(gt: &Tensor, estimate: &Tensor) -> Tensor {
    quat_log(&quat_mul(gt, &quat_conj(estimate)))
}

/// The residual `Log(δR̂ᵀ δR_gt)`, in the body frame at the increment's end (DIGDL's code):
/// the same angle as [`increment_residual`], rotated by `δR_gt`ᵀ.
pub fn increment_residual_at_end(gt: &Tensor, estimate: &Tensor) -> Tensor {
    quat_log(&quat_mul(&quat_conj(estimate), gt))
}

/// The kind the SO(3) computations run in: `Double` when `f64` is asked, else the input's.
pub(crate) fn so3_kind(input: Kind, f64_asked: bool) -> Kind {
    if f64_asked {
        Kind::Double
    } else {
        input
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::so3;
    use nalgebra::{UnitQuaternion, Vector3};
    use tch::Device;

    const F64: (Kind, Device) = (Kind::Double, Device::Cpu);

    fn to_vec(t: &Tensor) -> Vec<f64> {
        Vec::<f64>::try_from(&t.flatten(0, -1)).unwrap()
    }

    fn quat_of(v: &[f64]) -> UnitQuaternion<f64> {
        UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(v[0], v[1], v[2], v[3]))
    }

    /// `δR_gt δR̂ᵀ = δR_gt (δR̂ᵀ δR_gt) δR_gtᵀ`: the start-frame residual is the end-frame one
    /// rotated by the ground-truth increment (same angle, other axes).
    #[test]
    fn the_end_frame_residual_is_the_start_one_rotated_back() {
        tch::manual_seed(11);
        let gt = quat_exp(&(Tensor::randn([40, 3], F64) * 0.8));
        let est = quat_mul(&gt, &quat_exp(&(Tensor::randn([40, 3], F64) * 0.01)));
        let (start, end) = (to_vec(&increment_residual(&gt, &est)), to_vec(&increment_residual_at_end(&gt, &est)));
        let g = to_vec(&gt);
        let mut turned = 0;
        for i in 0..40 {
            let (s, e) =
                (Vector3::new(start[3 * i], start[3 * i + 1], start[3 * i + 2]), Vector3::new(end[3 * i], end[3 * i + 1], end[3 * i + 2]));
            let rotated = quat_of(&g[4 * i..4 * i + 4]) * e;
            assert!((s - rotated).norm() < 1e-12 * s.norm().max(1e-3), "{i}: {s:?} vs {rotated:?}");
            turned += usize::from((s - e).norm() > 0.1 * s.norm());
        }
        assert!(turned > 30, "the frames differ when the body turns ({turned} of 40)");
    }

    #[test]
    fn exp_log_match_the_f64_reference() {
        tch::manual_seed(0);
        for scale in [1e-9, 1e-4, 1e-3, 0.3, 2.5] {
            let phi = Tensor::randn([50, 3], F64) * scale;
            let q = quat_exp(&phi);
            let back = quat_log(&q);
            let (pv, qv, bv) = (to_vec(&phi), to_vec(&q), to_vec(&back));
            for i in 0..50 {
                let p = Vector3::new(pv[3 * i], pv[3 * i + 1], pv[3 * i + 2]);
                let reference = so3::exp(&p);
                let mine = quat_of(&qv[4 * i..4 * i + 4]);
                assert!(mine.angle_to(&reference) < 1e-14, "exp at |φ| = {}", p.norm());
                let b = Vector3::new(bv[3 * i], bv[3 * i + 1], bv[3 * i + 2]);
                if p.norm() < std::f64::consts::PI {
                    assert!((b - p).norm() < 1e-13 * (1.0 + p.norm()), "log∘exp at |φ| = {}: {}", p.norm(), (b - p).norm());
                }
            }
        }
    }

    #[test]
    fn products_match_sequential() {
        tch::manual_seed(1);
        let q = quat_exp(&(Tensor::randn([2, 24, 3], F64) * 0.4));
        let qv = to_vec(&q);
        let mut seq = [UnitQuaternion::identity(), UnitQuaternion::identity()];
        let prefix = to_vec(&prefix_products(&q));
        for j in [1i64, 3, 4, 8, 24] {
            let blocks = to_vec(&block_products(&q, j));
            for b in 0..2 {
                for m in 0..(24 / j) as usize {
                    let mut acc = UnitQuaternion::identity();
                    for k in m * j as usize..(m + 1) * j as usize {
                        let o = (b * 24 + k) * 4;
                        acc *= quat_of(&qv[o..o + 4]);
                    }
                    let o = (b * (24 / j as usize) + m) * 4;
                    assert!(quat_of(&blocks[o..o + 4]).angle_to(&acc) < 1e-14, "j = {j}");
                }
            }
        }
        for (b, s) in seq.iter_mut().enumerate() {
            for k in 0..24 {
                let o = (b * 24 + k) * 4;
                *s *= quat_of(&qv[o..o + 4]);
                assert!(quat_of(&prefix[o..o + 4]).angle_to(s) < 1e-14);
            }
        }
    }

    #[test]
    fn increments_with_real_dt() {
        // A constant rate with jittered dt: the increment is Exp(ω Σdt) exactly.
        let w = [0.3, -0.2, 0.5];
        let t = 33;
        let dt: Vec<f64> = (0..t).map(|k| 0.005 + 1e-4 * ((k * 7 % 5) as f64 - 2.0)).collect();
        let omega = Tensor::from_slice(&w).to_kind(Kind::Double).expand([1, t, 3], false);
        let dt_t = Tensor::from_slice(&dt).reshape([1, t]);
        let inc = increments_from_gyro(&omega, &dt_t, 8);
        assert_eq!(inc.size(), [1, 4, 4]);
        let iv = to_vec(&inc);
        for m in 0..4 {
            let span: f64 = dt[m * 8..(m + 1) * 8].iter().sum();
            let expected = so3::exp(&(Vector3::from(w) * span));
            assert!(quat_of(&iv[4 * m..4 * m + 4]).angle_to(&expected) < 1e-14);
        }
        // Attitudes integrated from the same stream give the same increments.
        let mut att = vec![UnitQuaternion::from_scaled_axis(Vector3::new(0.1, 1.0, -0.4))];
        for k in 0..t as usize - 1 {
            let next = att[k] * so3::exp(&(Vector3::from(w) * dt[k]));
            att.push(next);
        }
        let flat: Vec<f64> = att.iter().flat_map(|q| [q.w, q.i, q.j, q.k]).collect();
        let gt = increments_from_attitudes(&Tensor::from_slice(&flat).reshape([1, t, 4]), 8);
        let residual = increment_residual(&gt, &inc);
        assert!(residual.abs().max().double_value(&[]) < 1e-13);
    }

    /// Central differences of a scalar function of `x` against autograd.
    fn check_gradient(x: &Tensor, f: impl Fn(&Tensor) -> Tensor, tol: f64) {
        let x = x.detach().set_requires_grad(true);
        let y = f(&x);
        let g = Tensor::run_backward(&[&y], &[&x], false, false).pop().unwrap();
        assert!(bool::try_from(g.isfinite().all()).unwrap(), "non-finite gradient");
        let gv = to_vec(&g);
        let base = to_vec(&x.detach());
        let h = 1e-6;
        for i in 0..base.len() {
            let at = |d: f64| {
                let mut v = base.clone();
                v[i] += d;
                f(&Tensor::from_slice(&v).reshape(x.size())).double_value(&[])
            };
            let fd = (at(h) - at(-h)) / (2.0 * h);
            assert!((fd - gv[i]).abs() < tol * (1.0 + fd.abs()), "∂/∂x[{i}]: autograd {} vs finite differences {fd}", gv[i]);
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        tch::manual_seed(2);
        let weights = Tensor::randn([4, 3], F64);
        let phi = Tensor::randn([4, 3], F64) * 0.7;
        check_gradient(&phi, |p| (quat_log(&quat_exp(p)) * &weights).sum(Kind::Double), 1e-7);
        let qw = Tensor::randn([4, 4], F64);
        check_gradient(&phi, |p| (quat_exp(p) * &qw).sum(Kind::Double), 1e-7);
        let q = quat_exp(&(Tensor::randn([4, 3], F64) * 0.7));
        check_gradient(&q, |q| (quat_log(q) * &weights).sum(Kind::Double), 1e-7);
        // A chain: log of products of exps (the loss path), small and large angles.
        let omega = Tensor::randn([1, 8, 3], F64);
        let dt = Tensor::full([1, 8], 0.05, F64);
        let gt = quat_exp(&(Tensor::randn([1, 2, 3], F64) * 0.2));
        check_gradient(&omega, |w| increment_residual(&gt, &increments_from_gyro(w, &dt, 3)).square().sum(Kind::Double), 1e-7);
    }

    #[test]
    fn gradients_are_finite_and_right_at_zero_rotation() {
        // d/dφ of w·log(exp(φ)) at φ = 0 is w; d/dφ of exp(φ) at 0 is (0, ½ I).
        let weights = Tensor::from_slice(&[0.3, -1.0, 2.0]).reshape([1, 3]);
        let phi = Tensor::zeros([1, 3], F64).set_requires_grad(true);
        let y = (quat_log(&quat_exp(&phi)) * &weights).sum(Kind::Double);
        let g = Tensor::run_backward(&[&y], &[&phi], false, false).pop().unwrap();
        assert!((g - &weights).abs().max().double_value(&[]) < 1e-15);
        let phi = Tensor::zeros([1, 3], F64).set_requires_grad(true);
        let y = quat_exp(&phi).narrow(-1, 1, 1).sum(Kind::Double);
        let g = Tensor::run_backward(&[&y], &[&phi], false, false).pop().unwrap();
        assert_eq!(to_vec(&g), [0.5, 0.0, 0.0]);
        // The identity quaternion's log, and angles near π (w → 0), keep finite gradients.
        for q0 in [[1.0, 0.0, 0.0, 0.0], [1e-9, 1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0]] {
            let q = Tensor::from_slice(&q0).reshape([1, 4]).set_requires_grad(true);
            let y = quat_log(&q).sum(Kind::Double);
            let g = Tensor::run_backward(&[&y], &[&q], false, false).pop().unwrap();
            assert!(bool::try_from(g.isfinite().all()).unwrap(), "{q0:?}: {g:?}");
        }
    }
}
