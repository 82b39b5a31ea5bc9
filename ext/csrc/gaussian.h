// Per-Gaussian math shared by both back-ends: preprocessing (quaternion -> R), bounds, the peak
// response along a ray (PHYSICS.md "Gaussian primitive") and its adjoint.
//
// The response is computed in the whitened frame of the Gaussian (x' = diag(1/s) R^T x), where
// with p = mu - o, p' = M p, d' = M d, u = d' / |d'|:
//   t*   = (u . p') / |d'|                      (peak of the Gaussian along the ray)
//   maha = |p' x u|^2                           (squared Mahalanobis distance at t*)
//   r    = u x (p' x u) = M (mu - x(t*))        (whitened residual, |r|^2 = maha)
// The cross-product form has no catastrophic cancellation for very flat Gaussians, unlike
// c - b^2 / a.
#pragma once

#include "common.h"

namespace rfir {

// (mean [3], log-scale [3], quaternion wxyz [4], not necessarily unit) -> prim [kPrimStride].
template <typename T>
RFIR_HD void preprocess_gaussian(const T* mean, const T* log_scale, const T* quat, T* prim) {
  T w = quat[0], x = quat[1], y = quat[2], z = quat[3];
  const T inv_n = T(1) / r_sqrt(w * w + x * x + y * y + z * z);
  w *= inv_n; x *= inv_n; y *= inv_n; z *= inv_n;
  T* R = prim + kRot;
  R[0] = 1 - 2 * (y * y + z * z); R[1] = 2 * (x * y - w * z);     R[2] = 2 * (x * z + w * y);
  R[3] = 2 * (x * y + w * z);     R[4] = 1 - 2 * (x * x + z * z); R[5] = 2 * (y * z - w * x);
  R[6] = 2 * (x * z - w * y);     R[7] = 2 * (y * z + w * x);     R[8] = 1 - 2 * (x * x + y * y);
  for (int i = 0; i < 3; ++i) {
    prim[kMu + i] = mean[i];
    prim[kS + i] = r_exp(log_scale[i]);
    prim[kInvS + i] = r_exp(-log_scale[i]);
  }
}

// Axis-aligned half extents of the ellipsoid {maha <= kappa^2}.
template <typename T>
RFIR_HD void gaussian_half_extent(const T* prim, T kappa, T* half) {
  const T* R = prim + kRot;
  const T* s = prim + kS;
  for (int k = 0; k < 3; ++k) {
    T a = R[3 * k] * s[0], b = R[3 * k + 1] * s[1], c = R[3 * k + 2] * s[2];
    half[k] = kappa * r_sqrt(a * a + b * b + c * c);
  }
}

// Whitened ray quantities shared by the forward evaluation and the adjoint.
template <typename T>
struct Peak {
  T t;        // t*
  T maha;     // squared Mahalanobis distance at t*
  T pw[3];    // p' = M (mu - o)
  T u[3];     // unit whitened direction
  T inv_len;  // 1 / |d'|
};

// Returns false when the whitened direction is degenerate (never for finite inputs and d != 0).
template <typename T>
RFIR_HD bool peak_along_ray(const T* prim, const T* o, const T* d, Peak<T>& pk) {
  const T* R = prim + kRot;
  const T* is = prim + kInvS;
  const T p[3] = {prim[0] - o[0], prim[1] - o[1], prim[2] - o[2]};
  T dw[3];
  for (int i = 0; i < 3; ++i) {  // (R^T v)_i = sum_j R_ji v_j
    pk.pw[i] = is[i] * (R[i] * p[0] + R[3 + i] * p[1] + R[6 + i] * p[2]);
    dw[i] = is[i] * (R[i] * d[0] + R[3 + i] * d[1] + R[6 + i] * d[2]);
  }
  T len2 = dot3(dw, dw);
  T len;
  if (len2 > T(1e-30) && len2 < T(1e30)) {
    len = r_sqrt(len2);
  } else {  // rescale to avoid under/overflow for extremely flat or huge Gaussians
    T m = r_max(r_abs(dw[0]), r_max(r_abs(dw[1]), r_abs(dw[2])));
    if (!(m > T(0))) return false;
    T a = dw[0] / m, b = dw[1] / m, c = dw[2] / m;
    len = m * r_sqrt(a * a + b * b + c * c);
  }
  if (!(len > T(0)) || !(len < INFINITY)) return false;
  pk.inv_len = T(1) / len;
  for (int i = 0; i < 3; ++i) pk.u[i] = dw[i] * pk.inv_len;
  pk.t = dot3(pk.u, pk.pw) * pk.inv_len;
  T c[3];
  cross3(pk.pw, pk.u, c);
  pk.maha = dot3(c, c);
  return true;
}

// Adjoint of one hit's (G, t*) with respect to the Gaussian's geometry.
// g_maha = dL/dmaha, g_t = dL/dt*. Adds into acc (layout kGradStride: mean, log-scale, R).
// Envelope theorem for maha (t* is its minimiser), explicit derivative for t*:
//   v = 2 g_maha r + g_t u / |d'|,  dL/dmean = R (v / s),
//   dL/dlog s_i = -r_i (v_i + g_t u_i / |d'|),
//   dL/dR_ji = (v_i q_j + (g_t / |d'|^2) r_i d_j) / s_i,  q = mu - x(t*) = R (s * r).
template <typename T>
RFIR_HD void peak_backward(const T* prim, const T* d, const Peak<T>& pk, T g_maha, T g_t, T* acc) {
  const T* R = prim + kRot;
  const T* is = prim + kInvS;
  const T* s = prim + kS;
  T c[3], r[3];
  cross3(pk.pw, pk.u, c);
  cross3(pk.u, c, r);
  T sr[3] = {s[0] * r[0], s[1] * r[1], s[2] * r[2]};
  T q[3];
  for (int j = 0; j < 3; ++j) q[j] = R[3 * j] * sr[0] + R[3 * j + 1] * sr[1] + R[3 * j + 2] * sr[2];
  const T gu = g_t * pk.inv_len;
  const T beta = gu * pk.inv_len;
  T a[3], b[3];
  for (int i = 0; i < 3; ++i) {
    const T v = 2 * g_maha * r[i] + gu * pk.u[i];
    acc[gLogS + i] -= r[i] * (v + gu * pk.u[i]);
    a[i] = v * is[i];
    b[i] = beta * r[i] * is[i];
  }
  for (int j = 0; j < 3; ++j) {
    acc[gMu + j] += R[3 * j] * a[0] + R[3 * j + 1] * a[1] + R[3 * j + 2] * a[2];
    for (int i = 0; i < 3; ++i) acc[gRot + 3 * j + i] += a[i] * q[j] + b[i] * d[j];
  }
}

// dL/dR (row-major 3x3) -> dL/dq for the raw (unnormalised) quaternion wxyz.
template <typename T>
RFIR_HD void quat_backward(const T* quat, const T* gR, T* gq) {
  T w = quat[0], x = quat[1], y = quat[2], z = quat[3];
  const T inv_n = T(1) / r_sqrt(w * w + x * x + y * y + z * z);
  w *= inv_n; x *= inv_n; y *= inv_n; z *= inv_n;
  const T g[4] = {
      2 * (-z * gR[1] + y * gR[2] + z * gR[3] - x * gR[5] - y * gR[6] + x * gR[7]),
      2 * (y * gR[1] + z * gR[2] + y * gR[3] - 2 * x * gR[4] - w * gR[5] + z * gR[6] + w * gR[7] -
           2 * x * gR[8]),
      2 * (-2 * y * gR[0] + x * gR[1] + w * gR[2] + x * gR[3] + z * gR[5] - w * gR[6] + z * gR[7] -
           2 * y * gR[8]),
      2 * (-2 * z * gR[0] - w * gR[1] + x * gR[2] + w * gR[3] - 2 * z * gR[4] + y * gR[5] + x * gR[6] +
           y * gR[7])};
  const T qn[4] = {w, x, y, z};
  const T proj = qn[0] * g[0] + qn[1] * g[1] + qn[2] * g[2] + qn[3] * g[3];
  for (int i = 0; i < 4; ++i) gq[i] = (g[i] - qn[i] * proj) * inv_n;
}

}  // namespace rfir
