#!/bin/sh
# Bring up the CAN interface drivetrain-id runs on (SocketCAN). Idempotent: running it again
# changes nothing when the interface is already as asked.
#
#   setup-can.sh vcan [NAME]           virtual interface for the virtual vehicle (default vcan0)
#   setup-can.sh can0 [BITRATE]        real interface (any canN) at BITRATE bit/s (default 500000),
#                                      bus-off recovery after 100 ms
#
# Needs root (ip link and modprobe). The product opens the interface as an ordinary user: raw CAN
# sockets need no privilege, only configuring the interface does.
set -eu

DEFAULT_VCAN=vcan0
DEFAULT_BITRATE=500000
RESTART_MS=100

usage() {
    cat >&2 <<EOF
usage: $0 vcan [NAME]       create and bring up a virtual CAN interface (default $DEFAULT_VCAN)
       $0 canN [BITRATE]    configure and bring up a real CAN interface (default $DEFAULT_BITRATE bit/s)
EOF
    exit 2
}

die() {
    echo "setup-can: $*" >&2
    exit 1
}

need_root() {
    [ "$(id -u)" -eq 0 ] || die "configuring $1 needs root: sudo $0 $ARGS"
}

link_exists() {
    ip link show dev "$1" >/dev/null 2>&1
}

link_is_up() {
    # "state UP" for real interfaces; vcan reports "state UNKNOWN" but the flag <...,UP,...>
    ip link show dev "$1" | head -n 1 | grep -q '[<,]UP[,>]'
}

setup_vcan() {
    name=$1
    if link_exists "$name"; then
        ip -details link show dev "$name" | grep -Eq '^[[:space:]]+vcan ' ||
            die "$name exists but is not a vcan interface; choose another name"
        if link_is_up "$name"; then
            echo "setup-can: $name is already up (vcan)"
            return 0
        fi
    else
        need_root "$name"
        # vcan may be a module (load it) or built in (modprobe then fails harmlessly)
        modprobe vcan 2>/dev/null || true
        if ! error=$(ip link add dev "$name" type vcan 2>&1); then
            die "cannot create $name ($error). This kernel seems to have no vcan: install its \
modules (Debian/Ubuntu: apt-get install linux-modules-extra-\$(uname -r); reboot if the kernel \
was updated) or use a kernel with CONFIG_CAN_VCAN. Without vcan, the virtual vehicle runs on \
python-can's udp_multicast interface inside a private network namespace (tests/hil/README.md)."
        fi
        echo "setup-can: created $name"
    fi
    need_root "$name"
    ip link set dev "$name" up || die "ip link set dev $name up failed"
    echo "setup-can: $name is up (vcan)"
}

current_bitrate() {
    ip -details link show dev "$1" | sed -n 's/.*bitrate \([0-9][0-9]*\).*/\1/p' | head -n 1
}

current_restart_ms() {
    ip -details link show dev "$1" | sed -n 's/.*restart-ms \([0-9][0-9]*\).*/\1/p' | head -n 1
}

setup_can() {
    name=$1
    bitrate=$2
    case $bitrate in
    '' | *[!0-9]*) die "bit rate must be a number in bit/s, e.g. 500000; got '$bitrate'" ;;
    esac
    link_exists "$name" ||
        die "no interface $name: is the CAN adapter plugged in and its driver loaded? \
(ip link show lists the interfaces)"
    ip -details link show dev "$name" | grep -Eq '^[[:space:]]+can ' ||
        die "$name is not a CAN interface (for a virtual one: $0 vcan $name)"
    if link_is_up "$name" && [ "$(current_bitrate "$name")" = "$bitrate" ] &&
        [ "$(current_restart_ms "$name")" = "$RESTART_MS" ]; then
        echo "setup-can: $name is already up at $bitrate bit/s, restart-ms $RESTART_MS"
        return 0
    fi
    need_root "$name"
    # the bit rate can only change while the interface is down
    ip link set dev "$name" down || die "ip link set dev $name down failed"
    ip link set dev "$name" type can bitrate "$bitrate" restart-ms "$RESTART_MS" ||
        die "the driver of $name refused bitrate $bitrate restart-ms $RESTART_MS"
    ip link set dev "$name" up || die "ip link set dev $name up failed"
    echo "setup-can: $name is up at $bitrate bit/s, restart-ms $RESTART_MS"
}

ARGS="$*"
if [ $# -lt 1 ] || [ $# -gt 2 ]; then usage; fi
command -v ip >/dev/null 2>&1 || die "the ip command (iproute2) is not installed"
case $1 in
vcan) setup_vcan "${2:-$DEFAULT_VCAN}" ;;
can[0-9]*) setup_can "$1" "${2:-$DEFAULT_BITRATE}" ;;
-h | --help) usage ;;
*) usage ;;
esac
