#!/usr/bin/env bash
# Installs dvrk-sidecar on a dVRK PC: the binary, /etc/dvrk-sidecar/ (never overwriting an
# existing configuration), the service user and the systemd unit.
#
#   sudo deploy/install.sh                 # build (release) from this checkout and install
#   sudo deploy/install.sh --binary PATH   # install a binary built elsewhere
#   sudo deploy/install.sh --no-enable     # install without enabling/starting the unit
#   sudo deploy/install.sh --tap           # source = "tap:IFACE": grant CAP_NET_RAW (drop-in)
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/.." && pwd)"
binary=""
enable=1
tap=0
prefix="${DESTDIR:-}"

while [ $# -gt 0 ]; do
    case "$1" in
        --binary) binary="$2"; shift 2 ;;
        --no-enable) enable=0; shift ;;
        --tap) tap=1; shift ;;
        -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
        *) echo "install.sh: unknown option $1" >&2; exit 2 ;;
    esac
done

if [ -z "$prefix" ] && [ "$(id -u)" -ne 0 ]; then
    echo "install.sh: run as root (sudo), or set DESTDIR for a staged install" >&2
    exit 1
fi

if [ -z "$binary" ]; then
    (cd "$repo" && cargo build --release -p dvrk-sidecar)
    binary="$repo/target/release/dvrk-sidecar"
fi
[ -x "$binary" ] || { echo "install.sh: $binary is not an executable" >&2; exit 1; }

install -D -m 0755 "$binary" "$prefix/usr/local/bin/dvrk-sidecar"

etc="$prefix/etc/dvrk-sidecar"
install -d -m 0755 "$etc" "$etc/compliance" "$etc/io" "$etc/sim"
copy_config() { # never overwrite a lab's calibrated files
    local src="$1" dst="$2"
    if [ -e "$dst" ]; then echo "keeping existing $dst"; else install -m 0644 "$src" "$dst"; fi
}
copy_config "$repo/config/sidecar.toml" "$etc/sidecar.toml"
for f in "$repo"/config/compliance/*.toml; do copy_config "$f" "$etc/compliance/$(basename "$f")"; done
for f in "$repo"/config/io/*.toml; do copy_config "$f" "$etc/io/$(basename "$f")"; done
for f in "$repo"/config/sim/*.toml; do copy_config "$f" "$etc/sim/$(basename "$f")"; done

install -D -m 0644 "$here/dvrk-sidecar.service" "$prefix/etc/systemd/system/dvrk-sidecar.service"
# CAP_NET_RAW for the passive tap only; any other install removes a drop-in left from before.
dropin="$prefix/etc/systemd/system/dvrk-sidecar.service.d/tap-mode.conf"
if [ "$tap" -eq 1 ]; then
    install -D -m 0644 "$here/tap-mode.conf" "$dropin"
else
    rm -f "$dropin"
fi

if [ -n "$prefix" ]; then
    echo "staged install in $prefix (no user, no systemctl)"
    exit 0
fi

getent group fpgaqla >/dev/null || groupadd --system fpgaqla
getent group dvrk-sidecar >/dev/null || groupadd --system dvrk-sidecar
if ! getent passwd dvrk-sidecar >/dev/null; then
    useradd --system --gid dvrk-sidecar --groups fpgaqla --no-create-home \
        --home-dir /nonexistent --shell /usr/sbin/nologin dvrk-sidecar
fi

/usr/local/bin/dvrk-sidecar check-config --config /etc/dvrk-sidecar/sidecar.toml
systemctl daemon-reload
if [ "$enable" -eq 1 ]; then
    systemctl enable --now dvrk-sidecar.service
    systemctl --no-pager status dvrk-sidecar.service || true
fi
echo "installed. Consumers must run as user dvrk-sidecar (or share its iceoryx2 root): see deploy/README.md"
