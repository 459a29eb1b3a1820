//! Adapters from the in-process simulator to the driver's transports: its serial streams as a
//! [`PortOpener::Stream`] (reopened on reconnect) and its USB power meter as a [`UsbPipe`].

use std::sync::Arc;
use std::time::Duration;

use gonio_driver::pm100::PipeOpener;
use gonio_driver::transport::PortOpener;
use gonio_driver::transport::usb::{BoxFuture, UsbError, UsbPipe};
use gonio_simulator::SimInstrument;
use gonio_simulator::pm100::{SimUsbDevice, UsbSimError};

/// A port opener on the simulator's stream for `device`; reconnecting asks the simulator again.
pub fn serial_opener(sim: SimInstrument, device: &str) -> PortOpener {
    let dev = device.to_string();
    PortOpener::Stream(Arc::new(move || {
        sim.serial_port(&dev)
            .map(|s| Box::new(s) as _)
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::NotConnected, e.to_string()))
    }))
}

/// Open the simulator's USB power meter `device` as a pipe.
pub fn open_pipe(sim: &SimInstrument, device: &str) -> Result<Arc<dyn UsbPipe>, UsbError> {
    sim.usb_device(device)
        .map(|d| Arc::new(SimPipe(d)) as Arc<dyn UsbPipe>)
        .map_err(|e| UsbError::Other(e.to_string()))
}

/// Reopens the simulated power meter after a (simulated) disconnect.
pub fn pipe_opener(sim: SimInstrument, device: String) -> PipeOpener {
    Arc::new(move || open_pipe(&sim, &device))
}

/// Adapter: the simulator's USB device as a [`UsbPipe`].
#[derive(Debug)]
pub struct SimPipe(pub SimUsbDevice);

fn usb_err(e: UsbSimError) -> UsbError {
    match e {
        UsbSimError::Timeout { transferred } => UsbError::Timeout { transferred },
        UsbSimError::Pipe { .. } => UsbError::Pipe,
        UsbSimError::NoDevice => UsbError::NoDevice,
        other => UsbError::Other(other.to_string()),
    }
}

impl UsbPipe for SimPipe {
    fn bulk_out<'a>(&'a self, data: &'a [u8], timeout: Duration) -> BoxFuture<'a, Result<usize, UsbError>> {
        Box::pin(async move {
            self.0
                .bulk_out(self.0.bulk_out_endpoint(), data, timeout)
                .await
                .map_err(usb_err)
        })
    }
    fn bulk_in(&self, max_len: usize, timeout: Duration) -> BoxFuture<'_, Result<Vec<u8>, UsbError>> {
        Box::pin(async move {
            self.0
                .bulk_in(self.0.bulk_in_endpoint(), max_len, timeout)
                .await
                .map_err(usb_err)
        })
    }
    fn control_in(
        &self,
        rt: u8,
        rq: u8,
        value: u16,
        index: u16,
        max_len: usize,
        timeout: Duration,
    ) -> BoxFuture<'_, Result<Vec<u8>, UsbError>> {
        Box::pin(async move {
            self.0
                .control_in(rt, rq, value, index, max_len, timeout)
                .await
                .map_err(usb_err)
        })
    }
    fn clear_halt(&self, endpoint: u8) -> BoxFuture<'_, Result<(), UsbError>> {
        Box::pin(async move { self.0.clear_halt(endpoint).await.map_err(usb_err) })
    }
    fn bulk_out_endpoint(&self) -> u8 {
        self.0.bulk_out_endpoint()
    }
    fn bulk_in_endpoint(&self) -> u8 {
        self.0.bulk_in_endpoint()
    }
    fn interface_number(&self) -> u8 {
        0
    }
}
