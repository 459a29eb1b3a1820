//! `gonio devices`: the serial ports and USB instruments this machine can see, and plainly why not when it
//! cannot look (no sysfs, no USB bus, no permission).

use gonio_driver::discovery::{self, SerialScan, UsbScan};

use crate::CliError;

#[derive(Debug, clap::Args)]
pub struct DevicesArgs {}

pub fn run(_args: DevicesArgs) -> Result<(), CliError> {
    let mut out = String::new();
    out.push_str(&serial_report(&discovery::scan_serial()));
    out.push_str(&usb_report(&discovery::scan_usb()));
    print!("{out}");
    Ok(())
}

fn serial_report(scan: &SerialScan) -> String {
    let mut s = String::from("Serial ports:\n");
    match scan {
        SerialScan::Unavailable(why) => s.push_str(&format!("  cannot list serial ports: {why}\n")),
        SerialScan::Ports(ports) if ports.is_empty() => {
            s.push_str(
                "  none found (only ports backed by hardware are listed; pseudo-terminals never are)\n",
            );
        }
        SerialScan::Ports(ports) => {
            for p in ports {
                s.push_str(&format!("  {} ({})", p.path, p.kind));
                if let Some(u) = &p.usb {
                    s.push_str(&format!(" usb {:04x}:{:04x}", u.vid, u.pid));
                    if let Some(model) = discovery::known_usb(u.vid, u.pid) {
                        s.push_str(&format!(" [{model}]"));
                    }
                    for v in [&u.manufacturer, &u.product].into_iter().flatten() {
                        s.push_str(&format!(" {v}"));
                    }
                    if let Some(sn) = &u.serial {
                        s.push_str(&format!(" serial {sn}"));
                    }
                }
                s.push('\n');
            }
        }
    }
    s
}

fn usb_report(scan: &UsbScan) -> String {
    let mut s = String::from("USB instruments:\n");
    match scan {
        UsbScan::Unavailable(why) => s.push_str(&format!("  USB cannot be used on this machine: {why}\n")),
        UsbScan::Devices { total, instruments } if instruments.is_empty() => {
            s.push_str(&format!(
                "  none with a known vendor/product id ({total} USB devices seen)\n"
            ));
        }
        UsbScan::Devices { instruments, .. } => {
            for d in instruments {
                s.push_str(&format!(
                    "  bus {:03} device {:03}: {:04x}:{:04x} {}",
                    d.bus, d.address, d.vid, d.pid, d.model
                ));
                if let Some(sn) = &d.serial {
                    s.push_str(&format!(" serial {sn}"));
                }
                if let Some(e) = &d.open_error {
                    s.push_str(&format!(" (cannot open: {e})"));
                }
                s.push('\n');
            }
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use gonio_driver::discovery::{SerialPortEntry, UsbEntry, UsbIds};

    use super::*;

    #[test]
    fn reports_say_what_was_found_and_why_not() {
        let none = serial_report(&SerialScan::Ports(vec![]));
        assert!(none.contains("none found"));
        let one = serial_report(&SerialScan::Ports(vec![SerialPortEntry {
            path: "/dev/ttyUSB0".into(),
            kind: "usb",
            usb: Some(UsbIds {
                vid: 0x0403,
                pid: 0x6001,
                serial: Some("A1".into()),
                manufacturer: None,
                product: None,
            }),
        }]));
        assert!(
            one.contains("/dev/ttyUSB0 (usb) usb 0403:6001 [FTDI USB-serial bridge] serial A1"),
            "{one}"
        );
        let no_bus = usb_report(&UsbScan::Unavailable("no USB bus".into()));
        assert!(no_bus.contains("USB cannot be used on this machine: no USB bus"));
        let meter = usb_report(&UsbScan::Devices {
            total: 3,
            instruments: vec![UsbEntry {
                bus: 1,
                address: 4,
                vid: 0x1313,
                pid: 0x8072,
                model: "PM100USB",
                serial: None,
                open_error: Some("no permission".into()),
            }],
        });
        assert!(
            meter.contains("1313:8072 PM100USB (cannot open: no permission)"),
            "{meter}"
        );
    }
}
