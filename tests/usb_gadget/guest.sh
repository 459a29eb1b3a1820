#!/bin/busybox sh
# /init of the USB tier's guest (built into the initramfs by tests/usb_gadget/run.sh). Every line of the report
# starts with "tier:"; the last is "tier: PASS" or "tier: FAIL ...". The guest always powers off.
/bin/busybox --install -s /bin
export PATH=/bin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
mkdir -p /dev/pts
mount -t devpts -o ptmxmode=666 devpts /dev/pts
mkdir -p /run/links /run/out
cd /run

say() { echo "tier: $*"; }
finish() {
    say "$@"
    sync
    poweroff -f
}
fail() {
    for f in /run/sim.log /run/run.err; do
        [ -f "$f" ] && { echo "--- $f"; tail -n 40 "$f"; }
    done
    finish "FAIL $*"
}
# wait_for SECONDS COMMAND...: poll every 0.1 s until COMMAND succeeds; fails after the deadline.
wait_for() {
    n=$(($1 * 10))
    shift
    while ! "$@" >/dev/null 2>&1; do
        n=$((n - 1))
        [ $n -le 0 ] && return 1
        sleep 0.1
    done
}
uptime_s() { cut -d' ' -f1 /proc/uptime; }
scale=$(sed -n 's/.*tier_scale=\([0-9.]*\).*/\1/p' /proc/cmdline)
scale=${scale:-3}
say "guest up at $(uptime_s) s, kernel $(uname -r)"

# --- the kernel's USB stack: host and device controllers (dummy_hcd), gadget framework, FunctionFS, usbtmc
for m in usb-common usbcore udc-core dummy_hcd configfs libcomposite usb_f_fs usbtmc; do
    insmod /lib/modules/$m.ko || fail "insmod $m"
done
[ -e /sys/class/udc/dummy_udc.0 ] || fail "no dummy_udc.0"

# --- the gadget: PM100USB ids, one configuration, one FunctionFS function
mount -t configfs none /sys/kernel/config
G=/sys/kernel/config/usb_gadget/pm100
mkdir $G
echo 0x1313 >$G/idVendor
echo 0x8072 >$G/idProduct
echo 0x0200 >$G/bcdUSB
mkdir $G/strings/0x409
echo "Thorlabs" >$G/strings/0x409/manufacturer
echo "PM100USB" >$G/strings/0x409/product
echo "P2000001" >$G/strings/0x409/serialnumber
mkdir $G/configs/c.1 $G/configs/c.1/strings/0x409
echo "USBTMC" >$G/configs/c.1/strings/0x409/configuration
echo 100 >$G/configs/c.1/MaxPower
mkdir $G/functions/ffs.pm100
ln -s $G/functions/ffs.pm100 $G/configs/c.1/
mkdir -p /dev/ffs-pm100
mount -t functionfs pm100 /dev/ffs-pm100 || fail "mount functionfs"

# --- the device side: the simulator, its serial devices on links, the meter behind FunctionFS
mkfifo /run/sim.in /run/run.in
exec 3<>/run/sim.in 4<>/run/run.in
RUST_LOG=info,gonio_simulator::pm100=debug gonio sim --time-scale "$scale" --material spectralon --link-dir /run/links \
    --usb-gadget /dev/ffs-pm100 <&3 >/run/sim.out 2>/run/sim.log &
sim_pid=$!
sim_ready() { grep -q '"ready":true' /run/sim.out || ! kill -0 $sim_pid; }
wait_for 60 sim_ready && kill -0 $sim_pid || fail "gonio sim not ready"
echo dummy_udc.0 >$G/UDC || fail "bind the gadget"

# --- enumeration and the kernel driver
dev_dir() {
    for d in /sys/bus/usb/devices/*; do
        [ "$(cat "$d/idVendor" 2>/dev/null):$(cat "$d/idProduct" 2>/dev/null)" = "1313:8072" ] && {
            echo "$d"
            return 0
        }
    done
    return 1
}
wait_for 20 dev_dir || fail "the gadget was not enumerated"
D=$(dev_dir)
I="$D/$(basename "$D"):1.0"
driver_of() { basename "$(readlink "$I/driver" 2>/dev/null)" 2>/dev/null; }
usbtmc_bound() { [ "$(driver_of)" = usbtmc ]; }
say "enumerated $(cat "$D/idVendor"):$(cat "$D/idProduct") at $(basename "$D"), $(cat "$D/speed") Mb/s," \
    "$(cat "$D/manufacturer") $(cat "$D/product") serial $(cat "$D/serial"), interface class" \
    "$(cat "$I/bInterfaceClass")/$(cat "$I/bInterfaceSubClass")/$(cat "$I/bInterfaceProtocol") at $(uptime_s) s"
wait_for 10 usbtmc_bound || fail "usbtmc did not bind the interface (driver: $(driver_of))"
say "kernel driver bound first: $(driver_of) ($(ls /dev | grep usbtmc))"

# --- gonio devices
gonio devices >/run/devices.txt 2>&1
grep -q '1313:8072 PM100USB serial P2000001' /run/devices.txt || { cat /run/devices.txt; fail "gonio devices"; }
say "gonio devices: $(grep 1313:8072 /run/devices.txt | sed 's/^ *//')"

# --- permissions on the device node: a user it does not admit is told why; a mode a udev rule would set admits them
mkdir -p /etc
printf 'root:x:0:0::/root:/bin/sh\nlab:x:1000:1000::/tmp:/bin/sh\n' >/etc/passwd
printf 'root:x:0:\nlab:x:1000:\n' >/etc/group
node=/dev/bus/usb/$(printf %03d "$(cat "$D/busnum")")/$(printf %03d "$(cat "$D/devnum")")
mode=$(stat -c %a "$node")
su -s /bin/sh lab -c 'PATH=/bin gonio devices' >/run/devices-lab.txt 2>&1
grep -q '1313:8072 PM100USB (cannot open: no permission' /run/devices-lab.txt ||
    { cat /run/devices-lab.txt; fail "gonio devices as a user without access"; }
say "as a user, with $node mode $mode: $(grep 1313:8072 /run/devices-lab.txt | sed 's/^ *//')"
chmod 0666 "$node"
su -s /bin/sh lab -c 'PATH=/bin gonio devices' >/run/devices-lab.txt 2>&1
grep -q '1313:8072 PM100USB serial P2000001' /run/devices-lab.txt ||
    { cat /run/devices-lab.txt; fail "gonio devices as a user once the node is 0666"; }
say "as a user, with $node mode 0666: $(grep 1313:8072 /run/devices-lab.txt | sed 's/^ *//')"
chmod "$mode" "$node"

# --- the campaign, with an operator answering prompts and the USB faults injected while it runs
gonio plan /tier/campaign.toml --instrument /tier/lab.toml --points /run/plan.csv >/dev/null 2>&1 ||
    fail "gonio plan"
planned=$(($(wc -l </run/plan.csv) - 1))
RUST_LOG=warn,gonio_driver=info gonio run /tier/campaign.toml --instrument /tier/lab.toml --out /run/out --quiet \
    <&4 >/run/run.out 2>/run/run.err &
run_pid=$!
t0=$(uptime_s)
running() { kill -0 $run_pid 2>/dev/null; }
answered=0
operator() {
    # Answer every new "operator:" prompt: do it on the simulator, then confirm with Enter.
    prompts=$(grep -c '^operator:' /run/run.err)
    while [ "$answered" -lt "$prompts" ]; do
        answered=$((answered + 1))
        prompt=$(grep '^operator:' /run/run.err | sed -n "${answered}p")
        case "$prompt" in
        *"remove the sample"*) echo "sample out" >&3 ;;
        *"mount the sample again"*) echo "sample in" >&3 ;;
        *) fail "unexpected prompt: $prompt" ;;
        esac
        sleep 0.2
        echo "" >&4
    done
}
# wait_running SECONDS: answer prompts for that long while the campaign runs.
wait_running() {
    n=$(($1 * 5))
    while [ $n -gt 0 ] && running; do
        operator
        sleep 0.2
        n=$((n - 1))
    done
}

# The faults are paced by the meter's readings (every MEAS:POW? the emulator receives is in its log), so they land
# mid-campaign whatever the guest's speed (KVM or TCG); the unplug lasts 3 s of wall time.
readings() { grep -c 'MEAS:POW?' /run/sim.log; }
# after_readings N: answer prompts until N more readings were taken; fails if the campaign ends first.
after_readings() {
    target=$(($(readings) + $1))
    while [ "$(readings)" -lt $target ]; do
        running || fail "the campaign ended before the next fault"
        operator
        sleep 0.1
    done
}
while running && [ "$answered" -lt 2 ]; do
    operator
    sleep 0.2
done
say "calibration steps done at $(uptime_s) s ($(readings) readings so far)"
after_readings 2
# While gonio holds the meter, the interface belongs to usbfs (libusb's claim), not to usbtmc.
[ "$(driver_of)" = usbfs ] || fail "gonio did not detach usbtmc (interface driver: $(driver_of))"
say "while gonio runs, the interface is claimed through usbfs (usbtmc detached)"
say "fault 1: unplug (gadget unbound) at $(uptime_s) s, reading $(readings)"
echo "" >$G/UDC
wait_running 3
running || fail "the campaign ended during the unplug"
echo dummy_udc.0 >$G/UDC || fail "rebind the gadget"
say "replugged at $(uptime_s) s"
after_readings 4
say "fault 2: Bulk-IN halted at $(uptime_s) s, reading $(readings)"
echo "usb halt in" >&3
after_readings 4
say "fault 3: Bulk-OUT halted at $(uptime_s) s, reading $(readings)"
echo "usb halt out" >&3
after_readings 4
say "fault 4: next reply 2.5 s late (driver timeout 1 s) at $(uptime_s) s, reading $(readings)"
echo "usb delay 2500" >&3
after_readings 2
# Ctrl-C mid-campaign: gonio stops, releases the interface, and usbtmc must be back; then the same command resumes.
kill -INT $run_pid
wait $run_pid
say "gonio run interrupted (SIGINT) at $(uptime_s) s, exit $?, reading $(readings)"
wait_for 5 usbtmc_bound || fail "usbtmc not re-attached after an interrupted run (driver: $(driver_of))"
say "kernel driver re-attached after the interrupted run: $(driver_of)"
RUST_LOG=warn,gonio_driver=info gonio run /tier/campaign.toml --instrument /tier/lab.toml --out /run/out --quiet \
    <&4 >/run/run2.out 2>>/run/run.err &
run_pid=$!
while running; do
    operator
    sleep 0.2
done
wait $run_pid
rc=$?
say "gonio run (resumed) exited $rc; whole campaign $(awk -v a="$t0" -v b="$(uptime_s)" 'BEGIN{printf "%.1f", b-a}') s"
[ $rc = 0 ] || fail "the resumed gonio run failed"
say "resumed run: $(grep -h -m1 'completed' /run/run2.out /run/run.err)"

# --- the kernel driver is back once gonio has exited
wait_for 5 usbtmc_bound || fail "usbtmc not re-attached after gonio exited (driver: $(driver_of))"
say "kernel driver re-attached after exit: $(driver_of)"

# --- what the driver saw (its own log lines)
for what in "USB device reopened" "configuration restored after reconnect" "Bulk-IN halted" "Bulk-OUT halted" \
    "Bulk-IN timed out"; do
    c=$(grep -c "$what" /run/run.err)
    say "driver log: \"$what\" x$c"
    [ "$c" -gt 0 ] || fail "the driver never logged \"$what\": the fault did not reach it"
done
# The meter came back in its power-up state (633 nm): the emulator must have been told the wavelength again before
# its next reading.
awk '/power cycled/ { p = 1 } p && /SCPI message/ && /MEAS:POW\?/ { exit 1 } p && /SENS:CORR:WAV 550/ { ok = 1; exit }
    END { exit !ok }' /run/sim.log || fail "the meter was read after its power cycle before it was reconfigured"
say "after the power cycle the emulator received SENS:CORR:WAV 550 before its next MEAS:POW?"
say "simulator log: $(grep -c 'power cycled' /run/sim.log) power cycle(s), $(grep -c 'endpoint halted' /run/sim.log) halt(s), $(readings) readings"

# --- every planned point exactly once, each a valid reading of the material the simulator holds
csv=/run/out/points.csv
[ -f $csv ] || fail "no points.csv"
points=$(($(wc -l <$csv) - 1))
# Columns by name: the geometry of each point, sorted, against the plan's.
geom() { awk -F, -v want="theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,band_nm" '
    NR == 1 { n = split(want, w, ","); for (i = 1; i <= NF; i++) col[$i] = i; next }
    { line = ""; for (k = 1; k <= n; k++) line = line sprintf("%.3f ", $col[w[k]]); print line }' "$1" | sort; }
geom /run/plan.csv >/run/plan.geom
geom $csv >/run/run.geom
dups=$(uniq -d /run/run.geom | wc -l)
[ "$dups" = 0 ] || fail "$dups duplicated points"
cmp -s /run/plan.geom /run/run.geom || fail "points differ from the plan ($points measured, $planned planned)"
say "points: $points measured = $planned planned, none duplicated, none missing"
awk -F, 'NR == 1 { for (i = 1; i <= NF; i++) col[$i] = i; next }
    { print $col["theta_i_deg"], $col["phi_i_deg"], $col["theta_o_deg"], $col["phi_o_deg"] }' $csv |
    gonio brdf eval --material spectralon --wavelength 550 >/run/truth.txt || fail "gonio brdf eval"
awk -F, 'NR == 1 { for (i = 1; i <= NF; i++) col[$i] = i; next }
    { print $col["brdf_sr"], $col["flags"] }' $csv | paste -d' ' - /run/truth.txt | awk '
    { if ($2 != "" && NF == 3) { bad++; next } m = $1; t = $NF; e = (m - t) / t; if (e < 0) e = -e;
      if (e > worst) worst = e; if (e > 0.03) bad++ }
    END { printf "%d %.4f\n", bad + 0, worst }' >/run/check.txt
read bad worst </run/check.txt
say "values: worst relative error against spectralon $worst, $bad beyond 3%"
[ "$bad" = 0 ] || fail "$bad points disagree with the material (meter not reconfigured?)"

kill $sim_pid 2>/dev/null
# For the record: the driver's USB lines and the kernel's.
grep -a 'gonio_driver::\(pm100\|usbtmc\|transport\)' /run/run.err | sed 's/\x1b\[[0-9;]*m//g; s/^/tier-log: /'
dmesg | grep -ai 'usb' | sed 's/^/tier-dmesg: /'
finish "PASS ($points points at time scale $scale, campaign $(awk -v a="$t0" -v b="$(uptime_s)" 'BEGIN{printf "%.1f", b-a}') s)"
