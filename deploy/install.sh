#!/usr/bin/env bash
# Installs dvrk-sidecar on a dVRK PC from a binary you built as yourself (no cargo runs as root).
#
#   cargo build --release -p dvrk-sidecar          # as your user, in the checkout
#   sudo deploy/install.sh --binary target/release/dvrk-sidecar --dvrk-json ~/dvrk-config/system.json
#   sudo deploy/install.sh --uninstall [--purge]
#
# Options:
#   --binary PATH      the dvrk-sidecar binary to install (required for an install)
#   --dvrk-json PATH   the lab's dVRK system JSON (2.3+) or console JSON (2.1-2.2): writes
#                      sidecar.toml with one [[arm]] per PSM in it (name, boards and kind from its
#                      IO file sawRobotIO1394-<arm>-<serial>.json found next to it, base frame,
#                      instrument "console") and the source from its IO port; copies the JSON
#                      to /etc/dvrk-sidecar/dvrk/ and the IO files to /etc/dvrk-sidecar/io/
#                      (needs python3, which the dVRK's ROS tools need anyway)
#   --arms A,B         with --dvrk-json: only these PSMs (default: every PSM on the boards)
#   --source SOURCE    the source instead of the JSON's port, e.g. tap:eth1 (implies --tap)
#   --io-json PATH     without --dvrk-json: one arm; copy its sawRobotIO1394 JSON to
#                      /etc/dvrk-sidecar/io/ and point a fresh single-arm sidecar.toml at it
#   --user NAME        run the service, the bridge and every consumer as this existing account
#                      (default: the account that ran sudo, $SUDO_USER)
#   --system-user      run them as the system user dvrk-sidecar (created if missing) instead
#   --bridge           enable and start the ROS 2 bridge unit (dvrk-sidecar-ros2-bridge) too
#   --console-unit U   the dVRK console runs as the system unit U (e.g. dvrk-console.service):
#                      the sidecar starts when U starts and stops when it stops
#   --tap              grant CAP_NET_RAW through a drop-in (for a tap:IFACE source)
#   --no-enable        install without enabling/starting the units
#   --root DIR         install into the scratch root DIR (like DESTDIR): no users, groups or
#                      systemctl; for trying the steps and for tests
#   --uninstall        remove what an install added (binary, units, drop-ins, the user and group
#                      it created, its group memberships); /etc/dvrk-sidecar is kept
#   --purge            with --uninstall: remove /etc/dvrk-sidecar as well
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/.." && pwd)"
binary=""
io_json=""
dvrk_json=""
arms=""
source_override=""
user=""
system_user=0
bridge=0
console_unit=""
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
        --arms) need_arg "$@"; arms="$2"; shift 2 ;;
        --source) need_arg "$@"; source_override="$2"; shift 2 ;;
        --user) need_arg "$@"; user="$2"; shift 2 ;;
        --system-user) system_user=1; shift ;;
        --bridge) bridge=1; shift ;;
        --console-unit) need_arg "$@"; console_unit="$2"; shift 2 ;;
        --root) need_arg "$@"; root="$2"; shift 2 ;;
        --no-enable) enable=0; shift ;;
        --tap) tap=1; shift ;;
        --uninstall) uninstall=1; shift ;;
        --purge) purge=1; shift ;;
        -h|--help) sed -n '2,33p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
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
units="$root/etc/systemd/system"
unit="$units/dvrk-sidecar.service"
bridge_unit="$units/dvrk-sidecar-ros2-bridge.service"
dropins="$units/dvrk-sidecar.service.d"
bridge_dropins="$units/dvrk-sidecar-ros2-bridge.service.d"
state_dir="$root/var/lib/dvrk-sidecar"
state="$state_dir/install-state"

systemctl_or_skip() {
    if [ -n "$root" ]; then
        echo "skipped under --root: systemctl $*"
    else
        systemctl "$@"
    fi
}

# Lines of the install state (what this script added), and replacing the lines of one kind.
state_lines() { [ -f "$state" ] && grep "^$1 " "$state" | cut -d' ' -f2- || true; }
state_drop() { [ ! -f "$state" ] || { grep -v "^$1 " "$state" > "$state.tmp" || true; mv "$state.tmp" "$state"; }; }

# Removes the `.wants` links that make the console's unit start the sidecar.
remove_console_links() {
    local link
    while read -r link; do
        [ -n "$link" ] || continue
        rm -f "$root$link"
        rmdir "$(dirname "$root$link")" 2>/dev/null || true
    done < <(state_lines wants-link)
    state_drop wants-link
}

# ---------------------------------------------------------------------------------------------
if [ "$uninstall" -eq 1 ]; then
    [ -z "$binary$io_json$dvrk_json$user$arms$source_override$console_unit" ] && [ "$system_user$bridge" = "00" ] \
        || die "--uninstall takes only --purge and --root"
    for u in dvrk-sidecar-ros2-bridge.service dvrk-sidecar.service; do
        if [ -e "$units/$u" ]; then
            systemctl_or_skip disable --now "$u" || true
        fi
    done
    remove_console_links
    rm -f "$bin_path" "$unit" "$bridge_unit"
    rm -f "$dropins/tap-mode.conf" "$dropins/user.conf" "$dropins/console.conf" "$bridge_dropins/user.conf"
    rmdir "$dropins" "$bridge_dropins" 2>/dev/null || true
    [ -n "$root" ] || systemctl daemon-reload
    # Only what this script created or changed (recorded at install time) is undone.
    if [ -f "$state" ]; then
        while read -r what name group; do
            case "$what" in
                added-to-group)
                    if [ -n "$root" ]; then echo "skipped under --root: gpasswd -d $name $group"
                    elif getent group "$group" >/dev/null; then gpasswd -d "$name" "$group" >/dev/null || true; fi ;;
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
safe_json_name() {
    [[ "$(basename "$2")" =~ ^[A-Za-z0-9._-]+\.json$ ]] \
        || die "$1 $2: the file name must end in .json and use only letters, digits, '.', '_' and '-'"
}
[ -z "$io_json" ] || [ -z "$dvrk_json" ] \
    || die "--io-json and --dvrk-json exclude each other: --dvrk-json finds each arm's IO file itself (sawRobotIO1394-<arm>-<serial>.json next to it)"
[ -z "$arms" ] || [ -n "$dvrk_json" ] || die "--arms $arms needs --dvrk-json (it chooses among the JSON's PSMs)"
if [ -n "$io_json" ]; then
    [ -f "$io_json" ] && [ -r "$io_json" ] || die "--io-json $io_json: not a readable file"
    safe_json_name --io-json "$io_json"
fi
if [ -n "$source_override" ]; then
    source_re='^(udp:[][0-9A-Fa-f.:]+|fw:[0-9]+|tap:[A-Za-z0-9._-]+(:[0-9]+)?|sim)$'
    [[ "$source_override" =~ $source_re ]] \
        || die "--source $source_override: not one of udp:IP[:PORT], fw:N, tap:IFACE[:PORT], sim"
    [[ "$source_override" != tap:* ]] || tap=1
fi
if [ -n "$console_unit" ]; then
    [[ "$console_unit" =~ ^[A-Za-z0-9@._:-]+\.service$ ]] \
        || die "--console-unit $console_unit: give the console's systemd unit, e.g. dvrk-console.service"
fi

# The account of the service, the bridge and every consumer: iceoryx2 0.10 creates its files
# owner-only, so they must all be one user (deploy/README.md, "The account").
[ -z "$user" ] || [ "$system_user" -eq 0 ] || die "--user $user and --system-user exclude each other"
[ "$user" != "dvrk-sidecar" ] || { user=""; system_user=1; }
if [ "$system_user" -eq 1 ]; then
    account="dvrk-sidecar"
elif [ -n "$user" ]; then
    account="$user"
elif [ -n "${SUDO_USER:-}" ] && [ "$SUDO_USER" != "root" ]; then
    account="$SUDO_USER"
    echo "the service and its consumers will run as $account (the account that ran sudo); --user NAME or --system-user to choose another"
else
    die "say which account runs the service and every program that reads it (they must be one
account: iceoryx2 gives its files owner-only modes):
    --user NAME      an existing account, e.g. the one that runs the dVRK console
    --system-user    the system user dvrk-sidecar (programs then run with sudo -u dvrk-sidecar)"
fi
[[ "$account" =~ ^[a-z_][a-z0-9_-]*$ ]] || die "--user $account: not a user name"
[ "$account" != "root" ] || die "--user root: the service never runs as root (files iceoryx2 creates as root lock every other user out)"
if [ -z "$root" ] && [ "$system_user" -eq 0 ]; then
    getent passwd "$account" >/dev/null || die "--user $account: no such account"
fi

# The lab's dVRK JSON: its PSMs, their IO files, boards, kinds, base frames and the port.
declare -a arm_names=() arm_io=() arm_kind=() arm_boards=() arm_frame=() arm_serial=() arm_hw=()
source_value=""
source_origin=""
if [ -n "$dvrk_json" ]; then
    [ -f "$dvrk_json" ] && [ -r "$dvrk_json" ] || die "--dvrk-json $dvrk_json: not a readable file"
    safe_json_name --dvrk-json "$dvrk_json"
    command -v python3 >/dev/null \
        || die "--dvrk-json needs python3 to read the JSON (sudo apt-get install python3; the dVRK's ROS 2 tools need it too)"
    facts="$(python3 "$here/dvrk-json-arms.py" "$dvrk_json" ${arms:+"$arms"})" || exit 1
    while IFS=$'\t' read -r kind a b c d e f g; do
        case "$kind" in
            note) echo "$a" ;;
            source) source_value="$a"; source_origin="$b" ;;
            arm)
                arm_names+=("$a"); arm_io+=("$b"); arm_kind+=("$c"); arm_boards+=("$d")
                arm_frame+=("$e"); arm_serial+=("$f"); arm_hw+=("$g")
                # Two arms of a lab never share an IO file name; a lab's copy never clobbers another arm's.
                ;;
        esac
    done <<< "$facts"
    [ "${#arm_names[@]}" -gt 0 ] && [ -n "$source_value" ] || die "--dvrk-json $dvrk_json: reading it gave no arm (a bug of dvrk-json-arms.py)"
    if [ -n "$source_override" ]; then
        source_origin="--source (the JSON says $source_value)"
        source_value="$source_override"
    fi
fi

# ---------------------------------------------------------------------------------------------
install -D -m 0755 "$binary" "$bin_path"

# Configuration: /etc/dvrk-sidecar, readable by the service and the group dvrk, never overwriting
# a file the lab has (the lab's calibrated files and edits survive every later install).
install -d -m 0750 "$etc" "$etc/compliance" "$etc/io" "$etc/sim" "$etc/dvrk"
install -d -m 0755 "$state_dir"
touch "$state"
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
for f in "$repo"/config/compliance/*.toml; do copy_config "$f" "$etc/compliance/$(basename "$f")"; done
for f in "$repo"/config/io/*.toml; do copy_config "$f" "$etc/io/$(basename "$f")"; done
for f in "$repo"/config/sim/*.toml; do copy_config "$f" "$etc/sim/$(basename "$f")"; done

if [ -n "$dvrk_json" ]; then
    dvrk_name="$(basename "$dvrk_json")"
    # The lab named these files: an older copy of the same name is replaced.
    install -m 0640 "$dvrk_json" "$etc/dvrk/$dvrk_name"
    echo "copied $dvrk_json to $etc/dvrk/$dvrk_name"
    for i in "${!arm_names[@]}"; do
        install -m 0640 "${arm_io[$i]}" "$etc/io/$(basename "${arm_io[$i]}")"
        echo "copied ${arm_io[$i]} to $etc/io/$(basename "${arm_io[$i]}")"
    done

    # Each arm's compliance file: a placeholder holding the paper's published stiffness with no
    # backlash and no torque offset, until the lab fits its own (`fit --out` to this path). It
    # lets the service start and publish the raw state, which calibration needs; check-config
    # warns about it on every start, and its header says what it is.
    for i in "${!arm_names[@]}"; do
        c="$etc/compliance/${arm_names[$i]}.toml"
        if [ -e "$c" ]; then
            echo "keeping existing $c"
        else
            {
                echo "# PLACEHOLDER for ${arm_names[$i]} (serial ${arm_serial[$i]}), written by install.sh: NOT fitted for"
                echo "# this arm. It is compliance/paper-psm.toml: the paper's published stiffness, no backlash,"
                echo "# no torque offset, so on this arm gravity and friction count as contact and the"
                echo "# compensated values are wrong (the raw ones are right). Calibrate, then replace this file:"
                echo "#   dvrk-sidecar fit ... --out $([ -n "$root" ] && echo "$c" || echo "/etc/dvrk-sidecar/compliance/${arm_names[$i]}.toml")"
                echo "#"
                cat "$repo/config/compliance/paper-psm.toml"
            } > "$c.tmp"
            install -m 0640 "$c.tmp" "$c"
            rm -f "$c.tmp"
            echo "wrote the placeholder $c (paper parameters, not this arm's: fit your own)"
        fi
    done

    # sidecar.toml, one [[arm]] per PSM. Replaced by a later --dvrk-json install only while the
    # lab has not edited it (its checksum is the one recorded here); otherwise written next to it.
    rate=1500
    [[ "$source_value" != tap:* ]] || rate='"follow"'
    gen="$state_dir/sidecar.toml.generated"
    {
        echo "# /etc/dvrk-sidecar/sidecar.toml, written by install.sh --dvrk-json $dvrk_name${arms:+ --arms $arms}."
        echo "# The service reads every [[arm]] from one source. A later install --dvrk-json rewrites this"
        echo "# file only as long as you have not edited it. Check it as the service's account:"
        echo "#   sudo -u $account /usr/local/bin/dvrk-sidecar check-config --config /etc/dvrk-sidecar/sidecar.toml"
        echo "# Relative paths are resolved against /etc/dvrk-sidecar."
        echo
        echo "# From $source_origin."
        echo "source = \"$source_value\""
        echo "access = \"shared\""
        echo "rate = $rate"
        echo
        echo "[realtime]"
        echo "# cpu = 1"
        echo "# fifo_priority = 80"
        echo "mlockall = false"
        for i in "${!arm_names[@]}"; do
            n="${arm_names[$i]}"
            echo
            echo "[[arm]]"
            echo "name = \"$n\""
            echo "# Boards and kind of $(basename "${arm_io[$i]}") (hardware_version ${arm_hw[$i]})."
            echo "boards = [${arm_boards[$i]//,/, }]"
            echo "io = \"io/$(basename "${arm_io[$i]}")\""
            echo "kind = \"${arm_kind[$i]}\""
            echo "# The instrument the console detects (/$n/tool_type over DDS), and its state and base frame."
            echo "instrument = \"console\""
            echo "# PLACEHOLDER until you fit this arm: see the file's header."
            echo "compliance = \"compliance/$n.toml\""
            case "${arm_frame[$i]}" in
                transform)
                    echo "[arm.base_frame]"
                    echo "dvrk_json = \"dvrk/$dvrk_name\""
                    echo "arm = \"$n\"" ;;
                component:*)
                    echo "# base frame: set at run time by ${arm_frame[$i]#component:} on the console, followed over DDS." ;;
                *)
                    echo "# base frame: none in $dvrk_name (the console uses the identity)." ;;
            esac
        done
    } > "$gen"
    chmod 0640 "$gen"
    new_sum="$(sha256sum "$gen" | cut -d' ' -f1)"
    recorded="$(state_lines generated-config)"
    if [ ! -e "$etc/sidecar.toml" ] \
        || { [ -n "$recorded" ] && [ "$(sha256sum "$etc/sidecar.toml" | cut -d' ' -f1)" = "$recorded" ]; }; then
        install -m 0640 "$gen" "$etc/sidecar.toml"
        state_drop generated-config
        echo "generated-config $new_sum" >> "$state"
        rm -f "$etc/sidecar.toml.new"
        echo "wrote $etc/sidecar.toml: ${arm_names[*]} from $source_value"
    else
        install -m 0640 "$gen" "$etc/sidecar.toml.new"
        echo "NOTE: $etc/sidecar.toml was edited since install wrote it: kept it; the configuration"
        echo "      from $dvrk_name is in $etc/sidecar.toml.new (compare, then move it over)"
    fi
    rm -f "$gen"
else
    # One arm: the annotated template, which names no source and refuses to start until the lab
    # names one (unless --source does).
    copy_config "$here/sidecar.toml" "$etc/sidecar.toml"
    if [ "$fresh_config" -eq 1 ] && [ -n "$source_override" ]; then
        sed -i "s|^source = \"\"$|source = \"$source_override\"|" "$etc/sidecar.toml"
        [[ "$source_override" != tap:* ]] || sed -i 's|^rate = 1500$|rate = "follow"|' "$etc/sidecar.toml"
        echo "set source = \"$source_override\" in $etc/sidecar.toml"
    fi
    if [ -n "$io_json" ]; then
        io_name="$(basename "$io_json")"
        install -m 0640 "$io_json" "$etc/io/$io_name"
        echo "copied $io_json to $etc/io/$io_name"
        if [ "$fresh_config" -eq 1 ]; then
            sed -i "s|^io = \"io/psm-classic.toml\"$|io = \"io/$io_name\"|" "$etc/sidecar.toml"
            echo "set io = \"io/$io_name\" in $etc/sidecar.toml"
        else
            echo "NOTE: $etc/sidecar.toml existed: set io = \"io/$io_name\" in it yourself"
        fi
    fi
fi

# Units and drop-ins. Any install removes the drop-ins a previous one wrote and this one does not.
install -D -m 0644 "$here/dvrk-sidecar.service" "$unit"
install -D -m 0644 "$here/dvrk-sidecar-ros2-bridge.service" "$bridge_unit"
install -d -m 0755 "$dropins" "$bridge_dropins"
# CAP_NET_RAW for the passive tap only.
if [ "$tap" -eq 1 ]; then
    install -m 0644 "$here/tap-mode.conf" "$dropins/tap-mode.conf"
else
    rm -f "$dropins/tap-mode.conf"
fi
if [ "$account" != "dvrk-sidecar" ]; then
    for d in "$dropins" "$bridge_dropins"; do
        printf '# Written by install.sh: the service runs as %s, the account of every program that\n# reads it (iceoryx2 files are owner-only).\n[Service]\nUser=%s\n' \
            "$account" "$account" > "$d/user.conf"
        chmod 0644 "$d/user.conf"
    done
else
    rm -f "$dropins/user.conf" "$bridge_dropins/user.conf"
fi
remove_console_links
if [ -n "$console_unit" ]; then
    printf '# Written by install.sh --console-unit %s: the sidecar follows the dVRK console.\n# Started after it (and by it: %s.wants/), refused while it is not active, stopped\n# and restarted with it.\n[Unit]\nAfter=%s\nRequisite=%s\nPartOf=%s\n' \
        "$console_unit" "$console_unit" "$console_unit" "$console_unit" "$console_unit" > "$dropins/console.conf"
    chmod 0644 "$dropins/console.conf"
else
    rm -f "$dropins/console.conf"
fi
rmdir "$dropins" "$bridge_dropins" 2>/dev/null || true

if [ -n "$root" ]; then
    echo "skipped under --root: groups dvrk and fpgaqla, the account $account, ownership root:dvrk of $etc"
else
    # dvrk: the service's group; it owns /etc/dvrk-sidecar. fpgaqla: the group the dVRK udev rule
    # gives /dev/fw*.
    if ! getent group dvrk >/dev/null; then
        groupadd --system dvrk
        echo "created-group dvrk" >> "$state"
    fi
    # fpgaqla belongs to the dVRK's own setup (its udev rule): created if missing, never removed.
    getent group fpgaqla >/dev/null || groupadd --system fpgaqla
    if [ "$account" = "dvrk-sidecar" ] && ! getent passwd dvrk-sidecar >/dev/null; then
        useradd --system --gid dvrk --groups fpgaqla --no-create-home \
            --home-dir /nonexistent --shell /usr/sbin/nologin dvrk-sidecar
        echo "created-user dvrk-sidecar" >> "$state"
    fi
    # The account reads /etc/dvrk-sidecar from a terminal too (check-config, ros2-bridge --config).
    if ! id -nG "$account" | tr ' ' '\n' | grep -qx dvrk; then
        usermod -aG dvrk "$account"
        echo "added-to-group $account dvrk" >> "$state"
        echo "added $account to the group dvrk (effective at its next login)"
    fi
    chgrp -R dvrk "$etc"
    # The service keeps its iceoryx2 state in /tmp/dvrk-sidecar-<uid>/ (the account's own, 0700)
    # and /dev/shm/dvrk_<uid>_*; it refuses to start when that directory belongs to another user
    # (who could hide it from its consumers) or is a link. Say so now rather than at start.
    uid="$(id -u "$account")"
    for f in "/tmp/dvrk-sidecar-$uid" /dev/shm/dvrk_"${uid}"_*; do
        [ -e "$f" ] || [ -L "$f" ] || continue
        owner="$(stat -c %U "$f")"
        if [ "$owner" != "$account" ] || [ -L "$f" ]; then
            echo "WARNING: $f belongs to $owner, not to $account: the service refuses it. When no"
            echo "         program using iceoryx2 runs: sudo rm -rf /tmp/dvrk-sidecar-$uid /dev/shm/dvrk_${uid}_*"
            break
        fi
    done
fi

# The check as the service's account, never as root: check-config creates the account's
# iceoryx2 directory (/tmp/dvrk-sidecar-<uid>/), which must be the account's own.
config_ok=1
echo "checking $etc/sidecar.toml:"
check=("$bin_path" check-config --config "$etc/sidecar.toml")
if [ -z "$root" ]; then
    caps=()
    [ "$tap" -eq 0 ] || caps=(--inh-caps=+net_raw --ambient-caps=+net_raw)
    check=(setpriv --reuid="$account" --regid=dvrk --init-groups "${caps[@]}" "${check[@]}")
fi
if ! "${check[@]}"; then
    config_ok=0
fi

systemctl_or_skip daemon-reload
if [ "$config_ok" -eq 1 ] && [ "$enable" -eq 1 ]; then
    if [ -n "$console_unit" ]; then
        # Started by the console's unit, not at boot on its own.
        systemctl_or_skip disable dvrk-sidecar.service
        install -d -m 0755 "$units/$console_unit.wants"
        ln -sfn /etc/systemd/system/dvrk-sidecar.service "$units/$console_unit.wants/dvrk-sidecar.service"
        echo "wants-link /etc/systemd/system/$console_unit.wants/dvrk-sidecar.service" >> "$state"
        systemctl_or_skip daemon-reload
        if [ -z "$root" ] && systemctl is-active --quiet "$console_unit"; then
            systemctl start dvrk-sidecar.service
        fi
        echo "dvrk-sidecar starts with $console_unit and stops with it"
    else
        systemctl_or_skip enable --now dvrk-sidecar.service
    fi
    if [ "$bridge" -eq 1 ]; then
        systemctl_or_skip enable --now dvrk-sidecar-ros2-bridge.service
    fi
    [ -n "$root" ] || systemctl --no-pager status dvrk-sidecar.service || true
elif [ "$bridge" -eq 1 ]; then
    echo "the bridge is not enabled either: it reads what the sidecar publishes"
fi
echo "installed $bin_path, the units $unit and $bridge_unit, and the configuration in $etc"
if [ "$config_ok" -eq 0 ]; then
    echo "NOT started: edit $etc/sidecar.toml (the message above names the field), then:"
    echo "    sudo -u $account $bin_path check-config --config $etc/sidecar.toml"
    echo "    sudo systemctl enable --now dvrk-sidecar${console_unit:+  (or: start $console_unit)}"
fi
echo "Run every program that reads the sidecar as $account (e.g. sudo -u $account ...), never with plain sudo: see deploy/README.md, \"The account\"."
