#!/bin/sh
# Run by tests/daemon/test_systemd_vm.py (docs/daemon.md, "Under a real systemd"), which boots
# the qemu VM and judges the report this writes; by hand, the same way:
#   .venv/bin/python -m pytest -q -s tests/daemon/test_systemd_vm.py
# Inside the SocketCAN VM: a real systemd as PID 1 of a new
# PID namespace (the way container managers run it) runs the shipped unit, as
# `adxlgw install-files` installs it, and a driver service that exercises it
# (tests/inside_vm/systemd_driver.py). Everything written here lands in the guest's RAM
# overlay, never on the host. $1: the venv's adxlgw; results: $ADXLGW_VM_OUT_DIR.
set -eu
adxlgw=$1
out=${ADXLGW_VM_OUT_DIR:?}
python=$(dirname "$adxlgw")/python
repo=$(pwd)

# The guest's root is an overlay of the host's: whatever state an `adxlgw run` left there
# (a root-owned /var/lib/adxl-gateway from a run as root: the unit then exits
# 238/STATE_DIRECTORY) must not decide this test. Removed in the overlay only (the host's
# root is shared read-only); the unit starts from no state, as on a fresh machine.
rm -rf /var/lib/adxl-gateway /var/lib/private/adxl-gateway /etc/adxl-gateway
"$adxlgw" install-files --root /
# the board: the built-in emulated one, chosen on purpose; it lives on a pty, which the
# unit's device policy (serial adapters only) must be told about — in the field it is a ttyUSB
cat >/etc/adxl-gateway/gateway.toml <<TOML
[serial]
port = "emulated"
# qemu emulates the CPU (no KVM, and no numba: below): the plain-Python daemon takes 10-20x
# the CPU of this machine per sample, more than one emulated core at the board's 500
# samples/s. It then fell behind, worked through ever larger backlogs in one go (7-9 s
# without a sample seen) until one outlasted WatchdogSec and systemd restarted it under the
# test. An ADXL202 with RSET 1.25 MOhm (T2 10 ms, 100 samples/s; data sheet range) is a
# board the daemon keeps up with here; what systemd sees is the same program.
emulated_rset_kohm = 1250
[modbus]
# the emulated CPU may leave a request unread in the socket for longer than the 60 s idle
# timeout while the plain-Python daemon works through queued board bytes: the sweep would
# close the driver's connection, which is not what this test is about (tests/modbus/
# cover the idle sweep)
idle_timeout_s = 0
[can]
interface = "socketcan"
channel = "vcan0"
TOML
mkdir -p /etc/systemd/system/adxl-gateway.service.d
cat >/etc/systemd/system/adxl-gateway.service.d/pty-board.conf <<UNIT
[Service]
DeviceAllow=/dev/ptmx rw
DeviceAllow=char-pts rw
UNIT
# qemu emulates the CPU here (no KVM): Python runs 10-20x slower than on hardware. The
# drop-ins below are for that emulated CPU only; each says why.
# - No numba: compiling the estimator's kernels into an empty cache took 394 s to READY
#   (by hand, 2026-11-24) and the first samples after READY longer than WatchdogSec. The
#   same functions run as plain Python (gateway/core/jit.py), so what systemd sees
#   (READY, WATCHDOG=1, reload, stop, state) is the same program.
# - TimeoutStartSec: the cold imports of numpy, scipy, pymodbus and python-can alone take
#   minutes there; the unit's 60 s would measure the emulator. The driver reports the time.
# - WatchdogSec: a ping every WatchdogSec/2 once samples flow; on a loaded host the
#   emulated guest can stall for seconds, so 10 s would test the host's load. 30 s still
#   shows pings advancing and a restart once the board falls silent.
# - TimeoutStopSec: the daemon's stop is 0.3 s on this machine's CPU, 0.4-1.7 s measured
#   here (docs/daemon.md): close to the unit's 2 s, where systemd would SIGKILL it and the
#   test could not tell a slow CPU from a hang. 30 s: the driver reports the stop time
#   and the test bounds it.
cat >/etc/systemd/system/adxl-gateway.service.d/emulated-cpu.conf <<UNIT
[Service]
Environment=ADXLGW_NO_JIT=1
TimeoutStartSec=${ADXLGW_VM_START_TIMEOUT_SEC:-600}
WatchdogSec=${ADXLGW_VM_WATCHDOG_SEC:-30}
TimeoutStopSec=${ADXLGW_VM_STOP_TIMEOUT_SEC:-30}
UNIT

# This machine's Python lives under /root (pyenv), which ProtectHome=yes hides and
# DynamicUser cannot enter (mode 700): show the service that one tree, read-only. A
# production install (/opt/adxl-gateway/venv on /usr/bin/python3) needs none of this.
real_python=$(readlink -f "$python")
case "$real_python" in
    /root/*|/home/*)
        cat >/etc/systemd/system/adxl-gateway.service.d/python-under-home.conf <<UNIT
[Service]
ProtectHome=tmpfs
BindReadOnlyPaths=$(dirname "$(dirname "$real_python")")
UNIT
        ;;
esac

# The venv (and the package, installed editable) live in this checkout. Under /root or
# /home ProtectHome hides it: shown read-only, like the Python tree above. (Under /tmp or
# /var/tmp nothing can show it: DynamicUser implies a private /tmp, and a bind mount from
# there fails with 226/NAMESPACE — tests/daemon/test_systemd_vm.py refuses such a checkout.)
case "$repo" in
    /root/*|/home/*)
        cat >/etc/systemd/system/adxl-gateway.service.d/checkout-in-home.conf <<UNIT
[Service]
ProtectHome=tmpfs
BindReadOnlyPaths=$repo
UNIT
        ;;
esac

cat >/etc/systemd/system/adxl-vmtest.target <<UNIT
[Unit]
Description=adxl-gateway under systemd: the test
DefaultDependencies=no
Wants=systemd-journald.socket systemd-journald.service adxl-vmtest.service
UNIT
cat >/etc/systemd/system/adxl-vmtest.service <<UNIT
[Unit]
DefaultDependencies=no
After=systemd-journald.socket systemd-journald.service
[Service]
Type=oneshot
WorkingDirectory=$repo
Environment=PYTHONPATH=$repo PYTHONDONTWRITEBYTECODE=1
ExecStart=$python $repo/tests/inside_vm/systemd_driver.py $out/systemd-report.json
StandardOutput=file:$out/driver.log
StandardError=inherit
UNIT

[ -s /etc/machine-id ] || systemd-machine-id-setup >/dev/null 2>&1 || true
# systemd as PID 1 of its own PID and mount namespaces; the driver writes its report,
# then this script ends systemd (the harness's timeout bounds the whole)
env -u container unshare --pid --fork --mount --mount-proc --kill-child \
    /lib/systemd/systemd --unit=adxl-vmtest.target --log-target=kmsg &
pid1=$!
i=0
while [ ! -f "$out/systemd-report.json.done" ] && kill -0 $pid1 2>/dev/null && [ $i -lt ${ADXLGW_VM_JOB_LIMIT_S:-1500} ]; do
    sleep 1
    i=$((i + 1))
done
dmesg | grep 'systemd\[1\]' | tail -400 >"$out/pid1.log" || true
kill -KILL $pid1 2>/dev/null || true
wait $pid1 2>/dev/null || true
[ -f "$out/systemd-report.json.done" ] || { echo "no report from the driver after ${i} s"; exit 1; }
