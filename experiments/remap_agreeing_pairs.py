"""Does mapping a photo collection again, without the verified pairs the first model disagrees with, give better poses?

The experiment behind `SfMConfig.pair_pruning` (docs/poses.md): thresholds 5/15 degrees (every disagreeing
pair) and 30/60 (`poses.placement.GROSS_*`) were tried, and the choice between the two models by the inliers
of all pairs they agree with.

Many verified pairs of the rendered photo collections join views of different walls that share a repeated
texture: 20-50 % of a well-placed photo's inliers lie in pairs whose own relative pose disagrees with the
model (experiments/photo_outliers.py). For each kept bench run (`recon bench poses --sections photos --keep
DIR`), this copies the database, deletes those pairs' two-view geometries, maps again with the same settings
and compares ATE (after the placement check, as the bench reports it) with the first model's.

    python experiments/remap_agreeing_pairs.py runs/bench_photos/photos2_exif runs/bench_photos/photos4 ...
"""
from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path


def main() -> None:
    import cv2  # noqa: F401  (before pycolmap)
    import pycolmap

    from poses.evaluate import pose_metrics
    from poses.sfm import (MappingAttempt, SfMConfig, SfMResult, agreeing_inliers, copy_database_without,
                           distortion_test, drop_misplaced_photos, map_images, pair_residuals, posed_pairs, scan_from_sfm)
    from recon.readers import open_scan

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="kept bench folders (photosN...)")
    parser.add_argument("--rotation", type=float, default=5.0, help="remove pairs off the model by more degrees")
    parser.add_argument("--direction", type=float, default=15.0, help="or off in travel direction by more degrees")
    args = parser.parse_args()
    for root in map(Path, args.runs):
        run = root / "sfm" / "run0"
        report = json.loads((run / "poses_report.json").read_text())["sfm"]
        gt = open_scan(root / "ground_truth")
        first = pycolmap.Reconstruction(report["model_dir"])
        database = Path(report["colmap_dir"]) / "database.db"
        residuals = pair_residuals(first, posed_pairs(first, database))
        gross = [(a, b) for a, b, _, r, d in residuals if r > args.rotation or d > args.direction]
        work = root / "remap"
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir()
        copy_database_without(database, work / "database.db", gross)
        config = SfMConfig()
        attempt = MappingAttempt("incremental", distortion=False)
        timings: dict = {}
        models = map_images(work / "database.db", run / "frames", work / "sparse", attempt, config, timings)
        rec, _ = distortion_test(max(models.values(), key=lambda r: r.num_reg_images()), config, timings)
        dropped = drop_misplaced_photos(rec, pair_residuals(rec, posed_pairs(rec, work / "database.db")))
        names = sorted(im.name for im in rec.images.values() if im.has_pose)
        result = SfMResult(rec, run / "frames", "incremental", names, [], timings, work, work / "database.db",
                           work / "sparse", [], {}, 0.0, "exhaustive", displaced=dropped)
        scan = scan_from_sfm(result)
        before = pose_metrics(open_scan(run), gt)
        after = pose_metrics(scan, gt)

        kept_first, kept_second = (agreeing_inliers(pair_residuals(m, posed_pairs(m, database))) for m in (first, rec))
        chosen = after if kept_second > kept_first else before
        print(f"{root.name:18} pairs removed {len(gross)}/{len(residuals)}  first: {before['registered'] * 50:.0f} "
              f"registered, ATE {100 * before['ate_rmse']:.1f} cm, agreeing {kept_first}  remapped: {len(names)} "
              f"registered (left out {len(dropped)}), ATE {100 * after['ate_rmse']:.1f} cm, agreeing {kept_second}; "
              f"kept ATE {100 * chosen['ate_rmse']:.1f} cm; mapping {timings.get('map_incremental', 0):.0f} s", flush=True)


if __name__ == "__main__":
    main()
