// Shared definitions for the CPU (OpenMP) and CUDA back-ends of the Gaussian ray tracer.
//
// Everything in this header and in gaussian.h / trace_ray.h is plain C++ that compiles for the
// host and, under nvcc, for the device (RFIR_HD). No torch here: the kernels see raw pointers
// packed into a few small structs, so argument lists stay short.
#pragma once

#include <cmath>
#include <cstdint>

#if defined(__CUDACC__)
#define RFIR_HD __host__ __device__ __forceinline__
#else
#define RFIR_HD inline
#endif

namespace rfir {

// Layout of one preprocessed Gaussian ("prim"), kPrimStride = 16 scalars (one 64-byte cache line
// in float32), computed once per call from (mean, log-scale, quaternion, opacity): the mean, the
// whitening map M = diag(1/s) R^T (row-major; Sigma^-1 = M^T M), the scales s and the opacity.
// R (columns = principal axes) is recovered as R_ji = M_ij s_i where the adjoint needs it.
constexpr int kMu = 0;
constexpr int kM = 3;
constexpr int kS = 12;
constexpr int kOpa = 15;  // opacity used by this call (scene's or an override)
constexpr int kPrimStride = 16;

// Number of scalars of per-Gaussian gradient accumulated by the backward pass before the
// quaternion epilogue: d/dmean (3), d/dlog-scale (3), d/dR (9), d/dopacity (1), d/dnormal (3).
constexpr int gMu = 0;
constexpr int gLogS = 3;
constexpr int gRot = 6;
constexpr int gOpa = 15;
constexpr int gNrm = 16;
constexpr int kGradStride = 19;  // features' gradients live in their own [N, K] buffer

// One BVH node, 32 bytes. Leaf: count > 0, prims prim_order[first .. first+count).
// Inner: count == 0, children are nodes `first` and `first + 1`.
struct BVHNode {
  float lo[3];
  int32_t first;
  float hi[3];
  int32_t count;
};

// Read-only view of the scene for one call. Pointers to contiguous tensors.
// The forward pass reads prims in BVH leaf order (prim slot k holds Gaussian prim_order[k], so a
// leaf's prims are contiguous in memory); the backward pass reads them by Gaussian id.
template <typename T>
struct SceneView {
  const T* prims;       // [N, kPrimStride], BVH order (forward) or id order (backward)
  const T* opacity;     // [N] in [0, 1]
  const T* normals;     // [N, 3] (may be null when no normal output is wanted)
  const T* features;    // [N, K] (null when K == 0)
  int64_t n;            // number of Gaussians
  int k;                // feature width K
  const BVHNode* nodes;       // [n_nodes]
  const int32_t* prim_order;  // [N]
  int64_t n_nodes;
};

// A batch of rays x(t) = o + t d, hits accepted for t_min < t* < t_max.
template <typename T>
struct RayBatch {
  const T* origins;        // [R, 3]
  const T* dirs;           // [R, 3], any non-zero length (t is in units of |d|)
  const T* t_min;          // [R]
  const T* t_max;          // [R]
  const int32_t* exclude;  // [R] Gaussian id skipped by that ray (-1: none), or null
  int64_t n;
};

struct TraceParams {
  double alpha_min;  // hits with alpha < alpha_min are ignored
  double t_stop;     // stop compositing once transmittance < t_stop
  double alpha_max;  // alpha = min(opacity * G, alpha_max)
  double kappa2;     // squared sigma multiplier of the bounds: 2 ln(1 / alpha_min)
};

// Per-ray outputs of the forward pass.
template <typename T>
struct ForwardOut {
  T* features;       // [R, K]
  T* depth;          // [R]
  T* depth_sq;       // [R]
  T* normal;         // [R, 3]
  T* transmittance;  // [R]
  int32_t* count;    // [R] composited hits
  int32_t* evals;    // [R] Gaussians evaluated (BVH candidates; diagnostic), may be null
};

// Per-ray upstream gradients (same shapes as ForwardOut, counts excluded).
template <typename T>
struct GradIn {
  const T* features;
  const T* depth;
  const T* depth_sq;
  const T* normal;
  const T* transmittance;
};

// Hit lists in CSR form: ray r owns entries offsets[r] .. offsets[r+1].
template <typename T>
struct HitsView {
  const int64_t* offsets;  // [R + 1]
  const int32_t* ids;      // [H]
  const T* t;              // [H]
};

// ---------------------------------------------------------------------------------------------
// Small math helpers with float/double overloads that work on host and device.
RFIR_HD float r_exp(float x) { return expf(x); }
RFIR_HD double r_exp(double x) { return exp(x); }
RFIR_HD float r_sqrt(float x) { return sqrtf(x); }
RFIR_HD double r_sqrt(double x) { return sqrt(x); }
RFIR_HD float r_abs(float x) { return fabsf(x); }
RFIR_HD double r_abs(double x) { return fabs(x); }
template <typename T>
RFIR_HD T r_min(T a, T b) { return a < b ? a : b; }
template <typename T>
RFIR_HD T r_max(T a, T b) { return a > b ? a : b; }

template <typename T>
RFIR_HD T dot3(const T* a, const T* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

template <typename T>
RFIR_HD void cross3(const T* a, const T* b, T* out) {
  out[0] = a[1] * b[2] - a[2] * b[1];
  out[1] = a[2] * b[0] - a[0] * b[2];
  out[2] = a[0] * b[1] - a[1] * b[0];
}

}  // namespace rfir
