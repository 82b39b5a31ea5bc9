// CUDA launchers (torch-free; implemented in tracer_cuda.cu, called from ops_cuda.cpp).
#pragma once

#include <cuda_runtime.h>

#include "common.h"

namespace rfir {
namespace cuda {

constexpr int kBufCuda = 16;  // k-buffer size per ray on the GPU (registers / local memory)

// prims[k] = preprocess(Gaussian order ? order[k] : k).
template <typename T>
void launch_preprocess(const T* means, const T* log_scales, const T* quats, const T* opacity,
                       const int32_t* order, int64_t n, T* prims, cudaStream_t stream);

// Forward over all rays. With offsets == nullptr only the outputs and counts are written;
// otherwise the composited hits of ray r are written at offsets[r] .. offsets[r+1].
template <typename T>
void launch_forward(const SceneView<T>& sc, const RayBatch<T>& rays, const TraceParams& p,
                    const ForwardOut<T>& out, const int64_t* offsets, int32_t* hit_ids, T* hit_t,
                    T* hit_g, cudaStream_t stream);

// Backward over all rays; atomically accumulates into acc [N, kGradStride] and gfeat [N, K].
template <typename T>
void launch_backward(const SceneView<T>& sc, const RayBatch<T>& rays, const TraceParams& p,
                     const HitsView<T>& hits, const ForwardOut<T>& out, const GradIn<T>& g, T* acc,
                     T* gfeat, cudaStream_t stream);

// dL/dR in acc -> dL/dquat [N, 4].
template <typename T>
void launch_quat_backward(const T* quats, const T* acc, int64_t n, T* g_quat, cudaStream_t stream);

}  // namespace cuda
}  // namespace rfir
