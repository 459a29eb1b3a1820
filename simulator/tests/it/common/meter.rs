//! A host's raw view of the simulated PM100USB: USBTMC frames written out from the USBTMC 1.0 specification
//! (not the driver's code), a query, a number.

use std::time::Duration;

use gonio_simulator::SimUsbDevice;
use gonio_simulator::pm100::*;

const T: Duration = Duration::from_secs(1);

pub fn out_msg(btag: u8, text: &str) -> Vec<u8> {
    let mut v = vec![DEV_DEP_MSG_OUT, btag, !btag, 0];
    v.extend_from_slice(&(text.len() as u32).to_le_bytes());
    v.extend_from_slice(&[1, 0, 0, 0]);
    v.extend_from_slice(text.as_bytes());
    while v.len() % 4 != 0 {
        v.push(0);
    }
    v
}

pub fn request_in(btag: u8, max: u32) -> Vec<u8> {
    let mut v = vec![REQUEST_DEV_DEP_MSG_IN, btag, !btag, 0];
    v.extend_from_slice(&max.to_le_bytes());
    v.extend_from_slice(&[0, 0, 0, 0]);
    v
}

/// Send `text`, request up to `max`, return (header, data).
pub async fn query(dev: &SimUsbDevice, btag: u8, text: &str, max: u32) -> (Vec<u8>, Vec<u8>) {
    dev.bulk_out(BULK_OUT_EP, &out_msg(btag, text), T)
        .await
        .expect("out");
    let rb = btag.wrapping_add(1).max(1);
    dev.bulk_out(BULK_OUT_EP, &request_in(rb, max), T)
        .await
        .expect("request");
    let t = dev
        .bulk_in(BULK_IN_EP, max as usize + 12 + 3, T)
        .await
        .expect("in");
    let n = u32::from_le_bytes([t[4], t[5], t[6], t[7]]) as usize;
    (t[..12].to_vec(), t[12..12 + n].to_vec())
}

pub fn value(data: &[u8]) -> f64 {
    String::from_utf8_lossy(data).trim_end().parse().expect("number")
}

/// A host talking to the meter: one bTag counter, write and ask.
pub struct Host {
    pub dev: SimUsbDevice,
    btag: u8,
}

impl Host {
    pub fn new(sim: &gonio_simulator::SimInstrument) -> Host {
        Host {
            dev: sim.usb_device("meter").expect("open"),
            btag: 0,
        }
    }

    pub fn tag(&mut self) -> u8 {
        self.btag = self.btag.wrapping_add(1).max(1);
        self.btag
    }

    pub async fn write(&mut self, text: &str) {
        let b = self.tag();
        self.dev
            .bulk_out(BULK_OUT_EP, &out_msg(b, &format!("{text}\n")), T)
            .await
            .expect("out");
    }

    pub async fn ask(&mut self, text: &str) -> String {
        self.write(text).await;
        let b = self.tag();
        let mut req = vec![REQUEST_DEV_DEP_MSG_IN, b, !b, 0];
        req.extend_from_slice(&256u32.to_le_bytes());
        req.extend_from_slice(&[0, 0, 0, 0]);
        self.dev.bulk_out(BULK_OUT_EP, &req, T).await.expect("request");
        let t = self.dev.bulk_in(BULK_IN_EP, 256 + 12, T).await.expect("in");
        let n = u32::from_le_bytes([t[4], t[5], t[6], t[7]]) as usize;
        String::from_utf8_lossy(&t[12..12 + n]).trim_end().to_string()
    }
}
