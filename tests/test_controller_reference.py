"""The controller gives the recorded numbers, bit for bit (the reference of the commit before issue 11).

``tests/data/controller_reference.npz`` holds, for four set-ups of the slide over the pipe (UKF and bypass,
hard switch and smooth blend across the R1/R3 border, a failed rotor, corrupted sensor frames), the packed
frames the controller received and a digest of all it produced (``tests/reference/record_controller.py``).
Replaying the frames through the public :meth:`InteractionController.step` must give the same digest. This
replaces the comparisons of the compiled step with its Python twin (removed): it pins the numbers of every
block of the controller to those of the code before the architecture change, independent of the simulator.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent / "reference"))

from record_controller import CASES, EVERY, controller, digest, frame_of_flat, slide  # noqa: E402

from omnirotor.messages import ControlStatus  # noqa: E402

DATA = Path(__file__).parent / "data" / "controller_reference.npz"


def replay(name: str, params=None):
    """The controller of case ``name`` fed the recorded frames; returns it, the statuses and the regions."""
    ref = np.load(DATA)
    estimator, mode, blend, failed, _, _ = CASES[name]
    frames = ref[f"{name}/frames"]
    pipe = ref[f"{name}/pipe"]
    ctl = controller(estimator, mode, blend, failed, params)
    traj = slide(pipe[:3], float(pipe[3]))
    ctl.log.ensure_capacity(frames.shape[0] - 1)
    ctl.reset(frame_of_flat(frames[0]), traj)
    statuses, regions = [], []
    for k in range(1, frames.shape[0]):
        cmd = ctl.step(frame_of_flat(frames[k]))
        statuses.append(int(cmd.status))
        regions.append(ctl.scheduler.region_index)
    return ctl, statuses, regions, ref


@pytest.mark.parametrize("name", list(CASES))
def test_controller_replays_the_recorded_reference_bit_for_bit(name):
    ctl, statuses, regions, ref = replay(name)
    width = ref[f"{name}/rows"].shape[1]  # the log's columns when the reference was recorded
    h, rows = digest(ctl, statuses, regions, width)
    # The frame supervision's column, added since: a clean run is never flagged.
    assert list(ctl.log.column_names[width:]) == ["frame_reject"]
    rejected = ctl.log.group("frame_reject")
    if not CASES[name][4]:
        assert not np.any(rejected) and not np.any(np.asarray(statuses) & int(ControlStatus.FRAME_REJECTED))
    # The sampled rows first: a difference there says where (which step, which column).
    np.testing.assert_array_equal(rows, ref[f"{name}/rows"])
    assert h == str(ref[f"{name}/digest"])
    assert ctl.log.n == ref[f"{name}/frames"].shape[0] - 1 and EVERY > 1


def test_the_frame_supervision_changed_the_corrupted_case_only_where_it_acts():
    """The corrupted case was re-digested (same recorded frames) when the frame supervision came (issue 14).

    Its rows before the supervision are kept: up to the first corrupted rotor speeds (1.1 s) every number is
    the same and the status differs only by ``FRAME_REJECTED`` on the rejected frames (the gyroscope and
    motion-capture samples were replaced as the estimator did before). From there the observer takes the last
    command in place of rejected speeds instead of the whole step holding the last command, as before.
    """
    name = "ukf_piecewise_corrupted"
    ref = np.load(DATA)
    old, new = ref[f"{name}/rows_before_supervision"], ref[f"{name}/rows"]
    ctl, statuses, regions, _ = replay(name)
    assert digest(ctl, statuses, regions, new.shape[1])[0] == str(ref[f"{name}/digest"])
    before = old[:, 0] < 1.1 - 1e-9
    status_col = 2
    others = [j for j in range(old.shape[1]) if j != status_col]
    np.testing.assert_array_equal(new[before][:, others], old[before][:, others])
    rejected = int(ControlStatus.FRAME_REJECTED)
    np.testing.assert_array_equal(new[before, status_col].astype(int) & ~rejected, old[before, status_col])
    assert np.any(new[before, status_col].astype(int) & rejected)
    assert not np.array_equal(new[~before], old[~before])
