"""Ingest: decoding, rate / motion / blur selection, resizing, frame numbers and timestamps, bad input."""
import cv2
import numpy as np
import pytest

from poses.ingest import IngestConfig, blurry_indices, ingest
from recon.io import working_size
from recon.errors import ReconError

W, H, FPS = 320, 240, 30.0


def texture(seed: int = 0, size: int = 900) -> np.ndarray:
    """A photo-like random texture (blobs at several scales) wide enough to pan over."""
    rng = np.random.default_rng(seed)
    img = np.zeros((size, size, 3), np.float32)
    for scale in (3, 9, 27):
        noise = rng.uniform(0, 255, (size // scale + 1, size // scale + 1, 3)).astype(np.float32)
        img += cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC)[:size, :size] / 3
    return np.clip(img, 0, 255).astype(np.uint8)


def write_video(path, n: int, blurred=(), static_until: int = 0, step_px: int = 4) -> None:
    tex = texture()
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (W, H))
    assert writer.isOpened()
    for i in range(n):
        x = max(0, i - static_until) * step_px
        frame = np.ascontiguousarray(tex[100:100 + H, x:x + W])
        if i in blurred:
            frame = cv2.GaussianBlur(frame, (0, 0), 6)
        writer.write(frame)
    writer.release()


def test_video_blur_rejection_keeps_frame_numbers_and_timestamps(tmp_path):
    video = tmp_path / "clip.mp4"
    write_video(video, 40, blurred=(10, 25))
    result = ingest(video, tmp_path / "frames", IngestConfig())
    assert result.kind == "video" and result.video_fps == pytest.approx(FPS) and result.size == (W, H)
    assert result.dropped_blurry == ["frame_000010", "frame_000025"]
    assert [f.source_index for f in result.frames] == [i for i in range(40) if i not in (10, 25)]
    f = result.frames[20]
    assert f.name == f"frame_{f.source_index:06d}" and f.timestamp == pytest.approx(f.source_index / FPS)
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == sorted(f"{f.name}.jpg" for f in result.frames)


def test_video_target_fps_keeps_the_sharpest_of_each_interval(tmp_path):
    video = tmp_path / "clip.mp4"
    write_video(video, 60, blurred=(3, 4, 13, 14))
    result = ingest(video, tmp_path / "frames", IngestConfig(fps=10.0, blur_ratio=0.0))
    indices = [f.source_index for f in result.frames]
    assert len(indices) == 20  # 2 s at 10 frames per second
    assert [i // 3 for i in indices] == list(range(20))  # one per interval of 3 source frames
    assert indices[1] == 5 and indices[4] == 12  # the blurred 3, 4, 13, 14 lose to their sharp neighbour


def test_stride_max_frames_and_resize(tmp_path):
    video = tmp_path / "clip.mp4"
    write_video(video, 60)
    result = ingest(video, tmp_path / "frames", IngestConfig(stride=3, max_frames=12, max_size=160))
    assert [f.source_index for f in result.frames] == list(range(0, 36, 3))
    assert result.size == (160, 120)
    assert cv2.imread(str(result.frames[0].path)).shape == (120, 160, 3)


def test_motion_selection_drops_frames_before_the_camera_moves(tmp_path):
    video = tmp_path / "clip.mp4"
    write_video(video, 50, static_until=20, step_px=3)
    result = ingest(video, tmp_path / "frames", IngestConfig(min_motion_px=8.0, min_frames=5))
    indices = [f.source_index for f in result.frames]
    assert indices[0] == 0 and indices[1] >= 22  # nothing kept while the picture stands still
    assert np.all(np.diff(indices[1:]) >= 2) and np.all(np.diff(indices[1:]) <= 4)  # ~3 px per frame -> every ~3rd
    assert len(result.dropped_static) == 50 - len(indices)


def test_image_folder_names_and_mixed_sizes(tmp_path):
    folder = tmp_path / "imgs"
    folder.mkdir()
    tex = texture(1)
    for i in range(12):
        cv2.imwrite(str(folder / f"img_{i:03d}.png"), tex[:H, i * 5:i * 5 + W])
    result = ingest(folder, tmp_path / "frames", IngestConfig(blur_ratio=0.0))
    assert result.kind == "images" and [f.name for f in result.frames] == [f"img_{i:03d}" for i in range(12)]
    assert all(f.timestamp is None for f in result.frames)
    cv2.imwrite(str(folder / "img_999.png"), tex[:100, :100])
    with pytest.raises(ReconError, match="one size"):
        ingest(folder, tmp_path / "frames2")


@pytest.mark.parametrize("content", [b"", b"not a video at all" * 100])
def test_unreadable_or_empty_video(tmp_path, content):
    video = tmp_path / "broken.mp4"
    video.write_bytes(content)
    with pytest.raises(ReconError, match="cannot be opened as a video") as err:
        ingest(video, tmp_path / "frames")
    assert "\n" not in str(err.value) and "ffmpeg" in str(err.value)


def test_too_few_usable_frames_explains_what_to_try(tmp_path):
    video = tmp_path / "short.mp4"
    write_video(video, 6)
    with pytest.raises(ReconError, match=r"only 6 usable frames.*at least 10.*longer clip") as err:
        ingest(video, tmp_path / "frames")
    assert "\n" not in str(err.value)
    assert len(list((tmp_path / "frames").glob("*.jpg"))) == 6  # what was decoded stays


def test_helpers():
    assert working_size(1920, 1080, 640) == (640, 360)
    assert working_size(1080, 1920, 640) == (360, 640)
    assert working_size(320, 240, 640) == (320, 240)  # never upscaled
    sharp = [100.0] * 9
    sharp[4] = 20.0
    assert blurry_indices(sharp, window=9, ratio=0.35) == [4]
    assert blurry_indices([5.0] * 9, window=9, ratio=0.35) == []  # uniformly soft footage is not "blurry"


def test_photo_folder_starts_sfm_from_the_exif_focal_length(tmp_path, caplog):
    """Phone photos carry their 35 mm-equivalent focal length; the working copies SfM reads do not, so ingest
    turns it into SfM's starting camera at the working size (the median when the photos disagree)."""
    from recon.geometry import equivalent_focal_mm, focal_px_from_equivalent
    from recon.io import read_exif_focal_35mm, write_image

    tex = texture(2)
    plain, phone = tmp_path / "plain", tmp_path / "phone"
    plain.mkdir(), phone.mkdir()
    for i in range(12):
        view = np.ascontiguousarray(cv2.resize(tex[:480, i * 10:i * 10 + 640], (640, 480))[..., ::-1])
        write_image(plain / f"IMG_{i:04d}.jpg", view)
        write_image(phone / f"IMG_{i:04d}.jpg", view, focal_35mm=52 if i == 11 else 26)  # one zoomed photo
    assert read_exif_focal_35mm(phone / "IMG_0000.jpg") == 26 and read_exif_focal_35mm(plain / "IMG_0000.jpg") is None
    assert equivalent_focal_mm(focal_px_from_equivalent(26, 640, 480), 640, 480) == pytest.approx(26)

    without = ingest(plain, tmp_path / "f1", IngestConfig(max_size=320))
    assert without.camera is None and without.summary()["camera_source"] is None
    with caplog.at_level("WARNING", logger="poses.ingest"):
        result = ingest(phone, tmp_path / "f2", IngestConfig(max_size=320))
    assert result.size == (320, 240) and result.camera_source == "exif"
    # 26 mm across the 43.3 mm diagonal of 35 mm film: 400 px across the 320x240 diagonal -> 240.4 px
    assert result.camera.fx == result.camera.fy == pytest.approx(26 / np.hypot(36, 24) * 400)
    assert (result.camera.cx, result.camera.cy) == (159.5, 119.5)
    assert result.summary()["camera_focal_px"] == pytest.approx(240.37, abs=0.01)
    assert "different zooms (26-52 mm" in caplog.text


def test_photos_of_both_orientations_are_turned_to_the_folders(tmp_path, caplog):
    """A phone's photo folder mixes landscape and portrait shots of one camera: the minority is turned a quarter
    (said in one warning, counted in the summary) so that SfM's one camera fits every photo."""
    from recon.io import write_image

    folder = tmp_path / "photos"
    folder.mkdir()
    tex = texture(3)
    views = [np.ascontiguousarray(tex[:H, i * 7:i * 7 + W]) for i in range(10)]
    for i, view in enumerate(views):
        write_image(folder / f"IMG_{i:04d}.jpg", np.rot90(view, 1) if i in (2, 5, 7) else view)  # three in portrait
    with caplog.at_level("WARNING", logger="poses.ingest"):
        result = ingest(folder, tmp_path / "frames", IngestConfig(blur_ratio=0.0))
    assert result.size == (W, H) and result.summary()["turned_photos"] == 3
    assert result.turned == ["IMG_0002", "IMG_0005", "IMG_0007"] and "3 of 10 photos are portrait" in caplog.text
    for i in (2, 5):  # a counter-clockwise portrait turned clockwise: the landscape shot again (up to JPEG noise)
        back = cv2.cvtColor(cv2.imread(str(result.frames[i].path)), cv2.COLOR_BGR2RGB).astype(float)
        assert np.abs(back - views[i]).mean() < 10 < np.abs(back - np.rot90(views[i], 2)).mean()
    write_image(folder / "IMG_0100.jpg", tex[:100, :150])
    with pytest.raises(ReconError, match="one size"):
        ingest(folder, tmp_path / "frames2")


def test_image_size_from_the_header_agrees_with_the_decoded_image(tmp_path):
    """Ingest sorts photos by orientation from their headers; a phone's EXIF quarter turn (orientation 6) is
    applied by the decoder, so the header's size must be turned the same way."""
    from PIL import Image

    from recon.io import image_size, read_image

    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 degrees clockwise to display"
    Image.fromarray(np.zeros((30, 40, 3), np.uint8)).save(tmp_path / "turned.jpg", exif=exif)
    Image.fromarray(np.zeros((30, 40, 3), np.uint8)).save(tmp_path / "plain.jpg")
    for name in ("turned.jpg", "plain.jpg"):
        height, width = read_image(tmp_path / name).shape[:2]
        assert image_size(tmp_path / name) == (width, height)
    assert image_size(tmp_path / "turned.jpg") == (30, 40) and image_size(tmp_path / "missing.jpg") is None
