"""Reference-pose step check (io.checks.inconsistent_steps) and the ATE that cuts the trajectory
at a wrong reference step (metrics.ate_rmse_segments)."""

from pathlib import Path

import numpy as np
import pytest

from splat_core.camera import pose_matrix, quat_to_rotmat_np
from splat_core.io.checks import inconsistent_steps, reference_step_residuals
from splat_core.metrics import ate_rmse, ate_rmse_segments
from splat_core.synthetic import SyntheticSource

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"


class ReferenceWithJump(SyntheticSource):
    """Synthetic frames rendered at the true poses; the reference poses from frame `at` on are
    moved by one rigid transform, the way 7-Scenes' redkitchen jumps between frames 121 and 122."""

    def __init__(self, at: int, jump: np.ndarray | None = None, jitter_m: float = 0.0, **kw):
        super().__init__(**kw)
        self.ref = self.c2w.copy()
        if jump is not None:
            self.ref[at:] = jump @ self.ref[at:]
        rng = np.random.default_rng(1)
        self.ref[:, :3, 3] += jitter_m * rng.normal(size=(len(self.ref), 3))

    def reference_c2w(self) -> np.ndarray:
        return self.ref.copy()


JUMP = pose_matrix(quat_to_rotmat_np([np.cos(np.radians(0.75)), 0.0, np.sin(np.radians(0.75)), 0.0]),
                   [0.03, 0.0, 0.04])     # 1.5 degrees and 5 cm


def test_a_wrong_reference_step_is_flagged_and_only_it():
    kw = dict(n_frames=24, width=160, height=120)
    assert inconsistent_steps(reference_step_residuals(ReferenceWithJump(12, None, **kw))) == []
    residuals = reference_step_residuals(ReferenceWithJump(12, JUMP, **kw))
    assert inconsistent_steps(residuals) == [11]
    assert residuals[11, 0] > 0.02 and np.nanmedian(residuals[:, 1]) > 0.9


def test_a_reference_noisy_throughout_is_not_one_wrong_step():
    # 1.5 cm of jitter on every reference pose: every step disagrees a little, none stands out
    src = ReferenceWithJump(12, None, jitter_m=0.015, n_frames=24, width=160, height=120)
    residuals = reference_step_residuals(src)
    assert np.nanmedian(residuals[:, 1]) < 0.9
    assert inconsistent_steps(residuals) == []


def test_segmented_ate_removes_a_reference_jump_and_nothing_else():
    src = ReferenceWithJump(12, JUMP, n_frames=24)
    est, ref = src.c2w, src.reference_c2w()          # the estimate is the truth
    assert ate_rmse(est, ref) > 0.004
    assert ate_rmse_segments(est, ref, [11]) == pytest.approx(0.0, abs=1e-9)
    assert ate_rmse_segments(est, ref, []) == pytest.approx(ate_rmse(est, ref))
    drift = est.copy()
    drift[:, 0, 3] += np.linspace(0, 0.05, len(est))     # an estimate error within a piece stays
    assert ate_rmse_segments(drift, src.c2w, [11]) > 0.002


@pytest.mark.realdata
@pytest.mark.skipif(not (DATA / "7scenes_redkitchen_300").is_dir(), reason=f"real data not found at {DATA}")
def test_the_real_references_have_one_wrong_step():
    from splat_core.io import open_capture

    flagged = {name: inconsistent_steps(reference_step_residuals(open_capture(DATA / name)))
               for name in ("7scenes_redkitchen_300", "sun3d_3dmatch_fragment1", "sun3d_3dmatch_fragment2")
               if (DATA / name).is_dir()}
    assert flagged.pop("7scenes_redkitchen_300") == [121]
    assert all(steps == [] for steps in flagged.values())


def test_info_steps_names_the_wrong_step():
    from app.commands.info import format_text, gather

    info = gather(ReferenceWithJump(12, JUMP, n_frames=24, width=160, height=120), steps=True)
    assert [b["step"] for b in info["step_check"]["inconsistent"]] == [[11, 12]]
    text = format_text(info)
    assert "1 contradicted by the depth (11->12)" in text
    assert "reference poses 11 -> 12: the depth contradicts this step" in text
