#!/usr/bin/env bash
# Install gx3 for a fleet on a Debian machine (or any with systemd), as root:
#
#   sudo configs/install.sh                # gx3 from this checkout
#   sudo configs/install.sh gx3_bridge-0.1.0-*.whl  # or from a built wheel
#
# It puts gx3 in a virtual environment at /opt/gx3 (pip fetches its dependencies),
# creates the system user gx3 in the group dialout (serial ports), /etc/gx3 (zenoh.json5
# and imu.env.example) and /var/lib/gx3 (the recorder's archives, owned by gx3),
# installs the systemd units and the udev rules, and reloads systemd and udev.
# Files already in /etc/gx3 and the udev rules are kept; the units are replaced (change
# them with `systemctl edit`). Run it again to upgrade gx3.
#
#   --root DIR   install under DIR instead of / (an image being built, a test): DIR
#                must hold etc/passwd and etc/group; nothing is reloaded
#   --no-venv    leave /opt/gx3 as it is (gx3 installed there some other way)
#
# Needs python3 with venv (Debian: apt-get install python3-venv; PYTHON=python3.12 picks
# another interpreter) and useradd.
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
root=""
venv=1
from=""
usage() { echo "usage: $0 [--root DIR] [--no-venv] [WHEEL | CHECKOUT]"; }
fail() { echo "error: $*" >&2; exit 2; }
while [ $# -gt 0 ]; do
    case "$1" in
        --root) [ $# -ge 2 ] || fail "--root needs a directory"; root=$2; shift 2 ;;
        --root=*) root=${1#--root=}; shift ;;
        --no-venv) venv=0; shift ;;
        -h | --help) usage; exit 0 ;;
        -*) usage >&2; fail "unknown option $1" ;;
        *) [ -z "$from" ] || fail "one WHEEL or CHECKOUT only"; from=$1; shift ;;
    esac
done
from=${from:-$(dirname "$here")}
[ -e "$from" ] || fail "$from: no such wheel or checkout"
if [ -n "$root" ]; then
    [ -d "$root" ] || fail "--root $root: no such directory"
    root=$(cd "$root" && pwd)
    [ -f "$root/etc/passwd" ] && [ -f "$root/etc/group" ] \
        || fail "--root $root: it has no etc/passwd and etc/group to add the gx3 user to"
elif [ "$(id -u)" -ne 0 ]; then
    fail "run it as root (sudo $0), or give --root DIR"
fi
PATH=$PATH:/usr/sbin:/sbin
prefix=()
[ -z "$root" ] || prefix=(--prefix "$root")

if [ "$venv" = 1 ]; then
    echo "gx3 into $root/opt/gx3 from $from"
    [ -x "$root/opt/gx3/bin/pip" ] || "${PYTHON:-python3}" -m venv "$root/opt/gx3" \
        || fail "python3 -m venv failed (Debian: apt-get install python3-venv)"
    "$root/opt/gx3/bin/pip" install --quiet --upgrade "$from"
fi

if grep -q '^gx3:' "$root/etc/passwd"; then
    usermod "${prefix[@]}" --append --groups dialout gx3
else
    grep -q '^dialout:' "$root/etc/group" || groupadd "${prefix[@]}" --system dialout
    useradd "${prefix[@]}" --system --user-group --groups dialout --home-dir /var/lib/gx3 \
        --no-create-home --shell /usr/sbin/nologin --comment "gx3 bridges and recorder" gx3
    echo "user gx3 (groups gx3, dialout)"
fi
uid=$(awk -F: '$1 == "gx3" { print $3 }' "$root/etc/passwd")
gid=$(awk -F: '$1 == "gx3" { print $4 }' "$root/etc/passwd")

install -d -m 0755 "$root/etc/gx3" "$root/etc/systemd/system" "$root/etc/udev/rules.d"
install -d -m 0750 "$root/var/lib/gx3"
if [ "$(id -u)" -eq 0 ]; then
    chown "$uid:$gid" "$root/var/lib/gx3"
else
    echo "not root: $root/var/lib/gx3 is yours, not gx3's ($uid:$gid)"
fi
keep() {  # install $1 as $2 unless $2 is there already
    if [ -e "$2" ]; then echo "kept $2"; else install -m 0644 "$1" "$2"; echo "wrote $2"; fi
}
keep "$here/systemd/zenoh.json5" "$root/etc/gx3/zenoh.json5"
keep "$here/systemd/imu.env.example" "$root/etc/gx3/imu.env.example"
keep "$here/udev/99-gx3.rules" "$root/etc/udev/rules.d/99-gx3.rules"
install -m 0644 "$here/systemd/gx3-bridge@.service" "$here/systemd/gx3-record.service" \
    "$root/etc/systemd/system/"
echo "wrote $root/etc/systemd/system/gx3-bridge@.service and gx3-record.service"

if [ -z "$root" ]; then
    systemctl daemon-reload 2> /dev/null || echo "systemd is not running: no units reloaded"
    udevadm control --reload 2> /dev/null || echo "udev is not running: no rules reloaded"
fi
cat <<DONE
next: name each unit in /etc/udev/rules.d/99-gx3.rules, then
  udevadm control --reload && udevadm trigger
  systemctl enable --now gx3-bridge@imu1 gx3-record
DONE
