#!/bin/sh
# NOT YET A TEST: no host-side test runs this (see docs/daemon.md, "Under a real systemd").
# Run by hand:
#   ADXLGW_VM_WATCHDOG_SEC=300 .venv/bin/python -c 'import sys; from pathlib import Path;
#     from tests.vmcan.harness import *; r = run_in_can_vm(["/bin/sh",
#     "tests/inside_vm/systemd_job.sh", str(Path(sys.executable).parent / "adxlgw")],
#     cwd=REPO_ROOT, timeout_s=2300, env={**default_guest_env(), "ADXLGW_VM_WATCHDOG_SEC":
#     "300"}, settings=VmSettings(cpu_count=2, memory_mib=1536)); print(r.out_files)'
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

"$adxlgw" install-files --root /
# the board: the built-in emulated one, chosen on purpose; it lives on a pty, which the
# unit's device policy (serial adapters only) must be told about — in the field it is a ttyUSB
cat >/etc/adxl-gateway/gateway.toml <<TOML
[serial]
port = "emulated"
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
# qemu emulates the CPU here (no KVM): Python runs ~10x slower than on hardware, and the
# first start imports numpy, scipy, numba and pymodbus cold. The unit's 60 s would
# measure the emulator; the driver reports how long READY took.
cat >/etc/systemd/system/adxl-gateway.service.d/emulated-cpu.conf <<UNIT
[Service]
TimeoutStartSec=600
UNIT
# Under emulation the daemon sent no WATCHDOG=1 within 10 s (nor 60 s) of READY, and the
# watchdog restarted it: its first samples after a cold start (numba compiling into an
# empty cache, the emulated board on the same emulated CPU) take that long there. On this
# machine's real CPU, with an empty NUMBA_CACHE_DIR, the first WATCHDOG=1 came 5.0 s after
# READY. ADXLGW_VM_WATCHDOG_SEC sets a longer WatchdogSec for the VM.
if [ "${ADXLGW_VM_WATCHDOG_SEC:-}" ]; then
    cat >/etc/systemd/system/adxl-gateway.service.d/emulated-cpu-watchdog.conf <<UNIT
[Service]
WatchdogSec=$ADXLGW_VM_WATCHDOG_SEC
UNIT
fi

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
while [ ! -f "$out/systemd-report.json.done" ] && kill -0 $pid1 2>/dev/null && [ $i -lt 1500 ]; do
    sleep 1
    i=$((i + 1))
done
dmesg | grep 'systemd\[1\]' | tail -100 >"$out/pid1.log" || true
kill -KILL $pid1 2>/dev/null || true
wait $pid1 2>/dev/null || true
[ -f "$out/systemd-report.json.done" ] || { echo "no report from the driver after ${i} s"; exit 1; }
