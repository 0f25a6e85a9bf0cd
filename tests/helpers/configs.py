"""Settings files the run tests share: a tiny run that finishes in seconds."""

# A few iterations at 64x48, a checkpoint every 3 frames: for CLI, resume and batch tests.
TINY = """base: cpu
resolution: [64, 48]
checkpoint_every: 3
eval_every: 2
tracking: {iterations: 6}
mapping: {iterations: 3, first_frame_iterations: 6, window_size: 4}
"""
