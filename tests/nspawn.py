"""A Debian bookworm container that boots systemd, for tests/test_system.py (`make test-system`).

The tree is made once by ``debootstrap`` from the Debian mirror apt is configured with and
kept, without the apt cache, OUTSIDE the repository: ``$IMUCALD_SYSTEST_CACHE`` (default
``/var/cache/imucald-systest``), one directory per package list (``bookworm-HASH``; a new
list replaces the old).  It is never written to: each run mounts an overlay of it (the
writes go to a fresh directory under ``/var/tmp``; a copy where overlayfs is missing) and
boots that with ``systemd-nspawn`` in the mode in
which systemd enforces ``DevicePolicy=``/``DeviceAllow=`` and ``IPAddressDeny=`` (the unified
cgroup hierarchy, all capabilities, the ``bpf`` system call); in nspawn's default mode systemd
logs "BPF device control is not supported" and silently skips them.  ``--keep-unit
--register=no``: the host's PID 1 need not be systemd (no bus to register with).

Commands run in the container through ``nsenter`` into its init's namespaces, with a clean
environment.  Everything is undone on every exit path: the container is halted (killed after
15 s), the tree removed; nspawn dies with the test process (PR_SET_PDEATHSIG), and a tree left
by a killed run is removed by the next one.

Only standard library; the caller decides to skip with :func:`cannot_boot_reason`.
"""
import fcntl
import hashlib
import os
import re
import shutil
import signal
import subprocess
import tempfile
import time

__all__ = ["cannot_boot_reason", "ensure_tree", "Container", "CACHE_DIR", "PACKAGES"]

CACHE_DIR = os.environ.get("IMUCALD_SYSTEST_CACHE", "/var/cache/imucald-systest")
WORK_DIR = os.environ.get("IMUCALD_SYSTEST_WORKDIR", "/var/tmp")
SUITE = "bookworm"
#: systemd 252 as on Raspberry Pi OS bookworm (libnss-systemd: the dynamic users' names; no procps:
#: the units must not need /bin/kill); python3-venv for `make install`; mosquitto as
#: the broker of the bridge's checks (its own service is masked: it would take the host's
#: port 1883, the container shares the host's network)
PACKAGES = ("systemd", "systemd-sysv", "libnss-systemd", "dbus", "python3", "python3-venv", "make",
            "ca-certificates", "mosquitto", "passwd")
PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
_PREFIX = "imucald-systest."


def _die_with_parent():
    """In nspawn's process: SIGTERM (nspawn then halts the container) when the test dies."""
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)     # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def cannot_boot_reason():
    """Why this host cannot boot the container (None when it can try)."""
    if os.name != "posix" or not os.path.isdir("/proc"):
        return "not Linux"
    if os.geteuid() != 0:
        return "needs root (systemd-nspawn and debootstrap): run `sudo make test-system`"
    for tool, pkg in (("systemd-nspawn", "systemd-container"), ("nsenter", "util-linux")):
        if shutil.which(tool) is None:
            return f"{tool} not found (apt-get install {pkg})"
    if not os.path.exists("/sys/fs/cgroup/cgroup.controllers") and \
            not os.path.exists("/sys/fs/cgroup/unified/cgroup.controllers"):
        return "no cgroup v2 hierarchy on this host (systemd in the container needs one)"
    if _cached_tree() is None and shutil.which("debootstrap") is None:
        return f"no cached tree in {CACHE_DIR} and debootstrap not found (apt-get install debootstrap)"
    return None


def _tree_name():
    h = hashlib.sha256(" ".join((SUITE,) + PACKAGES).encode()).hexdigest()[:10]
    return os.path.join(CACHE_DIR, f"{SUITE}-{h}")


def _cached_tree():
    p = _tree_name()
    return p if os.path.isfile(os.path.join(p, "usr/lib/systemd/systemd")) else None


def apt_mirror():
    """The Debian mirror apt uses here (deb822 or one-line sources), else deb.debian.org."""
    cands = []
    for p in ["/etc/apt/sources.list"] + sorted(
            os.path.join("/etc/apt/sources.list.d", f) for f in
            (os.listdir("/etc/apt/sources.list.d") if os.path.isdir("/etc/apt/sources.list.d") else [])):
        if not (p.endswith(".list") or p.endswith(".sources")) or not os.path.isfile(p):
            continue
        try:
            text = open(p, encoding="utf-8", errors="replace").read()
        except OSError:
            continue
        for line in text.splitlines():
            line = line.strip()
            if line.startswith("URIs:"):
                cands += line.split()[1:]
            elif line.startswith("deb ") and not line.startswith("deb-src"):
                cands += [w for w in line.split()[1:] if "://" in w][:1]
    for u in cands:
        if re.search(r"/debian/?$", u) and "security" not in u:
            return u.rstrip("/")
    return "http://deb.debian.org/debian"


def ensure_tree(log=print, timeout_s=900):
    """The cached tree (made now with debootstrap if absent); (path, seconds spent making it)."""
    os.makedirs(CACHE_DIR, exist_ok=True)
    tree = _tree_name()
    with open(os.path.join(CACHE_DIR, ".lock"), "w") as lk:
        fcntl.flock(lk, fcntl.LOCK_EX)          # two runs at once: one builds, the other waits
        if _cached_tree():
            return tree, 0.0
        shutil.rmtree(tree, ignore_errors=True)  # a half-made one
        for f in os.listdir(CACHE_DIR):           # a build of a killed run (we hold the lock)
            if f.startswith("build."):
                shutil.rmtree(os.path.join(CACHE_DIR, f), ignore_errors=True)
        t0 = time.monotonic()
        build = tempfile.mkdtemp(prefix="build.", dir=CACHE_DIR)
        try:
            root = os.path.join(build, "root")
            mirror = apt_mirror()
            log(f"debootstrap {SUITE} from {mirror} into {root} (once; cached as {tree})")
            r = subprocess.run(["debootstrap", "--variant=minbase", "--include=" + ",".join(PACKAGES),
                                SUITE, root, mirror], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               text=True, timeout=timeout_s)
            if r.returncode != 0:
                raise RuntimeError(f"debootstrap failed ({r.returncode}):\n{r.stdout[-3000:]}")
            # the broker's own service would listen on the host's 1883 (shared network)
            for w in ("multi-user.target.wants/mosquitto.service",):
                p = os.path.join(root, "etc/systemd/system", w)
                if os.path.lexists(p):
                    os.unlink(p)
            os.symlink("/dev/null", os.path.join(root, "etc/systemd/system/mosquitto.service"))
            shutil.rmtree(os.path.join(root, "var/cache/apt/archives"), ignore_errors=True)
            os.makedirs(os.path.join(root, "var/cache/apt/archives/partial"), exist_ok=True)
            shutil.rmtree(os.path.join(root, "var/lib/apt/lists"), ignore_errors=True)
            os.makedirs(os.path.join(root, "var/lib/apt/lists/partial"), exist_ok=True)
            for f in ("etc/machine-id",):            # each boot makes its own
                p = os.path.join(root, f)
                if os.path.exists(p):
                    open(p, "w").close()
            os.rename(root, tree)
            for f in os.listdir(CACHE_DIR):             # trees of an older package list
                p = os.path.join(CACHE_DIR, f)
                if f.startswith(SUITE + "-") and p != tree:
                    if os.path.isdir(p):
                        shutil.rmtree(p, ignore_errors=True)
                    else:
                        os.unlink(p)
        finally:
            shutil.rmtree(build, ignore_errors=True)
        return tree, time.monotonic() - t0


def _remove_stale():
    """Trees of earlier runs whose process is gone (a killed run): unmounted and removed."""
    try:
        names = os.listdir(WORK_DIR)
    except OSError:
        return
    for n in names:
        m = re.fullmatch(re.escape(_PREFIX) + r"(\d+)\.\w+", n)
        if not m:
            continue
        pid = int(m.group(1))
        if pid != os.getpid() and os.path.exists(f"/proc/{pid}"):
            continue
        d = os.path.join(WORK_DIR, n)
        _umount_under(d)
        shutil.rmtree(d, ignore_errors=True)


def _mounts_under(d):
    d = os.path.realpath(d)
    out = []
    try:
        with open("/proc/self/mountinfo") as fh:
            for line in fh:
                mp = line.split()[4].replace("\\040", " ")
                if mp == d or mp.startswith(d + "/"):
                    out.append(mp)
    except OSError:
        pass
    return out


def _umount_under(d):
    for mp in sorted(_mounts_under(d), key=len, reverse=True):
        subprocess.run(["umount", "-l", mp], capture_output=True)


def pip_setup():
    """What pip needs from this host: (files to copy: host path -> same path in the container,
    read-only bind mounts of local package directories, PIP_* and proxy environment)."""
    files, binds, env = {}, set(), {}
    home = os.path.expanduser("~")
    for p in ("/etc/pip.conf", os.path.join(home, ".config/pip/pip.conf"), os.path.join(home, ".pip/pip.conf"),
              os.environ.get("PIP_CONFIG_FILE", "")):
        if p and os.path.isfile(p):
            files[p] = p
    if os.path.isdir("/etc/xdg/pip"):
        for f in os.listdir("/etc/xdg/pip"):
            p = os.path.join("/etc/xdg/pip", f)
            if os.path.isfile(p):
                files[p] = p
    for k, v in os.environ.items():
        if k.startswith("PIP_") or k.lower() in ("http_proxy", "https_proxy", "no_proxy", "all_proxy"):
            env[k] = v
    # local paths named by the configuration (find-links, file:// indexes, cert, constraint)
    texts = list(env.values())
    for p in files:
        try:
            texts.append(open(p, encoding="utf-8", errors="replace").read())
        except OSError:
            pass
    for t in texts:
        for m in re.finditer(r"(?:file://)?(/[^\s'\"]+)", t):
            p = m.group(1).rstrip("/")
            if p.startswith(("/etc/", "/root/", "/home/")):
                if os.path.isfile(p):
                    files[p] = p
            elif os.path.isdir(p):
                # a PEP 503 index (.../simple) links to its files beside it (../files)
                binds.add(os.path.dirname(p) if os.path.basename(p) == "simple" else p)
            elif os.path.isfile(p):
                files[p] = p
    # the host's CA bundle (an intercepting proxy's CA is in it), where pip will look
    for ca in ("/etc/ssl/certs/ca-certificates.crt",):
        if os.path.isfile(ca):
            files[ca] = ca
    return files, sorted(binds), env


class Container:
    """One booted container; ``run(cmd)`` a shell command in it; ``close()`` undoes all."""

    def __init__(self, tree, log=print, binds=()):
        self.log = log
        self.name = f"imucald-systest-{os.getpid()}"
        _remove_stale()
        self.dir = tempfile.mkdtemp(prefix=f"{_PREFIX}{os.getpid()}.", dir=WORK_DIR)
        self.root = os.path.join(self.dir, "root")
        self.proc = None
        self.leader = None
        self.boot_log = os.path.join(self.dir, "nspawn.log")
        for d in ("root", "upper", "work"):
            os.makedirs(os.path.join(self.dir, d))
        t0 = time.monotonic()
        r = subprocess.run(["mount", "-t", "overlay", "overlay", "-o",
                            f"lowerdir={tree},upperdir={self.dir}/upper,workdir={self.dir}/work", self.root],
                           capture_output=True, text=True)
        self.overlay = r.returncode == 0
        if not self.overlay:
            subprocess.run(["cp", "-a", "--reflink=auto", tree + "/.", self.root], check=True, timeout=600)
        self.unpack_s = time.monotonic() - t0
        self.binds = list(binds)

    # -- boot and halt -------------------------------------------------------------------
    def boot(self, timeout_s=90):
        env = dict(os.environ, SYSTEMD_NSPAWN_UNIFIED_HIERARCHY="1")
        args = ["systemd-nspawn", "-q", "-D", self.root, "--boot", "--keep-unit", "--register=no",
                "--capability=all", "--system-call-filter=bpf", f"--machine={self.name}",
                "--console=pipe", "--link-journal=no"]
        args += [f"--bind-ro={b}" for b in self.binds]
        t0 = time.monotonic()
        self._logfh = open(self.boot_log, "wb")
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=self._logfh,
                                     stderr=subprocess.STDOUT, env=env, preexec_fn=_die_with_parent)
        deadline = t0 + timeout_s
        while self.leader is None:
            if self.proc.poll() is not None:
                raise RuntimeError(f"systemd-nspawn exited ({self.proc.returncode}): {self.boot_tail()}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"no init in the container after {timeout_s} s: {self.boot_tail()}")
            self.leader = self._find_leader()
            if self.leader is None:
                time.sleep(0.05)
        # the bus is up once is-system-running answers (it fails for a moment after init starts)
        state = ""
        while time.monotonic() < deadline:
            r = self.run("systemctl is-system-running --wait", timeout=max(1, deadline - time.monotonic()),
                         check=False)
            state = r.stdout.strip()
            if state in ("running", "degraded"):
                break
            time.sleep(0.2)
        else:
            raise RuntimeError(f"the container's systemd did not finish booting in {timeout_s} s "
                               f"(state {state!r}): {self.boot_tail()}")
        self.boot_s = time.monotonic() - t0
        self.state = state
        return state

    def _find_leader(self):
        try:
            for t in os.listdir(f"/proc/{self.proc.pid}/task"):
                with open(f"/proc/{self.proc.pid}/task/{t}/children") as fh:
                    for c in fh.read().split():
                        with open(f"/proc/{c}/comm") as fc:
                            if fc.read().strip() == "systemd":
                                return int(c)
        except OSError:
            pass
        return None

    def boot_tail(self, n=2000):
        try:
            with open(self.boot_log, "rb") as fh:
                return fh.read().decode("utf-8", "replace")[-n:]
        except OSError:
            return ""

    def close(self):
        """Halt (SIGTERM to nspawn: an orderly shutdown; killed after 15 s), unmount, remove."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                if self.leader:
                    try:
                        os.kill(self.leader, signal.SIGKILL)     # PID 1 of the namespace: all go
                    except OSError:
                        pass
                self.proc.kill()
                self.proc.wait(10)
        if getattr(self, "_logfh", None):
            self._logfh.close()
        _umount_under(self.dir)
        shutil.rmtree(self.dir, ignore_errors=True)
        left = _mounts_under(self.dir)
        if left:
            raise RuntimeError(f"mounts left under {self.dir}: {left}")

    # -- commands ----------------------------------------------------------------------
    def run(self, cmd, timeout=60, check=True, env=None, input=None):
        """``sh -c cmd`` as root in the container, clean environment; CompletedProcess (text)."""
        e = ["PATH=" + PATH, "LANG=C.UTF-8", "HOME=/root", "SYSTEMD_PAGER=", "SYSTEMD_COLORS=0"]
        e += [f"{k}={v}" for k, v in (env or {}).items()]
        args = ["nsenter", "-t", str(self.leader), "-m", "-u", "-i", "-p", "-C", "--",
                "/usr/bin/env", "-i"] + e + ["/bin/sh", "-c", cmd]
        try:
            r = subprocess.run(args, capture_output=True, text=True, timeout=timeout, input=input)
        except subprocess.TimeoutExpired as ex:
            raise AssertionError(f"in the container, `{cmd}` took more than {timeout:.0f} s "
                                 f"(output so far: {ex.stdout!r} {ex.stderr!r})") from None
        if check and r.returncode != 0:
            raise AssertionError(f"in the container, `{cmd}` exited {r.returncode}:\n"
                                 f"{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
        return r

    def path(self, p):
        """Host path of the container's ``p`` (for copying files in)."""
        return os.path.join(self.root, p.lstrip("/"))

    def copy_in(self, src, dst):
        d = self.path(dst)
        os.makedirs(os.path.dirname(d), exist_ok=True)
        shutil.copy2(src, d)

    def copy_tree_in(self, src, dst, files):
        """Copy ``files`` (relative to ``src``) to ``dst`` in the container."""
        base = self.path(dst)
        for f in files:
            s, d = os.path.join(src, f), os.path.join(base, f)
            if os.path.islink(s) or not os.path.isfile(s):
                continue
            os.makedirs(os.path.dirname(d), exist_ok=True)
            shutil.copy2(s, d)
