"""calibrate shows the determination of every parameter, the noise model and the
model-order choice, in text and in JSON (issue 9 item 2)."""
import json

import numpy as np
import pytest

from imucald.fitting.stillness.poses import write_poses, PoseSet
from imucald.cli import main
from imucald.sim.sensor import draw_truth, pose_sigma, simulate_pose_means
from imucald.specs import ACCEL

_C = np.cos(np.radians(45))
HAND = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0],
                 [_C, 0, _C], [-_C, 0, _C], [0, _C, _C], [0, -_C, -_C]], float)


@pytest.fixture(scope="module")
def hand_poses(tmp_path_factory):
    """Ten hand-placed pose means (MPU-6050, 3 s holds at 100 Hz), written as a pose file."""
    rng = np.random.default_rng(0)
    truth = draw_truth("mpu6050", rng).accel
    ups = HAND + rng.normal(scale=np.radians(1), size=HAND.shape)
    ups /= np.linalg.norm(ups, axis=1, keepdims=True)
    raw, cov = simulate_pose_means(truth, ups, pose_sigma(ACCEL["mpu6050"].noise_density_g_rthz,
                                                          100.0, 3.0)[1], rng)
    n = np.full(10, 300)
    ps = PoseSet(raw, cov, n, np.arange(10) * 10.0, np.arange(10) * 10.0 + 3, cov * 300,
                 meta={"board": "mpu6050"})
    path = tmp_path_factory.mktemp("hand") / "hand.poses"
    write_poses(ps, str(path))
    return path


def test_text_names_the_undetermined_parameter_and_the_pose_that_would_help(hand_poses, capsys):
    assert main(["calibrate", str(hand_poses)]) == 0
    out = capsys.readouterr().out
    line = next(l for l in out.splitlines() if l.strip().startswith("alpha_yz:"))
    assert "undetermined" in line and "hold a pose" in line
    assert "noise model: each pose its own" in out and "prior: datasheet tolerances (mpu6050)" in out


def test_json_carries_flags_determination_and_model_choice(hand_poses, capsys):
    assert main(["calibrate", str(hand_poses), "--json", "--model", "auto", "--method", "lm"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["model_selection"]["chosen"] == d["model"]
    assert set(d["determination"]) >= {"bias_x_g", "scale_z"}
    assert all(f["name"] in d["determination"] for f in d["flags"])
