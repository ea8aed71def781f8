#!/usr/bin/env bash
# Installs dvrk-sidecar on a dVRK PC from a binary you built as yourself (no cargo runs as root).
#
#   cargo build --release -p dvrk-sidecar          # as your user, in the checkout
#   sudo deploy/install.sh --binary target/release/dvrk-sidecar [options]
#   sudo deploy/install.sh --uninstall [--purge]
#
# Options:
#   --binary PATH    the dvrk-sidecar binary to install (required for an install)
#   --io-json PATH   copy the lab's sawRobotIO1394 JSON (e.g. sawRobotIO1394-PSM1-12345.json) to
#                    /etc/dvrk-sidecar/io/ and point a fresh sidecar.toml's `io` at the copy
#   --dvrk-json PATH copy the lab's dVRK console/system JSON (it holds the arm's base-frame) to
#                    /etc/dvrk-sidecar/dvrk/ and point a fresh sidecar.toml's [base_frame] at it
#   --user NAME      run the service as this existing account instead of the system user
#                    dvrk-sidecar (consumers must run as the service's user: deploy/README.md)
#   --tap            source = "tap:IFACE": grant CAP_NET_RAW through a drop-in
#   --no-enable      install without enabling/starting the unit
#   --root DIR       install into the scratch root DIR (like DESTDIR): no users, groups or
#                    systemctl; for trying the steps and for tests
#   --uninstall      remove what an install added (the binary, the unit and its drop-ins, the
#                    user and the group dvrk if it created them); /etc/dvrk-sidecar is kept
#   --purge          with --uninstall: remove /etc/dvrk-sidecar as well
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/.." && pwd)"
binary=""
io_json=""
dvrk_json=""
user=""
enable=1
tap=0
uninstall=0
purge=0
root="${DESTDIR:-}"

die() { echo "install.sh: $*" >&2; exit 1; }
need_arg() { [ $# -ge 2 ] && [ -n "$2" ] || die "$1 needs a value (see --help)"; }

while [ $# -gt 0 ]; do
    case "$1" in
        --binary) need_arg "$@"; binary="$2"; shift 2 ;;
        --io-json) need_arg "$@"; io_json="$2"; shift 2 ;;
        --dvrk-json) need_arg "$@"; dvrk_json="$2"; shift 2 ;;
        --user) need_arg "$@"; user="$2"; shift 2 ;;
        --root) need_arg "$@"; root="$2"; shift 2 ;;
        --no-enable) enable=0; shift ;;
        --tap) tap=1; shift ;;
        --uninstall) uninstall=1; shift ;;
        --purge) purge=1; shift ;;
        -h|--help) sed -n '2,24p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "install.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done

if [ -n "$root" ]; then
    mkdir -p "$root"
    root="$(cd "$root" && pwd)"
    [ "$root" != "/" ] || root=""
fi
if [ -z "$root" ] && [ "$(id -u)" -ne 0 ]; then
    die "run as root (sudo), or give --root DIR to install into a scratch root"
fi

bin_path="$root/usr/local/bin/dvrk-sidecar"
etc="$root/etc/dvrk-sidecar"
unit="$root/etc/systemd/system/dvrk-sidecar.service"
dropins="$root/etc/systemd/system/dvrk-sidecar.service.d"
state_dir="$root/var/lib/dvrk-sidecar"
state="$state_dir/install-state"

systemctl_or_skip() {
    if [ -n "$root" ]; then
        echo "skipped under --root: systemctl $*"
    else
        systemctl "$@"
    fi
}

# ---------------------------------------------------------------------------------------------
if [ "$uninstall" -eq 1 ]; then
    [ -z "$binary$io_json$dvrk_json$user" ] || die "--uninstall takes no --binary, --io-json, --dvrk-json or --user"
    if [ -e "$unit" ]; then
        systemctl_or_skip disable --now dvrk-sidecar.service || true
    fi
    rm -f "$bin_path" "$unit" "$dropins/tap-mode.conf" "$dropins/user.conf"
    rmdir "$dropins" 2>/dev/null || true
    [ -n "$root" ] || systemctl daemon-reload
    # Only the user and group this script created (recorded at install time) are removed.
    if [ -f "$state" ]; then
        while read -r what name; do
            case "$what" in
                created-user)
                    if [ -n "$root" ]; then echo "skipped under --root: userdel $name"
                    elif getent passwd "$name" >/dev/null; then userdel "$name"; fi ;;
                created-group)
                    if [ -n "$root" ]; then echo "skipped under --root: groupdel $name"
                    elif getent group "$name" >/dev/null; then groupdel "$name"; fi ;;
            esac
        done < <(tac "$state")
    fi
    rm -rf "$state_dir"
    if [ "$purge" -eq 1 ]; then
        rm -rf "$etc"
        echo "removed dvrk-sidecar and its configuration $etc"
    else
        [ ! -d "$etc" ] || echo "kept the configuration in $etc (remove it with --uninstall --purge)"
        echo "removed dvrk-sidecar"
    fi
    exit 0
fi

[ "$purge" -eq 0 ] || die "--purge only goes with --uninstall"

# ---------------------------------------------------------------------------------------------
# Checks first: nothing is installed when an argument is wrong.
if [ -z "$binary" ]; then
    die "--binary PATH is required. Build as your own user first (cargo is usually not on root's
PATH, and a build as root leaves root-owned files in your checkout):
    cargo build --release -p dvrk-sidecar
    sudo deploy/install.sh --binary target/release/dvrk-sidecar"
fi
[ -e "$binary" ] || die "--binary $binary: no such file (build it with: cargo build --release -p dvrk-sidecar)"
[ -f "$binary" ] && [ -x "$binary" ] || die "--binary $binary: not an executable file"
if [ -n "$io_json" ]; then
    [ -f "$io_json" ] && [ -r "$io_json" ] || die "--io-json $io_json: not a readable file"
    io_name="$(basename "$io_json")"
    [[ "$io_name" =~ ^[A-Za-z0-9._-]+\.json$ ]] \
        || die "--io-json $io_json: the file name must end in .json and use only letters, digits, '.', '_' and '-'"
fi
if [ -n "$dvrk_json" ]; then
    [ -f "$dvrk_json" ] && [ -r "$dvrk_json" ] || die "--dvrk-json $dvrk_json: not a readable file"
    dvrk_name="$(basename "$dvrk_json")"
    [[ "$dvrk_name" =~ ^[A-Za-z0-9._-]+\.json$ ]] \
        || die "--dvrk-json $dvrk_json: the file name must end in .json and use only letters, digits, '.', '_' and '-'"
fi
if [ -n "$user" ] && [ -z "$root" ]; then
    getent passwd "$user" >/dev/null || die "--user $user: no such account"
fi

# ---------------------------------------------------------------------------------------------
install -D -m 0755 "$binary" "$bin_path"

# Configuration: /etc/dvrk-sidecar, readable by the service and the group dvrk, never overwriting
# a file the lab has (the lab's calibrated files and edits survive every later install).
install -d -m 0750 "$etc" "$etc/compliance" "$etc/io" "$etc/sim" "$etc/dvrk"
fresh_config=0
copy_config() {
    local src="$1" dst="$2"
    if [ -e "$dst" ]; then
        echo "keeping existing $dst"
    else
        install -m 0640 "$src" "$dst"
        [ "$dst" != "$etc/sidecar.toml" ] || fresh_config=1
    fi
}
# The installed default names no source and refuses to start until the lab names one.
copy_config "$here/sidecar.toml" "$etc/sidecar.toml"
for f in "$repo"/config/compliance/*.toml; do copy_config "$f" "$etc/compliance/$(basename "$f")"; done
for f in "$repo"/config/io/*.toml; do copy_config "$f" "$etc/io/$(basename "$f")"; done
for f in "$repo"/config/sim/*.toml; do copy_config "$f" "$etc/sim/$(basename "$f")"; done

if [ -n "$io_json" ]; then
    # The lab asked for this file explicitly: an older copy of the same name is replaced.
    install -m 0640 "$io_json" "$etc/io/$io_name"
    echo "copied $io_json to $etc/io/$io_name"
    if [ "$fresh_config" -eq 1 ]; then
        sed -i "s|^io = \"io/psm-classic.toml\"$|io = \"io/$io_name\"|" "$etc/sidecar.toml"
        echo "set io = \"io/$io_name\" in $etc/sidecar.toml"
    else
        echo "NOTE: $etc/sidecar.toml existed: set io = \"io/$io_name\" in it yourself"
    fi
fi

if [ -n "$dvrk_json" ]; then
    install -m 0640 "$dvrk_json" "$etc/dvrk/$dvrk_name"
    echo "copied $dvrk_json to $etc/dvrk/$dvrk_name"
    if [ "$fresh_config" -eq 1 ]; then
        printf '\n# Written by install.sh --dvrk-json: the base frame of the arm named like the prefix\n# (add arm = "NAME" for another entry).\n[base_frame]\ndvrk_json = "dvrk/%s"\n' \
            "$dvrk_name" >> "$etc/sidecar.toml"
        echo "set [base_frame] dvrk_json = \"dvrk/$dvrk_name\" in $etc/sidecar.toml"
    else
        echo "NOTE: $etc/sidecar.toml existed: set [base_frame] dvrk_json = \"dvrk/$dvrk_name\" in it yourself"
    fi
fi

install -D -m 0644 "$here/dvrk-sidecar.service" "$unit"
# CAP_NET_RAW for the passive tap only; any other install removes a drop-in left from before.
if [ "$tap" -eq 1 ]; then
    install -D -m 0644 "$here/tap-mode.conf" "$dropins/tap-mode.conf"
else
    rm -f "$dropins/tap-mode.conf"
fi
if [ -n "$user" ]; then
    install -d -m 0755 "$dropins"
    printf '# Written by install.sh --user %s: the service runs as this account.\n[Service]\nUser=%s\n' \
        "$user" "$user" > "$dropins/user.conf"
    chmod 0644 "$dropins/user.conf"
else
    rm -f "$dropins/user.conf"
fi
rmdir "$dropins" 2>/dev/null || true

install -d -m 0755 "$state_dir"
touch "$state"
if [ -n "$root" ]; then
    echo "skipped under --root: groups dvrk and fpgaqla, user dvrk-sidecar, ownership root:dvrk of $etc"
else
    # dvrk: the service's group; it owns /etc/dvrk-sidecar. fpgaqla: the group the dVRK udev rule
    # gives /dev/fw*.
    if ! getent group dvrk >/dev/null; then
        groupadd --system dvrk
        echo "created-group dvrk" >> "$state"
    fi
    # fpgaqla belongs to the dVRK's own setup (its udev rule): created if missing, never removed.
    getent group fpgaqla >/dev/null || groupadd --system fpgaqla
    if [ -z "$user" ] && ! getent passwd dvrk-sidecar >/dev/null; then
        useradd --system --gid dvrk --groups fpgaqla --no-create-home \
            --home-dir /nonexistent --shell /usr/sbin/nologin dvrk-sidecar
        echo "created-user dvrk-sidecar" >> "$state"
    fi
    chgrp -R dvrk "$etc"
fi

# The installed default refuses to start until the lab names its source: say what to do.
config_ok=1
echo "checking $etc/sidecar.toml:"
check=("$bin_path" check-config --config "$etc/sidecar.toml")
if [ -z "$root" ]; then
    # As the service's user and group, never as root: check-config creates iceoryx2's files
    # (/tmp/iceoryx2), and files made by root would lock the service's user out of them. With
    # --tap, with the capability the tap drop-in grants.
    caps=()
    [ "$tap" -eq 0 ] || caps=(--inh-caps=+net_raw --ambient-caps=+net_raw)
    check=(setpriv --reuid="${user:-dvrk-sidecar}" --regid=dvrk --init-groups "${caps[@]}" "${check[@]}")
fi
if ! "${check[@]}"; then
    config_ok=0
fi

systemctl_or_skip daemon-reload
if [ "$config_ok" -eq 1 ] && [ "$enable" -eq 1 ]; then
    systemctl_or_skip enable --now dvrk-sidecar.service
    [ -n "$root" ] || systemctl --no-pager status dvrk-sidecar.service || true
fi
echo "installed $bin_path, the unit $unit and the configuration in $etc"
if [ "$config_ok" -eq 0 ]; then
    echo "NOT started: edit $etc/sidecar.toml (above all \`source\`), then:"
    echo "    sudo -u ${user:-dvrk-sidecar} -g dvrk $bin_path check-config --config $etc/sidecar.toml"
    echo "    sudo systemctl enable --now dvrk-sidecar"
fi
echo "Consumers must run as the service's user (${user:-dvrk-sidecar}): see deploy/README.md, \"Consumers\"."
