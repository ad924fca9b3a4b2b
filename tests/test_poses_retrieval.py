"""Loop candidates from a video's own SIFT descriptors (poses/retrieval.py), on real photos."""
import cv2
import numpy as np
import pytest

from poses.retrieval import bag_of_words, find_loop_pairs, loop_candidates, nearest_word, root_sift, visual_words


def _sift(gray: np.ndarray) -> np.ndarray:
    _, d = cv2.SIFT_create(nfeatures=800).detectAndCompute(gray, None)
    return np.clip(np.round(d), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def revisit_video():
    """A 'video' that pans across one photo (frames 0-11), then two others (12-35), then pans across
    the first photo again (36-47): frames 36-47 revisit 0-11 and nothing else."""
    from skimage import data

    photos = [cv2.resize(cv2.cvtColor(p, cv2.COLOR_RGB2GRAY), (640, 480)) for p in
              (data.astronaut(), data.coffee(), data.chelsea())]

    def pan(photo, count, shift):
        return [photo[40:440, 20 + k * shift:340 + k * shift] for k in range(count)]

    frames = pan(photos[0], 12, 20) + pan(photos[1], 12, 20) + pan(photos[2], 12, 20) + pan(photos[0], 12, 19)
    return [_sift(f) for f in frames]


def test_revisits_are_found_and_nothing_else(revisit_video):
    pairs = find_loop_pairs(revisit_video, min_gap=10, per_frame=3)
    assert pairs == find_loop_pairs(revisit_video, min_gap=10, per_frame=3)  # seeded: reruns agree
    assert all(j - i > 10 for i, j in pairs)
    # Every candidate shows one photo twice: the revisit, or the two ends of one pan.
    assert all((i < 12 and j >= 36) or i // 12 == j // 12 for i, j in pairs), pairs
    revisits = [(i, j) for i, j in pairs if i < 12 and j >= 36]
    assert {j for _, j in revisits} == set(range(36, 48))  # every revisiting frame finds its loop


def test_no_revisit_no_candidates(revisit_video):
    """Without the return to the first photo every far frame shows another photo: nothing passes the bar."""
    assert [(i, j) for i, j in find_loop_pairs(revisit_video[:36], min_gap=10, per_frame=3)
            if i // 12 != j // 12] == []


def test_words_cluster_and_vote():
    rng = np.random.default_rng(0)
    centres = root_sift(rng.integers(0, 255, (4, 128)).astype(np.uint8))
    features = np.concatenate([centres[k] + 0.002 * rng.standard_normal((50, 128)) for k in range(4)])
    features /= np.linalg.norm(features, axis=1, keepdims=True)
    words = visual_words(features.astype(np.float32), 4, seed=0)
    assign = nearest_word(features.astype(np.float32), words)
    assert sorted(len(set(assign[50 * k:50 * k + 50])) for k in range(4)) == [1, 1, 1, 1]
    assert len(set(assign)) == 4
    vectors = bag_of_words([assign[:50], assign[50:100], assign[:50]], 4)
    assert vectors[0] @ vectors[2] == pytest.approx(1.0) and vectors[0] @ vectors[1] == pytest.approx(0.0)


def test_candidates_keep_the_window_out_and_obey_the_bar():
    vectors = np.eye(3)[[0, 0, 0, 1, 1, 1, 2, 2, 0]].astype(float)  # frame 8 looks like frames 0-2
    pairs = loop_candidates(vectors, min_gap=2, per_frame=3, relative=0.5)
    assert pairs == [(0, 8), (1, 8), (2, 8)]
