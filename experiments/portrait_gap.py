"""The orientation slow test's two takes (one walk filmed sideways and upright) with any weights.

    python experiments/portrait_gap.py compact-preview [more weights ...]

Prints mesh F, precision and recall of each take: the slow test
(tests/test_poses_orientation.py) runs only the default weights and asks the two F within 0.03.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from depth.inference import estimate_depth  # noqa: E402
from depth.options import DepthOptions  # noqa: E402
from fusion.evaluate import mesh_metrics  # noqa: E402
from fusion.tsdf import TSDFConfig, fuse_scan  # noqa: E402
from recon.keyframes import KeyframeConfig, select_keyframes  # noqa: E402
from test_poses_orientation import upright_and_sideways  # noqa: E402


def main(weights: list[str]) -> None:
    (sideways, gt_mesh), (upright, _) = upright_and_sideways(1, 40, 4.0)
    with tempfile.TemporaryDirectory() as tmp:
        for w in weights:
            scores = {}
            for name, take in (("landscape", sideways), ("portrait", upright)):
                take = take.subset(select_keyframes(take.camera_to_world, KeyframeConfig(keyframe_distance=0.2)))
                out = Path(tmp) / w.replace("/", "_") / name
                estimate_depth(take, out, DepthOptions(mode="estm", device="cpu", weights=w))
                m = mesh_metrics(fuse_scan(take, out, TSDFConfig(device="cpu")), gt_mesh, scan=take)
                scores[name] = m["fscore"]
                print(f"{w} {name}: F {m['fscore']:.3f} (precision {m['prec']:.3f}, recall {m['recall']:.3f})",
                      flush=True)
            print(f"{w}: {abs(scores['portrait'] - scores['landscape']):.3f} apart (bound 0.03)", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["compact"])
