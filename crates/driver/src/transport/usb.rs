//! USB pipes: bulk OUT/IN with timeouts, class control-IN requests and clear-halt.
//!
//! [`UsbPipe`] is object-safe and async: every method returns a boxed future. The rusb implementation
//! ([`RusbPipe`]) runs each blocking libusb call on tokio's blocking pool (`spawn_blocking`), so a transfer that
//! waits for its timeout never blocks the runtime. [`MemoryPipe`] is an in-memory device for tests: a scripted
//! responder sees every OUT transfer and queues IN transfers, and every control request is logged.
//!
//! What a real Linux USB stack does to [`RusbPipe`], as established by the USB tier (tests/usb_gadget/: a Debian
//! kernel with dummy_hcd, the PM100 emulator behind a FunctionFS gadget with the PM100USB's ids, usbtmc loaded):
//! - The kernel's `usbtmc` binds the interface at enumeration, before gonio opens it. Auto-detach is set before
//!   the claim, so libusb detaches it, the interface shows `usbfs` while gonio holds it, and releasing the
//!   interface when the last handle is dropped (gonio exiting, also after SIGINT) re-attaches `usbtmc` (libusb
//!   does it on release in auto-detach mode, so the handle must be dropped, not leaked; a SIGKILLed gonio is
//!   not covered by the tier).
//! - Permissions: without a udev rule the device node (`/dev/bus/usb/BBB/DDD`) is root's, mode 600; opening it
//!   as another user fails with an access error, which discovery and [`UsbError::Access`] name as such.
//! - Unplugged (the gadget unbound), every transfer fails with "no device" at once; the device comes back at a
//!   new address, so the handle is useless and [`RusbPipe::open`] enumerates again, detaching `usbtmc` again
//!   from the new interface. The meter comes back in its power-up state (bus-powered): the PM100 driver
//!   restores its configuration before reading.
//! - A halted endpoint fails the transfer with a pipe error at once, and `clear_halt` (CLEAR_FEATURE
//!   ENDPOINT_HALT) resets it at the controller. A reply already handed to the device's controller survives the
//!   halt and the INITIATE_CLEAR that follows (the gadget holds one, as a real device's endpoint buffer may): the
//!   next Bulk-IN transfer is then that old reply, which the USBTMC layer discards by its bTag.
//! - A reply later than the transfer's timeout: libusb cancels the URB and reports a timeout with nothing
//!   transferred; the USBTMC layer aborts the Bulk-IN transfer (INITIATE_ABORT_BULK_IN, answered SUCCESS by
//!   the emulator) and asks again.
//! - Short and zero-length packets: the device runs at high speed (512-byte bulk packets). A Bulk-IN read is
//!   now a whole number of 512-byte packets (it was a multiple of 64, which libusb's overflow rule does not
//!   allow at high speed) and larger than any transfer requested, so a transfer ends at its short packet; one
//!   that is an exact multiple of 512 bytes ends at the device's zero-length packet, which the gadget sends as
//!   USBTMC devices do. Bulk-OUT never needs one: the device knows each transfer's size from its header.

use std::collections::VecDeque;
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rusb::UsbContext;

/// A boxed, sendable future (what object-safe async traits return).
pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

/// USB transfer failures.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UsbError {
    /// The transfer did not complete in time; `transferred` bytes moved anyway (never a whole message).
    #[error("transfer timed out after {transferred} bytes")]
    Timeout { transferred: usize },
    /// The endpoint is halted (stalled): clear_halt before reuse.
    #[error("endpoint halted (pipe error)")]
    Pipe,
    /// The device is gone.
    #[error("no such device (it was disconnected)")]
    NoDevice,
    /// The operating system refused access (permissions).
    #[error("access denied: {0}")]
    Access(String),
    /// Anything else libusb reports.
    #[error("{0}")]
    Other(String),
}

/// The bulk and control pipes of one USB interface.
pub trait UsbPipe: Send + Sync + std::fmt::Debug {
    /// Write `data` to the bulk OUT endpoint; returns the bytes written.
    fn bulk_out<'a>(&'a self, data: &'a [u8], timeout: Duration) -> BoxFuture<'a, Result<usize, UsbError>>;
    /// Read one bulk IN transfer of at most `max_len` bytes.
    fn bulk_in(&self, max_len: usize, timeout: Duration) -> BoxFuture<'_, Result<Vec<u8>, UsbError>>;
    /// A control IN request (class requests: `request_type` 0xA1 interface, 0xA2 endpoint).
    fn control_in(
        &self,
        request_type: u8,
        request: u8,
        value: u16,
        index: u16,
        max_len: usize,
        timeout: Duration,
    ) -> BoxFuture<'_, Result<Vec<u8>, UsbError>>;
    /// Clear a halt (stall) on an endpoint.
    fn clear_halt(&self, endpoint: u8) -> BoxFuture<'_, Result<(), UsbError>>;
    fn bulk_out_endpoint(&self) -> u8;
    fn bulk_in_endpoint(&self) -> u8;
    fn interface_number(&self) -> u8;
}

impl From<rusb::Error> for UsbError {
    fn from(e: rusb::Error) -> UsbError {
        match e {
            rusb::Error::Timeout => UsbError::Timeout { transferred: 0 },
            rusb::Error::Pipe => UsbError::Pipe,
            rusb::Error::NoDevice | rusb::Error::NotFound => UsbError::NoDevice,
            rusb::Error::Access => UsbError::Access("no permission to open the USB device".into()),
            other => UsbError::Other(other.to_string()),
        }
    }
}

/// One USBTMC interface on a real device, through libusb.
#[derive(Debug, Clone)]
pub struct RusbPipe {
    handle: Arc<rusb::DeviceHandle<rusb::Context>>,
    interface: u8,
    ep_in: u8,
    ep_out: u8,
}

/// USBTMC interface class / subclass (USBTMC 1.0, section 4.2).
const USBTMC_CLASS: u8 = 0xFE;
const USBTMC_SUBCLASS: u8 = 0x03;

impl RusbPipe {
    /// Open the first USBTMC interface of the device `vendor:product` (and `serial`, if given).
    /// Blocking (device enumeration): call from `spawn_blocking` or before the runtime starts.
    pub fn open(vendor: u16, product: u16, serial: Option<&str>) -> Result<RusbPipe, UsbError> {
        let context = rusb::Context::new()?;
        let devices = context.devices()?;
        for device in devices.iter() {
            let Ok(desc) = device.device_descriptor() else {
                continue;
            };
            if desc.vendor_id() != vendor || desc.product_id() != product {
                continue;
            }
            let handle = device.open()?;
            if let Some(want) = serial {
                let got = handle.read_serial_number_string_ascii(&desc).unwrap_or_default();
                if got != want {
                    continue;
                }
            }
            let config = device.active_config_descriptor()?;
            for iface in config.interfaces() {
                for alt in iface.descriptors() {
                    if alt.class_code() != USBTMC_CLASS || alt.sub_class_code() != USBTMC_SUBCLASS {
                        continue;
                    }
                    let mut ep_in = None;
                    let mut ep_out = None;
                    for ep in alt.endpoint_descriptors() {
                        if ep.transfer_type() != rusb::TransferType::Bulk {
                            continue;
                        }
                        match ep.direction() {
                            rusb::Direction::In => ep_in = ep_in.or(Some(ep.address())),
                            rusb::Direction::Out => ep_out = ep_out.or(Some(ep.address())),
                        }
                    }
                    if let (Some(ep_in), Some(ep_out)) = (ep_in, ep_out) {
                        let number = alt.interface_number();
                        // Linux binds usbtmc.ko to these devices; detach it for the time we hold the interface.
                        let _ = handle.set_auto_detach_kernel_driver(true);
                        handle.claim_interface(number)?;
                        tracing::info!(
                            vendor,
                            product,
                            interface = number,
                            ep_in,
                            ep_out,
                            "USBTMC interface claimed"
                        );
                        return Ok(RusbPipe {
                            handle: Arc::new(handle),
                            interface: number,
                            ep_in,
                            ep_out,
                        });
                    }
                }
            }
        }
        Err(UsbError::NoDevice)
    }
}

async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, UsbError> + Send + 'static,
) -> Result<T, UsbError> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| UsbError::Other(format!("USB worker failed: {e}")))?
}

impl UsbPipe for RusbPipe {
    fn bulk_out<'a>(&'a self, data: &'a [u8], timeout: Duration) -> BoxFuture<'a, Result<usize, UsbError>> {
        let handle = Arc::clone(&self.handle);
        let ep = self.ep_out;
        let data = data.to_vec();
        Box::pin(blocking(move || Ok(handle.write_bulk(ep, &data, timeout)?)))
    }

    fn bulk_in(&self, max_len: usize, timeout: Duration) -> BoxFuture<'_, Result<Vec<u8>, UsbError>> {
        let handle = Arc::clone(&self.handle);
        let ep = self.ep_in;
        Box::pin(blocking(move || {
            let mut buf = vec![0u8; max_len];
            let n = handle.read_bulk(ep, &mut buf, timeout)?;
            buf.truncate(n);
            Ok(buf)
        }))
    }

    fn control_in(
        &self,
        request_type: u8,
        request: u8,
        value: u16,
        index: u16,
        max_len: usize,
        timeout: Duration,
    ) -> BoxFuture<'_, Result<Vec<u8>, UsbError>> {
        let handle = Arc::clone(&self.handle);
        Box::pin(blocking(move || {
            let mut buf = vec![0u8; max_len];
            let n = handle.read_control(request_type, request, value, index, &mut buf, timeout)?;
            buf.truncate(n);
            Ok(buf)
        }))
    }

    fn clear_halt(&self, endpoint: u8) -> BoxFuture<'_, Result<(), UsbError>> {
        let handle = Arc::clone(&self.handle);
        Box::pin(blocking(move || Ok(handle.clear_halt(endpoint)?)))
    }

    fn bulk_out_endpoint(&self) -> u8 {
        self.ep_out
    }
    fn bulk_in_endpoint(&self) -> u8 {
        self.ep_in
    }
    fn interface_number(&self) -> u8 {
        self.interface
    }
}

/// A control request seen by a [`MemoryPipe`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ControlRequest {
    pub request_type: u8,
    pub request: u8,
    pub value: u16,
    pub index: u16,
    pub max_len: usize,
}

type Responder = Box<dyn FnMut(&[u8], &mut MemoryState) + Send>;

/// What a [`MemoryPipe`] has seen and will answer. Tests script it directly.
#[derive(Default)]
pub struct MemoryState {
    /// Every OUT transfer, in order.
    pub out_log: Vec<Vec<u8>>,
    /// IN transfers to hand out, in order; an empty queue times out.
    pub in_queue: VecDeque<Result<Vec<u8>, UsbError>>,
    /// Every control request, in order.
    pub control_log: Vec<ControlRequest>,
    /// Answers to control requests, in order; an empty queue answers with a pipe error (request not supported).
    pub control_replies: VecDeque<Vec<u8>>,
    /// Endpoints halted until clear_halt.
    pub halted: Vec<u8>,
    /// Endpoints that got clear_halt, in order.
    pub cleared: Vec<u8>,
    /// Errors for the next OUT transfers, in order (before the data is accepted).
    pub out_errors: VecDeque<UsbError>,
    /// The device is gone.
    pub gone: bool,
}

impl std::fmt::Debug for MemoryState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MemoryState")
            .field("out_log", &self.out_log.len())
            .field("in_queue", &self.in_queue.len())
            .field("control_log", &self.control_log)
            .finish()
    }
}

/// An in-memory USB device. A responder (optional) is called on each accepted OUT transfer and may queue replies.
#[derive(Clone)]
pub struct MemoryPipe {
    pub state: Arc<Mutex<MemoryState>>,
    responder: Arc<Mutex<Option<Responder>>>,
}

impl std::fmt::Debug for MemoryPipe {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MemoryPipe").finish_non_exhaustive()
    }
}

impl Default for MemoryPipe {
    fn default() -> Self {
        MemoryPipe::new()
    }
}

/// Endpoint addresses of the in-memory device.
pub const MEMORY_EP_OUT: u8 = 0x02;
pub const MEMORY_EP_IN: u8 = 0x81;

impl MemoryPipe {
    pub fn new() -> MemoryPipe {
        MemoryPipe {
            state: Arc::new(Mutex::new(MemoryState::default())),
            responder: Arc::new(Mutex::new(None)),
        }
    }

    /// Install a responder that sees every accepted OUT transfer.
    pub fn with_responder(self, f: impl FnMut(&[u8], &mut MemoryState) + Send + 'static) -> MemoryPipe {
        if let Ok(mut r) = self.responder.lock() {
            *r = Some(Box::new(f));
        }
        self
    }

    fn with_state<T>(&self, f: impl FnOnce(&mut MemoryState) -> T) -> Result<T, UsbError> {
        let mut s = self
            .state
            .lock()
            .map_err(|_| UsbError::Other("memory device poisoned".into()))?;
        if s.gone {
            return Err(UsbError::NoDevice);
        }
        Ok(f(&mut s))
    }
}

impl UsbPipe for MemoryPipe {
    fn bulk_out<'a>(&'a self, data: &'a [u8], _timeout: Duration) -> BoxFuture<'a, Result<usize, UsbError>> {
        Box::pin(async move {
            let mut state = self
                .state
                .lock()
                .map_err(|_| UsbError::Other("memory device poisoned".into()))?;
            if state.gone {
                return Err(UsbError::NoDevice);
            }
            if state.halted.contains(&MEMORY_EP_OUT) {
                return Err(UsbError::Pipe);
            }
            if let Some(e) = state.out_errors.pop_front() {
                return Err(e);
            }
            state.out_log.push(data.to_vec());
            if let Ok(mut r) = self.responder.lock()
                && let Some(f) = r.as_mut()
            {
                f(data, &mut state);
            }
            Ok(data.len())
        })
    }

    fn bulk_in(&self, max_len: usize, timeout: Duration) -> BoxFuture<'_, Result<Vec<u8>, UsbError>> {
        Box::pin(async move {
            let next = self.with_state(|s| {
                if s.halted.contains(&MEMORY_EP_IN) {
                    return Some(Err(UsbError::Pipe));
                }
                s.in_queue.pop_front()
            })?;
            match next {
                Some(Ok(mut bytes)) => {
                    bytes.truncate(max_len);
                    Ok(bytes)
                }
                Some(Err(e)) => Err(e),
                None => {
                    // Nothing to send: behave like a real device and time out.
                    tokio::time::sleep(timeout).await;
                    Err(UsbError::Timeout { transferred: 0 })
                }
            }
        })
    }

    fn control_in(
        &self,
        request_type: u8,
        request: u8,
        value: u16,
        index: u16,
        max_len: usize,
        _timeout: Duration,
    ) -> BoxFuture<'_, Result<Vec<u8>, UsbError>> {
        Box::pin(async move {
            self.with_state(|s| {
                s.control_log.push(ControlRequest {
                    request_type,
                    request,
                    value,
                    index,
                    max_len,
                });
                s.control_replies.pop_front()
            })?
            .ok_or(UsbError::Pipe)
        })
    }

    fn clear_halt(&self, endpoint: u8) -> BoxFuture<'_, Result<(), UsbError>> {
        Box::pin(async move {
            self.with_state(|s| {
                s.halted.retain(|e| *e != endpoint);
                s.cleared.push(endpoint);
            })
        })
    }

    fn bulk_out_endpoint(&self) -> u8 {
        MEMORY_EP_OUT
    }
    fn bulk_in_endpoint(&self) -> u8 {
        MEMORY_EP_IN
    }
    fn interface_number(&self) -> u8 {
        0
    }
}
