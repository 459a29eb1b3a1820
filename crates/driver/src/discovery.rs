//! Discovery: the serial ports and USB instruments this machine can see.
//!
//! Serial ports come from `serialport::available_ports()`. This build has no libudev: on Linux the crate then
//! scans `/sys/class/tty`, which still yields the USB vendor/product id, serial number, manufacturer and product
//! strings of USB-serial adapters (read from sysfs), but lists only ports backed by a real device
//! (pseudo-terminals are never listed). It panics when `/sys/class/tty` is missing, so that case is checked first.
//! USB devices come from libusb (vendored through rusb); when there is no USB bus or no permission the scan says
//! so instead of failing.

use std::path::Path;

use rusb::UsbContext;

use crate::pm100::{PRODUCTS, THORLABS_VID};

/// USB identity of a serial port's adapter.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UsbIds {
    pub vid: u16,
    pub pid: u16,
    pub serial: Option<String>,
    pub manufacturer: Option<String>,
    pub product: Option<String>,
}

/// One serial port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialPortEntry {
    pub path: String,
    /// "usb", "pci", "bluetooth" or "unknown".
    pub kind: &'static str,
    pub usb: Option<UsbIds>,
}

/// Result of the serial scan.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SerialScan {
    Ports(Vec<SerialPortEntry>),
    /// Ports cannot be listed on this machine; the text says why.
    Unavailable(String),
}

/// One USB device with a known vendor/product id.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UsbEntry {
    pub bus: u8,
    pub address: u8,
    pub vid: u16,
    pub pid: u16,
    /// What the ids say it is.
    pub model: &'static str,
    /// Serial number, when the device could be opened.
    pub serial: Option<String>,
    /// Why the device cannot be opened (permissions), if it cannot.
    pub open_error: Option<String>,
}

/// Result of the USB scan.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum UsbScan {
    Devices {
        total: usize,
        instruments: Vec<UsbEntry>,
    },
    /// USB cannot be used on this machine; the text says why.
    Unavailable(String),
}

/// What a vendor/product id is, if we know it.
pub fn known_usb(vid: u16, pid: u16) -> Option<&'static str> {
    if vid == THORLABS_VID {
        return Some(
            PRODUCTS
                .iter()
                .find(|(p, _)| *p == pid)
                .map(|(_, n)| *n)
                .unwrap_or("Thorlabs device"),
        );
    }
    match (vid, pid) {
        // Generic USB-serial bridges: what RS-232 controllers (SMC100, Zaber, FW102C) usually sit behind.
        (0x0403, _) => Some("FTDI USB-serial bridge"),
        (0x10C4, 0xEA60) => Some("Silicon Labs CP210x USB-serial bridge"),
        (0x067B, 0x2303) => Some("Prolific PL2303 USB-serial bridge"),
        _ => None,
    }
}

/// List serial ports.
pub fn scan_serial() -> SerialScan {
    if cfg!(target_os = "linux") && !Path::new("/sys/class/tty").is_dir() {
        return SerialScan::Unavailable(
            "/sys/class/tty does not exist (no sysfs in this environment)".into(),
        );
    }
    match std::panic::catch_unwind(serialport::available_ports) {
        Err(_) => SerialScan::Unavailable("the serial port scan failed".into()),
        Ok(Err(e)) => SerialScan::Unavailable(format!("cannot list serial ports: {e}")),
        Ok(Ok(ports)) => SerialScan::Ports(
            ports
                .into_iter()
                .map(|p| {
                    let (kind, usb) = match p.port_type {
                        serialport::SerialPortType::UsbPort(u) => (
                            "usb",
                            Some(UsbIds {
                                vid: u.vid,
                                pid: u.pid,
                                serial: u.serial_number,
                                manufacturer: u.manufacturer,
                                product: u.product,
                            }),
                        ),
                        serialport::SerialPortType::PciPort => ("pci", None),
                        serialport::SerialPortType::BluetoothPort => ("bluetooth", None),
                        serialport::SerialPortType::Unknown => ("unknown", None),
                    };
                    SerialPortEntry {
                        path: p.port_name,
                        kind,
                        usb,
                    }
                })
                .collect(),
        ),
    }
}

/// List USB devices with a known id. Blocking (enumeration): fine from a command-line tool.
pub fn scan_usb() -> UsbScan {
    let no_bus = cfg!(target_os = "linux") && !Path::new("/dev/bus/usb").exists();
    let context = match rusb::Context::new() {
        Ok(c) => c,
        Err(_) if no_bus => {
            return UsbScan::Unavailable(
                "no USB bus is visible (/dev/bus/usb is missing: a container or VM without USB access?)"
                    .into(),
            );
        }
        Err(rusb::Error::Access) => {
            return UsbScan::Unavailable("no permission to use USB (udev rules or group membership)".into());
        }
        Err(e) => return UsbScan::Unavailable(format!("libusb cannot start: {e}")),
    };
    let devices = match context.devices() {
        Ok(d) => d,
        Err(e) => return UsbScan::Unavailable(format!("cannot enumerate USB devices: {e}")),
    };
    if devices.is_empty() && no_bus {
        return UsbScan::Unavailable(
            "no USB bus is visible (/dev/bus/usb is missing: a container or VM without USB access?)".into(),
        );
    }
    let total = devices.len();
    let mut instruments = Vec::new();
    for device in devices.iter() {
        let Ok(desc) = device.device_descriptor() else {
            continue;
        };
        let Some(model) = known_usb(desc.vendor_id(), desc.product_id()) else {
            continue;
        };
        let (serial, open_error) = match device.open() {
            Ok(h) => (h.read_serial_number_string_ascii(&desc).ok(), None),
            Err(rusb::Error::Access) => (
                None,
                Some("no permission to open it (udev rules or group membership)".to_string()),
            ),
            Err(e) => (None, Some(e.to_string())),
        };
        instruments.push(UsbEntry {
            bus: device.bus_number(),
            address: device.address(),
            vid: desc.vendor_id(),
            pid: desc.product_id(),
            model,
            serial,
            open_error,
        });
    }
    UsbScan::Devices { total, instruments }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_ids() {
        assert_eq!(known_usb(0x1313, 0x8072), Some("PM100USB"));
        assert_eq!(known_usb(0x1313, 0x80BB), Some("PM5020"));
        assert_eq!(known_usb(0x1313, 0x1234), Some("Thorlabs device"));
        assert_eq!(known_usb(0x1234, 0x8072), None);
    }

    #[test]
    fn scans_never_panic() {
        // Whatever this machine has (or lacks), the scans answer.
        let _ = scan_serial();
        let _ = scan_usb();
    }
}
