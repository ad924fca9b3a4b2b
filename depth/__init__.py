"""Depth stage: the EST network (depth.model), ESTM inference (depth.inference), plane sweep,
training (depth.train) and checkpoints. See docs/depth.md. Imports torch, numpy and OpenCV only."""
