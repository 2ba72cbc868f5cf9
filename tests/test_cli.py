"""Command line: simulate -> calibrate, JSON schema, one-line user errors."""
import json
import subprocess
import sys

import numpy as np
import pytest

from imucald.cli import main


def run(*args):
    p = subprocess.run([sys.executable, "-m", "imucald.cli", *args], capture_output=True, text=True)
    return p.returncode, p.stdout, p.stderr


@pytest.fixture(scope="module")
def sim9(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    rec, truth = d / "r.csv", d / "truth.json"
    assert main(["simulate", "-o", str(rec), "--board", "9dof", "--poses", "26", "--hold", "6",
                 "--seed", "5", "--truth", str(truth)]) == 0
    return rec, json.loads(truth.read_text())


def test_calibrate_json_schema_and_values(sim9, capsys):
    rec, truth = sim9
    assert main(["calibrate", str(rec), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["sensor"] == "accel" and out["model"] == "triangular9" and out["method"] == "ga"
    assert out["poses"] == 26
    assert set(out["params"]) == {"bias_g", "scale", "alpha"}
    assert set(out["stderr"]) == set(out["params"])
    for k in ("bias_g", "scale", "alpha"):
        assert len(out["params"][k]) == 3 and len(out["stderr"][k]) == 3
    assert isinstance(out["fitness"], float) and isinstance(out["heldout_rms_g"], float)
    # against the truth, in units of the reported standard errors
    th = np.array(truth["accel_triangular9"])
    est = np.array(out["params"]["alpha"] + out["params"]["scale"] + out["params"]["bias_g"])
    se = np.array(out["stderr"]["alpha"] + out["stderr"]["scale"] + out["stderr"]["bias_g"])
    assert np.all(np.abs(est - th) < 4 * se)


def test_raw_table_options_on_a_recording_are_said_to_be_ignored(sim9, capsys):
    """An imucald recording is read as it is (its header names its columns, in g): a user who
    took it for counts and gave --nominal-scale (or --columns) got the same fit with no word
    (a newcomer's walk).  Now one warning names the options ignored; the answer is the same.
    Broken once (no warning): fails."""
    rec, _ = sim9
    assert main(["calibrate", str(rec), "--json"]) == 0
    plain = capsys.readouterr()
    assert "warning" not in plain.err
    assert main(["calibrate", str(rec), "--json", "--nominal-scale", "16384", "--columns", "t,ax,ay,az"]) == 0
    got = capsys.readouterr()
    strip = lambda o: {k: v for k, v in json.loads(o).items() if k != "wall_s"}
    assert strip(got.out) == strip(plain.out)
    assert got.err.count("\n") == 1 and got.err == (
        f"imucald: warning: {rec}: an imucald recording (its header names its columns, in g, deg/s and "
        f"gauss): --columns, --nominal-scale apply to raw tables only and are ignored\n"), got.err


def test_calibrate_mag_and_gyro(sim9, capsys):
    rec, truth = sim9
    assert main(["calibrate", str(rec), "--sensor", "mag", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["model"] == "mag_sym"
    v = np.array(out["params"]["hard_iron_gauss"])
    se = np.array(out["stderr"]["hard_iron_gauss"])
    assert np.all(np.abs(v - truth["mag_hard_iron_gauss"]) < 4 * se + 1e-4)
    W = np.array(truth["mag_soft_iron"])
    F_true = truth["field_gauss"] / np.linalg.det(W) ** (1 / 3)   # field in the det(W) = 1 gauge
    assert out["params"]["field_gauss"] == pytest.approx(F_true, abs=4 * out["stderr"]["field_gauss"] + 1e-4)
    assert main(["calibrate", str(rec), "--sensor", "gyro", "--json"]) == 0
    g = json.loads(capsys.readouterr().out)
    assert np.all(np.abs(np.array(g["params"]["bias_dps"]) - truth["gyro_bias_dps"])
                  < 4 * np.array(g["stderr"]["bias_dps"]) + 0.01)


def test_text_output_mentions_residuals(sim9):
    rc, out, err = run("calibrate", str(sim9[0]), "--method", "lm")
    assert rc == 0
    assert "held-out" in out and "bias_g" in out
    assert "still poses" in err


@pytest.mark.parametrize("args,msg", [
    (["calibrate", "/nonexistent/file.csv"], "cannot open"),
    (["calibrate", "{rec}", "--model", "mag_sym"], "does not fit --sensor accel"),
    (["calibrate", "{table}"], "--columns"),
    (["calibrate", "{table}", "--columns", "t,ax,ay,qq"], "unknown column 'qq'"),
    (["calibrate", "{table}", "--columns", "t,ax,ay,az"], "only 0 still poses"),
    (["simulate", "-o", "{out}", "--euler", "1,2"], "three integers"),
])
def test_user_errors_are_one_line_exit_2(sim9, tmp_path, args, msg):
    table = tmp_path / "t.txt"
    table.write_text("0 1 2 3\n0.01 1 2 3\n")
    args = [a.format(rec=sim9[0], table=table, out=tmp_path / "o.csv") for a in args]
    rc, out, err = run(*args)
    assert rc == 2
    assert msg in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_parser_choices_come_from_their_owners():
    """The CLI's board, method and format choices are the owners' lists, not copies."""
    from imucald.fitting.solvers.optim import METHODS
    from imucald.cli.boards import EMULATED_BOARDS
    from imucald.cli.parser import build_parser
    from imucald.daemon.config import SCHEMA
    from imucald.drivers.board import BOARD_NAMES
    assert set(SCHEMA["calibration.method"][2]) == set(METHODS)
    assert tuple(SCHEMA["sensor.board"][2]) == BOARD_NAMES
    assert set(BOARD_NAMES) < set(EMULATED_BOARDS)
    sub = next(a for a in build_parser()._actions if a.dest == "cmd").choices
    opt = lambda cmd, flag: next(a for a in sub[cmd]._actions if flag in a.option_strings).choices
    assert set(opt("calibrate", "--method")) == set(METHODS) == set(opt("run", "--method"))
    assert tuple(opt("record", "--board")) == BOARD_NAMES


def test_help_does_not_import_numpy():
    """`imucald --help` stays light: command modules import their heavy dependencies lazily."""
    code = ("import sys; from imucald.cli import build_parser; build_parser(); "
            "print(sorted(m for m in ('numpy', 'imucald.sim.sensor', 'imucald.sim.emulators', "
            "'imucald.gap.diagnose') if m in sys.modules))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "[]"


@pytest.mark.parametrize("argv", [["--help"], ["status"], ["watch"]])
def test_light_commands_load_no_heavy_module(argv, tmp_path):
    """--help, status and watch (here with no daemon: they stop at the missing socket after
    loading all they need) load neither numpy, the YAML parser (no configuration file is
    read), the I2C bus layer nor the calibration code (issue 15: fast start)."""
    heavy = ("numpy", "yaml", "imucald.drivers.bus", "imucald.fitting", "imucald.daemon.pipeline",
             "imucald.specs", "dataclasses")
    extra = [] if argv == ["--help"] else ["--runtime-dir", str(tmp_path)]
    code = ("import sys, contextlib, io\nfrom imucald.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    try:\n        main(sys.argv[1:])\n    except SystemExit:\n        pass\n"
            f"print(sorted(m for m in {heavy!r} if m in sys.modules))")
    p = subprocess.run([sys.executable, "-c", code, *argv, *extra], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "[]"


@pytest.mark.parametrize("effect", [[], ["--effect", "gyro.thermal_bias"]])
def test_simulate_sway_deg_reaches_the_motion(tmp_path, effect):
    """`simulate --sway-deg` sways the board (the simulator draws the sway after everything
    else, so the same seed without it is the same session but for the sway): 0 changes
    nothing, 0.3 deg moves the accelerometer's direction within the holds by about that
    much.  Seen to fail with the flag parsed but not passed on (both sessions identical),
    on either path (plain, and with --effect)."""
    from imucald.files.recording import read_recording
    base = ["simulate", "--seed", "3", "--poses", "10", "--hold", "4", *effect]
    names = []
    for sway in (None, "0", "0.3"):
        out = tmp_path / f"s{sway}.csv"
        assert main(base + ["-o", str(out)] + ([] if sway is None else ["--sway-deg", sway])) == 0
        names.append(read_recording(out))
    a, z, s = names
    assert np.array_equal(a.acc, z.acc) and np.array_equal(a.gyro, z.gyro)
    # the direction change between the swayed and the plain session's samples, deg
    cos = np.sum(a.acc * s.acc, 1) / np.linalg.norm(a.acc, axis=1) / np.linalg.norm(s.acc, axis=1)
    dev = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    assert 0.1 < np.median(dev) < 1.0, np.median(dev)


def test_every_numeric_option_refuses_nan_and_inf_up_front(capsys):
    """Every option the parser converts (a type other than str) refuses 'nan' and 'inf' in
    one argparse line naming the option (exit 2), before any command runs: before this,
    `--seed -1` gave a numpy traceback in every command, `noise --rate-hz nan` a traceback,
    and `simulate --magnitude nan` wrote a recording of NaN that nothing reads.  A seed is
    an integer >= 0, a bus number 0..99.  Broken once each: calibrate's --seed back to type=int,
    noise's --rate-hz back to type=float: each fails."""
    from imucald.cli import main
    from imucald.cli.parser import build_parser
    sub = next(a for a in build_parser()._actions if a.dest == "cmd").choices
    typed = [(cmd, a.option_strings[0]) for cmd, sp in sub.items() for a in sp._actions
             if a.option_strings and a.type not in (None, str) and a.nargs != 0]
    assert len(typed) > 30
    for cmd, flag in typed:
        for bad in ("nan", "inf"):
            with pytest.raises(SystemExit) as e:
                main([cmd, flag, bad])
            err = capsys.readouterr().err
            assert e.value.code == 2 and f"argument {flag}" in err and err.count("\n") == 1, (cmd, flag, err)
    for cmd, flag in (("calibrate", "--seed"), ("simulate", "--seed"), ("probe", "--bus"),
                      ("run", "--bus")):
        with pytest.raises(SystemExit):
            main([cmd, flag, "-1"])
        assert f"argument {flag}: -1 is" in capsys.readouterr().err


def test_the_bus_number_limit_is_the_configurations():
    """--bus and sensor.bus take the same range (two declarations, one of them numpy- and
    YAML-free for --help: this keeps them one).  Broken once: BUS_NUMBER_MAX 127 (fails)."""
    from imucald.cli.checks import BUS_NUMBER_MAX
    from imucald.daemon.config import SCHEMA
    assert SCHEMA["sensor.bus"][2] == (0, BUS_NUMBER_MAX)


@pytest.mark.parametrize("argv", [["calibrate", "REC", "--plot", "DIR"], ["gap", "REC", "--report", "DIR"],
                                  ["noise", "REC", "--plot", "DIR"], ["status", "--plot", "DIR/c.png"]])
def test_a_missing_plots_extra_is_said_before_any_work(argv, tmp_path, monkeypatch, capsys):
    """Without matplotlib, --plot (--report) said so only after the fit had printed its
    report: now one line before anything runs, naming the extra.  Broken once: the check in
    check_args removed (4 of 4 fail: the commands' own errors come instead)."""
    import importlib.util
    from imucald.cli import main
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "matplotlib" else real(name, *a))
    rec = tmp_path / "r.csv"
    rec.write_text("not read\n")
    (tmp_path / "p").mkdir()
    argv = [str(rec) if a == "REC" else a.replace("DIR", str(tmp_path / "p")) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"needs matplotlib, the plots extra: {sys.executable} -m pip install " \
        "'imucald[plots]'" in err, err


def test_an_unknown_option_names_the_nearest_and_the_commands_help(capsys):
    """A typo in an option ('--colums') was 'unrecognized arguments ... (see imucald --help)':
    the top-level help, and no hint.  Now the command's parser says it, with the nearest of
    its options when one is close, in one line.  Broken once: parse_args as before (fails)."""
    from imucald.cli import main
    with pytest.raises(SystemExit) as e:
        main(["calibrate", "x.csv", "--colums", "t,ax,ay,az"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1
    assert err.startswith("imucald calibrate: error: unrecognized arguments: --colums t,ax,ay,az "
                          "(did you mean --columns?) (see 'imucald calibrate --help')"), err
    with pytest.raises(SystemExit):
        main(["gap", "x.csv", "--zzz"])
    assert "unrecognized arguments: --zzz (see 'imucald gap --help')" in capsys.readouterr().err
    # words after '--' are positionals: no option suggested for them (a cold review)
    with pytest.raises(SystemExit):
        main(["calibrate", "x.csv", "--", "--colums"])
    assert "did you mean" not in capsys.readouterr().err


def test_echo_prints_every_event_and_one_sample_a_second(capsys, tmp_path):
    """make run's --echo printed the last line of a batch once a second, so 4 of the demo's 5
    CAL events never showed (newcomer walk-through); with --format binary it decoded record
    bytes as text.  Now every event line (a JSON object other than a sample, a CSV '# '
    comment) and one sample a second; binary refused up front.  Broken once: the event lines
    dropped (fails)."""
    from types import SimpleNamespace
    from imucald.cli import main
    from imucald.daemon.run import Daemon
    d = SimpleNamespace()
    imu = b'{"class":"IMU","seq":%d}'
    batch = b"\n".join([imu % 1, b'{"class":"CAL","id":1}', imu % 2, b""])
    Daemon._echo(d, batch, 100.0)
    assert capsys.readouterr().out.splitlines() == ['{"class":"CAL","id":1}', '{"class":"IMU","seq":2}']
    Daemon._echo(d, b"\n".join([imu % 3, b'{"class":"CAL","id":2}', b""]), 100.5)
    assert capsys.readouterr().out.splitlines() == ['{"class":"CAL","id":2}']
    Daemon._echo(d, b"1.0,0,0,1\n# {\"class\":\"GAP\"}\n", 101.5)
    assert capsys.readouterr().out.splitlines() == ['# {"class":"GAP"}', "1.0,0,0,1"]
    assert main(["run", "--emulate", "--echo", "--format", "binary", "--duration", "1",
                 "--state-dir", str(tmp_path / "s"), "--runtime-dir", str(tmp_path / "r")]) == 2
    assert "output.format binary has none" in capsys.readouterr().err


def test_a_column_list_starting_with_a_skipped_column_needs_no_equals_sign(tmp_path, capsys):
    """``--columns -,t,ax,...`` (a logger's index column first, skipped) was argparse's bare
    "expected one argument": the value starts with "-".  It now reads as ``--columns=-,t,...``.
    Broken once: without ``_glue_column_lists`` in cli.main (exit 2, that message)."""
    raw = tmp_path / "indexed.csv"
    t = np.arange(200) / 100.0
    rows = np.column_stack([np.arange(200), t, np.tile([0.0, 0.0, 1.0], (200, 1))])
    np.savetxt(raw, rows, delimiter=",", fmt="%.6f")
    rc = main(["calibrate", str(raw), "--columns", "-,t,ax,ay,az"])
    err = capsys.readouterr().err
    # the reader took the columns (the index skipped, t the time): constant axes, by name
    assert rc == 2 and "ax (always 0), ay (always 0), az (always 1)" in err, err
    # nothing after '--' is glued (it is a positional there)
    from imucald.cli import _glue_column_lists
    assert _glue_column_lists(["x", "--columns", "-,t", "--", "--columns", "-,t"]) == \
        ["x", "--columns=-,t", "--", "--columns", "-,t"]
    # an abbreviation argparse accepts (--col) is glued as typed (a cold review)
    assert _glue_column_lists(["x", "--col", "-,t", "--join-col", "-,t"]) == ["x", "--col=-,t", "--join-col=-,t"]


def test_no_still_moment_in_the_wrong_unit_asks_for_the_scale_first(tmp_path, capsys):
    """A phone's log in m/s^2 given no --nominal-scale: every quiet stretch reads |a| ~ 9.8 g,
    and the error ended "hold the board still for a few seconds", the wrong fix (a newcomer's
    walk).  It now says to check --nominal-scale first.  A noisier phone (0.03 m/s^2, read as
    0.03 g: no window quiet enough) still got "hold the board still" (a cold review); its
    median |a| of 9.8 "g" now says the unit too.  Broken once: the fix text without the units
    case (fails); without the median |a| (the 0.03 case fails)."""
    rng = np.random.default_rng(0)
    ups = rng.normal(size=(12, 3))
    ups /= np.linalg.norm(ups, axis=1, keepdims=True)
    for noise in (0.01, 0.03):
        a = np.repeat(ups, 300, axis=0) * 9.80665 + rng.normal(scale=noise, size=(3600, 3))
        p = tmp_path / "phone.csv"
        np.savetxt(p, np.column_stack([np.arange(3600) / 100.0, a]), delimiter=",", fmt="%.6f")
        assert main(["calibrate", str(p), "--columns", "t,ax,ay,az"]) == 2
        last = capsys.readouterr().err.strip().splitlines()[-1]
        assert "no still moment" in last and last.endswith(
            "check --nominal-scale first (is the file in g? counts or m/s^2 read as g fail every test), "
            "then hold the board still for a few seconds in each orientation"), (noise, last)
