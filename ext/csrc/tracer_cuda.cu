// CUDA back-end: one thread per ray around the shared per-ray algorithm (trace_ray.h).
// Hit lists use two launches (count, then write at the scanned offsets); gradients are
// accumulated with atomicAdd (float64 atomics need sm_60 or newer).
#include "tracer_cuda.h"
#include "trace_ray.h"

namespace rfir {
namespace cuda {
namespace {

constexpr int kThreads = 128;

inline unsigned blocks_for(int64_t n) { return static_cast<unsigned>((n + kThreads - 1) / kThreads); }

template <typename T>
__global__ void preprocess_kernel(const T* means, const T* log_scales, const T* quats, const T* opacity,
                                  const int32_t* order, int64_t n, T* prims) {
  const int64_t k = blockIdx.x * int64_t(blockDim.x) + threadIdx.x;
  if (k >= n) return;
  const int64_t i = order ? order[k] : k;
  preprocess_gaussian(means + 3 * i, log_scales + 3 * i, quats + 4 * i, opacity[i], prims + kPrimStride * k);
}

template <typename T>
struct ArrayHitSink {
  int32_t* ids;
  T* t;
  T* g;
  int64_t pos;
  __device__ void push(int32_t id, T tt, T gg) {
    ids[pos] = id;
    t[pos] = tt;
    g[pos] = gg;
    ++pos;
  }
};

template <typename T>
__global__ void forward_kernel(SceneView<T> sc, RayBatch<T> rays, TraceParams p, ForwardOut<T> out,
                               const int64_t* offsets, int32_t* hit_ids, T* hit_t, T* hit_g) {
  const int64_t r = blockIdx.x * int64_t(blockDim.x) + threadIdx.x;
  if (r >= rays.n) return;
  if (offsets == nullptr) {
    NullHitSink sink;
    trace_ray_forward<T, kBufCuda>(sc, rays, r, p, out, sink);
  } else {
    ArrayHitSink<T> sink{hit_ids, hit_t, hit_g, offsets[r]};
    trace_ray_forward<T, kBufCuda>(sc, rays, r, p, out, sink);
  }
}

template <typename T>
struct AtomicGradSink {
  T* acc;
  T* gfeat;
  __device__ void add(int32_t id, const T* a) {
    T* dst = acc + int64_t(id) * kGradStride;
    for (int i = 0; i < kGradStride; ++i)
      if (a[i] != T(0)) atomicAdd(dst + i, a[i]);
  }
  __device__ void add_features(int32_t id, T w, const T* gF, int K) {
    T* dst = gfeat + int64_t(id) * K;
    for (int k = 0; k < K; ++k) atomicAdd(dst + k, w * gF[k]);
  }
};

template <typename T>
__global__ void backward_kernel(SceneView<T> sc, RayBatch<T> rays, TraceParams p, HitsView<T> hits,
                                ForwardOut<T> out, GradIn<T> g, T* acc, T* gfeat) {
  const int64_t r = blockIdx.x * int64_t(blockDim.x) + threadIdx.x;
  if (r >= rays.n) return;
  AtomicGradSink<T> sink{acc, gfeat};
  trace_ray_backward<T>(sc, rays, r, p, hits, out, g, sink);
}

template <typename T>
__global__ void quat_backward_kernel(const T* quats, const T* acc, int64_t n, T* g_quat) {
  const int64_t i = blockIdx.x * int64_t(blockDim.x) + threadIdx.x;
  if (i >= n) return;
  quat_backward(quats + 4 * i, acc + i * kGradStride + gRot, g_quat + 4 * i);
}

}  // namespace

template <typename T>
void launch_preprocess(const T* means, const T* log_scales, const T* quats, const T* opacity,
                       const int32_t* order, int64_t n, T* prims, cudaStream_t stream) {
  if (n == 0) return;
  preprocess_kernel<T><<<blocks_for(n), kThreads, 0, stream>>>(means, log_scales, quats, opacity, order, n, prims);
}

template <typename T>
void launch_forward(const SceneView<T>& sc, const RayBatch<T>& rays, const TraceParams& p,
                    const ForwardOut<T>& out, const int64_t* offsets, int32_t* hit_ids, T* hit_t,
                    T* hit_g, cudaStream_t stream) {
  if (rays.n == 0) return;
  forward_kernel<T><<<blocks_for(rays.n), kThreads, 0, stream>>>(sc, rays, p, out, offsets, hit_ids, hit_t, hit_g);
}

template <typename T>
void launch_backward(const SceneView<T>& sc, const RayBatch<T>& rays, const TraceParams& p,
                     const HitsView<T>& hits, const ForwardOut<T>& out, const GradIn<T>& g, T* acc,
                     T* gfeat, cudaStream_t stream) {
  if (rays.n == 0) return;
  backward_kernel<T><<<blocks_for(rays.n), kThreads, 0, stream>>>(sc, rays, p, hits, out, g, acc, gfeat);
}

template <typename T>
void launch_quat_backward(const T* quats, const T* acc, int64_t n, T* g_quat, cudaStream_t stream) {
  if (n == 0) return;
  quat_backward_kernel<T><<<blocks_for(n), kThreads, 0, stream>>>(quats, acc, n, g_quat);
}

#define RFIR_INSTANTIATE(T)                                                                           \
  template void launch_preprocess<T>(const T*, const T*, const T*, const T*, const int32_t*, int64_t, \
                                     T*, cudaStream_t);                                              \
  template void launch_forward<T>(const SceneView<T>&, const RayBatch<T>&, const TraceParams&,       \
                                  const ForwardOut<T>&, const int64_t*, int32_t*, T*, T*,             \
                                  cudaStream_t);                                                      \
  template void launch_backward<T>(const SceneView<T>&, const RayBatch<T>&, const TraceParams&,      \
                                   const HitsView<T>&, const ForwardOut<T>&, const GradIn<T>&, T*,    \
                                   T*, cudaStream_t);                                                 \
  template void launch_quat_backward<T>(const T*, const T*, int64_t, T*, cudaStream_t);

RFIR_INSTANTIATE(float)
RFIR_INSTANTIATE(double)
#undef RFIR_INSTANTIATE

}  // namespace cuda
}  // namespace rfir
