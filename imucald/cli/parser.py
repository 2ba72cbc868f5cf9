"""The ``imucald`` argument parser.

Choices come from the modules that own them: boards, formats, methods and log
levels from the daemon's configuration schema, simulated boards from the
datasheet table, emulated boards from the board factory.  Each subcommand names
its command function as (module, function); the module is imported only when
that command runs, so ``imucald --help`` loads neither numpy nor the simulator.

``build_parser(command)`` builds that one subcommand only (``build_parser("")`` lists
them all by their help line): building all of them, and importing the modules that own
their choices, was a tenth of ``imucald status``'s start.
"""
from __future__ import annotations

import argparse
import importlib
from typing import Optional

from .. import __version__
from .checks import (LIMITS, at_least, bus_number, count_in, finite_float, fraction, number_in,
                     per_sensor, positive_float, seed)


def _lim(name: str):
    lo, hi, unit = LIMITS[name]
    return number_in(lo, hi, unit, low_open=lo == 0.0)


def _choices(key: str):
    from ..daemon.config import SCHEMA
    return list(SCHEMA[key][2])


def _command(module: str, name: str):
    """The command function ``name`` of ``imucald.cli.<module>``, imported when called."""
    def run(args) -> int:
        return getattr(importlib.import_module(f"{__package__}.{module}"), name)(args)
    run.__name__ = name
    return run


class OneLineParser(argparse.ArgumentParser):
    """A usage error is one line, as every other error (exit 2), naming --help; when the
    command line asks for ``--json``, also one JSON object on stdout."""

    json_errors = False             # set by cli.main when --json is among the words
    _checking = False

    def add_argument(self, *args, **kwargs):
        # argparse makes a help formatter for each argument only to check its metavar, which
        # does not depend on the width: given one, the formatter does not ask the terminal
        # (shutil, and bz2/lzma under it: ~1.8 ms of every command's start)
        self._checking = True
        try:
            return super().add_argument(*args, **kwargs)
        finally:
            self._checking = False

    def _get_formatter(self):
        if self._checking:
            return self.formatter_class(prog=self.prog, width=80)
        return super()._get_formatter()

    def error(self, message):
        line = f"{message} (see '{self.prog} --help')"
        if OneLineParser.json_errors:
            import json
            import sys
            print(json.dumps({"error": line, "exit_code": 2}), file=sys.stdout)
        self.exit(2, f"{self.prog}: error: {line}\n")


def _add_simulate(s) -> None:
    from ..specs import BOARDS as SIM_BOARDS
    s.add_argument("-o", "--output", required=True, help="recording file to write")
    s.add_argument("--board", default="mpu6050", choices=list(SIM_BOARDS))
    s.add_argument("--poses", type=count_in(1, 10000), default=30, help="number of well-spread orientations")
    s.add_argument("--euler", help="paper 000 pose set NX,NY,NZ instead of --poses")
    s.add_argument("--rate", type=_lim("rate"), default=100.0, help="sample rate, Hz")
    s.add_argument("--hold", type=_lim("hold"), default=10.0, help="mean still time per pose, s")
    s.add_argument("--move", type=_lim("move"), default=3.0, help="mean move time between poses, s")
    s.add_argument("--temp-profile", default="warmup", choices=["warmup", "ramp", "heatcool", "constant"])
    s.add_argument("--temp-rise", type=number_in(*LIMITS["temp_rise"][:2], "degC", low_open=False), default=6.0,
                   help="temperature change, degC")
    s.add_argument("--seed", type=seed, default=0)
    s.add_argument("--tremor-dps", type=number_in(0, LIMITS["tremor"][1], "deg/s", low_open=False), default=0.0,
                   help="hand tremor (6-12 Hz) RMS per gyro axis, deg/s; real hands 0.5-2")
    s.add_argument("--sway-deg", type=number_in(0, LIMITS["sway"][1], "deg", low_open=False), default=0.0,
                   help="a hand's slow sway (0.2-2 Hz), RMS angle per axis, deg; real hands 0.05-0.4")
    s.add_argument("--truth", help="also write the true parameters as JSON here")
    s.add_argument("--effect", action="append", help="inject an unmodelled effect: NAME or NAME=MAGNITUDE, "
                   "e.g. thermal_bias, accel.nonlinearity=0.002, gyro.g_sensitivity, mag.thermal_bias; "
                   "'none' for a baseline-only recording (repeatable)")
    s.add_argument("--magnitude", type=finite_float, help="magnitude of the single --effect (default: datasheet)")
    s.add_argument("--logger-rate", type=positive_float, metavar="HZ",
                   help="sample-and-hold: a logger reads the chip (at --rate) at HZ, repeating its latest "
                        "sample (e.g. --rate 100 --logger-rate 385: each value 3-4 times)")
    s.add_argument("--duplicate-rows", action="store_true",
                   help="write every row twice, timestamp included (a logger fault seen in the wild)")
    s.add_argument("--fifo-burst", type=positive_float, metavar="S",
                   help="a logger that drains the chip's FIFO every S seconds and stamps each burst's rows "
                        "with its read time (e.g. --rate 400 --fifo-burst 0.1: 40 rows a stamp)")
    s.set_defaults(func=_command("offline", "cmd_simulate"))


def _raw_table_options(p, example: str) -> None:
    """The options that read a raw numeric table (a logger's file) as a recording."""
    p.add_argument("--columns", help=f"raw table columns, e.g. {example} (- skips one; the time as "
                                     f"t_ms, t_us or t_ns when in ms, us or ns)")
    p.add_argument("--nominal-scale", type=per_sensor, default=1.0,
                   help="raw table: counts per unit (g, deg/s, gauss), e.g. 16384, or one per "
                        "sensor, e.g. accel=16384,gyro=131 (temp=N with --nominal-offset temp=N: a "
                        "temperature in counts, e.g. 340 and -12420.2 for an MPU-6050)")
    p.add_argument("--nominal-offset", type=per_sensor, default=0.0,
                   help="raw table: counts at zero input, e.g. 32768 for unsigned 16-bit (or "
                        "accel=N,gyro=N,temp=N)")
    p.add_argument("--rate-hz", type=positive_float,
                   help="raw table: the sample rate (needed without a time column; with one, within "
                        "100x of its steps)")
    p.add_argument("--board", choices=_choices("sensor.board"),
                   help="raw table: the board it was logged from; its chips' datasheet figures are "
                        "used (stillness limits, priors), and calibrate -o writes it into the file, "
                        "which a daemon on that board loads (without it: board 'unknown', set aside)")
    _join_options(p)


def _join_options(p) -> None:
    """--join and --join-columns: a second raw table of the same session (fitting.inputs.join_tables)."""
    p.add_argument("--join", metavar="FILE",
                   help="raw table: a second table of the same session (its columns by --join-columns), "
                        "its sensors joined to the first's by time, e.g. IMU-TK's xsens_gyro.mat beside "
                        "xsens_acc.mat, or a magnetometer logged to its own file")
    p.add_argument("--join-columns", metavar="COLUMNS", help="--join's columns, e.g. t,gx,gy,gz")


def _add_calibrate(c) -> None:
    from ..stillness_defaults import STILLNESS_DEFAULTS as _ST
    from .offline import SENSORS
    c.add_argument("input", help="recording, pose file, or raw table (with --columns)")
    c.add_argument("--sensor", choices=(*SENSORS, "all"), help="default accel; mag for a recording with "
                   "magnetometer columns only; all: every part the recording supports, in one file")
    c.add_argument("--method", default="ga", choices=_choices("calibration.method"))
    c.add_argument("--model", help="accel: triangular9 (default), diag6, full12, cosine[-o|-s|-os|-om|-sm], "
                                   "auto (order by leave-one-pose-out error); "
                                   "mag: mag_sym (default), mag_diag, mag_sphere; gyro: mean, eq6")
    c.add_argument("--json", action="store_true", help="print one JSON object")
    c.add_argument("-o", "--output", help="also write the calibration file (the daemon's calibration.yaml "
                                          "format, read by imucald.load_calibration)")
    c.add_argument("--plot", metavar="DIR", help="accel: write coverage.png (the pose-coverage sphere) and "
                                             "residuals.png (|a| - 1 g per pose before/after) here (plots extra)")
    c.add_argument("--seed", type=seed, default=0, help="seed for the GA")
    c.add_argument("--start-s", type=finite_float, help="use the recording from this time (s after its first "
                                                        "sample), e.g. after a warm-up")
    c.add_argument("--end-s", type=finite_float, help="use the recording up to this time (s after its first "
                                                      "sample), e.g. before the board was carried elsewhere")
    _raw_table_options(c, "t,ax,ay,az")
    c.add_argument("--window-s", type=_lim("window"), default=_ST["window_s"], help="still detector window, s")
    c.add_argument("--threshold-k", type=positive_float, default=_ST["k"],
                   help="still when the accelerometer's moving variance < k x its noise floor")
    c.add_argument("--min-still-s", type=_lim("window"), default=_ST["min_still_s"],
                   help="shortest still interval, s")
    c.add_argument("--thermal-min-span", type=positive_float, default=10.0, metavar="DEGC",
                   help="accel and gyro: fit a bias polynomial in temperature (order 0-3 by held-out "
                        "error) when the still poses span at least this many degC (default 10); "
                        "below it a constant only")
    c.set_defaults(func=_command("offline", "cmd_calibrate"))


def _add_apply(ap) -> None:
    ap.add_argument("calibration", help="calibration file (calibrate -o, or the daemon's state)")
    ap.add_argument("recording", help="recording, or raw table (with --columns)")
    ap.add_argument("-o", "--output", required=True, help="corrected recording to write")
    ap.add_argument("--orientation", metavar="FILE",
                    help="also write the orientation of the corrected samples to this CSV table "
                         "(the orientation extra)")
    _raw_table_options(ap, "t,ax,ay,az,gx,gy,gz,temp")
    ap.set_defaults(func=_command("thermal", "cmd_apply"))


def _add_probe(pr) -> None:
    from .boards import EMULATED_BOARDS
    pr.add_argument("--bus", type=bus_number, help="bus number N of /dev/i2c-N (default 1, or the first present)")
    pr.add_argument("--emulate", choices=EMULATED_BOARDS,
                    help="probe an emulated board instead of hardware")
    pr.set_defaults(func=_command("hardware", "cmd_probe"))


def _add_record(r) -> None:
    r.add_argument("-o", "--output", required=True)
    r.add_argument("--board", default="mpu6050", choices=_choices("sensor.board"))
    r.add_argument("--mag", default="auto", choices=_choices("sensor.magnetometer"),
                   help="9dof/gy273 magnetometer: found by ID (auto) or forced; emulated: auto = "
                        "HMC5883L on 9dof, QMC5883L on gy273")
    r.add_argument("--seconds", type=_lim("seconds"), default=10.0)
    r.add_argument("--rate", type=_lim("rate"), default=100.0, help="sample rate, Hz")
    r.add_argument("--bus", type=bus_number, help="bus number N of /dev/i2c-N (default 1)")
    r.add_argument("--emulate", action="store_true", help="use the emulated board even if a bus exists")
    r.add_argument("--realtime", action="store_true", help="emulator runs in wall-clock time")
    r.add_argument("--poses", type=count_in(1, 10000), default=30, help="emulator: orientations to move through")
    r.add_argument("--seed", type=seed, default=0, help="emulator: seed")
    r.add_argument("--tremor-dps", type=number_in(0, LIMITS["tremor"][1], "deg/s", low_open=False), default=0.0,
                   help="emulator: hand tremor (6-12 Hz) RMS per gyro axis, deg/s; real hands 0.5-2")
    r.add_argument("--fault", action="append", help="emulator fault, e.g. nack=0.01, reset=0x68@3 "
                                                    "(repeatable; see docs/guide/recording.md)")
    r.set_defaults(func=_command("hardware", "cmd_record"))


def daemon_opts(q, state=True) -> None:
    from .service import DEFAULT_CONFIG
    q.add_argument("--config", help=f"configuration file (default {DEFAULT_CONFIG} if present)")
    q.add_argument("--runtime-dir", help="directory of the sockets (overrides runtime.directory)")
    if state:
        q.add_argument("--state-dir", help="overrides state.directory")
    q.add_argument("--log-level", choices=_choices("log.level"))


def _add_run(rn) -> None:
    daemon_opts(rn)
    rn.add_argument("--board", choices=_choices("sensor.board"))
    rn.add_argument("--mag", choices=_choices("sensor.magnetometer"),
                    help="9dof/gy273 magnetometer (overrides sensor.magnetometer)")
    rn.add_argument("--rate", type=_lim("rate"), help="sample rate, Hz")
    rn.add_argument("--bus", type=bus_number, help="bus number N of /dev/i2c-N")
    rn.add_argument("--format", choices=_choices("output.format"))
    rn.add_argument("--fifo", help="also stream to this FIFO")
    rn.add_argument("--orientation", choices=_choices("output.orientation"),
                    help="orientation in the stream (the orientation extra): auto, yes, no")
    rn.add_argument("--method", choices=_choices("calibration.method"))
    rn.add_argument("--min-poses", type=int)
    g = rn.add_mutually_exclusive_group()
    g.add_argument("--emulate", action="store_true", help="use the emulated board")
    g.add_argument("--no-emulate", action="store_true", help="never fall back to the emulator")
    rn.add_argument("--speed", type=_lim("speed"), default=1.0, help="emulator: time runs this much faster")
    rn.add_argument("--seed", type=seed, default=0, help="emulator: seed")
    rn.add_argument("--tremor-dps", type=number_in(0, LIMITS["tremor"][1], "deg/s", low_open=False), default=1.0,
                    help="emulator: hand tremor RMS per gyro axis, deg/s (default 1: a hand-held "
                         "tour with 1.5-4 s holds; 0: a board set down on a bench)")
    rn.add_argument("--fault", action="append", help="emulator fault (as for record)")
    rn.add_argument("--duration", type=_lim("duration"), help="stop after this many (sensor-clock) seconds")
    rn.add_argument("--echo", action="store_true", help="print every event line (CAL, GAP) and one sample line a second")
    rn.set_defaults(func=_command("service", "cmd_run"))


def _add_replay(rp) -> None:
    rp.add_argument("recording", help="recording, or raw table (with --columns)")
    _raw_table_options(rp, "t,ax,ay,az,gx,gy,gz,temp")
    rp.add_argument("--state-dir", help="start from DIR/calibration.yaml when there is one, and save the "
                                        "calibration reached there (one it replaces is kept as DIR/history/replaced-TIME.yaml)")
    rp.add_argument("--config")
    rp.add_argument("--format", choices=_choices("output.format"))
    rp.add_argument("--orientation", choices=_choices("output.orientation"),
                    help="orientation in the stream (the orientation extra): auto, yes, no")
    rp.add_argument("--method", choices=_choices("calibration.method"))
    rp.add_argument("--min-poses", type=int)
    rp.add_argument("--log-level", choices=_choices("log.level"))
    rp.set_defaults(func=_command("service", "cmd_replay"))


def _add_status(q) -> None:
    daemon_opts(q, state=False)
    q.add_argument("--json", action="store_true")
    q.add_argument("--plot", metavar="FILE", help="also draw the pose-coverage sphere (poses collected, "
                                              "orientations missing) into FILE, .png or .svg (plots extra)")
    q.set_defaults(func=_command("service", "cmd_status"))


def _add_recalibrate(q) -> None:
    daemon_opts(q, state=False)
    q.set_defaults(func=_command("service", "cmd_recalibrate"))


def _add_watch(w) -> None:
    daemon_opts(w, state=False)
    w.add_argument("-n", "--count", type=at_least(1), help="stop after N samples (IMU lines; the VERSION banner and events are printed, not counted)")
    w.set_defaults(func=_command("service", "cmd_watch"))


def _add_gap(gp) -> None:
    from .offline import SENSORS
    gp.add_argument("recording")
    gp.add_argument("--sensor", action="append", choices=SENSORS,
                    help="sensor(s) to diagnose (default: all present)")
    gp.add_argument("--json", action="store_true", help="print one JSON object")
    gp.add_argument("--report", help="write plots to this directory (needs the plots extra)")
    gp.add_argument("--sims", type=count_in(20, 5000, " (p-values need some resolution)"), default=200,
                    help="twin re-simulations (20..5000)")
    gp.add_argument("--seed", type=seed, default=0)
    _raw_table_options(gp, "t,ax,ay,az,temp")
    gp.set_defaults(func=_command("gap", "cmd_gap"))


def _add_noise(nz) -> None:
    nz.add_argument("recording", help="recording or raw table of a still sensor")
    nz.add_argument("--sensor", action="append", choices=["accel", "gyro", "mag"],
                    help="sensor(s) to characterise (default: all present)")
    nz.add_argument("-o", "--output", help="write the noise figures (YAML; the daemon's noise.file)")
    nz.add_argument("--kalibr", help="write kalibr's imu.yaml here")
    nz.add_argument("--plot", help="write Allan deviation plots to this directory (plots extra)")
    nz.add_argument("--json", action="store_true", help="print one JSON object")
    nz.add_argument("--start-s", type=finite_float, help="use samples from this time (s after the first)")
    nz.add_argument("--end-s", type=finite_float, help="use samples up to this time (s after the first)")
    nz.add_argument("--max-gap-s", type=positive_float, default=1.0,
                    help="a time step above this splits the recording; the longest piece is used")
    nz.add_argument("--tau-min-s", type=positive_float, help="shortest averaging time fitted (default 10 samples)")
    nz.add_argument("--tau-max-s", type=positive_float, help="longest averaging time fitted (default a tenth)")
    nz.add_argument("--confidence", type=fraction, default=0.95, help="confidence of the intervals")
    nz.add_argument("--columns", help="raw table columns, e.g. t,ax,ay,az,gx,gy,gz (t_ms, t_us, t_ns: time in ms, us, ns)")
    nz.add_argument("--nominal-scale", type=per_sensor, default=1.0,
                    help="raw table: counts per unit, or one per sensor, e.g. accel=16384,gyro=131")
    nz.add_argument("--nominal-offset", type=per_sensor, default=0.0,
                    help="raw table: counts at zero input (or accel=N,gyro=N)")
    nz.add_argument("--rate-hz", type=positive_float, help="sample rate (default: the stretch's mean rate)")
    _join_options(nz)
    nz.set_defaults(func=_command("noise", "cmd_noise"))


def _add_mqtt(mq) -> None:
    daemon_opts(mq, state=False)
    mq.add_argument("--duration", type=_lim("duration"), help="stop after this many seconds")
    mq.set_defaults(func=_command("mqtt", "cmd_mqtt"))


def _add_calibration(cf) -> None:
    sub = cf.add_subparsers(dest="action", metavar="ACTION", parser_class=OneLineParser)
    sub.required = True
    m = sub.add_parser("merge", help="one calibration file from parts fitted separately "
                                     "(calibrate -o accel.yaml, --sensor gyro -o gyro.yaml, ...)")
    m.add_argument("files", nargs="+", metavar="FILE",
                   help="calibration files of one sensor; each part (accel, gyro, mag) from one file")
    m.add_argument("-o", "--output", required=True, help="the merged calibration file to write")
    m.set_defaults(func=_command("calfiles", "cmd_merge"))


def _add_demo(d) -> None:
    d.add_argument("--seed", type=seed, default=1)
    d.add_argument("--poses", type=count_in(10, 1000, " (the 9-parameter fit scored by leave-one-pose-out)"), default=25)
    d.set_defaults(func=_command("offline", "cmd_demo"))


#: (name, help line, the function that adds its arguments), in the order --help lists them
COMMANDS = (
    ("simulate", "write a simulated recording", _add_simulate),
    ("calibrate", "calibrate from a recording or pose file", _add_calibrate),
    ("apply", "write a recording corrected by a calibration file", _add_apply),
    ("probe", "list what answers on the I2C bus and what each device is", _add_probe),
    ("record", "record samples to a recording file", _add_record),
    ("run", "run the daemon (real I2C when a bus exists, else emulated)", _add_run),
    ("replay", "feed a recording through the pipeline; NDJSON to stdout", _add_replay),
    ("status", "the running daemon's state", _add_status),
    ("recalibrate", "ask the daemon to calibrate now", _add_recalibrate),
    ("watch", "print the daemon's stream", _add_watch),
    ("gap", "diagnose the sim-to-real gap of a recording", _add_gap),
    ("noise", "Allan deviation and noise figures of a still recording (kalibr imu.yaml, ROS covariances)", _add_noise),
    ("mqtt", "bridge the daemon's stream and status to an MQTT broker (the mqtt extra; "
             "the mqtt section of the configuration)", _add_mqtt),
    ("calibration", "calibration files: `calibration merge A.yaml B.yaml -o calibration.yaml`",
     _add_calibration),
    ("demo", "the calibration core alone: the GA converging on a simulated board, against the truth", _add_demo),
)


def build_parser(command: Optional[str] = None) -> argparse.ArgumentParser:
    """The parser: every subcommand (``None``); with a command's name, that subcommand alone
    (what ``main`` parses with: the fourteen others, each an ArgumentParser with its help
    formatter, were ~3 ms of every command's start); with ``""``, every subcommand listed
    by its help line, none filled in (``imucald --help``, a mistyped command)."""
    p = OneLineParser(prog="imucald", description="Field calibration of MEMS IMUs.")
    p.add_argument("--version", action="version", version=f"imucald {__version__}")
    # prog given: argparse would format it from a usage line, which with no positional
    # argument before the command is the program's name (and would import shutil for it)
    sub = p.add_subparsers(dest="cmd", metavar="COMMAND", prog=p.prog)
    for name, hlp, add in COMMANDS:
        if command and command != name:
            continue
        q = sub.add_parser(name, help=hlp)
        if command is None or command == name:
            add(q)
    return p
