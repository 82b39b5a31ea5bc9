// Python bindings of rfir_tracer._C: argument checks and CPU/CUDA dispatch.
//
// The friendly validation (NaN, ranges, shapes with clear ValueErrors) lives in Python
// (rfir_tracer/_checks.py); these TORCH_CHECKs guard the raw pointers against misuse.
#include <omp.h>

#include "ops.h"

namespace rfir {
namespace {

void check_float(const torch::Tensor& t, const char* name, const torch::Tensor& like, int64_t rows,
                 int64_t cols) {
  TORCH_CHECK(t.defined(), name, " is undefined");
  TORCH_CHECK(t.is_contiguous(), name, " must be contiguous");
  TORCH_CHECK(t.scalar_type() == like.scalar_type(), name, " must have dtype ", like.scalar_type());
  TORCH_CHECK(t.device() == like.device(), name, " must be on ", like.device());
  TORCH_CHECK(t.size(0) == rows, name, " must have ", rows, " rows, got ", t.size(0));
  if (cols >= 0) TORCH_CHECK(t.dim() == 2 && t.size(1) == cols, name, " must be [", rows, ", ", cols, "]");
}

void check_inputs(const SceneTensors& s, const RayTensors& r) {
  const auto& m = s.means;
  TORCH_CHECK(m.dim() == 2 && m.size(1) == 3, "means must be [N, 3]");
  TORCH_CHECK(m.scalar_type() == torch::kFloat32 || m.scalar_type() == torch::kFloat64,
              "means must be float32 or float64");
  TORCH_CHECK(m.is_contiguous(), "means must be contiguous");
  const int64_t N = m.size(0), R = r.origins.size(0);
  TORCH_CHECK(N < (int64_t(1) << 31) - 1, "too many Gaussians for int32 ids");
  check_float(s.log_scales, "log_scales", m, N, 3);
  check_float(s.rotations, "rotations", m, N, 4);
  TORCH_CHECK(s.opacities.dim() == 1, "opacities must be [N]");
  check_float(s.opacities, "opacities", m, N, -1);
  if (s.normals.numel()) check_float(s.normals, "normals", m, N, 3);
  TORCH_CHECK(s.features.dim() == 2, "features must be [N, K]");
  check_float(s.features, "features", m, N, s.features.size(1));
  TORCH_CHECK(s.nodes.dim() == 2 && s.nodes.size(1) == 8 && s.nodes.scalar_type() == torch::kInt32,
              "nodes must be [n_nodes, 8] int32");
  TORCH_CHECK(s.nodes.device() == m.device() && s.nodes.is_contiguous(), "nodes: wrong device/layout");
  TORCH_CHECK(s.prim_order.numel() == N && s.prim_order.scalar_type() == torch::kInt32 &&
                  s.prim_order.device() == m.device(), "prim_order must be [N] int32 on the scene's device");
  TORCH_CHECK(N == 0 || s.nodes.size(0) > 0, "BVH is empty for a non-empty scene");
  check_float(r.origins, "origins", m, R, 3);
  check_float(r.dirs, "directions", m, R, 3);
  TORCH_CHECK(r.t_min.dim() == 1 && r.t_max.dim() == 1, "t_min/t_max must be [R]");
  check_float(r.t_min, "t_min", m, R, -1);
  check_float(r.t_max, "t_max", m, R, -1);
  if (r.exclude.defined() && r.exclude.numel()) {
    TORCH_CHECK(r.exclude.scalar_type() == torch::kInt32 && r.exclude.numel() == R &&
                    r.exclude.device() == m.device() && r.exclude.is_contiguous(),
                "exclude must be [R] int32 on the scene's device");
  }
}

std::vector<torch::Tensor> forward(const SceneTensors& s, const RayTensors& r, const TraceParams& p,
                                   bool want_hits) {
  check_inputs(s, r);
  if (s.means.is_cuda()) {
#ifdef RFIR_WITH_CUDA
    return forward_cuda(s, r, p, want_hits);
#else
    TORCH_CHECK(false, "rfir_tracer was built without CUDA; move the tensors to the CPU");
#endif
  }
  return forward_cpu(s, r, p, want_hits);
}

std::vector<torch::Tensor> backward(const SceneTensors& s, const RayTensors& r, const TraceParams& p,
                                    const std::vector<torch::Tensor>& outs,
                                    const std::vector<torch::Tensor>& grads,
                                    const torch::Tensor& hit_offsets, const torch::Tensor& hit_ids,
                                    const torch::Tensor& hit_t) {
  check_inputs(s, r);
  TORCH_CHECK(outs.size() == 5 && grads.size() == 5, "backward needs 5 outputs and 5 gradients");
  const int64_t R = r.origins.size(0), K = s.features.size(1);
  const int64_t cols[5] = {K, -1, -1, 3, -1};
  const char* names[5] = {"features", "depth", "depth_sq", "normal", "transmittance"};
  for (int i = 0; i < 5; ++i) {
    check_float(outs[i], names[i], s.means, R, cols[i]);
    check_float(grads[i], names[i], s.means, R, cols[i]);
  }
  TORCH_CHECK(hit_offsets.numel() == R + 1 && hit_offsets.scalar_type() == torch::kInt64,
              "hit_offsets must be [R + 1] int64");
  TORCH_CHECK(hit_ids.scalar_type() == torch::kInt32, "hit_ids must be int32");
  if (s.means.is_cuda()) {
#ifdef RFIR_WITH_CUDA
    return backward_cuda(s, r, p, outs, grads, hit_offsets, hit_ids, hit_t);
#else
    TORCH_CHECK(false, "rfir_tracer was built without CUDA; move the tensors to the CPU");
#endif
  }
  return backward_cpu(s, r, p, outs, grads, hit_offsets, hit_ids, hit_t);
}

std::vector<torch::Tensor> transmittance(const SceneTensors& s, const RayTensors& r, const TraceParams& p) {
  check_inputs(s, r);
  TORCH_CHECK(!s.means.is_cuda(), "transmittance is CPU-only; on CUDA use forward (rfir_tracer.trace)");
  return transmittance_cpu(s, r, p);
}

std::vector<torch::Tensor> footprint_sums(const torch::Tensor& offsets, const torch::Tensor& ids,
                                          const torch::Tensor& t, const torch::Tensor& response,
                                          const torch::Tensor& opacities, const torch::Tensor& group_offsets,
                                          const torch::Tensor& ray_weight, double margin, double alpha_max) {
  TORCH_CHECK(!t.is_cuda(), "footprint_sums is CPU-only");
  TORCH_CHECK(t.dim() == 1 && (t.scalar_type() == torch::kFloat32 || t.scalar_type() == torch::kFloat64) &&
                  t.is_contiguous(), "t must be [H] float32 or float64, contiguous");
  const int64_t H = t.size(0);
  TORCH_CHECK(ids.scalar_type() == torch::kInt32 && ids.numel() == H && ids.is_contiguous(), "ids must be [H] int32");
  check_float(response, "response", t, H, -1);
  TORCH_CHECK(opacities.dim() == 1, "opacities must be [N]");
  check_float(opacities, "opacities", t, opacities.size(0), -1);
  for (const torch::Tensor* o : {&offsets, &group_offsets}) {
    TORCH_CHECK(o->dim() == 1 && o->numel() >= 1 && o->scalar_type() == torch::kInt64 && o->is_contiguous(),
                "offsets must be 1-D int64, contiguous");
    const int64_t* p = o->data_ptr<int64_t>();
    for (int64_t i = 1; i < o->numel(); ++i) TORCH_CHECK(p[i] >= p[i - 1], "offsets must be non-decreasing");
  }
  const int64_t R = offsets.size(0) - 1;
  TORCH_CHECK(offsets.data_ptr<int64_t>()[0] == 0 && offsets.data_ptr<int64_t>()[R] == H,
              "hit offsets must run from 0 to H");
  TORCH_CHECK(group_offsets.data_ptr<int64_t>()[0] == 0 && group_offsets.data_ptr<int64_t>()[group_offsets.numel() - 1] == R,
              "group offsets must run from 0 to the number of rays");
  check_float(ray_weight, "ray_weight", t, R, -1);
  if (H) {
    const auto mm = ids.aminmax();
    TORCH_CHECK(std::get<0>(mm).item<int32_t>() >= 0 && std::get<1>(mm).item<int32_t>() < opacities.size(0),
                "ids out of range of opacities");
  }
  return footprint_sums_cpu(offsets, ids, t, response, opacities, group_offsets, ray_weight, margin, alpha_max);
}

py::dict build_info() {
  py::dict d;
#ifdef RFIR_WITH_CUDA
  d["cuda_compiled"] = true;
#else
  d["cuda_compiled"] = false;
#endif
  d["openmp_max_threads"] = omp_get_max_threads();
  d["k_buffer_cpu"] = 64;
  d["k_buffer_cuda"] = 16;
  return d;
}

}  // namespace
}  // namespace rfir

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  using namespace rfir;
  m.doc() = "rfir Gaussian ray tracer (C++/OpenMP and CUDA back-ends)";
  py::class_<SceneTensors>(m, "SceneTensors")
      .def(py::init<>())
      .def_readwrite("means", &SceneTensors::means)
      .def_readwrite("log_scales", &SceneTensors::log_scales)
      .def_readwrite("rotations", &SceneTensors::rotations)
      .def_readwrite("opacities", &SceneTensors::opacities)
      .def_readwrite("normals", &SceneTensors::normals)
      .def_readwrite("features", &SceneTensors::features)
      .def_readwrite("nodes", &SceneTensors::nodes)
      .def_readwrite("prim_order", &SceneTensors::prim_order);
  py::class_<RayTensors>(m, "RayTensors")
      .def(py::init<>())
      .def_readwrite("origins", &RayTensors::origins)
      .def_readwrite("dirs", &RayTensors::dirs)
      .def_readwrite("t_min", &RayTensors::t_min)
      .def_readwrite("t_max", &RayTensors::t_max)
      .def_readwrite("exclude", &RayTensors::exclude);
  py::class_<TraceParams>(m, "TraceParams")
      .def(py::init<>())
      .def_readwrite("alpha_min", &TraceParams::alpha_min)
      .def_readwrite("t_stop", &TraceParams::t_stop)
      .def_readwrite("alpha_max", &TraceParams::alpha_max)
      .def_readwrite("kappa2", &TraceParams::kappa2);
  // The heavy calls release the GIL: other Python threads (data loading, monitoring) keep running.
  using release = py::call_guard<py::gil_scoped_release>;
  m.def("forward", &forward, "Trace rays: composited outputs and optional CSR hit lists", release());
  m.def("transmittance", &transmittance, "Transmittance only, hits in traversal order (CPU)", release());
  m.def("footprint_sums", &footprint_sums,
        "Per group of rays and Gaussian: sums of w G and w G T-in-front over sorted CSR hit lists (CPU)", release());
  m.def("backward", &backward, "Gradients of the traced outputs w.r.t. the Gaussians", release());
  m.def("build_bvh", &build_bvh, "Build a BVH (binned SAH) over the Gaussians' bounds", release());
  m.def("refit_bvh", &refit_bvh, "Refit a BVH's bounds to moved Gaussians", release());
  m.def("build_info", &build_info, "Compile-time configuration of the extension");
}
