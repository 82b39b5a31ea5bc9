"""Benchmark of the Gaussian ray tracer (issue 4); `make bench` runs it.

Scenes: flat Gaussians tiled on the faces of a room and four boxes (bench/tracer_scenes.py), seen by
a pinhole camera from inside the room, float32. For each scene size and image size it measures
(medians over --reps repetitions):
  * forward and forward+backward time (all six Gaussian parameters require grad; the loss touches
    features, depth, depth_sq, normal and transmittance), rays/s and Gaussian evaluations/s
    (evaluations = BVH candidates whose response was computed);
  * peak extra resident memory during forward+backward (sampled RSS above the pre-call level);
  * speed-up over the float64 brute-force torch reference, run on a random subset of the rays and
    extrapolated linearly to the full image (marked "extrapolated" in the JSON);
  * Open3D RaycastingScene on the same rays against an icosahedron proxy mesh of the same Gaussians
    (each icosahedron scaled to the BVH bound, kappa sigma per axis): closest hit (cast_rays) and
    all hits (count_intersections, the closer analogue of compositing every hit).
Writes bench/tracer.json and prints a table.

Usage: python bench/bench_tracer.py [--reps 5] [--quick] [--no-open3d] [--device cpu|cuda] [--out bench/tracer.json]
With --device cuda the scene and rays live on the GPU (the extension must have been built with CUDA):
times are taken after torch.cuda.synchronize(), memory is the peak of torch's CUDA allocator during one
forward+backward, and the reference and Open3D columns are left out (they run on the CPU).
On a shared machine wall times follow the other load; the CPU-time columns are steadier, and
`OMP_NUM_THREADS=1 python bench/bench_tracer.py --no-open3d --ref-rays 0` gives single-core figures.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import threading
import time

import psutil
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import rfir_tracer as rt  # noqa: E402
from rfir_tracer.reference import quat_to_rotmat, trace_reference  # noqa: E402
from tracer_scenes import pinhole_rays, surface_scene  # noqa: E402

PARAMS = ("means", "log_scales", "rotations", "opacities", "normals", "features")


class PeakRSS:
    """Samples this process's RSS in a thread; .peak_mb is the maximum above the starting level."""

    def __init__(self, interval: float = 0.002):
        self.interval, self.proc = interval, psutil.Process()

    def __enter__(self):
        self.base = self.peak = self.proc.memory_info().rss
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        return self

    def _run(self):
        while not self.stop.is_set():
            self.peak = max(self.peak, self.proc.memory_info().rss)
            time.sleep(self.interval)

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join()
        self.peak = max(self.peak, self.proc.memory_info().rss)
        self.peak_mb = (self.peak - self.base) / 2**20


def _sync() -> None:
    """GPU kernels run asynchronously: a wall time means something only after they finished."""
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        torch.cuda.synchronize()


def median_time(fn, reps: int, cpu: list | None = None, best: list | None = None) -> float:
    """Median wall time of fn() over reps calls after one warm-up; appends the median process CPU
    time (all threads) to `cpu` and the fastest wall time to `best` when given."""
    fn()  # warm-up
    _sync()
    times, cpus = [], []
    for _ in range(reps):
        c, t = time.process_time(), time.perf_counter()
        fn()
        _sync()
        times.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    if cpu is not None:
        cpu.append(statistics.median(cpus))
    if best is not None:
        best.append(min(times))
    return statistics.median(times)


def peak_memory_mb(n: int, res: int) -> float:
    """Peak extra RSS of one forward+backward, measured in a fresh child process in which glibc
    returns large blocks to the OS at once (MALLOC_MMAP_THRESHOLD_), so RSS tracks live memory."""
    env = dict(os.environ, MALLOC_MMAP_THRESHOLD_="131072")
    cmd = [sys.executable, os.path.abspath(__file__), "--_memory", f"{n},{res}"]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
    return float(out.strip().splitlines()[-1])


def _memory_child(spec: str) -> None:
    n, res = (int(x) for x in spec.split(","))
    s = surface_scene(n)
    o, d = pinhole_rays(res, res)
    scene, p = make_scene(s, grad=True)
    with PeakRSS(interval=0.001) as mem:
        loss_of(rt.trace(scene, o, d, features=p["features"])).backward()
    print(mem.peak_mb)


def peak_cuda_memory_mb(s, o, d) -> float:
    """Peak extra memory of torch's CUDA allocator during one forward+backward (scene on the GPU)."""
    scene, p = make_scene(s, grad=True)
    _sync()
    torch.cuda.reset_peak_memory_stats()
    base = torch.cuda.memory_allocated()
    loss_of(rt.trace(scene, o, d, features=p["features"])).backward()
    _sync()
    return (torch.cuda.max_memory_allocated() - base) / 2**20


def make_scene(s, grad: bool):
    p = {k: s[k].clone().requires_grad_(grad) for k in PARAMS}
    scene = rt.GaussianScene(p["means"], p["log_scales"], p["rotations"], p["opacities"], p["normals"])
    return scene, p


def loss_of(out) -> torch.Tensor:
    return (out.features.sum() + out.depth.sum() + 0.1 * out.depth_sq.sum() + out.normal.sum()
            + out.transmittance.sum())


def icosahedron_mesh(s, kappa: float):
    """Open3D TriangleMesh arrays: one icosahedron per Gaussian, scaled to kappa sigma per axis."""
    phi = (1 + 5**0.5) / 2
    v = torch.tensor([[-1, phi, 0], [1, phi, 0], [-1, -phi, 0], [1, -phi, 0], [0, -1, phi], [0, 1, phi],
                      [0, -1, -phi], [0, 1, -phi], [phi, 0, -1], [phi, 0, 1], [-phi, 0, -1], [-phi, 0, 1]],
                     dtype=torch.float64)
    v = v / v.norm(dim=1, keepdim=True)
    f = torch.tensor([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                      [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                      [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=torch.int64)
    R = quat_to_rotmat(s["rotations"].double())
    sc = torch.exp(s["log_scales"].double()) * kappa
    verts = s["means"].double()[:, None] + torch.einsum("nij,nkj->nki", R, v[None] * sc[:, None])
    n = verts.shape[0]
    tris = f[None] + 12 * torch.arange(n)[:, None, None]
    return verts.reshape(-1, 3).float().numpy(), tris.reshape(-1, 3).int().numpy()


def bench_open3d(s, o, d, reps, kappa):
    import open3d as o3d

    verts, tris = icosahedron_mesh(s, kappa)
    t = time.perf_counter()
    scene = o3d.t.geometry.RaycastingScene()
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(verts)
    mesh.triangle.indices = o3d.core.Tensor(tris)
    scene.add_triangles(mesh)
    rays = o3d.core.Tensor(torch.cat([o.expand_as(d), d], 1).float().numpy())
    scene.cast_rays(rays)  # builds the BVH lazily
    build = time.perf_counter() - t
    closest = median_time(lambda: scene.cast_rays(rays), reps)
    all_hits = median_time(lambda: scene.count_intersections(rays), reps)
    return dict(triangles=int(tris.shape[0]), build_s=build, closest_s=closest, all_hits_s=all_hits)


def bench_reference(s, o, d, n_rays, seed=0):
    """Reference forward and forward+backward on n_rays random rays; returns seconds per ray."""
    g = torch.Generator().manual_seed(seed)
    idx = torch.randperm(d.shape[0], generator=g)[:n_rays]
    p = {k: s[k].double().clone().requires_grad_(True) for k in PARAMS}
    args = (p["means"], p["log_scales"], p["rotations"], p["opacities"], o.double(), d[idx].double())
    kw = dict(features=p["features"], normals=p["normals"])
    with torch.no_grad():
        t = time.perf_counter()
        trace_reference(*args, **kw)
        fwd = time.perf_counter() - t
    t = time.perf_counter()
    loss_of(trace_reference(*args, **kw)).backward()
    fwd_bwd = time.perf_counter() - t
    return fwd / n_rays, fwd_bwd / n_rays


def bench_case(s, res, reps, ref_rays, use_o3d, device="cpu"):
    o, d = pinhole_rays(res, res)
    o, d = o.to(device), d.to(device)
    r = d.shape[0]
    scene, _ = make_scene(s, grad=False)
    with torch.no_grad():
        out = rt.trace(scene, o, d, features=s["features"])
    cpu: list = []
    best: list = []
    fwd = median_time(lambda: rt.trace(scene, o, d, features=s["features"]), reps, cpu, best)
    gscene, p = make_scene(s, grad=True)

    def fwd_bwd():
        for v in p.values():
            v.grad = None
        loss_of(rt.trace(gscene, o, d, features=p["features"])).backward()

    fb = median_time(fwd_bwd, reps, cpu, best)
    evals = float(out.evaluations.double().sum())
    row = dict(gaussians=s["means"].shape[0], image=f"{res}x{res}", rays=r, forward_s=fwd,
               forward_backward_s=fb, forward_cpu_s=cpu[0], forward_backward_cpu_s=cpu[1],
               forward_best_s=best[0], forward_backward_best_s=best[1], rays_per_s=r / fwd, gaussian_evals_per_s=evals / fwd,
               evals_per_ray=evals / r, hits_per_ray=float(out.hit_count.double().mean()),
               mean_transmittance=float(out.transmittance.mean()),
               device=device)
    if device == "cuda":
        row["peak_cuda_mb"] = peak_cuda_memory_mb(s, o, d)
        return row
    row["peak_extra_rss_mb"] = peak_memory_mb(s["means"].shape[0], res)
    if ref_rays:  # the reference's autograd keeps O(rays x N) tensors: fewer rays for big scenes
        n = min(ref_rays, r, max(16, 3_000_000 // s["means"].shape[0]))
        ref_fwd, ref_fb = bench_reference(s, o, d, n)
        row.update(reference_rays_timed=n, reference_extrapolated=True,
                   reference_forward_s=ref_fwd * r, reference_forward_backward_s=ref_fb * r,
                   speedup_forward=ref_fwd * r / fwd, speedup_forward_backward=ref_fb * r / fb)
    if use_o3d:
        kappa = math.sqrt(2 * math.log(255.0))
        o3 = bench_open3d(s, o, d, reps, kappa)
        row.update({f"open3d_{k}": v for k, v in o3.items()})
        row["ratio_forward_vs_open3d_closest"] = fwd / o3["closest_s"]
        row["ratio_forward_vs_open3d_all_hits"] = fwd / o3["all_hits_s"]
    return row


def print_table(rows):
    cols = [("gaussians", "N", "{:>7d}"), ("image", "image", "{:>7s}"), ("forward_s", "fwd ms", "{:>7.1f}"),
            ("forward_backward_s", "f+b ms", "{:>7.1f}"), ("forward_backward_best_s", "f+b best", "{:>8.1f}"),
            ("forward_backward_cpu_s", "f+b cpu ms", "{:>10.1f}"),
            ("rays_per_s", "Mray/s", "{:>6.2f}"),
            ("gaussian_evals_per_s", "Meval/s", "{:>7.1f}"), ("hits_per_ray", "hit/ray", "{:>7.1f}"),
            ("peak_extra_rss_mb", "peak MB", "{:>7.0f}"), ("peak_cuda_mb", "GPU MB", "{:>6.0f}"),
            ("speedup_forward", "ref x fwd", "{:>9.0f}"),
            ("speedup_forward_backward", "ref x f+b", "{:>9.0f}"),
            ("open3d_closest_s", "o3d-1st ms", "{:>10.1f}"), ("open3d_all_hits_s", "o3d-all ms", "{:>10.1f}"),
            ("ratio_forward_vs_open3d_all_hits", "fwd/o3d-all", "{:>11.2f}")]
    scale = {"forward_s": 1e3, "forward_backward_s": 1e3, "forward_backward_cpu_s": 1e3,
             "forward_backward_best_s": 1e3, "rays_per_s": 1e-6, "gaussian_evals_per_s": 1e-6,
             "open3d_closest_s": 1e3, "open3d_all_hits_s": 1e3}
    width = [max(len(h), len(f.format(0 if "d}" in f else ("" if "s}" in f else 0.0)))) for _, h, f in cols]
    print("  ".join(h.rjust(w) for (_, h, _), w in zip(cols, width)))
    for row in rows:
        cells = []
        for (key, _, fmt), w in zip(cols, width):
            v = row.get(key)
            if v is None:
                cells.append("-".rjust(w))
                continue
            v = v * scale.get(key, 1) if not isinstance(v, str) else v
            cells.append(fmt.format(int(v) if "d}" in fmt else v).rjust(w))
        print("  ".join(cells))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--gaussians", default="10000,100000")
    ap.add_argument("--sizes", default="128,256")
    ap.add_argument("--ref-rays", type=int, default=256, help="rays the reference is timed on (0: skip)")
    ap.add_argument("--no-open3d", action="store_true")
    ap.add_argument("--quick", action="store_true", help="tiny smoke run (2k Gaussians, 64x64, 1 rep)")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "tracer.json"))
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                    help="where the scene and rays live (cuda needs the CUDA build of the extension)")
    ap.add_argument("--_memory", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.device == "cuda":
        if not (torch.cuda.is_available() and rt.backend_info().get("cuda_compiled")):
            sys.exit("bench_tracer: --device cuda needs a visible GPU and the extension built with CUDA "
                     f"(backend_info: {rt.backend_info()})")
        a.no_open3d, a.ref_rays = True, 0
    if a._memory:
        return _memory_child(a._memory)
    if a.quick:
        a.gaussians, a.sizes, a.reps, a.ref_rays = "2000", "64", 1, 32
    use_o3d = not a.no_open3d
    if use_o3d:
        try:
            import open3d  # noqa: F401
        except ImportError:
            print("open3d not installed: skipping the Open3D comparison", file=sys.stderr)
            use_o3d = False
    rows, builds = [], []
    for n in [int(x) for x in a.gaussians.split(",")]:
        s = {k: v.to(a.device) for k, v in surface_scene(n).items()}
        build = median_time(lambda s=s: make_scene(s, grad=False), max(1, a.reps // 2))
        scene, _ = make_scene(s, grad=False)
        refit = median_time(scene.refit, max(1, a.reps // 2))
        builds.append(dict(gaussians=s["means"].shape[0], bvh_build_s=build, bvh_refit_s=refit,
                           bvh_nodes=int(scene.nodes.shape[0])))
        for res in [int(x) for x in a.sizes.split(",")]:
            rows.append(bench_case(s, res, a.reps, a.ref_rays, use_o3d, a.device))
            print(f"done: {rows[-1]['gaussians']} Gaussians, {res}x{res}", file=sys.stderr, flush=True)
    info = rt.backend_info()
    report = dict(
        machine=dict(platform=platform.platform(), cpu_count=os.cpu_count(), torch=torch.__version__,
                     torch_threads=torch.get_num_threads(), load_avg=os.getloadavg()),
        gpu=torch.cuda.get_device_name() if a.device == "cuda" else None,
        backend=info, device=a.device, reps=a.reps, statistic="median", dtype="float32", cases=rows, bvh=builds,
        notes=["reference timed on a random subset of rays (reference_rays_timed) and extrapolated linearly",
               "open3d proxy: one icosahedron per Gaussian scaled to kappa*sigma (kappa^2 = 2 ln 255)",
               "peak_extra_rss_mb: RSS sampled every 1 ms during one forward+backward in a fresh process "
               "(MALLOC_MMAP_THRESHOLD_=131072), minus the level before it",
               "*_best_s: fastest of the repetitions (least disturbed by other load)",
               "*_cpu_s: process CPU time summed over threads (wall time on an idle 2-core machine is "
               "about half of it); wall times depend on other load (see machine.load_avg)"])
    with open(a.out, "w") as fh:
        json.dump(report, fh, indent=2, default=str)
    print()
    print_table(rows)
    for b in builds:
        print(f"BVH N={b['gaussians']}: build {b['bvh_build_s'] * 1e3:.1f} ms, refit {b['bvh_refit_s'] * 1e3:.1f} ms,"
              f" {b['bvh_nodes']} nodes")
    print(f"backend: {info['backend']} ({info['openmp_max_threads']} OpenMP threads); "
          f"load average {os.getloadavg()[0]:.1f}; wrote {a.out}")


if __name__ == "__main__":
    main()
