#!/usr/bin/env bash
# Install what the SocketCAN-in-a-VM tests need (tests/vmcan/, docs/socketcan-vm.md).
#
# The host kernel has no vcan module and modules cannot be loaded here, so the
# tests boot a stock Debian kernel under qemu (software emulation) and run
# inside it. This script:
#   1. apt-installs qemu, can-utils, iproute2, busybox-static, cpio, kmod;
#   2. downloads (not installs) the current Debian generic amd64 kernel
#      package and unpacks only its vmlinuz and the modules we need;
#   3. builds a small initramfs (busybox + those modules + /init) that mounts
#      the host root over 9p and runs the job the test harness hands it.
# Everything lands in $ADXLGW_VM_DIR (default: <repo>/.cache/vm, gitignored).
#
# Idempotent: packages already present are not reinstalled, and a cache built
# by this same script version is left alone. Run as root.
set -euo pipefail

repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
vm_dir="${ADXLGW_VM_DIR:-$repo_root/.cache/vm}"
script_path="$repo_root/scripts/install-vm-deps.sh"

# The "generic" flavour: the "cloud" one lacks vcan, can-raw and 9p modules.
kernel_meta_package="linux-image-amd64"
host_packages=(qemu-system-x86 can-utils iproute2 busybox-static cpio kmod zstd xz-utils)
# Modules /init loads, dependencies first (resolved below via modules.dep).
wanted_modules=(virtio_pci 9pnet_virtio 9p overlay can can-raw can-bcm vcan)

log() { echo "install-vm-deps: $*" >&2; }

if [[ $(id -u) -ne 0 ]]; then
    log "must run as root (apt-get install)"; exit 1
fi

# --- 1. host packages -------------------------------------------------------
apt_updated=0
apt_update_once() {
    if [[ $apt_updated -eq 0 ]]; then
        apt-get update -qq
        apt_updated=1
    fi
}

missing=()
for pkg in "${host_packages[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$pkg")
    fi
done
if [[ ${#missing[@]} -gt 0 ]]; then
    log "installing ${missing[*]}"
    apt_update_once
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# --- 2./3. guest kernel and initramfs ---------------------------------------
# The stamp records the hash of this script: a changed /init or module list
# rebuilds the cache, an unchanged one costs nothing (and needs no network).
build_id="$(sha256sum "$script_path" | cut -d' ' -f1)"
if [[ -f "$vm_dir/stamp" && "$(cat "$vm_dir/stamp")" == "$build_id" \
      && -f "$vm_dir/vmlinuz" && -f "$vm_dir/initramfs.cpio.gz" ]]; then
    log "guest kernel $(cat "$vm_dir/kernel-release") already in $vm_dir"
    exit 0
fi

apt_update_once
kernel_package="$(apt-cache depends "$kernel_meta_package" \
    | awk '/Depends: linux-image-[0-9]/ {print $2; exit}')"
if [[ -z "$kernel_package" ]]; then
    log "cannot resolve $kernel_meta_package to a kernel package"; exit 1
fi
kernel_release="${kernel_package#linux-image-}"
log "guest kernel: $kernel_package"

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
# apt-get download writes into the current directory; _apt must be able to
# write there or apt falls back to an unsandboxed download with a warning.
chmod 755 "$work"
if id _apt >/dev/null 2>&1; then chown _apt "$work"; fi
(cd "$work" && apt-get download -qq "$kernel_package")
deb="$(ls "$work"/*.deb)"
mkdir "$work/root"
# Unpack only the kernel image and the module trees that hold what we load
# (~90 MB instead of ~400 MB). depmod then resolves dependencies within that
# subset; the modinfo check further down catches one that lies outside it.
dpkg-deb --fsys-tarfile "$deb" | tar -x -C "$work/root" --wildcards \
    "./boot/vmlinuz-$kernel_release" './lib/modules/*/modules.*' \
    './lib/modules/*/kernel/net/*' './lib/modules/*/kernel/fs/*' \
    './lib/modules/*/kernel/lib/*' './lib/modules/*/kernel/crypto/*' \
    './lib/modules/*/kernel/drivers/virtio/*' './lib/modules/*/kernel/drivers/net/can/*'
mod_root="$work/root/lib/modules/$kernel_release"
depmod -b "$work/root" "$kernel_release"

# Resolve the wanted modules to files, dependencies before dependants.
declare -A seen=()
load_order=()
module_path() {
    # modules.dep keys are paths; module names may use - or _ interchangeably.
    local name="$1" pattern
    pattern="$(echo "$name" | sed 's/[-_]/[-_]/g')"
    grep -E "(^|/)${pattern}\.ko(\.xz|\.zst|\.gz)?:" "$mod_root/modules.dep" | cut -d: -f1 | head -1
}
add_module_file() {
    local rel="$1" dep
    [[ -n "${seen[$rel]:-}" ]] && return 0
    seen[$rel]=1
    for dep in $(awk -F': ?' -v key="$rel" '$1 == key {print $2; exit}' "$mod_root/modules.dep"); do
        add_module_file "$dep"
    done
    load_order+=("$rel")
}
for name in "${wanted_modules[@]}"; do
    rel="$(module_path "$name")"
    if [[ -z "$rel" ]]; then
        if grep -qE "/${name//-/[-_]}\.ko$" "$mod_root/modules.builtin"; then
            continue  # built into this kernel
        fi
        log "module $name not found in $kernel_package"; exit 1
    fi
    add_module_file "$rel"
done

# Every module's own list of dependencies must be covered by the load order.
loaded_names=" "
for rel in "${load_order[@]}"; do
    name="$(basename "$rel")"; name="${name%%.ko*}"
    loaded_names+="${name//-/_} "
done
for rel in "${load_order[@]}"; do
    for dep in $(modinfo -F depends "$mod_root/$rel" | tr ',' ' '); do
        if [[ "$loaded_names" != *" ${dep//-/_} "* ]]; then
            log "$rel needs $dep, which is not in the unpacked module subset"; exit 1
        fi
    done
done

# Lay out the initramfs. busybox's insmod loads plain .ko files only, so
# compressed modules are decompressed here.
initrd="$work/initrd"
mkdir -p "$initrd"/{bin,sbin,usr/bin,usr/sbin,proc,sys,dev,host,modules}
cp /bin/busybox "$initrd/bin/busybox"
: >"$initrd/modules.order"
for rel in "${load_order[@]}"; do
    base="$(basename "$rel")"
    case "$rel" in
        *.ko.xz)  xz -dc "$mod_root/$rel" >"$initrd/modules/${base%.xz}"; base="${base%.xz}" ;;
        *.ko.zst) zstd -qdc "$mod_root/$rel" >"$initrd/modules/${base%.zst}"; base="${base%.zst}" ;;
        *.ko.gz)  gzip -dc "$mod_root/$rel" >"$initrd/modules/${base%.gz}"; base="${base%.gz}" ;;
        *.ko)     cp "$mod_root/$rel" "$initrd/modules/$base" ;;
    esac
    echo "$base" >>"$initrd/modules.order"
done
log "modules: $(tr '\n' ' ' <"$initrd/modules.order")"

# /init: the guest's whole userland before it chroots into the host root.
# The harness (tests/vmcan/harness.py) shares a host temp dir as 9p tag
# "vmjob" holding job.sh; /init writes the job's output and exit status there.
# Marker lines on the console ("VMCAN-...") let the harness tell an init
# failure from a hang or a kernel panic.
cat >"$initrd/init" <<'INIT'
#!/bin/busybox sh
/bin/busybox --install -s
export PATH=/sbin:/bin:/usr/sbin:/usr/bin

fail() {
    echo "VMCAN-INIT-FAILED: $*"
    sync
    reboot -f   # qemu runs with -no-reboot, so this ends qemu
}

mount -t proc proc /proc || fail "mount /proc"
mount -t sysfs sysfs /sys || fail "mount /sys"
mount -t devtmpfs devtmpfs /dev || fail "mount /dev"
exec </dev/null >/dev/console 2>&1

for m in $(cat /modules.order); do
    insmod "/modules/$m" || fail "insmod $m"
done

# The host root, read-only over 9p. cache=loose lets the guest cache file
# pages: the host tree is not expected to change while a job runs, and it
# makes Python's many imports much faster.
mkdir -p /lower /rw
mount -t 9p -o trans=virtio,version=9p2000.L,ro,msize=512000,cache=loose hostroot /lower \
    || fail "mount 9p hostroot"
# A copy-on-write overlay (writes go to guest RAM, never to the host), so
# the job sees every host file, /tmp included, and may write anywhere.
mount -t tmpfs -o mode=0755 tmpfs /rw || fail "tmpfs /rw"
mkdir -p /rw/upper /rw/work
mount -t overlay -o lowerdir=/lower,upperdir=/rw/upper,workdir=/rw/work overlay /host \
    || fail "mount overlay"

# Fresh kernel file systems and run-time dirs, as a booted system has.
mount -t proc proc /host/proc || fail "mount /host/proc"
mount -t sysfs sysfs /host/sys || fail "mount /host/sys"
mount -t devtmpfs devtmpfs /host/dev || fail "mount /host/dev"
mkdir -p /host/dev/pts /host/dev/shm
mount -t devpts -o newinstance,ptmxmode=0666 devpts /host/dev/pts || fail "mount devpts"
ln -sf pts/ptmx /host/dev/ptmx 2>/dev/null
mount -t tmpfs -o mode=1777 tmpfs /host/dev/shm || fail "mount /dev/shm"
mount -t tmpfs -o mode=0755 tmpfs /host/run || fail "mount /run"

# The job share: job.sh in, output and exit status out.
mkdir -p /host/run/vmjob
mount -t 9p -o trans=virtio,version=9p2000.L,rw,msize=512000 vmjob /host/run/vmjob \
    || fail "mount 9p vmjob"
[ -f /host/run/vmjob/job.sh ] || fail "no job.sh in the vmjob share"

# Network: loopback for tests that use 127.0.0.1, and the virtual CAN bus.
# The host's iproute2 is used: busybox ip cannot create vcan links.
chroot /host ip link set lo up || fail "ip link set lo up"
chroot /host ip link add dev vcan0 type vcan || fail "ip link add vcan0"
chroot /host ip link set up vcan0 || fail "ip link set up vcan0"

echo "VMCAN-READY"
chroot /host /bin/sh /run/vmjob/job.sh >/host/run/vmjob/output 2>&1 </dev/null
rc=$?
echo "$rc" >/host/run/vmjob/rc.tmp && mv /host/run/vmjob/rc.tmp /host/run/vmjob/rc
sync
echo "VMCAN-EXIT $rc"
reboot -f
INIT
chmod 755 "$initrd/init"

mkdir -p "$vm_dir"
(cd "$initrd" && find . -print0 | cpio --null -o -H newc --quiet) | gzip -1 >"$vm_dir/initramfs.cpio.gz.new"
cp "$work/root/boot/vmlinuz-$kernel_release" "$vm_dir/vmlinuz.new"
mv "$vm_dir/initramfs.cpio.gz.new" "$vm_dir/initramfs.cpio.gz"
mv "$vm_dir/vmlinuz.new" "$vm_dir/vmlinuz"
echo "$kernel_release" >"$vm_dir/kernel-release"
echo "$build_id" >"$vm_dir/stamp"
log "guest kernel $kernel_release and initramfs written to $vm_dir"
