"""What tells a photo SfM placed metres away from the rest (docs/poses.md, "Photo collections")?

Renders the bench's photo collections and poses each one as `recon poses` does with the placement check
off, then prints per photo: its centre error after a trimmed Sim(3) alignment to the ground truth, its
observations, its mean reprojection error, and two measures over its verified pairs (inlier counts as
weights): the share in pairs whose own relative pose (essential matrix from the inliers, poses/placement.py)
agrees with the model's, and the share of inlier matches the model's relative pose explains (Sampson
error under 2 px). The question is which of these singles out the misplaced ones.

    python experiments/photo_outliers.py --seeds 4 0:exif 5 --out runs/photo_outliers [--reuse]
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def trimmed_alignment(est: np.ndarray, gt: np.ndarray, rounds: int = 3) -> np.ndarray:
    """Per-camera centre error after a Sim(3) fitted to the cameras within 3x the median error (repeated)."""
    from poses.evaluate import umeyama

    keep = np.ones(len(est), bool)
    for _ in range(rounds):
        s, r, t = umeyama(est[keep], gt[keep])
        err = np.linalg.norm((s * est @ r.T + t) - gt, axis=1)
        keep = err <= 3 * np.median(err)
    return err


def sampson_px(x_a: np.ndarray, x_b: np.ndarray, e: np.ndarray, focal: float) -> np.ndarray:
    """Sampson distance (pixels) of normalised matches (N, 2) under the essential matrix e."""
    a, b = np.c_[x_a, np.ones(len(x_a))], np.c_[x_b, np.ones(len(x_b))]
    ea, etb = a @ e.T, b @ e
    num = np.einsum("ni,ni->n", b, ea) ** 2
    return np.sqrt(num / (ea[:, 0] ** 2 + ea[:, 1] ** 2 + etb[:, 0] ** 2 + etb[:, 1] ** 2 + 1e-30)) * focal


def pair_measures(rec, database_path: Path) -> dict[str, dict[str, float]]:
    """Per posed image: inliers over its pairs, the agreeing-pair share and the explained-match share."""
    from poses.placement import agrees
    from poses.sfm import _cam_from_world, pair_residuals, posed_pairs

    cam = next(iter(rec.cameras.values()))
    images = {im.name: im for im in rec.images.values() if im.has_pose}
    pairs = posed_pairs(rec, database_path)
    sums: dict[str, np.ndarray] = {}
    for (a, b, pixels_a, pixels_b), (_, _, n, rotation, direction) in zip(pairs, pair_residuals(rec, pairs)):
        m = np.asarray((_cam_from_world(images[b]) * _cam_from_world(images[a]).inverse()).matrix())
        t = m[:, 3]
        essential = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ m[:, :3]
        explained = int((sampson_px(np.asarray(cam.cam_from_img(pixels_a)), np.asarray(cam.cam_from_img(pixels_b)),
                                    essential, cam.mean_focal_length()) < 2.0).sum())
        for name in (a, b):
            sums[name] = sums.get(name, np.zeros(3)) + [n, n * agrees(rotation, direction), explained]
    return {n: {"inliers": int(s[0]), "agreeing_share": s[1] / s[0], "explained_share": s[2] / s[0]}
            for n, s in sums.items()}


def analyse(folder: Path, run_dir: Path, reuse: bool) -> list[dict]:
    import pycolmap

    from poses.ingest import IngestConfig
    from poses.sfm import PosesConfig, SfMConfig, estimate_poses
    from recon.readers import open_scan
    from recon.synthetic.collection import GROUND_TRUTH, PHOTOS

    if reuse and (run_dir / "scan.json").exists():
        scan = open_scan(run_dir)
    else:
        config = PosesConfig(ingest=IngestConfig(blur_ratio=0.0), sfm=SfMConfig(placement_check=False, pair_pruning=False))
        scan, _ = estimate_poses(folder / PHOTOS, run_dir, config)
    gt = {Path(f.name).stem: f.camera_to_world for f in open_scan(folder / GROUND_TRUTH).frames}
    sfm = json.loads((run_dir / "poses_report.json").read_text())["sfm"]
    rec = pycolmap.Reconstruction(sfm["model_dir"])
    names = [Path(f.name).stem for f in scan.frames]
    err = trimmed_alignment(np.array([f.camera_to_world[:3, 3] for f in scan.frames]),
                            np.array([gt[n][:3, 3] for n in names]))
    measures = pair_measures(rec, Path(sfm["colmap_dir"]) / "database.db")
    rows = []
    for im in rec.images.values():
        if not im.has_pose:
            continue
        cam = rec.cameras[im.camera_id]
        obs = [p for p in im.points2D if p.has_point3D()]
        errors = [np.linalg.norm(np.asarray(cam.img_from_cam((im.cam_from_world() * rec.points3D[p.point3D_id].xyz)[None]))
                                 .ravel() - p.xy) for p in obs]
        stem = Path(im.name).stem
        rows.append({"name": stem, "centre_error_m": float(err[names.index(stem)]), "observations": len(obs),
                     "reprojection_px": float(np.mean(errors)) if errors else float("nan"),
                     **measures.get(im.name, {"inliers": 0, "agreeing_share": float("nan"),
                                              "explained_share": float("nan")})})
    return sorted(rows, key=lambda r: -r["centre_error_m"])


def main() -> None:
    import cv2  # noqa: F401  (before pycolmap, see docs/CONTRIBUTING.md)
    import torch  # noqa: F401

    from recon.synthetic.collection import write_photo_collection
    from recon.synthetic.generate import SynthConfig

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", default=["4", "0:exif", "5"], help="SEED, SEED:exif or SEED:portraits")
    parser.add_argument("--out", default="runs/photo_outliers")
    parser.add_argument("--reuse", action="store_true", help="analyse the poses of an earlier run under --out")
    args = parser.parse_args()
    variants = {"": {}, "exif": {"exif": True}, "portraits": {"portrait_every": 3}}
    for item in args.seeds:
        seed, _, variant = item.partition(":")
        root = Path(args.out) / f"photos{seed}{'_' + variant if variant else ''}"
        folder = root / "input"
        if not (args.reuse and folder.exists()):
            write_photo_collection(SynthConfig(seed=int(seed), frames=50, width=640, height=480), folder,
                                   step_deg=25.0, **variants[variant])
        rows = analyse(folder, root / "sfm", args.reuse)
        (root / "rows.json").write_text(json.dumps(rows, indent=1))
        placed = [r for r in rows if r["centre_error_m"] < 0.5]
        print(f"\n== seed {item}: {len(rows)} registered, {len(rows) - len(placed)} over 0.5 m off; well placed: "
              f"agreeing share min {min(r['agreeing_share'] for r in placed):.2f}, explained share min "
              f"{min(r['explained_share'] for r in placed):.2f}")
        print(f"{'photo':10} {'err m':>7} {'obs':>5} {'reproj':>7} {'inliers':>7} {'agreeing':>8} {'explained':>9}")
        for r in rows[:6]:
            print(f"{r['name']:10} {r['centre_error_m']:7.3f} {r['observations']:5d} {r['reprojection_px']:7.2f} "
                  f"{r['inliers']:7d} {r['agreeing_share']:8.2f} {r['explained_share']:9.2f}")


if __name__ == "__main__":
    main()
