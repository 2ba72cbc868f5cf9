"""The daemon's use of the noise figures: per-sample covariance in the stream, and the
coloured-noise inflation of the pose covariances handed to the calibration job."""
import json
from concurrent.futures import Executor, Future

import numpy as np
import pytest

from imucald.fitting.noise.colour import inflation_of
from imucald.fitting.stillness.poses import PoseSet
from imucald.cli import main
from imucald.daemon.config import ConfigError, validate
from imucald.daemon.pipeline import Pipeline
from imucald.files.recording import Recording, write_recording

from .test_noise_figures import coloured

FS = 100.0


@pytest.fixture(scope="module")
def noise_file(tmp_path_factory):
    """Figures of a 300 s still recording with flicker noise (so the inflation is > 1)."""
    d = tmp_path_factory.mktemp("noise")
    n = int(300 * FS)
    rng = np.random.default_rng(3)
    rec = Recording(np.arange(n) / FS, acc=coloured(rng, n, FS, 300e-6, 300e-6, 0.0) + [0, 0, 1],
                    gyro=coloured(rng, n, FS, 0.01, 0.004, 0.0), meta={"board": "mpu6050", "rate_hz": "100"})
    write_recording(rec, str(d / "still.csv"))
    assert main(["noise", str(d / "still.csv"), "-o", str(d / "noise.yaml")]) == 0
    import yaml
    return d / "noise.yaml", yaml.safe_load((d / "noise.yaml").read_text())


def test_replay_streams_the_per_sample_variance_from_the_noise_file(noise_file, tmp_path, capsys):
    path, doc = noise_file
    n = 300
    rec = Recording(np.arange(n) / FS, acc=np.tile([0, 0, 1.0], (n, 1)), gyro=np.zeros((n, 3)),
                    temp=np.full(n, 25.0), meta={"board": "mpu6050", "rate_hz": "100"})
    write_recording(rec, str(tmp_path / "r.csv"))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"noise:\n  file: {path}\noutput:\n  covariance: true\n")
    capsys.readouterr()
    assert main(["replay", str(tmp_path / "r.csv"), "--config", str(cfg)]) == 0
    lines = [json.loads(l) for l in capsys.readouterr().out.splitlines()]
    imu = [l for l in lines if l["class"] == "IMU"]
    assert len(imu) == n
    for key, sec, u in (("acc_var_g2", "accel", "g"), ("gyro_var_dps2", "gyro", "dps")):
        want = np.array(doc[sec][f"white_density_{u}_rthz"]) ** 2 * FS
        assert np.array(imu[-1][key]) == pytest.approx(want, rel=1e-3)   # 4 significant digits
    cfg.write_text(f"noise:\n  file: {path}\n")                         # off unless asked for
    assert main(["replay", str(tmp_path / "r.csv"), "--config", str(cfg)]) == 0
    assert "acc_var_g2" not in capsys.readouterr().out


def test_covariance_without_a_noise_file_or_with_a_bad_one_is_a_config_error(tmp_path, capsys):
    with pytest.raises(ConfigError, match="needs noise.file"):
        validate({"output": {"covariance": True}})
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: nope\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"noise:\n  file: {bad}\n")
    rec = Recording(np.arange(10) / FS, acc=np.tile([0, 0, 1.0], (10, 1)), meta={"board": "mpu6050", "rate_hz": "100"})
    write_recording(rec, str(tmp_path / "r.csv"))
    assert main(["replay", str(tmp_path / "r.csv"), "--config", str(cfg)]) == 78
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "noise.file" in err and "imucald-noise-1" in err


class _Capture(Executor):
    def __init__(self):
        self.jobs = []

    def submit(self, fn, *a, **kw):
        self.jobs.append(a[0])
        f = Future()
        return f          # never done: the pipeline keeps waiting, which is all we need


def test_pose_covariances_are_inflated_by_the_noise_model(noise_file):
    """The fit job's pose covariances are the poses' own times k(T) of the noise file's Allan
    model at each pose's length (k > 1 here: the accelerometer has flicker noise), applied
    once, by the worker (daemon/fitjob.py _pose_cov: these poses, read back from a file,
    keep no structure function, so nothing else decides); the job carries them as they are."""
    from imucald.daemon.fitjob import _pose_cov
    path, doc = noise_file
    cfg = validate({"noise": {"file": str(path)}})
    ex = _Capture()
    p = Pipeline(cfg, "mpu6050", FS, False, executor=ex, chips={"accel": "mpu6050", "gyro": "mpu6050"})
    p.use_noise_file(str(path))
    rng = np.random.default_rng(0)
    m = 12
    up = rng.normal(size=(m, 3))
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    cov = np.tile(np.eye(3) * 1e-9, (m, 1, 1))
    n = np.linspace(200, 2000, m).astype(int)
    ps = PoseSet(up, cov, n, np.arange(m) * 30.0, np.arange(m) * 30.0 + n / FS, cov * n[:, None, None],
                 gyro=np.zeros((m, 3)), gyro_cov=cov.copy(), meta={"board": "mpu6050"})
    p.acc.load(ps)
    assert p.request_calibration()
    job = ex.jobs[-1]
    k = np.array([inflation_of(np.array(doc["accel"]["avar_coef"]), nn / FS)[0] for nn in n])
    assert k.max() > 1.2                                   # the file's flicker shows at 20 s
    assert np.array_equal(job["acc_cov"], p.acc.pose_set().acc_cov)        # not inflated twice
    got = _pose_cov(job, {})["acc_cov"][:, 0, 0] / 1e-9
    order = np.argsort(p.acc.pose_set().n)
    assert got[order] == pytest.approx(np.sort(k), rel=1e-9)
