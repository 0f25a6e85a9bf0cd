"""Refinement of a finished SLAM map (`splatam refine`): refiner.py is the algorithm, density.py
3DGS's clone / split / prune, run_data.py what a run folder provides, job.py the run around it
(checkpoints, held-out evaluation, output files)."""

from .job import RefineJob
from .refiner import RefineSettings, Refiner

__all__ = ["RefineJob", "RefineSettings", "Refiner"]
