#!/bin/sh
# imucald as a system service: `make install` / `make uninstall` run this.
#   sh packaging/install.sh install|uninstall
# Variables (make passes them through): DESTDIR (staging root, e.g. for a package or a
# test: nothing outside it is touched, no systemctl/udevadm/groupadd), PREFIX (the venv,
# /opt/imucald), SYSCONFDIR (/etc/imucald), UNITDIR (/etc/systemd/system), UDEVDIR
# (/etc/udev/rules.d), DOCDIR (/usr/share/doc/imucald), BINDIR (/usr/local/bin: a link to
# the venv's imucald, so that it is on root's PATH), PYTHON (python3), EXTRAS (mqtt),
# NO_VENV=1 (lay out the files only), PURGE=1 (uninstall also removes the configuration
# and the state in /var/lib/imucald and the instances' /var/lib/imucald-NAME).
# What install created is listed in $PREFIX/install-manifest.txt; uninstall removes those
# files only (a configuration that was already there is never in it).
set -eu

ACTION=${1:-}
SRC=$(cd "$(dirname "$0")/.." && pwd)
DESTDIR=${DESTDIR:-}
PREFIX=${PREFIX:-/opt/imucald}
SYSCONFDIR=${SYSCONFDIR:-/etc/imucald}
UNITDIR=${UNITDIR:-/etc/systemd/system}
UDEVDIR=${UDEVDIR:-/etc/udev/rules.d}
DOCDIR=${DOCDIR:-/usr/share/doc/imucald}
BINDIR=${BINDIR:-/usr/local/bin}
PYTHON=${PYTHON:-python3}
EXTRAS=${EXTRAS:-mqtt}
NO_VENV=${NO_VENV:-}
PURGE=${PURGE:-}
UNITS="imucald.service imucald@.service imucald-mqtt.service"
UDEV_RULE=60-imucald-i2c.rules
MANIFEST="$DESTDIR$PREFIX/install-manifest.txt"

say() { printf 'imucald install: %s\n' "$*"; }
die() { printf 'imucald install: error: %s\n' "$1" >&2; exit "${2:-1}"; }

case "$PREFIX" in
    /*) ;;
    *) die "PREFIX=$PREFIX must be an absolute path (e.g. /opt/imucald)" 2 ;;
esac
case "$PREFIX" in
    / | /usr | /usr/local | /opt | /etc | /var | /home) die "PREFIX=$PREFIX is a system directory: give one of imucald's own, e.g. /opt/imucald" 2 ;;
esac

# live: acting on this machine (not a staging DESTDIR) as root
live() { [ -z "$DESTDIR" ] && [ "$(id -u)" = 0 ]; }

record() { printf '%s\n' "$1" >> "$MANIFEST"; }

# an existing udev rule (the distribution's, e.g. Raspberry Pi OS's 99-com.rules) that
# already gives the i2c group the /dev/i2c-* devices
udev_has_i2c_rule() {
    for d in "$DESTDIR/etc/udev/rules.d" "$DESTDIR/lib/udev/rules.d" "$DESTDIR/usr/lib/udev/rules.d"; do
        [ -d "$d" ] || continue
        for f in "$d"/*.rules; do
            [ -f "$f" ] || continue
            [ "$(basename "$f")" = "$UDEV_RULE" ] && continue
            if grep -Eq 'i2c-dev.*GROUP="?i2c' "$f" 2>/dev/null; then
                echo "$f"
                return 0
            fi
        done
    done
    return 1
}

# Before issue 22 an instance imucald@NAME kept its state in /var/lib/imucald/NAME, inside
# the main unit's directory (with DynamicUser= that is /var/lib/private/imucald/NAME): the two
# could not run together.  Now it is /var/lib/imucald-NAME (/var/lib/private/imucald-NAME).
# Each NAME with a /etc/imucald/NAME.yaml is moved (its unit stopped first, started again
# after), unless the new directory exists already (then both are left and it says so).
RESTART_INSTANCES=""
migrate_instances() {
    for base in /var/lib/private /var/lib; do
        old="$base/imucald"
        [ -d "$old" ] && [ ! -L "$old" ] || continue
        for d in "$old"/*/; do
            [ -d "$d" ] || continue
            name=$(basename "$d")
            [ -f "$SYSCONFDIR/$name.yaml" ] || continue        # history/, sensors/: the main unit's
            new="$base/imucald-$name"
            if [ -e "$new" ]; then
                say "both $old/$name and $new exist: left as they are (imucald@$name uses $new)"
                continue
            fi
            if command -v systemctl >/dev/null 2>&1 && systemctl -q is-active "imucald@$name" 2>/dev/null; then
                systemctl stop "imucald@$name" && RESTART_INSTANCES="$RESTART_INSTANCES imucald@$name"
            fi
            mv "$d" "$new" && say "moved the state of imucald@$name from $old/$name to $new"
        done
    done
}

do_install() {
    "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 9))' 2>/dev/null ||
        die "imucald needs Python >= 3.9 ($PYTHON: $("$PYTHON" --version 2>&1 || echo missing))" 69
    if [ -z "$DESTDIR" ] && [ "$(id -u)" != 0 ]; then
        die "installing into / needs root: sudo make install (or DESTDIR=/tmp/stage make install to stage)" 77
    fi
    mkdir -p "$DESTDIR$PREFIX" || die "cannot create $DESTDIR$PREFIX" 73
    : > "$MANIFEST"

    # 1. the venv
    if [ -n "$NO_VENV" ]; then
        say "NO_VENV: no venv in $DESTDIR$PREFIX (files only)"
    else
        say "creating the venv $DESTDIR$PREFIX and installing imucald[$EXTRAS] into it"
        "$PYTHON" -m venv "$DESTDIR$PREFIX" ||
            die "could not create a venv: on Debian/Raspberry Pi OS run 'sudo apt install python3-venv'" 69
        "$DESTDIR$PREFIX/bin/python" -m pip install --quiet --upgrade pip >/dev/null 2>&1 || true
        spec="$SRC"
        [ -n "$EXTRAS" ] && spec="$SRC[$EXTRAS]"
        "$DESTDIR$PREFIX/bin/python" -m pip install --quiet "$spec" || die "pip install $spec failed" 74
        record "venv $PREFIX"
    fi

    # 2. the configuration, only where there is none (a user's file is never replaced)
    conf="$DESTDIR$SYSCONFDIR/imucald.yaml"
    if [ -e "$conf" ]; then
        say "kept the existing $SYSCONFDIR/imucald.yaml (the shipped one is $DOCDIR/imucald.yaml)"
    else
        install -D -m 0644 "$SRC/config/imucald.yaml" "$conf"
        record "config $SYSCONFDIR/imucald.yaml"
        say "installed $SYSCONFDIR/imucald.yaml"
    fi

    # 3. the units (ours: replaced on every install), ExecStart pointing into PREFIX
    mkdir -p "$DESTDIR$UNITDIR"
    for u in $UNITS; do
        sed -e "s#/opt/imucald/bin/imucald#$PREFIX/bin/imucald#g" -e "s#/etc/imucald/#$SYSCONFDIR/#g" \
            "$SRC/systemd/$u" > "$DESTDIR$UNITDIR/$u.tmp"
        chmod 0644 "$DESTDIR$UNITDIR/$u.tmp"
        mv "$DESTDIR$UNITDIR/$u.tmp" "$DESTDIR$UNITDIR/$u"
        record "file $UNITDIR/$u"
    done
    say "installed $UNITS into $UNITDIR"

    # 3b. `imucald` on the PATH: a link in BINDIR, unless something else is there
    link="$DESTDIR$BINDIR/imucald"
    if [ -e "$link" ] && [ ! -L "$link" ]; then
        say "kept $BINDIR/imucald (not ours); run $PREFIX/bin/imucald"
    elif [ -L "$link" ] && [ "$(readlink "$link")" != "$PREFIX/bin/imucald" ]; then
        say "kept $BINDIR/imucald -> $(readlink "$link") (not ours); run $PREFIX/bin/imucald"
    else
        mkdir -p "$DESTDIR$BINDIR"
        ln -sfn "$PREFIX/bin/imucald" "$link"
        record "link $BINDIR/imucald"
        say "linked $BINDIR/imucald -> $PREFIX/bin/imucald"
    fi

    # 4. documentation (the units' Documentation=) and the shipped configuration
    install -D -m 0644 "$SRC/README.md" "$DESTDIR$DOCDIR/README.md"
    install -D -m 0644 "$SRC/config/imucald.yaml" "$DESTDIR$DOCDIR/imucald.yaml"
    record "dir $DOCDIR"

    # 5. I2C access for the i2c group, where no rule gives it yet
    if existing=$(udev_has_i2c_rule); then
        say "udev: $existing already gives group i2c the I2C devices; no rule added"
    else
        install -D -m 0644 /dev/null "$DESTDIR$UDEVDIR/$UDEV_RULE"
        printf '%s\n' "# imucald: /dev/i2c-* to group i2c (the unit's SupplementaryGroups=i2c)" \
            'SUBSYSTEM=="i2c-dev", GROUP="i2c", MODE="0660"' > "$DESTDIR$UDEVDIR/$UDEV_RULE"
        record "file $UDEVDIR/$UDEV_RULE"
        say "installed $UDEVDIR/$UDEV_RULE (/dev/i2c-* to group i2c)"
    fi

    if live; then
        migrate_instances
        getent group i2c >/dev/null 2>&1 || { groupadd --system i2c && say "created the system group i2c"; }
        command -v udevadm >/dev/null 2>&1 && { udevadm control --reload 2>/dev/null || true;
            udevadm trigger --subsystem-match=i2c-dev 2>/dev/null || true; }
        command -v systemctl >/dev/null 2>&1 && systemctl daemon-reload 2>/dev/null || true
        for inst in $RESTART_INSTANCES; do
            systemctl start "$inst" && say "started $inst again"
        done
    elif [ -n "$DESTDIR" ]; then
        say "DESTDIR: no group, udev or systemd changes made on this machine"
    fi

    # hints: enabling the I2C interface changes the boot configuration; said, not done
    if ! ls /dev/i2c-* >/dev/null 2>&1; then
        say "no /dev/i2c-* here: enable the I2C interface first, e.g. 'sudo raspi-config nonint do_i2c 0'" \
            "(Raspberry Pi OS; or dtparam=i2c_arm=on in /boot/firmware/config.txt), then reboot"
    fi
    say "start it: sudo systemctl enable --now imucald   (the MQTT bridge: set mqtt.host in" \
        "$SYSCONFDIR/imucald.yaml, then sudo systemctl enable --now imucald-mqtt)"
    say "check its sandbox: systemd-analyze security imucald"
}

do_uninstall() {
    if [ -z "$DESTDIR" ] && [ "$(id -u)" != 0 ]; then
        die "uninstalling from / needs root: sudo make uninstall" 77
    fi
    if [ ! -f "$MANIFEST" ]; then
        die "no $MANIFEST: imucald was not installed with PREFIX=$PREFIX${DESTDIR:+ DESTDIR=$DESTDIR}" 69
    fi
    if live && command -v systemctl >/dev/null 2>&1; then
        for u in imucald-mqtt.service imucald.service; do
            systemctl disable --now "$u" >/dev/null 2>&1 || true
        done
        for inst in $(systemctl list-units --all --plain --no-legend 'imucald@*' 2>/dev/null | awk '{print $1}'); do
            systemctl disable --now "$inst" >/dev/null 2>&1 || true
        done
    fi
    kept_conf=""
    while read -r kind path; do
        case "$kind" in
            file) rm -f "$DESTDIR$path" ;;
            link) [ -L "$DESTDIR$path" ] && rm -f "$DESTDIR$path" ;;
            dir) rm -rf "$DESTDIR$path" ;;
            config)
                if [ -n "$PURGE" ]; then rm -f "$DESTDIR$path"; else kept_conf="$path"; fi ;;
            venv) ;;       # below: it holds the manifest
        esac
    done < "$MANIFEST"
    if [ -n "$PURGE" ]; then
        for d in "$DESTDIR$SYSCONFDIR" "$DESTDIR/var/lib/imucald" "$DESTDIR/var/lib/private/imucald" \
                 "$DESTDIR"/var/lib/imucald-* "$DESTDIR"/var/lib/private/imucald-*; do
            [ -e "$d" ] && rm -rf "$d" && say "purged $d"
        done
    else
        [ -n "$kept_conf" ] && say "kept $kept_conf (PURGE=1 removes it and the state in /var/lib/imucald)"
        [ -d "$DESTDIR/var/lib/imucald" ] || [ -d "$DESTDIR/var/lib/private/imucald" ] &&
            say "kept the calibrations in /var/lib/imucald (PURGE=1 removes them)"
    fi
    rm -rf "$DESTDIR$PREFIX"
    if live; then
        command -v systemctl >/dev/null 2>&1 && systemctl daemon-reload 2>/dev/null || true
        command -v udevadm >/dev/null 2>&1 && udevadm control --reload 2>/dev/null || true
    fi
    say "removed imucald from $PREFIX, its units and udev rule"
}

case "$ACTION" in
    install) do_install ;;
    uninstall) do_uninstall ;;
    *) die "usage: sh packaging/install.sh install|uninstall" 2 ;;
esac
