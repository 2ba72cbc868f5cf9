"""Issue 23's fixes to what a new user meets first: the coverage hint moves through the
missing orientations, `--json` errors are one JSON object, `watch -n` counts samples,
the emulated chips' block-wise motion gives the motion's own values, and the
pose-coverage picture is drawn from the poses."""
import json

import numpy as np
import pytest

from imucald.fitting.judging.coverage import (
    TARGETS, cube_coverage, next_orientation, target_name, target_vector
)
from imucald.cli import main


def test_the_hint_moves_through_every_missing_orientation():
    """Breakage it catches: the former hint, the first missing orientation every time
    (`next: try -X up` for 25 poses while the user placed the board elsewhere)."""
    missing = cube_coverage(np.array([[0, 0, 1.0]]))["missing"]          # +Z up only
    assert len(missing) == 25
    hinted, asked = {}, []
    for k in range(len(missing)):
        n = next_orientation(missing, hinted, up=[0, 0, 1.0])
        hinted[n] = hinted.get(n, 0) + 1
        asked.append(n)
    assert sorted(asked) == sorted(missing)              # each once before any twice
    assert all(a.count("+") + a.count("-") == 1 for a in asked[:5])   # faces first,
    assert asked[4] == "-Z up"                  # the turn over (from +Z up) last among them
    assert next_orientation([], {}) is None


def test_the_hint_prefers_the_nearest_orientation_among_equals():
    m = ["-Z up", "+X up", "-X up"]
    assert next_orientation(m, {}, up=[0.9, 0.1, 0.3]) == "+X up"
    assert next_orientation(m, {}, up=[-0.9, 0.1, 0.3]) == "-X up"
    assert next_orientation(m, {"+X up": 1}, up=[0.9, 0.1, 0.3]) == "-Z up"   # nearer than -X


def test_target_vector_inverts_target_name():
    for v in TARGETS:
        np.testing.assert_allclose(target_vector(target_name(v)), v, atol=1e-12)


def test_json_errors_are_one_json_object(tmp_path, capsys):
    """Breakage it catches: calibrate --json answering a user error in plain text only (the
    issue's `calibrate session.csv --sensor mag --json` on an accelerometer recording), and
    an argument error under --json."""
    rec = str(tmp_path / "s.csv")
    assert main(["simulate", "-o", rec, "--poses", "12", "--hold", "2", "--seed", "1"]) == 0
    capsys.readouterr()
    assert main(["calibrate", rec, "--sensor", "mag", "--json"]) == 2
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and json.loads(out[0]) == {
        "error": f"{rec}: no magnetometer columns (mx, my, mz)", "exit_code": 2}
    with pytest.raises(SystemExit) as e:
        main(["calibrate", rec, "--sensor", "nope", "--json"])
    assert e.value.code == 2
    d = json.loads(capsys.readouterr().out)
    assert d["exit_code"] == 2 and "--sensor" in d["error"]
    assert main(["calibrate", rec, "--sensor", "mag"]) == 2           # without --json: stderr only
    assert capsys.readouterr().out == ""


def test_watch_counts_samples_not_the_banner_or_events():
    """Breakage it catches: `watch -n 5` printing the VERSION line and four samples."""
    from imucald.cli.service import is_sample_line
    assert not is_sample_line(b'{"class":"VERSION","release":"0.1.0","proto_major":1}\n')
    assert not is_sample_line(b'{"class":"CAL","id":2,"applied":true}\n')
    assert not is_sample_line(b'{"class":"GAP","seq":1,"missing":3}\n')
    assert is_sample_line(b'{"class":"IMU","seq":12,"t":0.12,"acc_g":[0,0,1],"still":true,"cal":0}\n')
    assert not is_sample_line(b"seq,t,ax,ay,az,gx,gy,gz,mx,my,mz,temp,still,cal\n")
    assert not is_sample_line(b'# {"class":"CAL","id":1}\n')
    assert is_sample_line(b"12,0.12,0,0,1,,,,,,,,1,0\n")


def test_watch_says_so_when_the_daemon_closes_the_stream(tmp_path, capsys):
    """A watcher whose daemon stops must not end as if all went well.  Breakage it catches:
    `watch` returning 0 with no word when the stream ends before -n samples (the old code)."""
    import socket
    import threading
    from imucald.cli import main
    sock = tmp_path / "imucald.sock"
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    srv.bind(str(sock))
    srv.listen(1)

    def serve():                                   # a daemon that sends 2 samples, then dies
        c, _ = srv.accept()
        c.sendall(b'{"class":"VERSION","release":"x","proto_major":2}\n'
                  b'{"class":"IMU","seq":1,"t":0.01,"acc_g":[0,0,1],"still":true,"cal":0}\n'
                  b'{"class":"IMU","seq":2,"t":0.02,"acc_g":[0,0,1],"still":true,"cal":0}\n')
        c.close()
    th = threading.Thread(target=serve, daemon=True)
    th.start()
    code = main(["watch", "--runtime-dir", str(tmp_path), "-n", "5"])
    th.join(5)
    srv.close()
    err = capsys.readouterr().err
    assert code == 69, err
    assert "closed the stream after 2 samples" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_grid_motion_serves_the_motion_itself():
    """The block-wise motion the emulated chips read (the record speed-up) gives the values
    the motion model gives at the same times, on and off the chip's grid."""
    from imucald.sim.emulators.base import GridMotion
    from imucald.sim.motion import PoseTour
    from imucald.sim.orientations import random_pose_set
    rng = np.random.default_rng(5)
    tour = PoseTour(random_pose_set(6, rng), rng=rng, tremor_dps=1.0)

    class Dev:
        def odr_hz(self):
            return 100.0
    g = GridMotion(tour, Dev())
    t_next = 0.013
    for _ in range(700):                           # one sample per poll, as the ITG-3200
        t = np.array([t_next])
        a, b = g.sample(t), tour.sample(t)
        for k in ("f", "w", "h", "temp", "R"):
            np.testing.assert_allclose(a[k], b[k], rtol=0, atol=1e-9)
        assert a["still"][0] == b["still"][0]
        t_next += 0.01
    t = np.array([0.0171, 0.0234])                  # off the grid: the motion itself
    np.testing.assert_allclose(g.sample(t)["f"], tour.sample(t)["f"], rtol=0, atol=0)
    assert g.duration_s == tour.duration_s


def test_coverage_picture_maps_each_hemisphere_equal_area(tmp_path):
    from imucald.plots.coverage import lambert_disc, write_coverage
    u = np.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0, 1.0, 0]])
    p = lambert_disc(u)
    np.testing.assert_allclose(p, [[0, 0], [0, 0], [1, 0], [0, 1]], atol=1e-12)
    # equal area: the cap within 60 deg of the pole (a quarter of the sphere) fills a quarter
    # of the disc, i.e. radius 1/2... of area: r^2 = 1 - cos(60 deg) = 0.5
    c = np.array([[np.sin(np.radians(60)), 0, np.cos(np.radians(60))]])
    assert abs(np.hypot(*lambert_disc(c)[0]) ** 2 - 0.5) < 1e-12
    path = write_coverage(str(tmp_path / "c.png"), np.array([[0, 0, 1.0], [1, 0, 0.0]]),
                          next_orientation="-Z up")
    assert open(path, "rb").read(4) == b"\x89PNG"
