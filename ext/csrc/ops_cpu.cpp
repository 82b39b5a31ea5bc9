// CPU back-end: OpenMP loops over rays around the shared per-ray algorithm (trace_ray.h).
//
// Forward: dynamic schedule; composited hits go to per-thread vectors and are gathered into CSR.
// Backward: static schedule with per-thread gradient buffers reduced at the end, so the result is
// deterministic for a given thread count; the thread count is capped so the buffers stay within
// kGradBufferBytes.
#include <omp.h>

#include <algorithm>
#include <vector>

#include "ops.h"
#include "trace_ray.h"

namespace rfir {
namespace {

constexpr int kBufCpu = 64;                      // k-buffer size per ray
constexpr int64_t kGradBufferBytes = 1LL << 30;  // cap on per-thread gradient buffers
constexpr int64_t kMinParallel = 512;            // smaller loops run on one thread (no fork cost)

// Prims in BVH leaf order (bvh_order) for the forward pass, or by Gaussian id.
template <typename T>
torch::Tensor preprocess(const SceneTensors& s, bool bvh_order) {
  const int64_t n = s.means.size(0);
  auto prims = torch::empty({n, kPrimStride}, s.means.options());
  const T* m = s.means.data_ptr<T>();
  const T* l = s.log_scales.data_ptr<T>();
  const T* q = s.rotations.data_ptr<T>();
  const T* a = s.opacities.data_ptr<T>();
  const int32_t* order = s.prim_order.data_ptr<int32_t>();
  T* out = prims.data_ptr<T>();
#pragma omp parallel for schedule(static) if (n > 8 * kMinParallel)
  for (int64_t k = 0; k < n; ++k) {
    const int64_t i = bvh_order ? order[k] : k;
    preprocess_gaussian(m + 3 * i, l + 3 * i, q + 4 * i, a[i], out + kPrimStride * k);
  }
  return prims;
}

template <typename T>
struct VectorSink {
  std::vector<int32_t>* ids;
  std::vector<T>* t;
  std::vector<T>* g;
  void push(int32_t id, T tt, T gg) {
    ids->push_back(id);
    t->push_back(tt);
    g->push_back(gg);
  }
};

template <typename T>
std::vector<torch::Tensor> forward_impl(const SceneTensors& s, const RayTensors& r,
                                        const TraceParams& p, bool want_hits) {
  const torch::Tensor prims = preprocess<T>(s, true);
  const int64_t R = r.origins.size(0);
  const int64_t K = s.features.size(1);
  auto opt = s.means.options();
  auto feat = torch::empty({R, K}, opt), depth = torch::empty({R}, opt);
  auto depth_sq = torch::empty({R}, opt), normal = torch::empty({R, 3}, opt);
  auto trans = torch::empty({R}, opt);
  auto count = torch::empty({R}, opt.dtype(torch::kInt32));
  auto evals = torch::empty({R}, opt.dtype(torch::kInt32));
  const ForwardOut<T> fo{feat.data_ptr<T>(), depth.data_ptr<T>(), depth_sq.data_ptr<T>(),
                         normal.data_ptr<T>(), trans.data_ptr<T>(), count.data_ptr<int32_t>(),
                         evals.data_ptr<int32_t>()};
  const SceneView<T> sc = make_scene_view<T>(s, prims);
  const RayBatch<T> rb = make_ray_batch<T>(r);
  auto offsets = torch::zeros({R + 1}, opt.dtype(torch::kInt64));
  if (!want_hits) {
#pragma omp parallel for schedule(dynamic, 32) if (R > kMinParallel)
    for (int64_t i = 0; i < R; ++i) {
      NullHitSink sink;
      trace_ray_forward<T, kBufCpu>(sc, rb, i, p, fo, sink);
    }
    auto e = torch::empty({0}, opt);
    return {feat, depth, depth_sq, normal, trans, count, offsets,
            torch::empty({0}, opt.dtype(torch::kInt32)), e, e.clone(), evals};
  }
  const int nth = R > kMinParallel ? omp_get_max_threads() : 1;
  std::vector<std::vector<int32_t>> ids(nth);
  std::vector<std::vector<T>> ts(nth), gs(nth);
  std::vector<int64_t> start(R);
  std::vector<int32_t> owner(R);
#pragma omp parallel num_threads(nth)
  {
    const int tid = omp_get_thread_num();
    VectorSink<T> sink{&ids[tid], &ts[tid], &gs[tid]};
#pragma omp for schedule(dynamic, 32)
    for (int64_t i = 0; i < R; ++i) {
      start[i] = static_cast<int64_t>(ids[tid].size());
      owner[i] = tid;
      trace_ray_forward<T, kBufCpu>(sc, rb, i, p, fo, sink);
    }
  }
  int64_t* off = offsets.data_ptr<int64_t>();
  const int32_t* cnt = fo.count;
  for (int64_t i = 0; i < R; ++i) off[i + 1] = off[i] + cnt[i];
  const int64_t H = off[R];
  auto hit_ids = torch::empty({H}, opt.dtype(torch::kInt32));
  auto hit_t = torch::empty({H}, opt), hit_g = torch::empty({H}, opt);
  int32_t* hi = hit_ids.data_ptr<int32_t>();
  T* ht = hit_t.data_ptr<T>();
  T* hg = hit_g.data_ptr<T>();
#pragma omp parallel for schedule(static) if (H > 64 * kMinParallel)
  for (int64_t i = 0; i < R; ++i) {
    const int o = owner[i];
    std::copy_n(ids[o].data() + start[i], cnt[i], hi + off[i]);
    std::copy_n(ts[o].data() + start[i], cnt[i], ht + off[i]);
    std::copy_n(gs[o].data() + start[i], cnt[i], hg + off[i]);
  }
  return {feat, depth, depth_sq, normal, trans, count, offsets, hit_ids, hit_t, hit_g, evals};
}

template <typename T>
std::vector<torch::Tensor> transmittance_impl(const SceneTensors& s, const RayTensors& r, const TraceParams& p) {
  const torch::Tensor prims = preprocess<T>(s, true);
  const int64_t R = r.origins.size(0);
  auto trans = torch::empty({R}, s.means.options());
  auto evals = torch::empty({R}, s.means.options().dtype(torch::kInt32));
  T* tp = trans.data_ptr<T>();
  int32_t* ep = evals.data_ptr<int32_t>();
  const SceneView<T> sc = make_scene_view<T>(s, prims);
  const RayBatch<T> rb = make_ray_batch<T>(r);
#pragma omp parallel for schedule(dynamic, 64) if (R > kMinParallel)
  for (int64_t i = 0; i < R; ++i) tp[i] = trace_ray_transmittance<T>(sc, rb, i, p, ep[i]);
  return {trans, evals};
}

template <typename T>
std::vector<torch::Tensor> footprint_sums_impl(const torch::Tensor& offsets, const torch::Tensor& ids,
                                               const torch::Tensor& t, const torch::Tensor& response,
                                               const torch::Tensor& opacities, const torch::Tensor& group_offsets,
                                               const torch::Tensor& ray_weight, double margin, double alpha_max) {
  const int64_t M = group_offsets.size(0) - 1, N = opacities.size(0);
  auto num = torch::zeros({M, N}, t.options()), den = torch::zeros({M, N}, t.options());
  const int64_t* off = offsets.data_ptr<int64_t>();
  const int64_t* grp = group_offsets.data_ptr<int64_t>();
  const int32_t* id = ids.data_ptr<int32_t>();
  const T* tt = t.data_ptr<T>();
  const T* g = response.data_ptr<T>();
  const T* a = opacities.data_ptr<T>();
  const T* w = ray_weight.data_ptr<T>();
  T* np_ = num.data_ptr<T>();
  T* dp = den.data_ptr<T>();
  const T m = T(margin), amax = T(alpha_max);
  // one group per iteration: its rays write only into its own row, so threads never collide
#pragma omp parallel for schedule(dynamic, 1) if (M > 1 && off[grp[M]] > 64 * kMinParallel)
  for (int64_t k = 0; k < M; ++k) {
    T* nk = np_ + k * N;
    T* dk = dp + k * N;
    for (int64_t r = grp[k]; r < grp[k + 1]; ++r) {
      int64_t j = off[r];
      T tr = 1;
      for (int64_t h = off[r]; h < off[r + 1]; ++h) {
        for (; j < h && tt[j] < tt[h] - m; ++j) {
          const T alpha = a[id[j]] * g[j];
          tr *= T(1) - (alpha > amax ? amax : alpha);
        }
        const T wg = w[r] * g[h];
        dk[id[h]] += wg;
        nk[id[h]] += wg * tr;
      }
    }
  }
  return {num, den};
}

template <typename T>
struct BufferGradSink {
  T* acc;    // [N, kGradStride] of this thread
  T* gfeat;  // [N, K] of this thread
  void add(int32_t id, const T* a) {
    T* dst = acc + int64_t(id) * kGradStride;
    for (int i = 0; i < kGradStride; ++i) dst[i] += a[i];
  }
  void add_features(int32_t id, T w, const T* gF, int K) {
    T* dst = gfeat + int64_t(id) * K;
    for (int k = 0; k < K; ++k) dst[k] += w * gF[k];
  }
};

template <typename T>
std::vector<torch::Tensor> backward_impl(const SceneTensors& s, const RayTensors& r,
                                         const TraceParams& p, const std::vector<torch::Tensor>& outs,
                                         const std::vector<torch::Tensor>& grads,
                                         const torch::Tensor& hit_offsets, const torch::Tensor& hit_ids,
                                         const torch::Tensor& hit_t) {
  const torch::Tensor prims = preprocess<T>(s, false);
  const int64_t R = r.origins.size(0), N = s.means.size(0), K = s.features.size(1);
  const int64_t per_thread = std::max<int64_t>(1, N * (kGradStride + K) * int64_t(sizeof(T)));
  const int max_threads = R > kMinParallel ? omp_get_max_threads() : 1;
  const int nth = static_cast<int>(
      std::max<int64_t>(1, std::min<int64_t>(max_threads, kGradBufferBytes / per_thread)));
  auto opt = s.means.options();
  auto acc = torch::zeros({nth, N, kGradStride}, opt);
  auto gfeat = torch::zeros({nth, N, K}, opt);
  const SceneView<T> sc = make_scene_view<T>(s, prims);
  const RayBatch<T> rb = make_ray_batch<T>(r);
  const ForwardOut<T> fo{outs[0].data_ptr<T>(), outs[1].data_ptr<T>(), outs[2].data_ptr<T>(),
                         outs[3].data_ptr<T>(), outs[4].data_ptr<T>(), nullptr, nullptr};
  const GradIn<T> gi{grads[0].data_ptr<T>(), grads[1].data_ptr<T>(), grads[2].data_ptr<T>(),
                     grads[3].data_ptr<T>(), grads[4].data_ptr<T>()};
  const HitsView<T> hv{hit_offsets.data_ptr<int64_t>(), hit_ids.data_ptr<int32_t>(), hit_t.data_ptr<T>()};
  T* accp = acc.data_ptr<T>();
  T* gfp = gfeat.data_ptr<T>();
#pragma omp parallel num_threads(nth)
  {
    const int tid = omp_get_thread_num();
    BufferGradSink<T> sink{accp + tid * N * kGradStride, gfp + tid * N * K};
#pragma omp for schedule(static, 64)
    for (int64_t i = 0; i < R; ++i) trace_ray_backward<T>(sc, rb, i, p, hv, fo, gi, sink);
  }
  auto a = nth > 1 ? acc.sum(0) : acc[0];
  auto g_feat = nth > 1 ? gfeat.sum(0) : gfeat[0];
  a = a.contiguous();
  auto g_rot = torch::empty({N, 4}, opt);
  const T* ap = a.data_ptr<T>();
  const T* qp = s.rotations.data_ptr<T>();
  T* grp = g_rot.data_ptr<T>();
#pragma omp parallel for schedule(static) if (N > 8 * kMinParallel)
  for (int64_t i = 0; i < N; ++i) quat_backward(qp + 4 * i, ap + i * kGradStride + gRot, grp + 4 * i);
  return {a.slice(1, gMu, gMu + 3).contiguous(), a.slice(1, gLogS, gLogS + 3).contiguous(), g_rot,
          a.select(1, gOpa).contiguous(), a.slice(1, gNrm, gNrm + 3).contiguous(), g_feat.contiguous()};
}

}  // namespace

std::vector<torch::Tensor> forward_cpu(const SceneTensors& s, const RayTensors& r,
                                       const TraceParams& p, bool want_hits) {
  if (s.means.scalar_type() == torch::kFloat64) return forward_impl<double>(s, r, p, want_hits);
  return forward_impl<float>(s, r, p, want_hits);
}

std::vector<torch::Tensor> transmittance_cpu(const SceneTensors& s, const RayTensors& r, const TraceParams& p) {
  if (s.means.scalar_type() == torch::kFloat64) return transmittance_impl<double>(s, r, p);
  return transmittance_impl<float>(s, r, p);
}

std::vector<torch::Tensor> footprint_sums_cpu(const torch::Tensor& offsets, const torch::Tensor& ids,
                                              const torch::Tensor& t, const torch::Tensor& response,
                                              const torch::Tensor& opacities, const torch::Tensor& group_offsets,
                                              const torch::Tensor& ray_weight, double margin, double alpha_max) {
  if (t.scalar_type() == torch::kFloat64)
    return footprint_sums_impl<double>(offsets, ids, t, response, opacities, group_offsets, ray_weight, margin,
                                       alpha_max);
  return footprint_sums_impl<float>(offsets, ids, t, response, opacities, group_offsets, ray_weight, margin,
                                    alpha_max);
}

std::vector<torch::Tensor> backward_cpu(const SceneTensors& s, const RayTensors& r,
                                        const TraceParams& p, const std::vector<torch::Tensor>& outs,
                                        const std::vector<torch::Tensor>& grads,
                                        const torch::Tensor& hit_offsets, const torch::Tensor& hit_ids,
                                        const torch::Tensor& hit_t) {
  if (s.means.scalar_type() == torch::kFloat64)
    return backward_impl<double>(s, r, p, outs, grads, hit_offsets, hit_ids, hit_t);
  return backward_impl<float>(s, r, p, outs, grads, hit_offsets, hit_ids, hit_t);
}

}  // namespace rfir
