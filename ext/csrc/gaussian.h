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

// (mean [3], log-scale [3], quaternion wxyz [4], not necessarily unit, opacity) -> prim.
template <typename T>
RFIR_HD void preprocess_gaussian(const T* mean, const T* log_scale, const T* quat, T opacity, T* prim) {
  T w = quat[0], x = quat[1], y = quat[2], z = quat[3];
  const T inv_n = T(1) / r_sqrt(w * w + x * x + y * y + z * z);
  w *= inv_n; x *= inv_n; y *= inv_n; z *= inv_n;
  const T R[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - w * z),     2 * (x * z + w * y),
                  2 * (x * y + w * z),     1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                  2 * (x * z - w * y),     2 * (y * z + w * x),     1 - 2 * (x * x + y * y)};
  for (int i = 0; i < 3; ++i) {
    const T inv_s = r_exp(-log_scale[i]);
    prim[kMu + i] = mean[i];
    prim[kS + i] = r_exp(log_scale[i]);
    for (int j = 0; j < 3; ++j) prim[kM + 3 * i + j] = R[3 * j + i] * inv_s;  // M_ij = R_ji / s_i
  }
  prim[kOpa] = opacity;
}

// Axis-aligned half extents of the ellipsoid {maha <= kappa^2}: kappa sqrt(Sigma_kk),
// Sigma_kk = sum_j (R_kj s_j)^2 with R_kj s_j = M_jk s_j^2.
template <typename T>
RFIR_HD void gaussian_half_extent(const T* prim, T kappa, T* half) {
  const T* M = prim + kM;
  const T* s = prim + kS;
  for (int k = 0; k < 3; ++k) {
    T a = M[k] * s[0] * s[0], b = M[3 + k] * s[1] * s[1], c = M[6 + k] * s[2] * s[2];
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

// Returns false when the whitened direction is degenerate (never for finite inputs and d != 0)
// or, with cull_kappa2 > 0, when maha > cull_kappa2 for certain: Lagrange's identity
// |p' x d'|^2 = |p'|^2 |d'|^2 - (p'.d')^2 tests that before the square root and division, with
// a rounding slack so that no Gaussian within the bound is ever culled (most candidates of a BVH
// leaf miss, so this is the common exit).
template <typename T>
RFIR_HD bool peak_along_ray(const T* prim, const T* o, const T* d, Peak<T>& pk, T cull_kappa2 = T(-1)) {
  const T* M = prim + kM;
  const T p[3] = {prim[0] - o[0], prim[1] - o[1], prim[2] - o[2]};
  T dw[3];
  for (int i = 0; i < 3; ++i) {
    pk.pw[i] = M[3 * i] * p[0] + M[3 * i + 1] * p[1] + M[3 * i + 2] * p[2];
    dw[i] = M[3 * i] * d[0] + M[3 * i + 1] * d[1] + M[3 * i + 2] * d[2];
  }
  T len2 = dot3(dw, dw);
  if (cull_kappa2 > T(0) && len2 > T(1e-30) && len2 < T(1e30)) {
    const T pp = dot3(pk.pw, pk.pw), pd = dot3(pk.pw, dw);
    const T slack = sizeof(T) == 4 ? T(1e-4) : T(1e-10);
    if (pp * len2 - pd * pd > cull_kappa2 * len2 + slack * pp * len2) return false;
  }
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
//   v = 2 g_maha r + g_t u / |d'|,  dL/dmean = M^T v,
//   dL/dlog s_i = -r_i (v_i + g_t u_i / |d'|),
//   dL/dR_ji = (v_i q_j + (g_t / |d'|^2) r_i d_j) / s_i,  q = mu - x(t*) = R (s * r).
template <typename T>
RFIR_HD void peak_backward(const T* prim, const T* d, const Peak<T>& pk, T g_maha, T g_t, T* acc) {
  const T* M = prim + kM;
  const T* s = prim + kS;
  T c[3], r[3];
  cross3(pk.pw, pk.u, c);
  cross3(pk.u, c, r);
  const T ssr[3] = {s[0] * s[0] * r[0], s[1] * s[1] * r[1], s[2] * s[2] * r[2]};
  T q[3];
  for (int j = 0; j < 3; ++j) q[j] = M[j] * ssr[0] + M[3 + j] * ssr[1] + M[6 + j] * ssr[2];
  const T gu = g_t * pk.inv_len;
  const T beta = gu * pk.inv_len;
  T v[3], a[3], b[3];
  for (int i = 0; i < 3; ++i) {
    v[i] = 2 * g_maha * r[i] + gu * pk.u[i];
    acc[gLogS + i] -= r[i] * (v[i] + gu * pk.u[i]);
    const T inv_s = T(1) / s[i];
    a[i] = v[i] * inv_s;
    b[i] = beta * r[i] * inv_s;
  }
  for (int j = 0; j < 3; ++j) {
    acc[gMu + j] += M[j] * v[0] + M[3 + j] * v[1] + M[6 + j] * v[2];
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
