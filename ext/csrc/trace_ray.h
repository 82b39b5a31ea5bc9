// The per-ray algorithm, shared verbatim by the CPU (OpenMP) and CUDA back-ends.
//
// Forward: hits are gathered in passes with a fixed-size sorted buffer of the C nearest hits
// whose key (t*, id) is greater than the last composited key (a "k-buffer"). Each pass traverses
// the BVH near-child-first and prunes nodes that start beyond the farthest buffered hit once the
// buffer is full; the buffered hits are composited front to back; the next pass starts after the
// last composited key. The result is exactly "sort all hits by (t*, id) and composite", with
// fixed memory per ray and early stopping once transmittance < t_stop.
// Backward: walks the ray's hit list (CSR, as recorded by the forward) front to back using the
// standard adjoint of alpha compositing, dL/dalpha_i = T_i g.v_i - (g.Out - sum_{j<=i} w_j g.v_j
// + g_T T_final) / (1 - alpha_i), where v_i are the per-hit channels (features, t*, t*^2, normal).
#pragma once

#include "common.h"
#include "gaussian.h"

namespace rfir {

template <typename T, int C>
struct HitBuffer {
  int n;
  T t[C];
  T G[C];
  T alpha[C];
  int32_t id[C];

  RFIR_HD static bool before(T ta, int32_t ia, T tb, int32_t ib) {
    return ta < tb || (ta == tb && ia < ib);
  }
  // Keeps the C smallest keys, sorted ascending.
  RFIR_HD void insert(T tt, int32_t i, T g, T a) {
    int pos;
    if (n == C) {
      if (!before(tt, i, t[C - 1], id[C - 1])) return;
      pos = C - 1;
    } else {
      pos = n++;
    }
    while (pos > 0 && before(tt, i, t[pos - 1], id[pos - 1])) {
      t[pos] = t[pos - 1]; G[pos] = G[pos - 1]; alpha[pos] = alpha[pos - 1]; id[pos] = id[pos - 1];
      --pos;
    }
    t[pos] = tt; G[pos] = g; alpha[pos] = a; id[pos] = i;
  }
};

// Slab test in float. On success `entry` is where the ray enters the box (clamped to lo).
RFIR_HD bool ray_box(const BVHNode& nd, const float* o, const float* inv, float lo, float hi,
                     float& entry) {
  float t0 = lo, t1 = hi;
  for (int a = 0; a < 3; ++a) {
    float ta = (nd.lo[a] - o[a]) * inv[a];
    float tb = (nd.hi[a] - o[a]) * inv[a];
    // plain compares (inlined to minss/maxss); a NaN from 0 * inf leaves t0 / t1 unchanged
    const float tn = ta < tb ? ta : tb, tf = ta < tb ? tb : ta;
    t0 = tn > t0 ? tn : t0;
    t1 = tf < t1 ? tf : t1;
  }
  entry = t0;
  return t0 <= t1;
}

// Conservative float version of a t bound (the boxes are tested in float, the hits in T).
template <typename T>
RFIR_HD float widen_lo(T v) {
  float f = static_cast<float>(v);
  return f - 1e-5f * fabsf(f) - 1e-7f;
}
template <typename T>
RFIR_HD float widen_hi(T v) {
  float f = static_cast<float>(v);
  return f + 1e-5f * fabsf(f) + 1e-7f;
}

// The acceptance rules every traversal shares: the peak lies inside the bound (maha <= kappa2)
// and inside (t_lo, t_hi), and alpha = min(opacity G, alpha_max) >= alpha_min.
template <typename T>
RFIR_HD bool accept_candidate(const T* prim, const T* o, const T* d, T t_lo, T t_hi, T kappa2, T amin, T amax,
                              Peak<T>& pk, T& G, T& alpha) {
  if (!peak_along_ray(prim, o, d, pk, kappa2)) return false;
  if (!(pk.maha <= kappa2) || !(pk.t > t_lo && pk.t < t_hi)) return false;
  G = r_exp(T(-0.5) * pk.maha);
  alpha = prim[kOpa] * G;
  alpha = alpha > amax ? amax : alpha;
  return alpha >= amin;
}

// One pass: fill buf with the C nearest accepted hits with key > (last_t, last_id).
template <typename T, int C>
RFIR_HD void collect_hits(const SceneView<T>& sc, const T* o, const T* d, T t_lo, T t_hi,
                          T last_t, int32_t last_id, int32_t exclude, const TraceParams& p,
                          HitBuffer<T, C>& buf, int32_t& evals) {
  buf.n = 0;
  if (sc.n_nodes == 0) return;
  const float of[3] = {float(o[0]), float(o[1]), float(o[2])};
  const float inv[3] = {1.f / float(d[0]), 1.f / float(d[1]), 1.f / float(d[2])};
  const float lo = widen_lo(last_t > t_lo ? last_t : t_lo);
  const float hi = widen_hi(t_hi);
  const T kappa2 = T(p.kappa2), amin = T(p.alpha_min), amax = T(p.alpha_max);
  int stack_node[64];
  float stack_entry[64];
  int sp = 0;
  float entry;
  if (!ray_box(sc.nodes[0], of, inv, lo, hi, entry)) return;
  int node = 0;
  while (true) {
    const BVHNode& nd = sc.nodes[node];
    const float cut = buf.n == C ? widen_hi(buf.t[C - 1]) : hi;
    if (nd.count > 0) {
      for (int k = nd.first; k < nd.first + nd.count; ++k) {
        const int32_t id = sc.prim_order[k];
        if (id == exclude) continue;
        const T* prim = sc.prims + int64_t(k) * kPrimStride;
        ++evals;
        Peak<T> pk;
        T G, alpha;
        if (!accept_candidate(prim, o, d, t_lo, t_hi, kappa2, amin, amax, pk, G, alpha)) continue;
        if (pk.t < last_t || (pk.t == last_t && id <= last_id)) continue;
        buf.insert(pk.t, id, G, alpha);
      }
    } else {
      float e0, e1;
      const bool h0 = ray_box(sc.nodes[nd.first], of, inv, lo, cut, e0);
      const bool h1 = ray_box(sc.nodes[nd.first + 1], of, inv, lo, cut, e1);
      if (h0 && h1) {
        const bool near0 = e0 <= e1;
        if (sp < 64) {
          stack_node[sp] = near0 ? nd.first + 1 : nd.first;
          stack_entry[sp] = near0 ? e1 : e0;
          ++sp;
        }
        node = near0 ? nd.first : nd.first + 1;
        continue;
      }
      if (h0 || h1) {
        node = h0 ? nd.first : nd.first + 1;
        continue;
      }
    }
    // pop, skipping subtrees that now start beyond the farthest buffered hit
    bool found = false;
    while (sp > 0) {
      --sp;
      const float c2 = buf.n == C ? widen_hi(buf.t[C - 1]) : hi;
      if (stack_entry[sp] <= c2) {
        node = stack_node[sp];
        found = true;
        break;
      }
    }
    if (!found) return;
  }
}

// Sinks receive each composited hit in order: CPU appends to a per-thread vector, CUDA counts
// or writes into a pre-sized CSR array.
struct NullHitSink {
  RFIR_HD void push(int32_t, double, double) {}
};

template <typename T, int C, class Sink>
RFIR_HD void trace_ray_forward(const SceneView<T>& sc, const RayBatch<T>& rays, int64_t r,
                               const TraceParams& p, const ForwardOut<T>& out, Sink& sink) {
  const T* o = rays.origins + 3 * r;
  const T* d = rays.dirs + 3 * r;
  const T t_lo = rays.t_min[r], t_hi = rays.t_max[r];
  const int32_t exclude = rays.exclude ? rays.exclude[r] : -1;
  const int K = sc.k;
  T* F = out.features + r * K;
  for (int k = 0; k < K; ++k) F[k] = T(0);
  T D = 0, D2 = 0, N[3] = {0, 0, 0}, Tr = 1;
  int32_t count = 0, evals = 0;
  T last_t = -INFINITY;
  int32_t last_id = -1;
  HitBuffer<T, C> buf;
  bool done = false;
  while (!done) {
    collect_hits<T, C>(sc, o, d, t_lo, t_hi, last_t, last_id, exclude, p, buf, evals);
    for (int i = 0; i < buf.n; ++i) {
      const int32_t id = buf.id[i];
      const T t = buf.t[i], a = buf.alpha[i], w = a * Tr;
      const T* f = sc.features + int64_t(id) * K;
      for (int k = 0; k < K; ++k) F[k] += w * f[k];
      D += w * t;
      D2 += w * t * t;
      if (sc.normals) {
        const T* n = sc.normals + 3 * int64_t(id);
        N[0] += w * n[0]; N[1] += w * n[1]; N[2] += w * n[2];
      }
      sink.push(id, t, buf.G[i]);
      Tr *= T(1) - a;
      ++count;
      if (Tr < T(p.t_stop)) { done = true; break; }
    }
    if (buf.n < C) done = true;
    if (!done) { last_t = buf.t[C - 1]; last_id = buf.id[C - 1]; }
  }
  out.depth[r] = D;
  out.depth_sq[r] = D2;
  out.normal[3 * r] = N[0]; out.normal[3 * r + 1] = N[1]; out.normal[3 * r + 2] = N[2];
  out.transmittance[r] = Tr;
  out.count[r] = count;
  if (out.evals) out.evals[r] = evals;
}

// Transmittance only: the product over accepted hits of (1 - alpha), taken in traversal order
// (a product does not depend on the order), stopping as soon as it falls below t_stop. Same
// acceptance rules as collect_hits; without early stopping the result equals trace_ray_forward's
// transmittance, with it both are below t_stop. One traversal and no hit buffer: the fast path
// for frozen visibility (segments to many targets). Near-child-first order meets the occluders
// closest to the origin first, so occluded segments stop early.
template <typename T>
RFIR_HD T trace_ray_transmittance(const SceneView<T>& sc, const RayBatch<T>& rays, int64_t r,
                                  const TraceParams& p, int32_t& evals) {
  evals = 0;
  if (sc.n_nodes == 0) return T(1);
  const T* o = rays.origins + 3 * r;
  const T* d = rays.dirs + 3 * r;
  const T t_lo = rays.t_min[r], t_hi = rays.t_max[r];
  const int32_t exclude = rays.exclude ? rays.exclude[r] : -1;
  const float of[3] = {float(o[0]), float(o[1]), float(o[2])};
  const float inv[3] = {1.f / float(d[0]), 1.f / float(d[1]), 1.f / float(d[2])};
  const float lo = widen_lo(t_lo), hi = widen_hi(t_hi);
  const T kappa2 = T(p.kappa2), amin = T(p.alpha_min), amax = T(p.alpha_max), stop = T(p.t_stop);
  T Tr = 1;
  int stack[64];
  int sp = 0;
  float e0, e1;
  if (!ray_box(sc.nodes[0], of, inv, lo, hi, e0)) return Tr;
  int node = 0;
  while (true) {
    const BVHNode& nd = sc.nodes[node];
    if (nd.count > 0) {
      for (int k = nd.first; k < nd.first + nd.count; ++k) {
        const int32_t id = sc.prim_order[k];
        if (id == exclude) continue;
        const T* prim = sc.prims + int64_t(k) * kPrimStride;
        ++evals;
        Peak<T> pk;
        T G, alpha;
        if (!accept_candidate(prim, o, d, t_lo, t_hi, kappa2, amin, amax, pk, G, alpha)) continue;
        Tr *= T(1) - alpha;
        if (Tr < stop) return Tr;
      }
    } else {
      const bool h0 = ray_box(sc.nodes[nd.first], of, inv, lo, hi, e0);
      const bool h1 = ray_box(sc.nodes[nd.first + 1], of, inv, lo, hi, e1);
      if (h0 && h1) {
        const bool near0 = e0 <= e1;
        if (sp < 64) stack[sp++] = near0 ? nd.first + 1 : nd.first;
        node = near0 ? nd.first : nd.first + 1;
        continue;
      }
      if (h0 || h1) {
        node = h0 ? nd.first : nd.first + 1;
        continue;
      }
    }
    if (sp == 0) return Tr;
    node = stack[--sp];
  }
}

// GradSink needs add(id, const T* acc /*kGradStride*/) and add_features(id, T w, const T* gF, K).
template <typename T, class GradSink>
RFIR_HD void trace_ray_backward(const SceneView<T>& sc, const RayBatch<T>& rays, int64_t r,
                                const TraceParams& p, const HitsView<T>& hits,
                                const ForwardOut<T>& out, const GradIn<T>& g, GradSink& gs) {
  const T* o = rays.origins + 3 * r;
  const T* d = rays.dirs + 3 * r;
  const int K = sc.k;
  const T* F = out.features + r * K;
  const T* gF = g.features + r * K;
  const T gD = g.depth[r], gD2 = g.depth_sq[r], gT = g.transmittance[r];
  const T gN[3] = {g.normal[3 * r], g.normal[3 * r + 1], g.normal[3 * r + 2]};
  T gout = gD * out.depth[r] + gD2 * out.depth_sq[r] + gN[0] * out.normal[3 * r] +
           gN[1] * out.normal[3 * r + 1] + gN[2] * out.normal[3 * r + 2];
  for (int k = 0; k < K; ++k) gout += gF[k] * F[k];
  const T t_fin = out.transmittance[r];
  const T amax = T(p.alpha_max);
  T Tr = 1, S = 0;
  for (int64_t h = hits.offsets[r]; h < hits.offsets[r + 1]; ++h) {
    const int32_t id = hits.ids[h];
    const T* prim = sc.prims + int64_t(id) * kPrimStride;
    Peak<T> pk;
    peak_along_ray(prim, o, d, pk);
    const T t = pk.t;
    const T G = r_exp(T(-0.5) * pk.maha);
    const T opa = prim[kOpa];
    const bool clamped = opa * G > amax;
    const T alpha = clamped ? amax : opa * G;
    const T* f = sc.features + int64_t(id) * K;
    T gv = gD * t + gD2 * t * t;
    for (int k = 0; k < K; ++k) gv += gF[k] * f[k];
    if (sc.normals) {
      const T* n = sc.normals + 3 * int64_t(id);
      gv += gN[0] * n[0] + gN[1] * n[1] + gN[2] * n[2];
    }
    const T w = alpha * Tr;
    S += w * gv;
    const T one_m = T(1) - alpha;
    const T g_alpha = Tr * gv - (gout - S + gT * t_fin) / one_m;
    const T g_t = w * (gD + 2 * gD2 * t);
    const T g_G = clamped ? T(0) : g_alpha * opa;
    T acc[kGradStride];
    for (int i = 0; i < kGradStride; ++i) acc[i] = T(0);
    peak_backward(prim, d, pk, T(-0.5) * G * g_G, g_t, acc);
    acc[gOpa] = clamped ? T(0) : g_alpha * G;
    for (int i = 0; i < 3; ++i) acc[gNrm + i] = w * gN[i];
    gs.add(id, acc);
    if (K > 0) gs.add_features(id, w, gF, K);
    Tr *= one_m;
  }
}

}  // namespace rfir
