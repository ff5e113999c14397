#!/usr/bin/env bash
# run-in-guest.sh: runs host-built test binaries inside a QEMU guest whose kernel has a real CAN stack
# (vcan0 up), and returns the guest's exit code. The host kernel has no CAN, so this is the only way
# SocketCAN code meets a real kernel in our tests. See docs/vcan.md.
#
# Usage: tests/vcan/run-in-guest.sh [--timeout SECS] [--mem MIB] [--prepare-only]
#                                   [--] CMD [ARGS...] [--next CMD [ARGS...]]...
#
# Several commands (separated by --next) run one after another in ONE boot, as root; each runs in the
# caller's working directory, in the host's root file system shared read-only over 9p with a RAM
# overlay on top (host-built binaries, their shared libraries, fixtures and the cargo tree are all
# there; writes stay in the guest), and with can-utils (candump, cansend, cangen, canplayer) and
# busybox `ip` on PATH.
# The exit code is the first non-zero exit code of the commands (0 when all pass); 124 when the outer
# timeout hit; 125 when the harness itself failed (no QEMU, kernel not found, guest crashed).
#
# Everything comes from Debian packages: qemu-system-x86 and busybox-static (host tools), and
# linux-image-amd64 + can-utils fetched with `apt-get download` and unpacked with `dpkg-deb -x`
# (never installed). The kernel and initramfs are cached per kernel version under
# ${IMULAB_VCAN_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/imulab-vcan}.
set -euo pipefail

HARNESS_ERROR=125
say() { printf 'vcan: %s\n' "$*" >&2; }
die() {
  say "error: $*"
  exit "$HARNESS_ERROR"
}

timeout_secs=${IMULAB_VCAN_TIMEOUT:-240}
mem_mib=${IMULAB_VCAN_MEM:-1024}
prepare_only=false
while [ $# -gt 0 ]; do
  case "$1" in
    --timeout) timeout_secs=${2:?--timeout needs seconds}; shift 2 ;;
    --mem) mem_mib=${2:?--mem needs MiB}; shift 2 ;;
    --prepare-only) prepare_only=true; shift ;;
    -h | --help) sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    --) shift; break ;;
    -*) die "unknown option $1 (see --help)" ;;
    *) break ;;
  esac
done
if ! $prepare_only && [ $# -eq 0 ]; then die "no command given (see --help)"; fi

for tool in qemu-system-x86_64 busybox apt-get dpkg-deb flock timeout readelf objcopy; do
  command -v "$tool" >/dev/null || die "$tool not found (install: apt-get install qemu-system-x86 busybox-static binutils)"
done
busybox_bin=$(command -v busybox)
# The guest needs a busybox that runs without any shared library.
if readelf -l "$busybox_bin" 2>/dev/null | grep -q 'INTERP'; then
  die "$busybox_bin is dynamically linked: install busybox-static"
fi

cache_root=${IMULAB_VCAN_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/imulab-vcan}
mkdir -p "$cache_root"

# ---------------------------------------------------------------------------------------------------
# Which kernel: the versioned image package that linux-image-amd64 depends on right now (the generic
# flavour; the -cloud flavour has no CAN), and which can-utils. Resolved from apt's package lists at
# run time, so a point release is picked up; apt-cache takes seconds on a busy machine, so the answer
# is remembered until the lists change (apt-get update).
resolve_packages() {
  local pkg
  pkg=$(apt-cache depends linux-image-amd64 2>/dev/null |
    awk '$1 == "Depends:" && $2 ~ /^linux-image-[0-9].*-amd64$/ && $2 !~ /cloud/ { print $2; exit }')
  [ -n "$pkg" ] || return 1
  apt-cache policy "$pkg" can-utils 2>/dev/null | awk -v pkg="$pkg" '
    /^[^ ]/ { name = $1; sub(":$", "", name) }
    $1 == "Candidate:" { candidate[name] = $2 }
    END {
      if (candidate[pkg] == "" || candidate[pkg] == "(none)") exit 1
      cu = candidate["can-utils"]; if (cu == "(none)") cu = ""
      print pkg, candidate[pkg], cu
    }'
}
apt_state=$(stat -c '%Y' /var/lib/apt/lists /var/cache/apt/pkgcache.bin 2>/dev/null | tr '\n' ' ' || true)
resolution_file="$cache_root/apt-resolution"
resolution=""
if [ -f "$resolution_file" ] && [ "$(head -n 1 "$resolution_file")" = "$apt_state" ]; then
  resolution=$(sed -n 2p "$resolution_file")
fi
if [ -z "$resolution" ]; then
  resolution=$(resolve_packages || true)
  if [ -z "$resolution" ] && [ "$(id -u)" = 0 ]; then
    say "apt lists know no linux-image-amd64; running apt-get update"
    apt-get update -qq >/dev/null 2>&1 || true
    apt_state=$(stat -c '%Y' /var/lib/apt/lists /var/cache/apt/pkgcache.bin 2>/dev/null | tr '\n' ' ' || true)
    resolution=$(resolve_packages || true)
  fi
  [ -n "$resolution" ] && printf '%s\n%s\n' "$apt_state" "$resolution" >"$resolution_file"
fi
read -r kernel_pkg kernel_version can_utils_version <<<"${resolution:-}" || true
if [ -n "${kernel_pkg:-}" ]; then
  kernel_key="${kernel_pkg}_${kernel_version}"
else
  # Offline and apt knows nothing: fall back to the newest kernel already in the cache.
  kernel_key=""
  for candidate in "$cache_root"/linux-image-*/; do
    [ -e "$candidate/.kernel-ready" ] || continue
    if [ -z "$kernel_key" ] || [ "$candidate" -nt "$cache_root/$kernel_key" ]; then
      kernel_key=$(basename "$candidate")
    fi
  done
  [ -n "$kernel_key" ] || die "cannot resolve linux-image-amd64 (apt-get update?) and nothing is cached in $cache_root"
  say "apt cannot resolve linux-image-amd64; using cached $kernel_key"
fi
kernel_dir="$cache_root/$kernel_key"
mkdir -p "$kernel_dir"

# Serialise preparation: two test runs may start at once and must not build the same cache twice.
exec 9>"$kernel_dir/.lock"
flock 9

# Runs apt-get download in a directory _apt can write, then moves the .deb to $2.
download_deb() {
  local spec=$1 dest_dir=$2 tmp
  tmp=$(mktemp -d)
  chmod 0777 "$tmp"
  (cd "$tmp" && apt-get download -q "$spec" >/dev/null 2>"$tmp/err") || {
    cat "$tmp/err" >&2
    rm -rf "$tmp"
    die "apt-get download $spec failed"
  }
  mv "$tmp"/*.deb "$dest_dir"/
  rm -rf "$tmp"
}

# Finds the compressed payload inside a bzImage and writes the decompressed ELF vmlinux (the idea of
# the kernel's scripts/extract-vmlinux, done here because Debian does not ship that script).
extract_vmlinux() {
  local image=$1 out=$2 magic decoder offset
  local -a formats=(
    '\x1f\x8b\x08|gzip -dc'
    '\xfd7zXZ\x00|xz -dc'
    '\x28\xb5\x2f\xfd|zstd -dc'
    'BZh|bzip2 -dc'
    '\x5d\x00\x00\x00|xz -dc --format=lzma'
    '\x02\x21\x4c\x18|lz4 -dc'
  )
  for entry in "${formats[@]}"; do
    magic=${entry%%|*}
    decoder=${entry#*|}
    command -v "${decoder%% *}" >/dev/null || continue
    for offset in $(LC_ALL=C grep -obUaP "$magic" "$image" 2>/dev/null | cut -d: -f1 | head -n 20); do
      tail -c +$((offset + 1)) "$image" | $decoder >"$out" 2>/dev/null || true
      if [ "$(head -c 4 "$out" | od -An -tx1 | tr -d ' \n')" = "7f454c46" ]; then
        return 0
      fi
    done
  done
  rm -f "$out"
  return 1
}

# Module names in `depends=` may use '-' or '_' interchangeably with the file names.
find_module() {
  local name=$1 modroot=$2 pattern
  pattern=$(printf '%s' "$name" | sed 's/[-_]/[-_]/g')
  find "$modroot" -regextype posix-extended -regex ".*/${pattern}\.ko(\.xz|\.zst|\.gz)?" -print -quit
}

module_depends() {
  local file=$1
  case "$file" in
    *.ko.xz) xz -dc "$file" ;;
    *.ko.zst) zstd -dc "$file" ;;
    *.ko.gz) gzip -dc "$file" ;;
    *) cat "$file" ;;
  esac | tr '\0' '\n' | LC_ALL=C grep -a '^depends=' | head -n 1 | cut -d= -f2 | tr ',' ' '
}

# Appends NAME and (first) its dependencies to the global load order, each once, writing each module
# as a plain .ko into $module_out. The kernel package has no modules.dep, so the dependencies come
# from each module's own .modinfo section.
declare -a load_order=()
add_module_with_deps() {
  local name=$1 modroot=$2 file dep known
  for known in "${load_order[@]}"; do [ "$known" = "$name" ] && return 0; done
  file=$(find_module "$name" "$modroot")
  [ -n "$file" ] || die "kernel module $name not found under $modroot"
  for dep in $(module_depends "$file"); do add_module_with_deps "$dep" "$modroot"; done
  for known in "${load_order[@]}"; do [ "$known" = "$name" ] && return 0; done
  load_order+=("$name")
  case "$file" in
    *.ko.xz) xz -dc "$file" ;;
    *.ko.zst) zstd -dc "$file" ;;
    *.ko.gz) gzip -dc "$file" ;;
    *) cat "$file" ;;
  esac >"$module_out/$name.ko.signed"
  # Debian signs its modules; checking a signature under software emulation costs ~0.2 s per module
  # at boot. objcopy rewrites the ELF without the appended signature (the kernel then only notes
  # "tainted: unsigned module", which is harmless in a throw-away test VM).
  objcopy "$module_out/$name.ko.signed" "$module_out/$name.ko"
  rm "$module_out/$name.ko.signed"
}

# The guest's /init. Loads CAN and 9p modules, brings vcan0 up, mounts the host's root read-only and
# runs the job in a chroot of it; reports the exit code through the isa-debug-exit port.
write_guest_init() {
  cat <<'INIT'
#!/bin/busybox sh
/bin/busybox mkdir -p /proc /sys /dev /usr/bin /sbin /usr/sbin
/bin/busybox --install -s
export PATH=/bin:/sbin:/usr/bin:/usr/sbin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
stty -opost 2>/dev/null
report() {
  code=$1
  [ "$code" -gt 127 ] && code=127
  echo "vcan-guest: exit $1"
  sync
  # isa-debug-exit: QEMU exits with (value << 1) | 1. The format is the octal escape of the byte.
  # shellcheck disable=SC2059
  printf "\\$(printf %03o "$code")" | dd of=/dev/port bs=1 seek=244 count=1 2>/dev/null
  sleep 5
  echo "vcan-guest: isa-debug-exit did not stop the VM"
  poweroff -f
}
fail() {
  echo "vcan-guest: setup failed: $*"
  report 125
}
echo "vcan-guest: init started at $(cut -d' ' -f1 /proc/uptime) s"
for module in $(cat /lib/modules/load-order); do
  insmod "/lib/modules/$module.ko" || fail "insmod $module"
done
ip link set lo up
ip link add dev vcan0 type vcan || fail "ip link add vcan0"
ip link set vcan0 up || fail "ip link set vcan0 up"
mkdir -p /host /hostro /scratch
mount -t 9p -o trans=virtio,version=9p2000.L,ro,cache=loose,msize=262144 hostroot /hostro || fail "mount host root"
# The host's files, writable in the guest: an overlay whose upper layer is guest RAM. Writes never
# reach the host, and a checkout or target directory under the host's /tmp stays visible.
mount -t tmpfs tmpfs /scratch
mkdir -p /scratch/upper /scratch/work
if mount -t overlay overlay -o lowerdir=/hostro,upperdir=/scratch/upper,workdir=/scratch/work /host; then
  writable_tmp=""
else
  echo "vcan-guest: overlay mount failed; host root read-only, empty tmpfs on /tmp"
  mount --move /hostro /host || fail "move host root"
  writable_tmp=tmpfs:tmp
fi
for fs in proc:proc sysfs:sys devtmpfs:dev tmpfs:run $writable_tmp; do
  mount -t "${fs%%:*}" "${fs%%:*}" "/host/${fs#*:}" || fail "mount /host/${fs#*:}"
done
mkdir -p /host/dev/pts /host/dev/shm /host/run/imulab-vcan/job /host/run/imulab-vcan/bin
mount -t devpts devpts /host/dev/pts
mount -t tmpfs tmpfs /host/dev/shm
chmod 1777 /host/tmp
mount -t 9p -o trans=virtio,version=9p2000.L,ro,msize=262144 imulabjob /host/run/imulab-vcan/job || fail "mount job"
# can-utils run with their own loader and libraries, whatever the chroot's are.
cp -a /opt/can-utils /host/run/imulab-vcan/can-utils
for tool in /opt/can-utils/bin/*; do
  name=${tool##*/}
  printf '#!/run/imulab-vcan/bin/busybox sh\nexec /run/imulab-vcan/can-utils/lib/ld.so --library-path /run/imulab-vcan/can-utils/lib /run/imulab-vcan/can-utils/bin/%s "$@"\n' "$name" >"/host/run/imulab-vcan/bin/$name"
  chmod 755 "/host/run/imulab-vcan/bin/$name"
done
cp /bin/busybox /host/run/imulab-vcan/bin/busybox
ln -s busybox /host/run/imulab-vcan/bin/ip
echo "vcan-guest: ready in $(cut -d' ' -f1 /proc/uptime) s (kernel $(uname -r)), vcan0 up"
chroot /host /bin/sh /run/imulab-vcan/job/job.sh
report $?
INIT
}

kernel_file="$kernel_dir/kernel"
kernel_marker="$kernel_dir/.kernel-ready"
# The CAN stack, virtio + 9p for the host share, overlay to make it writable in guest RAM; their
# dependencies are added from .modinfo.
wanted_modules="can-dev vcan can can-raw virtio_pci 9pnet_virtio 9p overlay"
if [ "$(cat "$kernel_marker" 2>/dev/null)" != "$wanted_modules" ]; then
  [ -n "${kernel_pkg:-}" ] || die "kernel cache $kernel_dir is incomplete and apt cannot resolve a kernel"
  say "fetching $kernel_pkg=$kernel_version (cached in $kernel_dir)"
  rm -rf "$kernel_dir/unpacked" "$kernel_dir/modules" "$kernel_dir"/*.deb "$kernel_dir"/initramfs-*
  download_deb "$kernel_pkg=$kernel_version" "$kernel_dir"
  dpkg-deb -x "$kernel_dir"/*.deb "$kernel_dir/unpacked"
  vmlinuz=$(find "$kernel_dir/unpacked/boot" -name 'vmlinuz-*' -print -quit 2>/dev/null || true)
  [ -n "$vmlinuz" ] || die "no /boot/vmlinuz-* in $kernel_pkg"
  # A decompressed ELF with a PVH entry note boots directly (~4 s faster under TCG than vmlinuz,
  # which decompresses itself in the guest); fall back to vmlinuz otherwise.
  if extract_vmlinux "$vmlinuz" "$kernel_dir/vmlinux" &&
    readelf -n "$kernel_dir/vmlinux" 2>/dev/null | grep -q 'PHYS32_ENTRY\|note type: (0x00000012)'; then
    mv "$kernel_dir/vmlinux" "$kernel_file"
    echo "vmlinux-pvh" >"$kernel_dir/kernel-kind"
  else
    say "no PVH vmlinux could be made; booting the compressed vmlinuz (slower)"
    cp "$vmlinuz" "$kernel_file"
    echo "vmlinuz" >"$kernel_dir/kernel-kind"
  fi
  # Keep only the modules the guest loads (the whole tree is ~360 MB), with their load order.
  module_out="$kernel_dir/modules"
  mkdir -p "$module_out"
  modroot=$(find "$kernel_dir/unpacked/lib/modules" -mindepth 1 -maxdepth 1 -type d -print -quit)
  [ -n "$modroot" ] || die "no /lib/modules/<version> in $kernel_pkg"
  for wanted in $wanted_modules; do add_module_with_deps "$wanted" "$modroot"; done
  printf '%s\n' "${load_order[@]}" >"$module_out/load-order"
  rm -rf "$kernel_dir/unpacked" "$kernel_dir"/*.deb
  echo "$wanted_modules" >"$kernel_marker"
  # Older kernel versions are dead weight now; remove those no other run is using.
  for old_dir in "$cache_root"/linux-image-*/; do
    old_dir=${old_dir%/}
    [ "$old_dir" = "$kernel_dir" ] && continue
    if (exec 8>"$old_dir/.lock" && flock -n 8); then rm -rf "$old_dir"; fi
  done
fi

# can-utils, from the same Debian archive (version resolved at run time).
if [ -z "${can_utils_version:-}" ]; then
  can_utils_dir=""
  for candidate in "$cache_root"/can-utils_*; do
    [ -e "$candidate/.ready" ] && can_utils_dir=$candidate
  done
  [ -n "$can_utils_dir" ] || die "apt cannot resolve can-utils and none is cached"
else
  can_utils_dir="$cache_root/can-utils_$can_utils_version"
fi
if [ ! -e "$can_utils_dir/.ready" ]; then
  say "fetching can-utils=$can_utils_version"
  rm -rf "$can_utils_dir"
  mkdir -p "$can_utils_dir"
  download_deb "can-utils=$can_utils_version" "$can_utils_dir"
  dpkg-deb -x "$can_utils_dir"/*.deb "$can_utils_dir/unpacked"
  rm -f "$can_utils_dir"/*.deb
  touch "$can_utils_dir/.ready"
fi

# The initramfs depends on the kernel's modules, busybox, can-utils and this script's guest init:
# its cache name carries a hash of all of them, so editing the init rebuilds it.
init_text=$(write_guest_init)
initramfs_hash=$( {
  printf '%s' "$init_text"
  sha256sum "$busybox_bin" | cut -d' ' -f1
  echo "$can_utils_dir"
} | sha256sum | cut -c1-16)
initramfs="$kernel_dir/initramfs-$initramfs_hash.cpio.gz"
if [ ! -e "$initramfs" ]; then
  say "building initramfs $initramfs"
  staging=$(mktemp -d)
  trap 'rm -rf "$staging"' EXIT
  mkdir -p "$staging"/{bin,lib/modules,opt/can-utils/bin,opt/can-utils/lib}
  cp "$busybox_bin" "$staging/bin/busybox"
  printf '%s\n' "$init_text" >"$staging/init"
  chmod 755 "$staging/init"
  cp "$kernel_dir"/modules/* "$staging/lib/modules/"
  for tool in candump cansend cangen canplayer; do
    cp "$can_utils_dir/unpacked/usr/bin/$tool" "$staging/opt/can-utils/bin/"
    # Their shared libraries as the host's loader resolves them (same Debian release).
    ldd "$can_utils_dir/unpacked/usr/bin/$tool" | awk '$2 == "=>" && $3 ~ /^\// { print $3 }' |
      while read -r lib; do cp -L "$lib" "$staging/opt/can-utils/lib/"; done
  done
  interp=$(readelf -l "$staging/opt/can-utils/bin/candump" | sed -n 's/.*interpreter: \(.*\)]/\1/p')
  cp -L "$interp" "$staging/opt/can-utils/lib/ld.so"
  rm -f "$kernel_dir"/initramfs-*.cpio.gz
  (cd "$staging" && find . | busybox cpio -o -H newc 2>/dev/null | gzip -1) >"$initramfs.tmp"
  mv "$initramfs.tmp" "$initramfs"
  rm -rf "$staging"
  trap - EXIT
fi
flock -u 9

if $prepare_only; then
  say "ready: kernel $kernel_dir/kernel ($(cat "$kernel_dir/kernel-kind")), initramfs $initramfs"
  exit 0
fi

# ---------------------------------------------------------------------------------------------------
# The job: a bash script run by the guest in the chroot of the host's root, from the caller's
# directory, with the caller's Rust/cargo/imulab environment.
job_dir=$(mktemp -d)
trap 'rm -rf "$job_dir"' EXIT
{
  echo '#!/bin/sh'
  echo 'exec /bin/bash /run/imulab-vcan/job/job.bash'
} >"$job_dir/job.sh"
# shellcheck disable=SC2016 # the single-quoted $ expressions are for the job script, not here
{
  echo 'set -u'
  printf 'export PATH=%q\n' "/run/imulab-vcan/bin:$PATH"
  printf 'export HOME=%q\n' "$HOME"
  echo 'export IMULAB_VCAN_GUEST=1'
  env | LC_ALL=C grep -E '^(RUST_[A-Z_]*|CARGO[A-Z_]*|IMULAB_[A-Z_]*)=' | grep -v '^IMULAB_VCAN_GUEST=' |
    while IFS='=' read -r name value; do printf 'export %s=%q\n' "$name" "$value"; done
  printf 'cd %q || exit 125\n' "$PWD"
  echo 'first_failure=0'
  command_words=()
  emit_command() {
    printf 'echo "vcan-guest: run %s"\n' "$(printf '%q ' "${command_words[@]}" | sed 's/["$`\\]/\\&/g')"
    # Through a pipe, so stdout is not the console tty (no colours, output as under CI).
    printf '{ %s; } 2>&1 | cat\n' "$(printf '%q ' "${command_words[@]}")"
    printf 'code=${PIPESTATUS[0]}\n'
    echo 'echo "vcan-guest: exit code $code"'
    echo '[ "$first_failure" -eq 0 ] && first_failure=$code'
  }
  for word in "$@"; do
    if [ "$word" = "--next" ]; then
      [ ${#command_words[@]} -gt 0 ] && emit_command
      command_words=()
    else
      command_words+=("$word")
    fi
  done
  [ ${#command_words[@]} -gt 0 ] && emit_command
  echo 'exit "$first_failure"'
} >"$job_dir/job.bash"

# shellcheck disable=SC2054 # the commas are QEMU's option syntax
qemu_args=(
  -accel tcg # /dev/kvm exists on our machines but does not work: always software emulation
  -m "$mem_mib" -smp 1
  -nodefaults -display none -no-reboot
  -serial stdio
  -device isa-debug-exit,iobase=0xf4,iosize=0x04
  -kernel "$kernel_file" -initrd "$initramfs"
  # no_timer_check: under heavy host load the emulated clock runs so unevenly that the kernel's
  # IO-APIC timer check fails and panics ("IO-APIC + timer doesn't work!"); seen here at load 25.
  -append "console=ttyS0 panic=-1 quiet loglevel=3 no_timer_check rdinit=/init ${IMULAB_VCAN_KERNEL_ARGS:-}"
  -virtfs "local,path=/,mount_tag=hostroot,security_model=none,readonly=on,multidevs=remap"
  -virtfs "local,path=$job_dir,mount_tag=imulabjob,security_model=none,readonly=on"
)
# Boots once; the console goes to our stdout and to a log, so we can tell whether the job started.
boot_guest() {
  set +e
  timeout -k 5 "$timeout_secs" qemu-system-x86_64 "${qemu_args[@]}" </dev/null | tee "$job_dir/console.log"
  qemu_code=${PIPESTATUS[0]}
  set -e
}

start_ns=$(date +%s%N)
boot_guest
# A guest that died before the job started (a kernel panic while booting: under heavy host load
# emulated timers can fail the kernel's checks) ran nothing, so booting again is safe: once.
if [ "$qemu_code" -eq 0 ] && ! grep -q '^vcan-guest: run ' "$job_dir/console.log"; then
  say "the guest died before running anything (exit 0, no report); booting once more"
  boot_guest
fi
elapsed=$((($(date +%s%N) - start_ns) / 1000000))
if [ "$qemu_code" -eq 124 ] || [ "$qemu_code" -eq 137 ]; then
  say "guest timed out after ${timeout_secs} s (raise with --timeout or IMULAB_VCAN_TIMEOUT)"
  exit 124
fi
if [ $((qemu_code % 2)) -eq 1 ]; then
  guest_code=$(((qemu_code - 1) / 2))
  say "guest finished in $((elapsed / 1000)).$(printf %03d $((elapsed % 1000))) s, exit code $guest_code"
  exit "$guest_code"
fi
die "QEMU exited with $qemu_code without a report from the guest (kernel panic or QEMU error)"
