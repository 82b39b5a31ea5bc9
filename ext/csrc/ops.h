// Torch-level entry points of the extension (declarations). bindings.cpp checks arguments and
// dispatches to the CPU (ops_cpu.cpp) or CUDA (ops_cuda.cpp + tracer_cuda.cu) implementation.
#pragma once

#include <torch/extension.h>

#include <vector>

#include "common.h"

namespace rfir {

// Scene tensors, all on one device, one float dtype (float32 or float64), contiguous.
struct SceneTensors {
  torch::Tensor means;       // [N, 3] metres
  torch::Tensor log_scales;  // [N, 3] log metres
  torch::Tensor rotations;   // [N, 4] quaternion wxyz, any non-zero norm
  torch::Tensor opacities;   // [N] in [0, 1]
  torch::Tensor normals;     // [N, 3]
  torch::Tensor features;    // [N, K]
  torch::Tensor nodes;       // [n_nodes, 8] int32 (BVHNode), on the scene's device
  torch::Tensor prim_order;  // [N] int32
};

struct RayTensors {
  torch::Tensor origins;  // [R, 3]
  torch::Tensor dirs;     // [R, 3]
  torch::Tensor t_min;    // [R]
  torch::Tensor t_max;    // [R]
  torch::Tensor exclude;  // [R] int32 (-1: none) or undefined
};

// Forward returns {features [R,K], depth [R], depth_sq [R], normal [R,3], transmittance [R],
// count [R] int32, hit_offsets [R+1] int64, hit_ids [H] int32, hit_t [H], hit_response [H],
// evaluations [R] int32}.
// Without want_hits the four hit tensors are empty (offsets all zero).
std::vector<torch::Tensor> forward_cpu(const SceneTensors& s, const RayTensors& r,
                                       const TraceParams& p, bool want_hits);
// Transmittance only (no features, no hit lists, hits multiplied in traversal order, early stop):
// returns {transmittance [R], evaluations [R] int32}.
std::vector<torch::Tensor> transmittance_cpu(const SceneTensors& s, const RayTensors& r, const TraceParams& p);
// Footprint sums on CSR hit lists sorted front to back per ray (offsets [R+1] int64, ids [H]
// int32, t [H], response G [H]); rays come in groups (group_offsets [M+1] int64 over the rays)
// with weights w [R]. With T_h = prod of (1 - min(a G, alpha_max)) over the hits of the same ray
// with t < t_h - margin: den[k, i] = sum w_r G_h and num[k, i] = sum w_r G_h T_h over the hits h
// of Gaussian i on the rays of group k. Returns {num [M, N], den [M, N]}.
std::vector<torch::Tensor> footprint_sums_cpu(const torch::Tensor& offsets, const torch::Tensor& ids,
                                              const torch::Tensor& t, const torch::Tensor& response,
                                              const torch::Tensor& opacities, const torch::Tensor& group_offsets,
                                              const torch::Tensor& ray_weight, double margin, double alpha_max);
// Backward returns {g_means, g_log_scales, g_rotations, g_opacities, g_normals, g_features}.
// outs = {features, depth, depth_sq, normal, transmittance}; grads likewise.
std::vector<torch::Tensor> backward_cpu(const SceneTensors& s, const RayTensors& r,
                                        const TraceParams& p, const std::vector<torch::Tensor>& outs,
                                        const std::vector<torch::Tensor>& grads,
                                        const torch::Tensor& hit_offsets, const torch::Tensor& hit_ids,
                                        const torch::Tensor& hit_t);

#ifdef RFIR_WITH_CUDA
std::vector<torch::Tensor> forward_cuda(const SceneTensors& s, const RayTensors& r,
                                        const TraceParams& p, bool want_hits);
std::vector<torch::Tensor> backward_cuda(const SceneTensors& s, const RayTensors& r,
                                         const TraceParams& p, const std::vector<torch::Tensor>& outs,
                                         const std::vector<torch::Tensor>& grads,
                                         const torch::Tensor& hit_offsets, const torch::Tensor& hit_ids,
                                         const torch::Tensor& hit_t);
#endif

// BVH over the ellipsoids {maha <= kappa^2}; built on the CPU (inputs are copied there).
// Returns {nodes [n_nodes, 8] int32, prim_order [N] int32}.
std::vector<torch::Tensor> build_bvh(const torch::Tensor& means, const torch::Tensor& log_scales,
                                     const torch::Tensor& rotations, double kappa, int64_t leaf_size);
// Recomputes the node bounds for moved Gaussians, keeping the topology. Returns new nodes.
torch::Tensor refit_bvh(const torch::Tensor& nodes, const torch::Tensor& prim_order,
                        const torch::Tensor& means, const torch::Tensor& log_scales,
                        const torch::Tensor& rotations, double kappa);

// Typed views over the tensors (shared by both back-ends).
template <typename T>
SceneView<T> make_scene_view(const SceneTensors& s, const torch::Tensor& prims) {
  SceneView<T> v;
  v.prims = prims.data_ptr<T>();
  v.opacity = s.opacities.data_ptr<T>();
  v.normals = s.normals.numel() ? s.normals.data_ptr<T>() : nullptr;
  v.k = static_cast<int>(s.features.size(1));
  v.features = v.k ? s.features.data_ptr<T>() : nullptr;
  v.n = s.means.size(0);
  v.nodes = reinterpret_cast<const BVHNode*>(s.nodes.data_ptr<int32_t>());
  v.n_nodes = s.nodes.size(0);
  v.prim_order = s.prim_order.data_ptr<int32_t>();
  return v;
}

template <typename T>
RayBatch<T> make_ray_batch(const RayTensors& r) {
  RayBatch<T> b;
  b.origins = r.origins.data_ptr<T>();
  b.dirs = r.dirs.data_ptr<T>();
  b.t_min = r.t_min.data_ptr<T>();
  b.t_max = r.t_max.data_ptr<T>();
  b.exclude = r.exclude.defined() && r.exclude.numel() ? r.exclude.data_ptr<int32_t>() : nullptr;
  b.n = r.origins.size(0);
  return b;
}

}  // namespace rfir
