"""``imucald probe`` and ``record``: talking to a board (real I2C or emulated)."""
from __future__ import annotations

from ..errors import DeviceUnavailable, write_failure
from ._common import eprint as _eprint


def cmd_probe(args) -> int:
    from ..drivers.bus import open_bus, real_bus_numbers
    from ..drivers.probe import detect_board, magnetometer, probe
    if args.emulate:
        from .boards import emulated_bus
        bus, num = emulated_bus(args.emulate, seed=0, poses=4), None
        print(f"bus: emulated {args.emulate} board (no hardware)")
    else:
        nums = real_bus_numbers()
        num = args.bus if args.bus is not None else (1 if 1 in nums else (nums[0] if nums else None))
        if num is None:
            raise DeviceUnavailable("no I2C bus on this machine (/dev/i2c-* absent): enable I2C "
                            "(raspi-config, or dtparam=i2c_arm=on), or try --emulate 9dof")
        bus = open_bus(num)
        print(f"bus: /dev/i2c-{num}")
    found = probe(bus, num)
    if not found:
        print("nothing answered at 0x0C, 0x0D, 0x1D, 0x1E, 0x53, 0x68, 0x69: check wiring, power "
              "and pull-ups ('i2cdetect -y N' lists every address)")
        return 1
    for f in found:
        print("  " + f.line())
    b = detect_board(found)
    mag = magnetometer(found) if b in ("9dof", "gy273") else None
    print((f"board: {b}" + (f" (magnetometer: {mag.upper()})" if mag else "")) if b else
          "board: none of the supported boards (mpu6050, mpu6500, mpu9250, 9dof, gy273)")
    return 0


def _stop_on_signals():
    """SIGINT and SIGTERM end ``record`` after the block in hand is written (the first
    one; a second one interrupts at once).  Returns the list the signal number lands in."""
    import signal
    got = []

    def handler(signum, frame):
        if got:
            raise KeyboardInterrupt
        got.append(signum)
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, handler)
    return got


def _warn_emulated(asked: bool, desc: str) -> None:
    """A warning when ``record`` fell back to the emulator unasked (no I2C bus): a Pi whose I2C
    is off would otherwise record a simulated session in silence, which calibrate then fits
    (a newcomer's walk)."""
    if not asked and "no I2C bus found" in desc:
        _eprint("imucald: warning: no I2C bus on this machine (/dev/i2c-* absent): recording the "
                "EMULATED board, simulated data and not a sensor's; to record a board enable I2C "
                "(raspi-config, or dtparam=i2c_arm=on) and reboot; --emulate says you mean the emulator")


def cmd_record(args) -> int:
    """Samples are written as they come (recording.RecordingWriter): the header once the
    board runs, then every batch, fsynced each second, so an interrupted recording (Ctrl-C,
    SIGTERM, SIGKILL, a power cut) is a valid one of what was sampled."""
    import numpy as np

    from .boards import open_board
    from .faults import faults_from_options
    board, bus, desc = open_board(args.board, args.rate, "yes" if args.emulate else "auto", args.bus,
                                  speed=1.0 if args.realtime else None,
                                  seed=args.seed, poses=args.poses, faults=faults_from_options(args.fault),
                                  mag=args.mag, tour=dict(tremor_dps=args.tremor_dps))
    stop = _stop_on_signals()
    board.start()
    _warn_emulated(args.emulate, desc)
    _eprint(f"imucald: recording {args.seconds:g} s from {desc} at {board.rate_hz:g} Hz")
    meta = {"board": board.name, "rate_hz": f"{board.rate_hz:g}", "source": f"imucald record: {desc}",
            "chips": ",".join(f"{k}={v}" for k, v in board.chips().items())}
    if getattr(board, "gyro_range_dps", None):  # the orientation's saturation limit on replay
        meta["gyro_range_dps"] = f"{board.gyro_range_dps:g}"
    if not board.has_acc:       # gy273: the QMC5883L's temperature has no calibrated offset
        meta["temp"] = "relative (QMC5883L, offset not calibrated)"
    head, writer = [], None
    last = {"mag": None, "temp": None}
    try:
        while not stop:
            b = board.read_batch()
            if not len(b):
                if board.clock.now() - board.t0 > args.seconds + 5 and board.stats.samples == 0:
                    raise DeviceUnavailable(f"no samples from {desc} for {args.seconds + 5:.0f} s "
                                            f"(last fault: {getattr(board, 'last_fault', 'none')})")
                continue
            keep = b.t < args.seconds
            if keep.any():
                head.append(b if keep.all() else _cut(b, keep))
            done = not keep.all()
            if writer is None:
                # the columns are known once the magnetometer has read (its rows before are
                # filled with its first reading) or after the first second
                mag_seen = not board.has_mag or any(np.isfinite(h.mag).all(axis=1).any() for h in head)
                if not done and not (mag_seen and head) and (not head or head[-1].t[-1] - head[0].t[0] < 1.0):
                    continue
                if not head:
                    break
                writer, cols_temp = _open_writer(args.output, meta, board, head, last)
            for h in head:
                writer.write(_as_recording(h, board, cols_temp, last))
            head = []
            if done:
                break
        if writer is None and head:
            writer, cols_temp = _open_writer(args.output, meta, board, head, last)
            for h in head:
                writer.write(_as_recording(h, board, cols_temp, last))
    except KeyboardInterrupt:
        stop.append(2)
    except BrokenPipeError:         # -o - and the reader went away (| head): a normal end
        raise
    except OSError as e:
        err = write_failure(e, "-o", args.output)
        if writer is not None and args.output != "-":
            # the recording had started, so the name given is the new file (an old one there
            # is gone, docs/guide/recording.md): say what it holds (a cold review's full disk)
            err = type(err)(f"{err}; it holds the recording up to that point ({writer.rows} samples "
                            f"handed on, the last line possibly cut)")
        raise err from None
    finally:
        if writer is not None:
            try:
                writer.close()
            except OSError:
                pass
    st = board.stats
    rows = writer.rows if writer is not None else 0
    why = {2: " (interrupted: SIGINT)", 15: " (stopped: SIGTERM)"}.get(stop[0] if stop else 0, "")
    _eprint(f"imucald: wrote {args.output}{why}: {rows} samples; gaps {st.gaps} ({st.missing} samples "
            f"lost), re-initialisations {st.reinits}, bus faults {st.bus_faults}, retries "
            f"{bus.stats.retries}")
    return 128 + stop[0] if stop else 0


def _cut(b, keep):
    from dataclasses import replace
    f = lambda a: None if a is None else a[keep]
    return replace(b, t=b.t[keep], seq=b.seq[keep], acc=b.acc[keep], gyro=b.gyro[keep],
                   temp=b.temp[keep], mag=f(b.mag), mag_fresh=f(b.mag_fresh))


def _open_writer(path, meta, board, head, last):
    """The writer, its columns chosen from the first batches (``head``): temp only when the
    board reads one (a gy273 with an HMC5883L does not).  ``last`` gets the first finite
    magnetometer reading and temperature: the rows before them are filled with them."""
    import numpy as np
    from ..files.recording import Recording, RecordingWriter
    temp = np.concatenate([h.temp for h in head])
    if board.has_mag:
        mag = np.concatenate([h.mag for h in head])
        ok = np.isfinite(mag).all(axis=1)
        last["mag"] = mag[np.argmax(ok)] if ok.any() else np.zeros(3)
    last["temp"] = temp[np.argmax(np.isfinite(temp))] if np.isfinite(temp).any() else None
    cols_temp = board.has_acc or last["temp"] is not None
    if not cols_temp:
        meta.pop("temp", None)
    probe = Recording(t=np.zeros(0), acc=np.zeros((0, 3)) if board.has_acc else None,
                      gyro=np.zeros((0, 3)) if board.has_acc else None,
                      mag=np.zeros((0, 3)) if board.has_mag else None,
                      temp=np.zeros(0) if cols_temp else None)
    try:
        return RecordingWriter(path, meta, probe.columns(), "-o"), cols_temp
    except OSError as e:
        raise write_failure(e, "-o", path) from None


def _fill(a, last):
    """``a`` with its non-finite rows replaced by the last finite one before (or, at the
    start, the first finite one): the magnetometer before its first reading, a temperature
    the chip did not give."""
    import numpy as np
    a = np.array(a, float)
    bad = ~np.isfinite(a) if a.ndim == 1 else ~np.isfinite(a).all(axis=1)
    if not bad.any():
        return a, a[-1]
    good = np.flatnonzero(~bad)
    if last is None:
        if not len(good):
            return a, None
        last = a[good[0]]
    idx = np.maximum.accumulate(np.where(bad, -1, np.arange(len(a))))
    out = np.where((idx < 0)[:, None] if a.ndim == 2 else idx < 0, last, a[np.maximum(idx, 0)])
    return out, out[-1]


def _as_recording(b, board, cols_temp, last):
    from ..files.recording import Recording
    mag = temp = None
    if board.has_mag:
        mag, last["mag"] = _fill(b.mag, last["mag"])
    if cols_temp:
        temp, last["temp"] = _fill(b.temp, last["temp"])
    return Recording(t=b.t, acc=b.acc if board.has_acc else None, gyro=b.gyro if board.has_acc else None,
                     mag=mag, temp=temp)
