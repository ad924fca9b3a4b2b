"""Loop candidates for a sequentially matched video: which frames far apart in time see the same place.

COLMAP's loop detection needs a vocabulary tree trained offline on millions of images, a file
nothing here can download. A video of one room needs far less: its own SIFT descriptors,
clustered into a few hundred visual words (seeded k-means, so reruns agree), turn each frame
into a tf-idf weighted bag of words; the frames most similar to a frame, beyond the sequential
window, are the candidate pairs that geometric verification then accepts or rejects.
"""
from __future__ import annotations

import numpy as np


def _unit_rows(x: np.ndarray) -> np.ndarray:
    return x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)


def root_sift(descriptors: np.ndarray) -> np.ndarray:
    """(N, 128) uint8 SIFT -> (N, 128) float32 RootSIFT (L1-normalised, square-rooted: unit length), which
    compares descriptors by the Hellinger kernel and clusters better than raw SIFT."""
    d = descriptors.astype(np.float32)
    return np.sqrt(d / np.maximum(d.sum(axis=1, keepdims=True), 1e-12))


def nearest_word(features: np.ndarray, words: np.ndarray, chunk: int = 8192) -> np.ndarray:
    """(N, D) unit features, (W, D) unit words -> (N,) index of each feature's nearest word (largest dot)."""
    return np.concatenate([np.argmax(features[i:i + chunk] @ words.T, axis=1)
                           for i in range(0, len(features), chunk)]) if len(features) else np.zeros(0, int)


def visual_words(features: np.ndarray, num_words: int, seed: int, iterations: int = 10) -> np.ndarray:
    """(N, D) unit features -> (W, D) unit cluster centres (spherical k-means, k-means++ start).

    W = min(num_words, N). Deterministic for a given seed and input order.
    """
    rng = np.random.default_rng(seed)
    count = min(num_words, len(features))
    centres = [features[rng.integers(len(features))]]
    closest = 1.0 - features @ centres[0]
    for _ in range(1, count):  # k-means++: far points are likelier picks
        p = np.maximum(closest, 0) ** 2
        pick = rng.choice(len(features), p=p / p.sum()) if p.sum() > 0 else rng.integers(len(features))
        centres.append(features[pick])
        closest = np.minimum(closest, 1.0 - features @ features[pick])
    words = np.stack(centres)
    for _ in range(iterations):
        assign = nearest_word(features, words)
        sums = np.stack([np.bincount(assign, weights=features[:, k], minlength=len(words))
                         for k in range(features.shape[1])], axis=1)
        filled = np.bincount(assign, minlength=len(words)) > 0
        words[filled] = _unit_rows(sums[filled]).astype(words.dtype)
    return words


def bag_of_words(assignments: list[np.ndarray], num_words: int) -> np.ndarray:
    """Per-frame word indices -> (frames, W) L2-normalised tf-idf vectors (a word in every frame weighs 0)."""
    counts = np.stack([np.bincount(a, minlength=num_words) for a in assignments]).astype(np.float64)
    frames_with = np.count_nonzero(counts, axis=0)
    idf = np.log(len(assignments) / np.maximum(frames_with, 1))
    tf = counts / np.maximum(counts.sum(axis=1, keepdims=True), 1)
    return _unit_rows(tf * idf)


def loop_candidates(vectors: np.ndarray, min_gap: int, per_frame: int, relative: float) -> list[tuple[int, int]]:
    """(frames, W) bag-of-words vectors -> sorted pairs (i, j), i < j, j - i > min_gap.

    For each frame, its `per_frame` most similar frames more than `min_gap` away, kept when their
    similarity reaches `relative` x its similarity to its closest sequential neighbour (within
    `min_gap`, which overlaps): a revisit resembles a neighbour; a frame of another wall does not.
    """
    n = len(vectors)
    similarity = vectors @ vectors.T
    index = np.arange(n)
    gap = np.abs(index[:, None] - index[None, :])
    pairs = set()
    for i in range(n):
        near = similarity[i][(gap[i] >= 1) & (gap[i] <= min_gap)]
        if not len(near):
            continue
        bar = relative * float(near.max())
        far = np.flatnonzero(gap[i] > min_gap)
        for j in far[np.argsort(-similarity[i, far], kind="stable")][:per_frame]:
            if similarity[i, j] >= bar and similarity[i, j] > 0:
                pairs.add((min(i, int(j)), max(i, int(j))))
    return sorted(pairs)


def find_loop_pairs(descriptors: list[np.ndarray], min_gap: int, per_frame: int = 3, relative: float = 0.5,
                    num_words: int = 256, sample_per_frame: int = 200, seed: int = 0) -> list[tuple[int, int]]:
    """Per-frame (N_i, 128) uint8 SIFT descriptors, in video order -> candidate loop pairs (frame indices).

    The vocabulary is clustered from `sample_per_frame` descriptors of each frame (seeded), then every
    descriptor votes for its word. BLAS runs on one thread: the products take about 2 s for 200 frames,
    and OpenBLAS threads spinning against a busy core took 25-55 s for the same work.
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return _loop_pairs(descriptors, min_gap, per_frame, relative, num_words, sample_per_frame, seed)


def _loop_pairs(descriptors, min_gap, per_frame, relative, num_words, sample_per_frame, seed):
    rng = np.random.default_rng(seed)
    features = [root_sift(d) for d in descriptors]
    sample = np.concatenate([f[np.sort(rng.permutation(len(f))[:sample_per_frame])] for f in features if len(f)])
    if len(sample) == 0:
        return []
    words = visual_words(sample, num_words, seed)
    vectors = bag_of_words([nearest_word(f, words) for f in features], len(words))
    return loop_candidates(vectors, min_gap, per_frame, relative)
