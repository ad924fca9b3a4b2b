"""Turn a video, an image folder or a recorded scan into the frames SfM will see.

A phone clip has far more frames than SfM needs, many of them motion-blurred, at a
resolution SIFT does not need. Ingest decodes the input, keeps frames at a target
rate (the sharpest frame of each interval) or by image motion, drops frames that are
much blurrier than their neighbours, resizes to a working size and writes them as
JPEGs named after their original frame number, remembering each one's source index
and timestamp so poses can be traced back to the input.

Selection order: `stride` (every N-th input frame) -> `fps` (sharpest per interval)
-> `max_frames` (the first N, so a long input is not decoded past them) -> blur
rejection (videos and scans: an image folder is a photo collection, with no neighbours
in time to compare sharpness with) -> `min_motion_px`. As elsewhere in the project, --stride / --max-frames
select frames first; the filters can only leave fewer.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from recon import io as rio
from recon.io import working_size
from recon.errors import ReconError
from recon.geometry import focal_px_from_equivalent
from recon.scan import Intrinsics

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


@dataclass
class IngestConfig:
    """How frames are chosen and prepared for SfM."""

    stride: int = 1  # keep every N-th input frame before anything else
    fps: float | None = None  # videos: keep about this many frames per second (the sharpest of each interval)
    max_frames: int | None = None  # at most the first N frames after stride / fps (before the filters)
    min_motion_px: float | None = None  # keep a frame once features moved this far (median px) since the last kept one
    blur_window: int = 9  # neighbourhood (in candidate frames) that defines "normal" sharpness
    blur_ratio: float = 0.35  # drop a frame whose sharpness is below this share of its neighbourhood's median
    max_size: int = 640  # long side of the working images in pixels (never upscaled)
    min_frames: int = 10  # fewer usable frames than this cannot give a dependable reconstruction
    jpeg_quality: int = 95

    def validate(self) -> "IngestConfig":
        if self.stride < 1 or (self.max_frames is not None and self.max_frames < 1):
            raise ReconError(f"invalid frame selection: stride={self.stride} max_frames={self.max_frames}")
        if self.fps is not None and not self.fps > 0:
            raise ReconError(f"--fps must be positive, got {self.fps}")
        return self


@dataclass
class IngestedFrame:
    name: str  # stable frame id, e.g. "frame_000123" for a video's frame 123
    path: Path  # the working-size JPEG
    source_index: int  # frame number in the input (video frame, file order or scan frame index)
    timestamp: float | None  # seconds from the start of the video (or the scan's own timestamp)
    sharpness: float  # variance of the Laplacian at working size


@dataclass
class IngestResult:
    frames: list[IngestedFrame]
    image_dir: Path
    source: str
    kind: str  # "video", "images" or "scan"
    size: tuple[int, int]  # working (width, height)
    video_fps: float | None = None
    rotation_deg: int = 0  # phone orientation from the container, already applied to the frames
    dropped_blurry: list[str] = field(default_factory=list)
    dropped_static: list[str] = field(default_factory=list)
    camera: Intrinsics | None = None  # the capture's own pinhole camera at the working size, SfM's start
    camera_source: str | None = None  # where `camera` comes from: "scan" (recorded) or "exif" (photos)
    turned: list[str] = field(default_factory=list)  # photos turned a quarter to the folder's orientation

    def summary(self) -> dict:
        return {"source": self.source, "kind": self.kind, "frames": len(self.frames),
                "size": list(self.size), "video_fps": self.video_fps, "rotation_deg": self.rotation_deg,
                "dropped_blurry": len(self.dropped_blurry), "dropped_static": len(self.dropped_static),
                "turned_photos": len(self.turned), "camera_source": self.camera_source,
                "camera_focal_px": round(self.camera.fx, 2) if self.camera is not None else None}


def sharpness(rgb_or_gray: np.ndarray) -> float:
    """Variance of the Laplacian: high for crisp edges, low for motion blur or defocus."""
    gray = rgb_or_gray if rgb_or_gray.ndim == 2 else cv2.cvtColor(rgb_or_gray, cv2.COLOR_RGB2GRAY)
    return float(cv2.Laplacian(gray, cv2.CV_64F).var())


def blurry_indices(values: list[float], window: int, ratio: float) -> list[int]:
    """Indices whose sharpness is below `ratio` x the median of the `window` neighbours around them.

    Relative, not absolute: a dim or low-texture room has low Laplacian variance everywhere,
    and only the frames that are much worse than the ones around them are motion-blurred.
    """
    vals = np.asarray(values, dtype=np.float64)
    half = max(1, window // 2)
    out = []
    for i in range(len(vals)):
        lo, hi = max(0, i - half), min(len(vals), i + half + 1)
        if vals[i] < ratio * np.median(vals[lo:hi]):
            out.append(i)
    return out


def ingest(source: str | os.PathLike, out_dir: str | os.PathLike, config: IngestConfig | None = None) -> IngestResult:
    """Decode and select frames of `source` (video file, image folder or any readable scan) into `out_dir`.

    Recorded scans keep their frame names (so SfM poses can be scored against the scan's own),
    and their poses are ignored.
    """
    config = (config or IngestConfig()).validate()
    source = Path(source)
    if not source.exists():
        raise ReconError(f"{source}: no such file or folder")
    out_dir = rio.own_folder(out_dir)  # emptied below: never through a link to someone's photos
    for old in out_dir.glob("*.jpg"):  # a re-run must not mix in frames of an earlier selection
        rio.remove_path(old)
    fmt = scan_format(source)
    if fmt:
        result = _ingest_scan(source, fmt, out_dir, config)
    elif source.is_file():
        result = _ingest_video(source, out_dir, config)
    else:
        result = _ingest_image_folder(source, out_dir, config)
    return _finish(result, config)


def describe_capture(source: str | os.PathLike) -> dict:
    """What a video or a photo folder holds, read from its header and files without decoding it all
    (`recon info` on what `recon run` poses by SfM). Raises ReconError for anything else."""
    source = Path(source)
    if not source.exists():
        raise ReconError(f"{source}: no such file or folder")
    if source.is_file():
        cap = rio.open_video(source)
        try:
            fps = cap.get(cv2.CAP_PROP_FPS) or 0.0
            frames = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
            ok, bgr = cap.read()  # the decoded size, with the container's rotation applied
            rotation = int(round(cap.get(cv2.CAP_PROP_ORIENTATION_META) or 0)) % 360
        finally:
            cap.release()
        if not ok or bgr is None:
            raise ReconError(f"{source}: the video has no decodable frames (zero-length or damaged)")
        return {"path": str(source), "kind": "video", "frames": frames, "size": [bgr.shape[1], bgr.shape[0]],
                "video_fps": round(fps, 3) if fps > 0 else None,
                "duration_s": round(frames / fps, 2) if fps > 0 else None, "rotation_deg": rotation,
                "poses": "SfM (pycolmap)"}
    from recon.readers._common import numbered_files

    files = numbered_files(source, IMAGE_SUFFIXES)
    sizes = [rio.image_size(f) for f in files]
    shape = _folder_shape(source, sizes)
    turned = sum(size == shape[::-1] != shape for size in sizes)
    focals = [f for f in map(rio.read_exif_focal_35mm, files) if f is not None]
    camera = camera_from_exif(focals, shape)
    return {"path": str(source), "kind": "photos", "frames": len(files), "size": list(shape),
            "other_orientation": turned, "exif_focal_35mm": float(np.median(focals)) if focals else None,
            "photos_with_exif_focal": len(focals), "focal_px": round(camera.fx, 2) if camera is not None else None,
            "poses": "SfM (pycolmap), all pairs"}


# -- sources -----------------------------------------------------------------------------------

def _ingest_video(path: Path, out_dir: Path, config: IngestConfig) -> IngestResult:
    cap = rio.open_video(path, "; re-encode it (e.g. ffmpeg -i IN -c:v libx264 OUT.mp4) or pass a folder of images")
    try:
        video_fps = cap.get(cv2.CAP_PROP_FPS) or 0.0
        video_fps = video_fps if np.isfinite(video_fps) and video_fps > 0 else None
        # OpenCV applies the container's rotation (phone portrait clips) while decoding; record it.
        rotation = int(round(cap.get(cv2.CAP_PROP_ORIENTATION_META) or 0)) % 360
        bin_frames = max(1.0, video_fps / config.fps) if (config.fps and video_fps) else 1.0
        frames: list[IngestedFrame] = []
        best: tuple[int, IngestedFrame, np.ndarray] | None = None  # (bin, sharpest frame so far, its pixels)
        size = None
        index = -1
        while cap.grab():
            index += 1
            if index % config.stride:
                continue
            ok, bgr = cap.retrieve()
            if not ok or bgr is None:
                break
            if size is None:
                size = working_size(bgr.shape[1], bgr.shape[0], config.max_size)
            rgb = cv2.cvtColor(cv2.resize(bgr, size, interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2RGB)
            msec = cap.get(cv2.CAP_PROP_POS_MSEC)
            timestamp = index / video_fps if video_fps else (msec / 1000.0 if msec and msec > 0 else None)
            name = f"frame_{index:06d}"
            frame = IngestedFrame(name, out_dir / f"{name}.jpg", index, timestamp, sharpness(rgb))
            key = int(index // bin_frames)
            if best is not None and key != best[0]:  # bins arrive in order: the previous one is complete
                _keep(best, frames, config)
                best = None
                if config.max_frames is not None and len(frames) >= config.max_frames:
                    break
            if best is None or frame.sharpness > best[1].sharpness:
                best = (key, frame, rgb)
        if best is not None:
            _keep(best, frames, config)
    finally:
        cap.release()
    if index < 0 or size is None:
        raise ReconError(f"{path}: the video has no decodable frames (zero-length or damaged); "
                         "record a new clip or pass a folder of images")
    return IngestResult(frames, out_dir, str(path), "video", size, video_fps, rotation)


def _keep(best: tuple[int, IngestedFrame, np.ndarray], frames: list[IngestedFrame], config: IngestConfig) -> None:
    _, frame, rgb = best
    rio.write_image(frame.path, rgb, config.jpeg_quality)
    frames.append(frame)


def scan_format(path: Path) -> str | None:
    """The reader that recognises `path` as a recorded scan, or None for a plain video/image folder."""
    from recon.readers import READERS

    return next((r.NAME for r in READERS if r.detect(path)), None)


def camera_from_exif(focals_35mm: list[float], size: tuple[int, int]) -> Intrinsics | None:
    """SfM's starting pinhole camera at `size` from the photos' equivalent focal lengths (their median); None
    when no photo has one. Bundle adjustment refines it, as COLMAP refines the focal length it reads from
    EXIF itself (the working copies SfM reads carry none)."""
    if not focals_35mm:
        return None
    mm = float(np.median(focals_35mm))
    if max(focals_35mm) > 1.05 * min(focals_35mm):
        log.warning("ingest: the photos were taken at different zooms (%.0f-%.0f mm equivalent); SfM assumes one "
                    "camera and starts from the median, %.0f mm", min(focals_35mm), max(focals_35mm), mm)
    width, height = size
    focal = focal_px_from_equivalent(mm, width, height)
    return Intrinsics(focal, focal, (width - 1) / 2, (height - 1) / 2, width, height)


def _ingest_image_folder(folder: Path, out_dir: Path, config: IngestConfig) -> IngestResult:
    from recon.readers._common import numbered_files

    files = numbered_files(folder, IMAGE_SUFFIXES)[:: config.stride][: config.max_frames]
    shape = _folder_shape(folder, [rio.image_size(f) for f in files])
    frames, focals, turned = [], [], []
    for i, f in enumerate(files):
        try:  # through rio, so a broken file is one warning line, never libpng's own
            rgb = rio.read_image(f)
        except ReconError as exc:
            log.warning("%s; skipped", exc)
            continue
        if (rgb.shape[0], rgb.shape[1]) == shape != shape[::-1]:  # the other orientation: one camera, turned
            rgb = cv2.rotate(rgb, cv2.ROTATE_90_CLOCKWISE)
            turned.append(f.stem)
        if (rgb.shape[1], rgb.shape[0]) != shape:
            raise ReconError(f"{f}: image is {rgb.shape[1]}x{rgb.shape[0]}, the folder's photos are {shape[0]}x"
                             f"{shape[1]} (or turned); SfM assumes one camera, so pass photos of one size")
        rgb = cv2.resize(rgb, working_size(*shape, config.max_size), interpolation=cv2.INTER_AREA)
        frames.append(IngestedFrame(f.stem, out_dir / f"{f.stem}.jpg", i * config.stride, None, sharpness(rgb)))
        rio.write_image(frames[-1].path, rgb, config.jpeg_quality)  # working copies carry no EXIF: read it here
        focal = rio.read_exif_focal_35mm(f)
        if focal is not None:
            focals.append(focal)
    if not frames:
        raise _no_images(folder)
    if turned:
        landscape = shape[0] >= shape[1]
        log.warning("ingest: %d of %d photos are %s (%s); they are turned a quarter to the folder's %s orientation, "
                    "so that one camera fits all (their poses keep the turn)", len(turned), len(frames),
                    "portrait" if landscape else "landscape", ", ".join(turned[:5]) + (" ..." if len(turned) > 5 else ""),
                    "landscape" if landscape else "portrait")
    size = working_size(*shape, config.max_size)
    camera = camera_from_exif(focals, size)
    if camera is not None:
        log.info("ingest: %d of %d photos give a 35 mm-equivalent focal length: SfM starts from %.1f px",
                 len(focals), len(frames), camera.fx)
    return IngestResult(frames, out_dir, str(folder), "images", size, camera=camera,
                        camera_source="exif" if camera is not None else None, turned=turned)


def _folder_shape(folder: Path, sizes: list[tuple[int, int] | None]) -> tuple[int, int]:
    """(width, height) of the folder's photos (`sizes`: each one's, None when unreadable) in the orientation
    most of them have (landscape on a tie)."""
    sizes = [s for s in sizes if s is not None]
    if not sizes:
        raise _no_images(folder)
    landscape = sum(w >= h for w, h in sizes) * 2 >= len(sizes)
    return next(s for s in sizes if (s[0] >= s[1]) == landscape)


def _no_images(folder: Path) -> ReconError:
    return ReconError(f"{folder}: no readable images (.jpg/.png) and not a known scan format (see `recon formats`)")


def _ingest_scan(path: Path, fmt: str, out_dir: Path, config: IngestConfig) -> IngestResult:
    from recon.readers import open_scan

    scan = open_scan(path, fmt).select(0, config.stride, config.max_frames)
    src = scan.intrinsics
    size = working_size(src.width, src.height, config.max_size)
    scan = scan.resized(*size)
    frames = []
    for i, f in enumerate(scan.frames):
        rgb = scan.image(i)
        frames.append(IngestedFrame(f.name, out_dir / f"{f.name}.jpg",
                                    f.source_index if f.source_index is not None else i * config.stride,
                                    f.timestamp, sharpness(rgb)))
        rio.write_image(frames[-1].path, rgb, config.jpeg_quality)
    return IngestResult(frames, out_dir, str(path), "scan", size, camera=scan.intrinsics, camera_source="scan")


# -- selection ---------------------------------------------------------------------------------

def _finish(result: IngestResult, config: IngestConfig) -> IngestResult:
    frames = result.frames
    decoded = len(frames)
    # Blur is judged against neighbours in time; a folder of photos has none (it is matched as unordered too).
    ratio = 0.0 if result.kind == "images" else config.blur_ratio
    blurry = set(blurry_indices([f.sharpness for f in frames], config.blur_window, ratio))
    result.dropped_blurry = [frames[i].name for i in sorted(blurry)]
    frames = [f for i, f in enumerate(frames) if i not in blurry]
    if config.min_motion_px:
        kept = _select_by_motion(frames, config.min_motion_px)
        result.dropped_static = [f.name for f in frames if f not in kept]
        frames = kept
    keep = {f.path for f in frames}
    for f in result.frames:
        if f.path not in keep:
            f.path.unlink(missing_ok=True)
    result.frames = frames
    if len(frames) < config.min_frames:
        raise ReconError(
            f"{result.source}: only {len(frames)} usable frames ({decoded} selected, {len(result.dropped_blurry)} "
            f"too blurry, {len(result.dropped_static)} without motion); SfM needs at least {config.min_frames}: "
            "use a longer clip, a smaller --stride or a higher --fps, and move the camera slowly")
    log.info("ingest: %d frames kept of %d (%d blurry, %d static), %dx%d",
             len(frames), decoded, len(result.dropped_blurry), len(result.dropped_static), *result.size)
    return result


def _select_by_motion(frames: list[IngestedFrame], min_motion_px: float) -> list[IngestedFrame]:
    """Keep a frame once corners tracked from the last kept frame moved `min_motion_px` (median)."""
    kept = [frames[0]]
    ref_gray = cv2.imread(str(frames[0].path), cv2.IMREAD_GRAYSCALE)
    ref_pts = cv2.goodFeaturesToTrack(ref_gray, 400, 0.01, 8)
    for f in frames[1:]:
        gray = cv2.imread(str(f.path), cv2.IMREAD_GRAYSCALE)
        moved = np.inf  # a textureless reference cannot be tracked: keep the next frame
        if ref_pts is not None and len(ref_pts) >= 8:
            pts, status, _ = cv2.calcOpticalFlowPyrLK(ref_gray, gray, ref_pts, None)
            ok = status.reshape(-1) == 1
            # Losing most tracks means a big change of view: that counts as motion.
            if ok.sum() >= 0.3 * len(ref_pts):
                moved = float(np.median(np.linalg.norm((pts - ref_pts).reshape(-1, 2)[ok], axis=1)))
        if moved >= min_motion_px:
            kept.append(f)
            ref_gray = gray
            ref_pts = cv2.goodFeaturesToTrack(ref_gray, 400, 0.01, 8)
    return kept
