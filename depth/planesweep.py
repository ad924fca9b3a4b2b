"""Classical plane-sweep stereo: the non-learned baseline and the fallback without weights.

For each depth plane every source image is warped into the reference view (the same
homographies as the network, `depth.geometry.plane_sweep_warp`), compared with the
reference by zero-mean normalised cross-correlation over a window, averaged over the
sources, aggregated over a second window, and the best plane is taken per pixel
(winner-take-all) with a parabola fit between neighbouring planes for sub-plane depth.
Pixels are kept only where the match is distinctive and consistent: enough reference
texture, a high NCC score, and multi-view consistency: of the sources that see the pixel,
at least `min_agreeing_sources` (all of them when fewer see it) must have their own best
plane near the chosen one. Invalid pixels are 0.
"""
from __future__ import annotations

import collections
import math
from typing import Callable, Iterator

import torch
import torch.nn.functional as F

from recon.scan import Scan

from .device import resolve_device
from .geometry import depth_at_index, depth_planes, plane_sweep_warp
from .options import (DepthOptions, FrameDepth, PlaneSweepOptions, check_scan, frame_sources, scan_depth_range,
                      stored_size)
from .views import image_tensor


def _box(x: torch.Tensor, k: int) -> torch.Tensor:
    """(N, C, H, W) -> the same, each map averaged over a k x k window (over the pixels inside the image).
    Two 1D convolutions (a row pass, a column pass) divided by the window's pixel count: the same averages
    as avg_pool2d(count_include_pad=False), about 6x faster on the CPU (docs/depth.md, plane sweep)."""
    n, c, h, w = x.shape
    maps = n * c
    row = torch.ones(maps, 1, 1, k, dtype=x.dtype, device=x.device)
    col = row.view(maps, 1, k, 1)

    def window_sum(images: torch.Tensor) -> torch.Tensor:  # (1, maps, H, W), one depthwise filter per map
        rows = F.conv2d(images, row[:images.shape[1]], padding=(0, k // 2), groups=images.shape[1])
        return F.conv2d(rows, col[:images.shape[1]], padding=(k // 2, 0), groups=images.shape[1])

    count = window_sum(torch.ones(1, 1, h, w, dtype=x.dtype, device=x.device))
    return (window_sum(x.reshape(1, maps, h, w)) / count).view(n, c, h, w)


def to_gray(rgb: torch.Tensor) -> torch.Tensor:
    """(..., 3, H, W) RGB in [0, 1] -> (..., H, W) luma."""
    w = torch.tensor([0.299, 0.587, 0.114], dtype=rgb.dtype, device=rgb.device).view(3, 1, 1)
    return (rgb * w).sum(-3)


def _matching_costs(ref: torch.Tensor, sources: torch.Tensor, K: torch.Tensor, ref_camera_to_world: torch.Tensor,
                    src_camera_to_world: torch.Tensor, depths: torch.Tensor, window: int
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """1 - NCC of every source against the reference at every depth hypothesis.

    ref (H, W), sources (S, H, W) grey; depths (D,) planes or (D, H, W) one depth per pixel
    -> costs (S, D, H, W) (NaN where the window is not wholly inside that source), the reference's
    window variance (H, W) (its texture).
    """
    r = ref[None, None]
    mu_r = _box(r, window)
    var_r = (_box(r * r, window) - mu_r * mu_r).clamp_min(0)
    costs = []
    for s in range(sources.shape[0]):
        warped, valid = plane_sweep_warp(sources[s][None, None], K[None], K[None], ref_camera_to_world[None],
                                         src_camera_to_world[s][None], depths[None], ref_size=tuple(ref.shape))
        x = warped[0, 0].unsqueeze(1)  # (D, 1, H, W)
        mu_s = _box(x, window)
        var_s = (_box(x * x, window) - mu_s * mu_s).clamp_min(0)
        ncc = (_box(x * r, window) - mu_s * mu_r) / torch.sqrt(var_r * var_s + 1e-6)
        full = _box(valid[0].unsqueeze(1).to(ref.dtype), window) > 0.999  # the whole window inside the source
        costs.append(torch.where(full, 1.0 - ncc, torch.full_like(ncc, float("nan")))[:, 0])
    return torch.stack(costs), var_r[0, 0]


def _aggregated_cost(costs: torch.Tensor, window: int) -> torch.Tensor:
    """(S, D, H, W) per-source costs -> (D, H, W): the mean over the sources that see the pixel (2 where
    none does), averaged over a window."""
    seen = torch.isfinite(costs)
    mean_cost = torch.where(seen, costs, torch.zeros_like(costs)).sum(0) / seen.sum(0).clamp_min(1)
    mean_cost = torch.where(seen.any(0), mean_cost, torch.full_like(mean_cost, 2.0))
    return _box(mean_cost[:, None], window)[:, 0]


def _best_hypothesis(agg: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(D, H, W) cost -> the winner's index (H, W), its cost, the sub-hypothesis index from a parabola
    through it and its neighbours, and where that fit holds (an interior minimum)."""
    d = agg.shape[0]
    best = agg.argmin(0)
    c0 = agg.gather(0, best[None])[0]
    cm = agg.gather(0, (best - 1).clamp_min(0)[None])[0]
    cp = agg.gather(0, (best + 1).clamp_max(d - 1)[None])[0]
    curvature = cm - 2 * c0 + cp
    interior = (best > 0) & (best < d - 1) & (curvature > 1e-6)
    offset = torch.where(interior, 0.5 * (cm - cp) / curvature.clamp_min(1e-6), torch.zeros_like(c0))
    return best, c0, best.to(agg.dtype) + offset.clamp(-0.5, 0.5), interior


def _sources_agree(costs: torch.Tensor, best: torch.Tensor, index: torch.Tensor, opts: PlaneSweepOptions
                   ) -> torch.Tensor:
    """Multi-view consistency, (S, D, H, W) costs and the chosen (H, W) hypothesis -> (H, W) bool: of the
    sources that see the pixel there (others are out of view), at least `min_agreeing_sources` (all of them
    when fewer see it, and at least one) have their own aggregated best within `agreement_planes` of it."""
    s_count, d, h, w = costs.shape
    per_source = _box(torch.nan_to_num(costs, nan=2.0).flatten(0, 1)[:, None], opts.aggregation_window)
    per_source_best = per_source.view(s_count, d, h, w).argmin(1).to(index.dtype)
    seeing = torch.isfinite(costs).gather(1, best[None, None].expand(s_count, 1, h, w))[:, 0]  # (S, H, W)
    agreeing = (((per_source_best - index).abs() <= opts.agreement_planes) & seeing).sum(0)
    needed = torch.minimum(seeing.sum(0), torch.full_like(agreeing, opts.min_agreeing_sources))
    return (needed > 0) & (agreeing >= needed)


def grey_frames(scan: Scan, device: torch.device | str = "cpu", keep: int = 12) -> Callable[[int], torch.Tensor]:
    """Frame index -> its (H, W) grey image in [0, 1] on `device`, the last `keep` kept (a frame serves as
    reference once and as a source of its neighbours)."""
    cache: collections.OrderedDict[int, torch.Tensor] = collections.OrderedDict()

    def grey(i: int) -> torch.Tensor:
        if i not in cache:
            cache[i] = to_gray(image_tensor(scan, i).to(device))
            if len(cache) > keep:
                cache.popitem(last=False)
        return cache[i]
    return grey


@torch.no_grad()
def plane_sweep_depth(ref: torch.Tensor, sources: torch.Tensor, K: torch.Tensor, ref_camera_to_world: torch.Tensor,
                      src_camera_to_world: torch.Tensor, depth_range: tuple[float, float],
                      opts: PlaneSweepOptions = PlaneSweepOptions()) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth and confidence of the reference view.

    ref (H, W) and sources (S, H, W) grayscale in [0, 1]; K (3, 3) at H x W; poses (4, 4)
    and (S, 4, 4) camera-to-world -> depth (H, W) metres (0 = filtered out), confidence (H, W)
    in [0, 1] (NCC of the chosen plane, 0 where filtered).
    """
    dt = ref.dtype
    lo = torch.tensor([depth_range[0]], dtype=dt, device=ref.device)
    hi = torch.tensor([depth_range[1]], dtype=dt, device=ref.device)
    d = opts.num_planes
    planes = depth_planes(lo, hi, d, opts.spacing)[0]
    costs, texture = _matching_costs(ref, sources, K, ref_camera_to_world, src_camera_to_world, planes,
                                     opts.ncc_window)
    best, c0, index, _ = _best_hypothesis(_aggregated_cost(costs, opts.aggregation_window))
    depth = depth_at_index(index[None], lo, hi, d, opts.spacing)[0]
    score = 1.0 - c0
    keep = ((score >= opts.min_score) & (texture >= opts.min_texture) & _sources_agree(costs, best, index, opts)
            & (best > 0) & (best < d - 1))
    zero = torch.zeros_like(depth)
    return torch.where(keep, depth, zero), torch.where(keep, score.clamp(0, 1), zero)


@torch.no_grad()
def refine_depth(ref: torch.Tensor, sources: torch.Tensor, K: torch.Tensor, ref_camera_to_world: torch.Tensor,
                 src_camera_to_world: torch.Tensor, prior: torch.Tensor,
                 opts: PlaneSweepOptions = PlaneSweepOptions()) -> tuple[torch.Tensor, torch.Tensor]:
    """A narrow sweep around a prior depth map: each pixel tries `opts.refine_steps` depths within a factor
    1 +- `opts.refine_band` of its prior (log-spaced), scored like the plane sweep, and takes the best where
    the match is distinctive (NCC >= `opts.refine_min_score`, texture, a minimum inside the band); elsewhere
    the prior stays.

    ref (H, W), sources (S, H, W) grey; K (3, 3); poses (4, 4), (S, 4, 4); prior (H, W) metres (0 = none)
    -> depth (H, W), score (H, W): the match's NCC where refined, 0 where the prior stayed.
    """
    steps = opts.refine_steps
    log_band = math.log1p(opts.refine_band)
    offsets = torch.linspace(-log_band, log_band, steps, dtype=ref.dtype, device=ref.device)
    hypotheses = prior.clamp_min(1e-3)[None] * torch.exp(offsets)[:, None, None]  # (D, H, W)
    costs, texture = _matching_costs(ref, sources, K, ref_camera_to_world, src_camera_to_world, hypotheses,
                                     opts.ncc_window)
    best, c0, index, interior = _best_hypothesis(_aggregated_cost(costs, opts.aggregation_window))
    score = 1.0 - c0
    refined = interior & (score >= opts.refine_min_score) & (texture >= opts.min_texture) & (prior > 0)
    if opts.refine_agreement:
        refined &= _sources_agree(costs, best, index, opts)
    factor = torch.exp(-log_band + index * (2 * log_band / (steps - 1)))
    return torch.where(refined, prior * factor, prior), torch.where(refined, score.clamp(0, 1), torch.zeros_like(score))


def run_planesweep(scan: Scan, opts: DepthOptions = DepthOptions(),
                   skip: frozenset[int] = frozenset()) -> Iterator[FrameDepth]:
    """The classical baseline over every frame but `skip` (working width `opts.planesweep.width`)."""
    check_scan(scan)
    lo, hi = scan_depth_range(scan, opts.depth_range)
    sources = frame_sources(scan, opts.sources)
    intr = scan.intrinsics
    width = min(opts.planesweep.width, intr.width)
    height = max(8, int(round(intr.height * width / intr.width)))
    work = scan.resized(width, height)
    out_w, out_h = stored_size(intr.size, (width, height), opts.full_resolution)
    device = resolve_device(opts.device)
    K = torch.from_numpy(work.intrinsics.K).float().to(device)
    poses = torch.from_numpy(scan.camera_to_world).float().to(device)
    gray = grey_frames(work, device)

    for i, srcs in sources.items():
        if i in skip:
            continue
        depth, conf = plane_sweep_depth(gray(i), torch.stack([gray(j) for j in srcs]), K, poses[i], poses[srcs],
                                        (lo, hi), opts.planesweep)
        if (out_h, out_w) != tuple(depth.shape):
            depth = F.interpolate(depth[None, None], (out_h, out_w), mode="nearest")[0, 0]
            conf = F.interpolate(conf[None, None], (out_h, out_w), mode="nearest")[0, 0]
        yield FrameDepth(i, scan.frames[i].name, depth.cpu().numpy(), conf.cpu().numpy(), list(srcs))
