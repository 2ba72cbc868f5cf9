"""The real smbus2 ``SMBus`` driven against the emulators through a fake /dev/i2c-N.

smbus2 talks to the kernel with ``os.open("/dev/i2c-N")`` and ``fcntl.ioctl``; here both are
replaced (as smbus2's own tests do, by patching its module's ``os.open`` and ``ioctl``) by a
fake character device that decodes the i2c-dev ioctl structures -- I2C_FUNCS, I2C_SLAVE,
I2C_SMBUS (struct i2c_smbus_ioctl_data) and I2C_RDWR (struct i2c_rdwr_ioctl_data of
struct i2c_msg), as declared in linux/i2c-dev.h and linux/i2c.h -- into register reads and
writes on the emulated chips, and reports their faults as the kernel does (errno on the
ioctl).  imucald's Bus, probe and board drivers run over the unmodified smbus2 code, so
the only layer left untested on real hardware is the kernel.
"""
import ctypes
import errno
import os
import types

import numpy as np
import pytest

smbus2 = pytest.importorskip("smbus2")
from smbus2 import smbus2 as sm  # noqa: E402

from imucald.drivers.board import make_board, merge_batches  # noqa: E402
from imucald.drivers.bus import AddressBusy, Bus, NoAcknowledge, VirtualClock, open_bus  # noqa: E402
from imucald.drivers.probe import detect_board, probe  # noqa: E402
from imucald.sim.emulators import Faults, emulated_board  # noqa: E402
from imucald.sim.motion import PoseTour  # noqa: E402

# ioctl request numbers and transfer kinds of linux/i2c-dev.h and linux/i2c.h (facts of the
# kernel ABI, written out here so that the fake does not take them from the code under test)
I2C_SLAVE, I2C_SLAVE_FORCE, I2C_FUNCS, I2C_RDWR, I2C_PEC, I2C_SMBUS = 0x0703, 0x0706, 0x0705, 0x0707, 0x0708, 0x0720
SMBUS_READ, SMBUS_WRITE = 1, 0
SMBUS_BYTE_DATA, SMBUS_I2C_BLOCK_DATA = 2, 8
I2C_M_RD = 0x0001
#: what a Raspberry Pi's i2c-bcm2835 adapter reports: I2C, SMBus quick/byte/byte data/word
#: data/I2C block emulation (i2c_bcm2835: I2C_FUNC_I2C | I2C_FUNC_SMBUS_EMUL)
FUNCS = 0x00000001 | 0x0EFF0008


class FakeI2cDev:
    """/dev/i2c-N: file descriptors, the slave address set per descriptor, and the ioctls."""

    def __init__(self, emu, path="/dev/i2c-7"):
        self.emu, self.path = emu, path
        self.fds = {}            # fd -> current slave address (None until I2C_SLAVE)
        self.calls = {}          # request -> count
        self._next = 1000

    # os.open / os.close of smbus2's module
    def open(self, path, flags, *a):
        if path != self.path:
            raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), path)
        assert flags & os.O_RDWR
        self._next += 1
        self.fds[self._next] = None
        return self._next

    def close(self, fd):
        del self.fds[fd]

    def _oserror(self, code):
        return OSError(code, os.strerror(code))

    def ioctl(self, fd, request, arg=0, *a):
        if fd not in self.fds:
            raise self._oserror(errno.EBADF)
        self.calls[request] = self.calls.get(request, 0) + 1
        if request == I2C_FUNCS:
            arg.value = FUNCS
            return 0
        if request in (I2C_SLAVE, I2C_SLAVE_FORCE):
            addr = int(arg)
            if not 0 <= addr <= 0x7F:
                raise self._oserror(errno.EINVAL)
            if request == I2C_SLAVE and addr in self.emu.faults.busy:
                raise self._oserror(errno.EBUSY)        # a kernel driver owns it (i2cdetect: UU)
            self.fds[fd] = addr
            return 0
        if request == I2C_SMBUS:
            return self._smbus(self.fds[fd], arg)
        if request == I2C_RDWR:
            return self._rdwr(arg)
        raise self._oserror(errno.ENOTTY)

    def _dev(self, addr):
        if addr is None:
            raise self._oserror(errno.EINVAL)
        return self.emu._dev(addr)          # the emulator's fault injection: EREMOTEIO, ETIMEDOUT ...

    def _smbus(self, addr, d):
        data = d.data.contents
        if d.size == SMBUS_BYTE_DATA:
            if d.read_write == SMBUS_READ:
                data.byte = self._dev(addr).read(d.command, 1)[0]
            else:
                self._dev(addr).write(d.command, [data.byte])
            return 0
        if d.size == SMBUS_I2C_BLOCK_DATA:
            n = data.block[0]
            if not 1 <= n <= 32:
                raise self._oserror(errno.EINVAL)
            if d.read_write == SMBUS_READ:
                got = self._dev(addr).read(d.command, n)
                for i, b in enumerate(got):
                    data.block[1 + i] = b
            else:
                self._dev(addr).write(d.command, list(data.block[1:1 + n]))
            return 0
        raise self._oserror(errno.EOPNOTSUPP)     # not used by imucald

    def _rdwr(self, d):
        """Messages of one combined transfer: a write sets the register pointer (and writes
        what follows it), a read reads from it."""
        reg = None
        for i in range(d.nmsgs):
            m = d.msgs[i]
            if m.flags & I2C_M_RD:
                if reg is None:
                    raise self._oserror(errno.EINVAL)
                got = self._dev(m.addr).read(reg, m.len)
                ctypes.memmove(m.buf, bytes(got), m.len)
            else:
                b = ctypes.string_at(m.buf, m.len)
                dev = self._dev(m.addr)
                reg = b[0]
                if len(b) > 1:
                    dev.write(reg, b[1:])
        return 0


def _tour(seed):
    from imucald.sim.orientations import random_pose_set
    rng = np.random.default_rng(seed + 100)
    return PoseTour(random_pose_set(6, rng), rng=rng, loop=True)


@pytest.fixture
def fake_dev(monkeypatch, tmp_path):
    """(make, dev_dir): make(board, faults) -> (FakeI2cDev, clock) with smbus2 patched."""
    made = []

    def make(board, faults=None, seed=3):
        clk = VirtualClock()
        emu = emulated_board(board, _tour(seed), rng=np.random.default_rng(seed), clock=clk, faults=faults)
        dev = FakeI2cDev(emu)
        fake_os = types.SimpleNamespace(**{k: getattr(os, k) for k in dir(os) if not k.startswith("__")})
        fake_os.open, fake_os.close = dev.open, dev.close
        monkeypatch.setattr(sm, "os", fake_os)
        monkeypatch.setattr(sm, "ioctl", dev.ioctl)
        made.append(dev)
        return dev, clk
    (tmp_path / "i2c-7").touch()            # open_bus checks the node exists in its dev_dir
    return make, str(tmp_path)


@pytest.mark.parametrize("board,chips,rate", [("mpu6050", {"mpu6050"}, 1000.0),
                                              ("9dof", {"adxl345", "itg3200", "hmc5883l"}, 100.0),
                                              ("mpu9250", {"mpu9250", "ak8963"}, 200.0)])
def test_real_smbus2_identifies_and_reads_the_emulated_board(fake_dev, board, chips, rate):
    make, dev_dir = fake_dev
    dev, clk = make(board)
    bus = open_bus(7, clk, dev_dir=dev_dir)
    assert type(bus.smbus) is smbus2.SMBus and bus.smbus.funcs == FUNCS
    found = probe(bus)
    assert {f.chip for f in found} >= chips and detect_board(found) == board
    b = make_board(board, bus, clk, rate_hz=rate)
    b.start()
    t0 = clk.now()
    parts = [b.read_batch() for _ in range(60)]      # each waits for its batch (virtual time)
    batch = merge_batches([p for p in parts if len(p)])
    span = clk.now() - t0
    assert span > 0.5 and len(batch) >= 0.9 * rate * span and not sum((p.gaps for p in parts[1:]), [])
    assert set(b.chips().values()) >= chips - {"ak8963"}
    # what the drivers read through smbus2 and the ioctls is, bit for bit, what they read from
    # the same emulated board (same seed) handed to them directly
    emu = emulated_board(board, _tour(3), rng=np.random.default_rng(3), clock=VirtualClock(), faults=None)
    ref_clk = emu.clock
    ref_bus = Bus(emu, "emu", clock=ref_clk)
    assert probe(ref_bus) == found
    ref = make_board(board, ref_bus, ref_clk, rate_hz=rate)
    ref.start()
    rparts = [ref.read_batch() for _ in range(60)]
    rbatch = merge_batches([p for p in rparts if len(p)])
    for k in ("t", "acc", "gyro", "temp", "mag"):
        a, r = getattr(batch, k), getattr(rbatch, k)
        assert (a is None and r is None) or np.array_equal(a, r, equal_nan=True), k
    assert 0.5 < np.median(np.linalg.norm(batch.acc, axis=1)) < 1.5      # g: gravity, not garbage
    # the transfers went through the ioctls smbus2 makes
    assert dev.calls.get(I2C_SMBUS, 0) > 0 and dev.calls.get(I2C_SLAVE, 0) > 0
    if board != "9dof":
        assert dev.calls.get(I2C_RDWR, 0) > 0       # FIFO bursts beyond 32 bytes go as I2C_RDWR
    bus.smbus.close()
    assert not dev.fds


def test_kernel_errors_through_smbus2_become_imucald_errors(fake_dev):
    make, dev_dir = fake_dev
    dev, clk = make("mpu6050", Faults(nack_prob=1.0))
    bus = open_bus(7, clk, dev_dir=dev_dir)
    with pytest.raises(NoAcknowledge) as e:
        bus.read_byte(0x68, 0x75)
    assert "0x68" in str(e.value) and "\n" not in str(e.value)
    assert bus.stats.retries == bus.retries         # retried, then given up
    dev, clk = make("mpu6050", Faults(busy={0x68}))
    bus = open_bus(7, clk, dev_dir=dev_dir)
    with pytest.raises(AddressBusy):
        bus.read_byte(0x68, 0x75)
    assert [f.chip for f in probe(bus) if f.addr == 0x68] == ["busy"]


def test_a_missing_bus_node_is_one_line(fake_dev, tmp_path):
    make, dev_dir = fake_dev
    make("mpu6050")
    from imucald.errors import DeviceUnavailable
    with pytest.raises(DeviceUnavailable) as e:
        open_bus(3, dev_dir=dev_dir)
    assert "i2c-3 does not exist" in str(e.value)
