#!/usr/bin/env bash
# Disk trouble for real (issue #8): the filesystem holding the daemon's store goes read-only under its open
# files in the middle of a campaign, then the operator repairs it and resumes.
#
# The campaign runs on the real-hardware path, so that the store keeps the durability of a real campaign
# (every commit fsync'd; a dry-run's commits are not, see crates/engine/src/store.rs): the simulated instrument
# is a separate `gonio sim --link-dir` whose serial devices are pseudo-terminals and whose power meter is a
# Unix socket, and the daemon's instrument file names those ports; the operator's calibration steps are done
# by this script (the sample out of and back into the simulator through its stdin, each prompt confirmed).
#
# The store lives on an ext4 image mounted through a loop device with `errors=remount-ro`; mid-campaign the
# kernel is told that the filesystem is corrupt (/sys/fs/ext4/loopN/trigger_fs_error), which remounts it
# read-only at once: every write of the open SQLite file fails with EROFS, as on a failing disk (root ignores
# chmod, and an open file stays writable after one, so nothing else is as faithful). Checked:
#   - the campaign pauses by itself, with a reason naming the store file and the error;
#   - motion stops: no axis is commanded (driver log) and no point is added while it is paused;
#   - the daemon still answers: status and the points committed so far (read from the read-only store);
#   - the operator's fix: stop the daemon, unmount, e2fsck, mount again, restart, resume: the campaign
#     completes with exactly one row per planned point, the rows committed before the fault byte-identical.
#
# Needs root, a loop device and ext4 (kernel with trigger_fs_error); otherwise prints "SKIPPED: <reason>" and
# exits 0. Also needs curl and awk. Any failed check exits 1.
#
#   GONIO=/path/to/gonio tests/readonly/run.sh    # the binary under test (default: build it with cargo)
set -euo pipefail
cd "$(dirname "$0")/../.."

fail() {
    echo "FAIL: $*" >&2
    if [ -n "${work:-}" ] && [ -f "$work/daemon.log" ]; then
        echo "--- last lines of the daemon's log" >&2
        tail -n 30 "$work/daemon.log" >&2 || true
    fi
    exit 1
}
skip() {
    echo "SKIPPED: $*"
    exit 0
}

[ "$(id -u)" -eq 0 ] || skip "needs root (loop devices and mounts)"
for tool in losetup mkfs.ext4 e2fsck mount umount mountpoint; do
    command -v "$tool" >/dev/null 2>&1 || skip "$tool is not installed (no loop device or ext4 support)"
done
for tool in curl awk mkfifo truncate cmp; do
    command -v "$tool" >/dev/null 2>&1 || fail "$tool is needed"
done
grep -qw ext4 /proc/filesystems || skip "the kernel has no ext4"
[ -e /dev/loop-control ] || skip "no loop device support (/dev/loop-control)"

if [ -z "${GONIO:-}" ]; then
    echo "== cargo build -p gonio"
    cargo build -p gonio
    GONIO="${CARGO_TARGET_DIR:-target}/debug/gonio"
fi
[ -x "$GONIO" ] || fail "no gonio binary at $GONIO"
GONIO="$(cd "$(dirname "$GONIO")" && pwd)/$(basename "$GONIO")"

work="$(mktemp -d /tmp/gonio-readonly.XXXXXX)"
img="$work/store.img"
mnt="$work/mnt"
daemon_pid=""
sim_pid=""

cleanup() {
    set +e
    if [ -n "$daemon_pid" ] && kill -0 "$daemon_pid" 2>/dev/null; then
        kill "$daemon_pid"
        for _ in $(seq 1 50); do kill -0 "$daemon_pid" 2>/dev/null || break; sleep 0.1; done
        kill -9 "$daemon_pid" 2>/dev/null
    fi
    if [ -n "$sim_pid" ] && kill -0 "$sim_pid" 2>/dev/null; then
        kill "$sim_pid"
        for _ in $(seq 1 50); do kill -0 "$sim_pid" 2>/dev/null || break; sleep 0.1; done
        kill -9 "$sim_pid" 2>/dev/null
    fi
    exec 3>&- 2>/dev/null
    if mountpoint -q "$mnt" 2>/dev/null; then
        umount "$mnt" || umount -l "$mnt"
    fi
    # Loop devices still attached to the image (mount -o loop detaches on umount; this is for the odd case).
    for dev in $(losetup -j "$img" 2>/dev/null | cut -d: -f1); do losetup -d "$dev"; done
    rm -rf "$work"
}
trap cleanup EXIT

# ---------------------------------------------------------------- the disk

truncate -s 64M "$img"
mkfs.ext4 -q -F "$img" || skip "mkfs.ext4 cannot make a filesystem image here"
mkdir -p "$mnt"
mount_store() {
    mount -o loop,errors=remount-ro "$img" "$mnt"
}
mount_store 2>"$work/mount.err" || skip "cannot loop-mount an ext4 image: $(cat "$work/mount.err")"
loopdev="$(losetup -j "$img" | head -n 1 | cut -d: -f1)"
[ -n "$loopdev" ] || fail "the image is mounted but no loop device is attached to it"
trigger="/sys/fs/ext4/$(basename "$loopdev")/trigger_fs_error"
[ -w "$trigger" ] || skip "the kernel cannot simulate an ext4 error ($trigger missing: needs CONFIG_EXT4_DEBUG)"
data="$mnt/data"
store_file="$data/gonio.sqlite"

# ---------------------------------------------------------------- the instrument: a separate simulator

ports="$work/ports"
mkfifo "$work/operator"
NO_COLOR=1 RUST_LOG=warn "$GONIO" sim --time-scale 5 --material spectralon --link-dir "$ports" \
    <"$work/operator" >"$work/sim.out" 2>"$work/sim.log" &
sim_pid=$!
exec 3>"$work/operator" # the simulated operator's stdin, open for the whole run
for _ in $(seq 1 300); do
    grep -q '"ready":true' "$work/sim.out" 2>/dev/null && break
    kill -0 "$sim_pid" 2>/dev/null || fail "gonio sim exited: $(cat "$work/sim.log")"
    sleep 0.1
done
grep -q '"ready":true' "$work/sim.out" || fail "gonio sim was not ready within 30 s"
# The simulated instrument's file with every device on its port (the meter on its USB socket).
awk -v ports="$ports" '
    /^name = "/ { split($0, q, "\""); device = q[2] }
    /^port = "sim"/ {
        if (device == "meter") print "port = \"usb-socket:" ports "/meter\""
        else print "port = \"" ports "/" device "\""
        next
    }
    { print }
' config/instruments/simulated.toml >"$work/lab.toml"
if grep -q 'port = "sim"' "$work/lab.toml"; then
    fail "a device of the instrument file is still simulated in process"
fi

# Sample out of / into the simulator's holder: the operator's hands.
operator_does() { # "sample out" | "sample in"
    local before
    before="$(wc -l <"$work/sim.out")"
    echo "$1" >&3
    for _ in $(seq 1 100); do
        [ "$(wc -l <"$work/sim.out")" -gt "$before" ] && return 0
        sleep 0.05
    done
    fail "the simulator did not take \"$1\""
}

# ---------------------------------------------------------------- the daemon and its API

start_daemon() {
    : >"$work/daemon.out"
    NO_COLOR=1 RUST_LOG="info,gonio_driver=info" "$GONIO" daemon --listen 127.0.0.1:0 --data "$data" \
        --instrument "$work/lab.toml" --shutdown-grace-s 5 >"$work/daemon.out" 2>>"$work/daemon.log" &
    daemon_pid=$!
    url=""
    for _ in $(seq 1 300); do
        url="$(sed -n 's/^gonio daemon listening on \(http:\/\/[^ ]*\).*/\1/p' "$work/daemon.out")"
        [ -n "$url" ] && break
        kill -0 "$daemon_pid" 2>/dev/null || fail "gonio daemon exited: $(cat "$work/daemon.out")"
        sleep 0.1
    done
    [ -n "$url" ] || fail "gonio daemon did not print its address within 30 s"
}

stop_daemon() {
    kill -TERM "$daemon_pid"
    for _ in $(seq 1 300); do
        kill -0 "$daemon_pid" 2>/dev/null || break
        sleep 0.1
    done
    if kill -0 "$daemon_pid" 2>/dev/null; then
        fail "gonio daemon did not stop within 30 s of SIGTERM"
    fi
    wait "$daemon_pid" 2>/dev/null || true
    daemon_pid=""
}

api() { # method path [curl args...]: the body, failing on an HTTP error
    local method="$1" path="$2"
    shift 2
    curl -sS --fail-with-body --max-time 30 -X "$method" "$@" "$url$path"
}
field() { # name: a plain field of the JSON object on stdin
    sed -n "s/.*\"$1\":\\(\"[^\"]*\"\\|[^,}]*\\).*/\\1/p" | tr -d '"'
}
campaign() { api GET "/api/campaigns/$cid"; }

# Wait until the campaign's JSON matches a pattern (grep -E), within $2 seconds, doing what the operator is
# asked to on the way.
wait_campaign() {
    local pattern="$1" seconds="$2" json=""
    for _ in $(seq 1 $((seconds * 10))); do
        json="$(campaign)" || fail "GET /api/campaigns/$cid failed: $json"
        if grep -Eq "$pattern" <<<"$json"; then
            printf '%s' "$json"
            return 0
        fi
        if grep -q '"state":"waiting-operator"' <<<"$json"; then
            case "$json" in
                *"remove the sample"*) operator_does "sample out" ;;
                *"mount the sample again"*) operator_does "sample in" ;;
                *'"operator_message":null'*) sleep 0.1; continue ;; # the message is being written
                *) fail "an operator step this script does not know: $json" ;;
            esac
            api POST "/api/campaigns/$cid/confirm" >/dev/null || fail "confirm refused"
            # Until the daemon took it (the same prompt may come again later, e.g. after a resume).
            for _ in $(seq 1 100); do
                campaign | grep -q '"state":"waiting-operator"' || break
                sleep 0.05
            done
        fi
        sleep 0.1
    done
    fail "campaign $cid never matched /$pattern/ within $seconds s; last: $json"
}

moves_logged() { grep -Ec 'move absolute|move abs|homing' "$work/daemon.log" || true; }

# ---------------------------------------------------------------- the campaign

cat >"$work/campaign.toml" <<'EOF'
[campaign]
id = "readonly-store"

[sample]
radius_mm = 12.5

[plan]
bands_nm = [550.0]
reciprocity = false

[plan.grid]
kind = "in-plane"
theta_i_deg = [30.0]
theta_o_deg = { from = 10.0, to = 70.0, step = 1.0 }

[acquisition]
averaging = 4
EOF

start_daemon
echo "== daemon at $url, store $store_file on $loopdev (ext4, errors=remount-ro)"
submitted="$(api POST /api/campaigns --data-binary @"$work/campaign.toml" -H 'Content-Type: application/toml')" ||
    fail "submit refused: $submitted"
cid="$(field id <<<"$submitted")"
[ -n "$cid" ] || fail "no campaign id in $submitted"
total="$(campaign | field total_points)"
[ "${total:-0}" -ge 30 ] || fail "the campaign plans $total points, expected at least 30"

# Mid-campaign: a few points committed.
json="$(wait_campaign '"points_done":([89]|[1-9][0-9])[,}]' 120)"
grep -q '"state":"running"' <<<"$json" || fail "expected a running campaign at 8+ points: $json"
api GET "/api/campaigns/$cid/points.csv" >"$work/before.csv" || fail "points.csv before the fault"

echo 1 >"$trigger"
# Recent kernels mark the mount `emergency_ro` (the options still say rw); writes fail with EROFS either way.
opts="$(awk -v m="$mnt" '$2 == m { print $4 }' /proc/mounts)"
grep -Eq '(^|,)(ro|emergency_ro)(,|$)' <<<"$opts" || fail "the filesystem did not go read-only: $opts"
if probe="$(touch "$mnt/probe" 2>&1)"; then
    fail "a new file could still be written after the error"
fi
grep -q "Read-only file system" <<<"$probe" || fail "writing did not fail with EROFS: $probe"
echo "ok: $(basename "$loopdev") remounted read-only under the running daemon after $(($(wc -l <"$work/before.csv") - 1)) points"

# The campaign pauses by itself, saying why.
json="$(wait_campaign '"state":"paused"' 60)"
reason="$(sed -n 's/.*"last_error":"\(\([^"\\]\|\\.\)*\)".*/\1/p' <<<"$json")"
[ -n "$reason" ] || fail "paused without a reason: $json"
grep -q "gonio.sqlite" <<<"$reason" || fail "the reason does not name the store file: $reason"
grep -Eqi "read-only|readonly|disk I/O error|unable to open" <<<"$reason" ||
    fail "the reason does not give the store's error: $reason"
echo "ok: paused: $reason"

# Nothing moves and nothing is added while it waits for the disk; the daemon still answers and serves the
# points committed so far.
moves_at_pause="$(moves_logged)"
[ "$moves_at_pause" -gt 0 ] || fail "the driver log shows no move at all: it cannot show that motion stopped"
done_at_pause="$(campaign | field points_done)"
sleep 3
[ "$(moves_logged)" = "$moves_at_pause" ] || fail "axes were commanded while the campaign was paused for the store"
json="$(campaign)"
grep -q '"state":"paused"' <<<"$json" || fail "no longer paused: $json"
[ "$(field points_done <<<"$json")" = "$done_at_pause" ] || fail "points were added while paused: $json"
api GET "/api/campaigns/$cid/points.csv" >"$work/at_pause.csv" || fail "points.csv from the read-only store"
committed=$(($(wc -l <"$work/at_pause.csv") - 1))
[ "$committed" -eq "$done_at_pause" ] || fail "the CSV has $committed points, the status says $done_at_pause"
[ "$committed" -lt "$total" ] || fail "the fault came too late: all $total points were already in"
head -c "$(stat -c %s "$work/before.csv")" "$work/at_pause.csv" | cmp -s - "$work/before.csv" ||
    fail "the points committed before the fault changed"
echo "ok: motion stopped, $committed of $total points committed and served from the read-only store"

# ---------------------------------------------------------------- the operator repairs the disk

stop_daemon
umount "$mnt"
set +e
e2fsck -fy "$img" >"$work/e2fsck.out" 2>&1
fsck_rc=$?
set -e
[ "$fsck_rc" -lt 4 ] || fail "e2fsck could not repair the image (exit $fsck_rc): $(cat "$work/e2fsck.out")"
mount_store || fail "cannot mount the repaired image"
touch "$mnt/probe" && rm "$mnt/probe" || fail "the repaired filesystem is not writable"
echo "ok: daemon stopped, filesystem checked (e2fsck exit $fsck_rc) and mounted read-write again"

start_daemon
json="$(campaign)"
if grep -q '"state":"paused"' <<<"$json"; then
    api POST "/api/campaigns/$cid/resume" >/dev/null || fail "resume refused"
fi
json="$(wait_campaign '"state":"(completed|failed|aborted)"' 300)"
grep -q '"state":"completed"' <<<"$json" || fail "the campaign did not complete: $json"
grep -q '"last_error":null' <<<"$json" || ! grep -q '"last_error"' <<<"$json" ||
    fail "a completed campaign still shows an error: $json"
api GET "/api/campaigns/$cid/points.csv" >"$work/final.csv" || fail "points.csv after the repair"

rows=$(($(wc -l <"$work/final.csv") - 1))
[ "$rows" -eq "$total" ] || fail "$rows rows for $total planned points"
indices="$(tail -n +2 "$work/final.csv" | cut -d, -f1)"
[ "$indices" = "$(seq 0 $((total - 1)))" ] || fail "the rows are not exactly the points 0..$((total - 1)), once each"
# A completed campaign serves its completion (each value normalised again between the references around it and
# corrected to the nominal geometry, the budget completed: crates/engine/src/budget/complete.rs) beside the
# committed rows, which it never rewrites: what was read (geometry, signal, dark, normalisation, time, read-back:
# columns 1-9 and 13-17) stays byte-identical.
raw() { cut -d, -f1-9,13-17; }
if ! head -n $((committed + 1)) "$work/final.csv" | raw | cmp -s - <(raw <"$work/at_pause.csv"); then
    diff <(head -n $((committed + 1)) "$work/final.csv" | raw) <(raw <"$work/at_pause.csv") >&2 || true
    fail "rows committed before the fault changed"
fi
head -n 1 "$work/final.csv" | raw | grep -q '^index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,incident_w,t_s,light_deg,detector_deg,tilt_deg,rotation_deg$' ||
    fail "points.csv's columns moved: $(head -n 1 "$work/final.csv")"
echo "ok: completed after the repair: $rows rows for $total points, each once, the readings of the $committed rows committed before the fault byte-identical"
stop_daemon
echo "PASS: read-only store mid-campaign: paused with the reason, nothing lost, completed after the repair"
