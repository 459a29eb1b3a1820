//! `gonio devices` end to end: whatever this machine has, it exits 0 and says clearly what it found or why it
//! could not look.

use gonio_testkit::gonio;

#[test]
fn devices_lists_or_explains() {
    let out = gonio().arg("devices").output().expect("run gonio devices");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "exit {:?}\nstdout:\n{stdout}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let serial = stdout.split("USB instruments:").next().unwrap_or("");
    assert!(serial.starts_with("Serial ports:\n"), "{stdout}");
    assert!(
        serial.lines().count() >= 2,
        "the serial section says something: {stdout}"
    );
    let usb = stdout.split("USB instruments:\n").nth(1).expect("a USB section");
    let first = usb.lines().next().expect("a USB line");
    assert!(
        first.contains("USB cannot be used on this machine:")
            || first.contains("none with a known vendor/product id")
            || first.contains("bus "),
        "unclear USB line: {first:?}"
    );
    // In a container without /dev/bus/usb the reason must name it.
    if !std::path::Path::new("/dev/bus/usb").exists() && cfg!(target_os = "linux") {
        assert!(first.contains("/dev/bus/usb is missing"), "{first}");
    }
}
