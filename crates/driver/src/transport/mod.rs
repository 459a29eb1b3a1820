//! Byte transports: [`line`] for serial devices (real ports, pseudo-terminals, in-memory streams) and
//! [`usb`] for USB bulk/control pipes (rusb, or an in-memory device for tests), and [`usb_socket`] for a USB
//! device reached over a Unix socket (the simulator's power meter in another process).

pub mod line;
pub mod usb;
pub mod usb_socket;

pub use line::{LinePort, PortOpener, SerialSettings, TransportError};
pub use usb::{BoxFuture, UsbError, UsbPipe};

/// Render bytes for a trace: printable ASCII as is, everything else as `\xNN`.
pub fn escape_bytes(bytes: &[u8]) -> String {
    bytes
        .iter()
        .flat_map(|b| std::ascii::escape_default(*b))
        .map(char::from)
        .collect()
}
