// CUDA back-end, torch side: allocation, the count/scan/write scheme for hit lists, and the
// gradient epilogue. Compiled to nothing unless setup.py found a CUDA toolkit and a CUDA torch.
#ifdef RFIR_WITH_CUDA

#include <c10/cuda/CUDAGuard.h>
#include <c10/cuda/CUDAStream.h>

#include "ops.h"
#include "tracer_cuda.h"

namespace rfir {
namespace {

template <typename T>
torch::Tensor preprocess(const SceneTensors& s, bool bvh_order, cudaStream_t stream) {
  const int64_t n = s.means.size(0);
  auto prims = torch::empty({n, kPrimStride}, s.means.options());
  cuda::launch_preprocess<T>(s.means.data_ptr<T>(), s.log_scales.data_ptr<T>(), s.rotations.data_ptr<T>(),
                             s.opacities.data_ptr<T>(), bvh_order ? s.prim_order.data_ptr<int32_t>() : nullptr,
                             n, prims.data_ptr<T>(), stream);
  return prims;
}

template <typename T>
std::vector<torch::Tensor> forward_impl(const SceneTensors& s, const RayTensors& r,
                                        const TraceParams& p, bool want_hits) {
  const c10::cuda::CUDAGuard guard(s.means.device());
  const cudaStream_t stream = c10::cuda::getCurrentCUDAStream();
  const torch::Tensor prims = preprocess<T>(s, true, stream);
  const int64_t R = r.origins.size(0), K = s.features.size(1);
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
  cuda::launch_forward<T>(sc, rb, p, fo, nullptr, nullptr, nullptr, nullptr, stream);
  auto offsets = torch::zeros({R + 1}, opt.dtype(torch::kInt64));
  if (!want_hits) {
    auto e = torch::empty({0}, opt);
    return {feat, depth, depth_sq, normal, trans, count, offsets,
            torch::empty({0}, opt.dtype(torch::kInt32)), e, e.clone(), evals};
  }
  offsets.slice(0, 1).copy_(torch::cumsum(count, 0));
  const int64_t H = offsets[R].item<int64_t>();
  auto hit_ids = torch::empty({H}, opt.dtype(torch::kInt32));
  auto hit_t = torch::empty({H}, opt), hit_g = torch::empty({H}, opt);
  cuda::launch_forward<T>(sc, rb, p, fo, offsets.data_ptr<int64_t>(), hit_ids.data_ptr<int32_t>(),
                          hit_t.data_ptr<T>(), hit_g.data_ptr<T>(), stream);
  return {feat, depth, depth_sq, normal, trans, count, offsets, hit_ids, hit_t, hit_g, evals};
}

template <typename T>
std::vector<torch::Tensor> backward_impl(const SceneTensors& s, const RayTensors& r,
                                         const TraceParams& p, const std::vector<torch::Tensor>& outs,
                                         const std::vector<torch::Tensor>& grads,
                                         const torch::Tensor& hit_offsets, const torch::Tensor& hit_ids,
                                         const torch::Tensor& hit_t) {
  const c10::cuda::CUDAGuard guard(s.means.device());
  const cudaStream_t stream = c10::cuda::getCurrentCUDAStream();
  const torch::Tensor prims = preprocess<T>(s, false, stream);
  const int64_t N = s.means.size(0), K = s.features.size(1);
  auto opt = s.means.options();
  auto acc = torch::zeros({N, kGradStride}, opt);
  auto gfeat = torch::zeros({N, K}, opt);
  const SceneView<T> sc = make_scene_view<T>(s, prims);
  const RayBatch<T> rb = make_ray_batch<T>(r);
  const ForwardOut<T> fo{outs[0].data_ptr<T>(), outs[1].data_ptr<T>(), outs[2].data_ptr<T>(),
                         outs[3].data_ptr<T>(), outs[4].data_ptr<T>(), nullptr, nullptr};
  const GradIn<T> gi{grads[0].data_ptr<T>(), grads[1].data_ptr<T>(), grads[2].data_ptr<T>(),
                     grads[3].data_ptr<T>(), grads[4].data_ptr<T>()};
  const HitsView<T> hv{hit_offsets.data_ptr<int64_t>(), hit_ids.data_ptr<int32_t>(), hit_t.data_ptr<T>()};
  cuda::launch_backward<T>(sc, rb, p, hv, fo, gi, acc.data_ptr<T>(), gfeat.data_ptr<T>(), stream);
  auto g_rot = torch::empty({N, 4}, opt);
  cuda::launch_quat_backward<T>(s.rotations.data_ptr<T>(), acc.data_ptr<T>(), N, g_rot.data_ptr<T>(), stream);
  return {acc.slice(1, gMu, gMu + 3).contiguous(), acc.slice(1, gLogS, gLogS + 3).contiguous(), g_rot,
          acc.select(1, gOpa).contiguous(), acc.slice(1, gNrm, gNrm + 3).contiguous(), gfeat};
}

}  // namespace

std::vector<torch::Tensor> forward_cuda(const SceneTensors& s, const RayTensors& r,
                                        const TraceParams& p, bool want_hits) {
  if (s.means.scalar_type() == torch::kFloat64) return forward_impl<double>(s, r, p, want_hits);
  return forward_impl<float>(s, r, p, want_hits);
}

std::vector<torch::Tensor> backward_cuda(const SceneTensors& s, const RayTensors& r,
                                         const TraceParams& p, const std::vector<torch::Tensor>& outs,
                                         const std::vector<torch::Tensor>& grads,
                                         const torch::Tensor& hit_offsets, const torch::Tensor& hit_ids,
                                         const torch::Tensor& hit_t) {
  if (s.means.scalar_type() == torch::kFloat64)
    return backward_impl<double>(s, r, p, outs, grads, hit_offsets, hit_ids, hit_t);
  return backward_impl<float>(s, r, p, outs, grads, hit_offsets, hit_ids, hit_t);
}

}  // namespace rfir

#endif  // RFIR_WITH_CUDA
