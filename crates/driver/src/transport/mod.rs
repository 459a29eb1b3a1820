//! Byte transports: [`line`] for serial devices (real ports, pseudo-terminals, in-memory streams) and
//! [`usb`] for USB bulk/control pipes (rusb, or an in-memory device for tests).

pub mod line;
pub mod usb;

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
