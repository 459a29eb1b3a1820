//! The simulated power meter as a real USB device: its emulator (crate::pm100, the same one every dry-run
//! talks to) behind the endpoints of a Linux FunctionFS function, so that a kernel enumerates it, its `usbtmc`
//! driver binds it, and a host program reaches it through libusb exactly as it would a PM100USB on a cable.
//!
//! The gadget itself (vendor and product ids, strings, configuration, the UDC it binds to) is set up in configfs
//! by whoever runs this (tests/usb_gadget/guest.sh); this module owns the function mounted at `dir`:
//! - `ep0`: the descriptors and strings ([`descriptors`]) are written first; then its events are read forever.
//!   Class requests (USBTMC INITIATE_CLEAR, INITIATE_ABORT_BULK_*, GET_CAPABILITIES, ...) arrive as SETUP events
//!   and are answered by the emulator's `control_in`; what it refuses is stalled. UNBIND (the gadget unbound
//!   from its controller: the cable pulled) power-cycles the meter, as losing bus power does.
//! - `ep81` (Bulk-IN) and `ep02` (Bulk-OUT), one thread each: every packet the host sends is handed to the
//!   emulator's `bulk_out`; every transfer the emulator has ready is written as one Bulk-IN transfer, followed
//!   by a zero-length packet when its length is a multiple of the packet size (else a host reading more than
//!   that would wait for the rest of a transfer that has ended; no PM100 reply is that long, so the USB tier
//!   does not exercise it).
//!
//! Halts: the emulator decides when an endpoint halts (a malformed header halts Bulk-OUT); the bridge then
//! halts the kernel's endpoint (FunctionFS halts an endpoint on I/O in the wrong direction) and clears the
//! emulator's, because from then on the host's CLEAR_FEATURE(ENDPOINT_HALT) goes to the kernel, which never
//! forwards it here. The same path serves the fault commands [`FfsDevice::halt_in`] / [`FfsDevice::halt_out`].
//!
//! Limits: Bulk-OUT is read one high-speed packet (512 bytes) at a time and the emulator joins the packets into
//! transfers by the sizes in their USBTMC headers, so the bridge never waits for a short or zero-length packet
//! the host need not send (a full-speed controller would need reads of 64); the interrupt endpoint of USB488
//! (service requests) is not offered.

pub mod descriptors;

use std::fs::File;
use std::io::{Read, Write};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use nix::errno::Errno;

use crate::instrument::{SimError, SimInstrument};
use crate::pm100::{SimUsbDevice, UsbSimError};

/// Bulk packet size of the controller the gadget runs on (dummy_hcd runs at high speed by default).
const PACKET: usize = descriptors::HS_BULK_PACKET as usize;
/// Largest Bulk-IN transfer taken from the emulator at once (a USBTMC reply transfer is far smaller).
const MAX_IN_TRANSFER: usize = 64 * 1024;
/// How long one wait for the emulator's next Bulk-IN transfer lasts before the fault flags are looked at again.
const IN_POLL: Duration = Duration::from_millis(100);
/// Pause after a failed endpoint operation (the function is being unbound or not yet enabled).
const RETRY: Duration = Duration::from_millis(50);
/// FunctionFS event types (include/uapi/linux/usb/functionfs.h).
const EV_BIND: u8 = 0;
const EV_UNBIND: u8 = 1;
const EV_ENABLE: u8 = 2;
const EV_DISABLE: u8 = 3;
const EV_SETUP: u8 = 4;
/// One event: an 8-byte SETUP packet, the type, 3 bytes of padding.
const EVENT_LEN: usize = 12;

/// The power meter `device` of a simulator, served through the FunctionFS function mounted at a directory.
/// The endpoint threads run until the process ends (they block in the kernel; nothing else owns them).
#[derive(Debug)]
pub struct FfsDevice {
    shared: Arc<Shared>,
}

#[derive(Debug)]
struct Shared {
    name: String,
    dev: SimUsbDevice,
    runtime: tokio::runtime::Handle,
    halt_in: AtomicBool,
    halt_out: AtomicBool,
}

impl FfsDevice {
    /// Write the descriptors to `dir/ep0` and start serving the emulator of `device` on `dir/ep81` (Bulk-IN) and
    /// `dir/ep02` (Bulk-OUT). `runtime` drives the emulator's clock. After this returns, the gadget can be bound.
    pub fn serve(
        sim: &SimInstrument,
        device: &str,
        dir: &Path,
        runtime: tokio::runtime::Handle,
    ) -> Result<FfsDevice, SimError> {
        let dev = sim.usb_device(device)?;
        let err = |what: String, e: std::io::Error| SimError::Gadget {
            device: device.to_string(),
            message: format!("{what}: {e}"),
        };
        let ep0_path = dir.join("ep0");
        let mut ep0 = File::options()
            .read(true)
            .write(true)
            .open(&ep0_path)
            .map_err(|e| err(format!("cannot open {}", ep0_path.display()), e))?;
        ep0.write_all(&descriptors::descriptors(
            dev.bulk_in_endpoint(),
            dev.bulk_out_endpoint(),
        ))
        .map_err(|e| err("the kernel refused the descriptors".into(), e))?;
        ep0.write_all(&descriptors::strings("PM100 USBTMC"))
            .map_err(|e| err("the kernel refused the strings".into(), e))?;
        // With VIRTUAL_ADDR the kernel names the endpoint files by the addresses we wrote: ep81, ep02.
        let open_ep = |address: u8| {
            let path = dir.join(format!("ep{address:02x}"));
            File::options()
                .read(true)
                .write(true)
                .open(&path)
                .map_err(|e| err(format!("cannot open {}", path.display()), e))
        };
        let (ep_in, ep_out) = (
            open_ep(dev.bulk_in_endpoint())?,
            open_ep(dev.bulk_out_endpoint())?,
        );
        let shared = Arc::new(Shared {
            name: device.to_string(),
            dev,
            runtime,
            halt_in: AtomicBool::new(false),
            halt_out: AtomicBool::new(false),
        });
        let spawn = |what: &str, f: Box<dyn FnOnce() + Send>| {
            std::thread::Builder::new()
                .name(format!("ffs-{what}"))
                .spawn(f)
                .map(drop)
                .map_err(|e| err(format!("cannot start the {what} thread"), e))
        };
        let s = Arc::clone(&shared);
        spawn("ep0", Box::new(move || s.control_loop(ep0)))?;
        let s = Arc::clone(&shared);
        spawn("bulk-in", Box::new(move || s.bulk_in_loop(ep_in)))?;
        let s = Arc::clone(&shared);
        spawn("bulk-out", Box::new(move || s.bulk_out_loop(ep_out)))?;
        tracing::info!(device, dir = %dir.display(), "simulated USB device served through FunctionFS");
        Ok(FfsDevice { shared })
    }

    /// Fault: halt the Bulk-IN endpoint now (the host's next read fails with a pipe error until it clears it).
    pub fn halt_in(&self) {
        self.shared.halt_in.store(true, Ordering::SeqCst);
    }

    /// Fault: halt the Bulk-OUT endpoint on the next transfer the host sends (that transfer is lost).
    pub fn halt_out(&self) {
        self.shared.halt_out.store(true, Ordering::SeqCst);
    }

    /// Fault: the meter answers its next query `delay_s` simulated seconds late.
    pub fn delay_next_reply(&self, delay_s: f64) {
        self.shared.dev.delay_next_reply(delay_s);
    }
}

/// Halt an endpoint the FunctionFS way: I/O against its direction. The kernel answers EBADMSG once the halt is
/// set (EL2HLT on ep0); anything else is reported.
fn halt(file: &mut File, is_in: bool) -> std::io::Result<()> {
    let r = if is_in {
        file.read(&mut [0u8; 1]).map(drop)
    } else {
        file.write(&[0u8]).map(drop)
    };
    match r {
        Err(e)
            if e.raw_os_error() == Some(Errno::EBADMSG as i32)
                || e.raw_os_error() == Some(Errno::EL2HLT as i32) =>
        {
            Ok(())
        }
        Err(e) => Err(e),
        Ok(()) => Err(std::io::Error::other("the kernel did not halt the endpoint")),
    }
}

impl Shared {
    fn control_loop(&self, mut ep0: File) {
        let mut buf = [0u8; EVENT_LEN * 4];
        loop {
            let n = match ep0.read(&mut buf) {
                Ok(0) => {
                    tracing::warn!(device = %self.name, "FunctionFS ep0 closed; control requests end");
                    return;
                }
                Ok(n) => n,
                Err(e) => {
                    tracing::debug!(device = %self.name, error = %e, "FunctionFS ep0 read failed");
                    std::thread::sleep(RETRY);
                    continue;
                }
            };
            for ev in buf[..n].chunks_exact(EVENT_LEN) {
                match ev[8] {
                    EV_SETUP => self.setup(&mut ep0, ev),
                    EV_BIND => tracing::info!(device = %self.name, "gadget bound to its controller"),
                    EV_ENABLE => tracing::info!(device = %self.name, "host configured the device"),
                    EV_DISABLE => tracing::info!(device = %self.name, "device deconfigured"),
                    EV_UNBIND => {
                        tracing::info!(device = %self.name, "gadget unbound (unplugged)");
                        self.dev.power_cycle();
                    }
                    other => tracing::debug!(device = %self.name, event = other, "FunctionFS event"),
                }
            }
        }
    }

    /// Answer one SETUP packet: device-to-host class requests from the emulator, anything else stalled.
    fn setup(&self, ep0: &mut File, ev: &[u8]) {
        let (rt, rq) = (ev[0], ev[1]);
        let value = u16::from_le_bytes([ev[2], ev[3]]);
        let index = u16::from_le_bytes([ev[4], ev[5]]);
        let length = u16::from_le_bytes([ev[6], ev[7]]);
        let to_host = rt & 0x80 != 0;
        let reply = if to_host {
            self.runtime.block_on(self.dev.control_in(
                rt,
                rq,
                value,
                index,
                usize::from(length),
                Duration::from_secs(1),
            ))
        } else {
            Err(UsbSimError::Pipe { endpoint: 0 })
        };
        tracing::debug!(device = %self.name, rt, rq, value, index, length, ok = reply.is_ok(), "SETUP");
        let done = match reply {
            Ok(mut data) => {
                data.truncate(usize::from(length));
                ep0.write(&data).map(drop)
            }
            Err(_) => halt(ep0, to_host),
        };
        if let Err(e) = done {
            tracing::warn!(device = %self.name, rq, error = %e, "control reply failed");
        }
    }

    fn bulk_in_loop(&self, mut ep: File) {
        let in_ep = self.dev.bulk_in_endpoint();
        loop {
            if self.halt_in.swap(false, Ordering::SeqCst) {
                self.halt_kernel(&mut ep, true, "fault command");
                continue;
            }
            let next = self
                .runtime
                .block_on(self.dev.bulk_in(in_ep, MAX_IN_TRANSFER, IN_POLL));
            match next {
                Ok(data) => {
                    tracing::trace!(device = %self.name, len = data.len(), "Bulk-IN transfer");
                    let mut sent = ep.write(&data).map(drop);
                    if sent.is_ok() && !data.is_empty() && data.len() % PACKET == 0 {
                        sent = ep.write(&[]).map(drop);
                    }
                    if let Err(e) = sent {
                        tracing::info!(device = %self.name, error = %e, "Bulk-IN transfer lost");
                    }
                }
                Err(UsbSimError::Timeout { .. }) => {}
                Err(UsbSimError::Pipe { .. }) => {
                    let _ = self.runtime.block_on(self.dev.clear_halt(in_ep));
                    self.halt_kernel(&mut ep, true, "emulator halted Bulk-IN");
                }
                Err(e) => {
                    tracing::debug!(device = %self.name, error = %e, "Bulk-IN: emulator refused");
                    std::thread::sleep(RETRY);
                }
            }
        }
    }

    fn bulk_out_loop(&self, mut ep: File) {
        let out_ep = self.dev.bulk_out_endpoint();
        let mut buf = vec![0u8; PACKET];
        loop {
            let n = match ep.read(&mut buf) {
                Ok(n) => n,
                Err(e) => {
                    tracing::debug!(device = %self.name, error = %e, "Bulk-OUT read failed");
                    std::thread::sleep(RETRY);
                    continue;
                }
            };
            if self.halt_out.swap(false, Ordering::SeqCst) {
                self.halt_kernel(&mut ep, false, "fault command");
                continue;
            }
            let r = self
                .runtime
                .block_on(self.dev.bulk_out(out_ep, &buf[..n], Duration::from_secs(1)));
            match r {
                Ok(_) => {}
                Err(UsbSimError::Pipe { .. }) => {
                    let _ = self.runtime.block_on(self.dev.clear_halt(out_ep));
                    self.halt_kernel(&mut ep, false, "emulator halted Bulk-OUT");
                }
                Err(e) => tracing::debug!(device = %self.name, error = %e, "Bulk-OUT: emulator refused"),
            }
        }
    }

    fn halt_kernel(&self, ep: &mut File, is_in: bool, why: &str) {
        let which = if is_in { "Bulk-IN" } else { "Bulk-OUT" };
        match halt(ep, is_in) {
            Ok(()) => tracing::info!(device = %self.name, why, "{which} endpoint halted"),
            Err(e) => tracing::warn!(device = %self.name, why, error = %e, "cannot halt {which}"),
        }
    }
}
