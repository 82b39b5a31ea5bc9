// BVH over the Gaussians' bounding ellipsoids: binned SAH build and bottom-up refit (CPU).
//
// Bounds: the axis-aligned box of {x : maha(x) <= kappa^2}, kappa^2 = 2 ln(1 / alpha_min), i.e. the
// exact support of alpha >= alpha_min for any opacity <= 1 (3.33 sigma for alpha_min = 1/255). A
// hit's t* is the midpoint of the ray's chord through that ellipsoid, so it lies inside every
// ancestor box, which is what the traversal relies on. Boxes are rounded outwards to float.
// Children are always allocated after their parent, so a reverse sweep refits the tree.
#include <algorithm>
#include <cstring>
#include <cmath>
#include <numeric>
#include <vector>

#include "gaussian.h"
#include "ops.h"

namespace rfir {
namespace {

constexpr int kBins = 16;
constexpr int kMaxDepth = 60;  // the traversal stack holds 64 entries

struct Box {
  float lo[3] = {INFINITY, INFINITY, INFINITY};
  float hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  void grow(const Box& b) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], b.lo[a]);
      hi[a] = std::max(hi[a], b.hi[a]);
    }
  }
  float half_area() const {
    float dx = hi[0] - lo[0], dy = hi[1] - lo[1], dz = hi[2] - lo[2];
    if (!(dx >= 0.f)) return 0.f;
    return dx * dy + dy * dz + dz * dx;
  }
};

std::vector<Box> gaussian_boxes(const torch::Tensor& means, const torch::Tensor& log_scales,
                                const torch::Tensor& rotations, double kappa) {
  auto m = means.detach().to(torch::kCPU, torch::kFloat64).contiguous();
  auto l = log_scales.detach().to(torch::kCPU, torch::kFloat64).contiguous();
  auto q = rotations.detach().to(torch::kCPU, torch::kFloat64).contiguous();
  const int64_t n = m.size(0);
  std::vector<Box> boxes(n);
  const double* mp = m.data_ptr<double>();
  const double* lp = l.data_ptr<double>();
  const double* qp = q.data_ptr<double>();
#pragma omp parallel for schedule(static) if (n > 4096)
  for (int64_t i = 0; i < n; ++i) {
    double prim[kPrimStride], half[3];
    preprocess_gaussian(mp + 3 * i, lp + 3 * i, qp + 4 * i, 1.0, prim);
    gaussian_half_extent(prim, kappa, half);
    for (int a = 0; a < 3; ++a) {
      const double lo = prim[a] - half[a], hi = prim[a] + half[a];
      const double pad = 1e-6 * (std::fabs(prim[a]) + half[a]);
      boxes[i].lo[a] = std::nextafter(static_cast<float>(lo - pad), -INFINITY);
      boxes[i].hi[a] = std::nextafter(static_cast<float>(hi + pad), INFINITY);
    }
  }
  return boxes;
}

void set_bounds(BVHNode& nd, const Box& b) {
  for (int a = 0; a < 3; ++a) {
    nd.lo[a] = b.lo[a];
    nd.hi[a] = b.hi[a];
  }
}

struct Task {
  int32_t node, begin, end, depth;
};

}  // namespace

std::vector<torch::Tensor> build_bvh(const torch::Tensor& means, const torch::Tensor& log_scales,
                                     const torch::Tensor& rotations, double kappa, int64_t leaf_size) {
  const std::vector<Box> boxes = gaussian_boxes(means, log_scales, rotations, kappa);
  const int32_t n = static_cast<int32_t>(boxes.size());
  std::vector<float> cen(3 * static_cast<size_t>(n));
  for (int32_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) cen[3 * i + a] = 0.5f * (boxes[i].lo[a] + boxes[i].hi[a]);
  std::vector<int32_t> order(n);
  std::iota(order.begin(), order.end(), 0);
  std::vector<BVHNode> nodes;
  if (n > 0) {
    nodes.reserve(2 * static_cast<size_t>(n) / std::max<int64_t>(1, leaf_size / 2) + 1);
    nodes.push_back(BVHNode{});
    std::vector<Task> stack{{0, 0, n, 0}};
    while (!stack.empty()) {
      Task tk = stack.back();
      stack.pop_back();
      Box bb, cb;
      for (int32_t i = tk.begin; i < tk.end; ++i) {
        bb.grow(boxes[order[i]]);
        Box c;
        for (int a = 0; a < 3; ++a) c.lo[a] = c.hi[a] = cen[3 * order[i] + a];
        cb.grow(c);
      }
      set_bounds(nodes[tk.node], bb);
      const int32_t count = tk.end - tk.begin;
      int axis = 0;
      for (int a = 1; a < 3; ++a)
        if (cb.hi[a] - cb.lo[a] > cb.hi[axis] - cb.lo[axis]) axis = a;
      const float extent = cb.hi[axis] - cb.lo[axis];
      if (count <= leaf_size || tk.depth >= kMaxDepth || !(extent > 0.f)) {
        nodes[tk.node].first = tk.begin;
        nodes[tk.node].count = count;
        continue;
      }
      // binned SAH along the widest centroid axis
      Box bin_box[kBins];
      int32_t bin_n[kBins] = {0};
      const float scale = kBins / extent;
      auto bin_of = [&](int32_t id) {
        int b = static_cast<int>((cen[3 * id + axis] - cb.lo[axis]) * scale);
        return std::min(std::max(b, 0), kBins - 1);
      };
      for (int32_t i = tk.begin; i < tk.end; ++i) {
        const int b = bin_of(order[i]);
        bin_n[b]++;
        bin_box[b].grow(boxes[order[i]]);
      }
      float right_cost[kBins];
      Box acc;
      int32_t acc_n = 0;
      for (int b = kBins - 1; b > 0; --b) {
        acc.grow(bin_box[b]);
        acc_n += bin_n[b];
        right_cost[b] = acc.half_area() * acc_n;
      }
      float best = INFINITY;
      int split = -1;
      Box lacc;
      int32_t l_n = 0;
      for (int b = 0; b < kBins - 1; ++b) {
        lacc.grow(bin_box[b]);
        l_n += bin_n[b];
        if (l_n == 0 || l_n == count) continue;
        const float c = lacc.half_area() * l_n + right_cost[b + 1];
        if (c < best) { best = c; split = b; }
      }
      int32_t mid;
      if (split >= 0) {
        mid = static_cast<int32_t>(
            std::partition(order.begin() + tk.begin, order.begin() + tk.end,
                           [&](int32_t id) { return bin_of(id) <= split; }) - order.begin());
      } else {  // all centroids in one bin: median split
        mid = tk.begin + count / 2;
        std::nth_element(order.begin() + tk.begin, order.begin() + mid, order.begin() + tk.end,
                         [&](int32_t a, int32_t b) { return cen[3 * a + axis] < cen[3 * b + axis]; });
      }
      const int32_t left = static_cast<int32_t>(nodes.size());
      nodes[tk.node].first = left;
      nodes[tk.node].count = 0;
      nodes.push_back(BVHNode{});
      nodes.push_back(BVHNode{});
      stack.push_back({left + 1, mid, tk.end, tk.depth + 1});
      stack.push_back({left, tk.begin, mid, tk.depth + 1});
    }
  }
  static_assert(sizeof(BVHNode) == 32, "BVHNode must be 32 bytes");
  auto nodes_t = torch::empty({static_cast<int64_t>(nodes.size()), 8}, torch::kInt32);
  if (!nodes.empty()) std::memcpy(nodes_t.data_ptr<int32_t>(), nodes.data(), nodes.size() * 32);
  auto order_t = torch::empty({n}, torch::kInt32);
  if (n > 0) std::memcpy(order_t.data_ptr<int32_t>(), order.data(), sizeof(int32_t) * n);
  return {nodes_t, order_t};
}

torch::Tensor refit_bvh(const torch::Tensor& nodes, const torch::Tensor& prim_order,
                        const torch::Tensor& means, const torch::Tensor& log_scales,
                        const torch::Tensor& rotations, double kappa) {
  const std::vector<Box> boxes = gaussian_boxes(means, log_scales, rotations, kappa);
  auto out = nodes.to(torch::kCPU).clone().contiguous();
  auto order = prim_order.to(torch::kCPU).contiguous();
  TORCH_CHECK(order.numel() == static_cast<int64_t>(boxes.size()),
              "refit: the number of Gaussians changed; rebuild the BVH instead");
  BVHNode* nd = reinterpret_cast<BVHNode*>(out.data_ptr<int32_t>());
  const int32_t* op = order.data_ptr<int32_t>();
  for (int64_t i = out.size(0) - 1; i >= 0; --i) {
    Box b;
    if (nd[i].count > 0) {
      for (int32_t k = nd[i].first; k < nd[i].first + nd[i].count; ++k) b.grow(boxes[op[k]]);
    } else {
      for (int c = 0; c < 2; ++c) {
        Box cb;
        for (int a = 0; a < 3; ++a) {
          cb.lo[a] = nd[nd[i].first + c].lo[a];
          cb.hi[a] = nd[nd[i].first + c].hi[a];
        }
        b.grow(cb);
      }
    }
    set_bounds(nd[i], b);
  }
  return out;
}

}  // namespace rfir
