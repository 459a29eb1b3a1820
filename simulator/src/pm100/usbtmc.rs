//! The USB side: Bulk-OUT framing into SCPI messages, Bulk-IN transfers of the responses, the USBTMC class
//! requests on the control pipe, halted endpoints.

use std::time::Duration;

use super::*;

impl Pm100 {
    // ---------------------------------------------------------------- USBTMC

    pub(super) fn bulk_out(&self, opened_s: f64, endpoint: u8, data: &[u8]) -> Result<usize, UsbSimError> {
        let now = self.now();
        if !self.handle_alive(opened_s, now) {
            return Err(UsbSimError::NoDevice);
        }
        if endpoint != BULK_OUT_EP {
            return Err(UsbSimError::InvalidParam(format!(
                "endpoint {endpoint:#04x} is not the Bulk-OUT endpoint"
            )));
        }
        let mut st = self.lock();
        if st.halted_out {
            return Err(UsbSimError::Pipe { endpoint });
        }
        tracing::trace!(meter = %self.name, len = data.len(), "PM100 Bulk-OUT");
        let mut rest = data;
        while !rest.is_empty() {
            if let Some(mut t) = st.out {
                let take = t.remaining.min(rest.len());
                st.message.extend_from_slice(&rest[..take]);
                t.remaining -= take;
                t.received += take;
                rest = &rest[take..];
                let pad = t.pad.min(rest.len());
                t.pad -= pad;
                rest = &rest[pad..];
                if t.remaining == 0 {
                    st.out = None;
                    if t.eom {
                        self.message_complete(&mut st, now);
                    }
                } else {
                    st.out = Some(t);
                }
                continue;
            }
            let Some(h) = rest.get(..12) else {
                return self.halt_out(&mut st, "short header");
            };
            let (msg_id, btag, inv) = (h[0], h[1], h[2]);
            if btag == 0 || inv != !btag {
                return self.halt_out(&mut st, "bTag check failed");
            }
            let size = u32::from_le_bytes([h[4], h[5], h[6], h[7]]) as usize;
            match msg_id {
                DEV_DEP_MSG_OUT => {
                    let pad = (4 - size % 4) % 4;
                    st.last_out_btag = btag;
                    st.out = Some(OutTransfer {
                        btag,
                        remaining: size,
                        pad,
                        eom: h[8] & 1 == 1,
                        received: 0,
                    });
                    if size == 0 {
                        let eom = h[8] & 1 == 1;
                        st.out = None;
                        if eom {
                            self.message_complete(&mut st, now);
                        }
                    }
                    rest = &rest[12..];
                }
                REQUEST_DEV_DEP_MSG_IN => {
                    if size == 0 {
                        return self.halt_out(&mut st, "REQUEST_DEV_DEP_MSG_IN for 0 bytes");
                    }
                    st.request = Some(InRequest { btag, max: size });
                    st.last_in_btag = btag;
                    if st.responses.is_empty() && st.in_fifo.is_empty() {
                        // Reading with no query pending.
                        Self::push_error(&mut st, -420, "Query UNTERMINATED");
                    }
                    rest = &[];
                }
                _ => return self.halt_out(&mut st, "unsupported MsgID"),
            }
        }
        drop(st);
        self.notify.notify_waiters();
        Ok(data.len())
    }

    fn halt_out(&self, st: &mut MeterState, why: &str) -> Result<usize, UsbSimError> {
        tracing::debug!(meter = %self.name, why, "PM100: Bulk-OUT halted");
        st.halted_out = true;
        st.out = None;
        Err(UsbSimError::Pipe {
            endpoint: BULK_OUT_EP,
        })
    }

    fn message_complete(&self, st: &mut MeterState, now: f64) {
        let msg = std::mem::take(&mut st.message);
        let text = String::from_utf8_lossy(&msg).into_owned();
        // Newline ends a program message; a final one without newline is taken as ended by EOM (EOI).
        for line in text.split('\n') {
            let line = line.trim_end_matches('\r');
            if !line.trim().is_empty() {
                self.execute_message(st, line, now);
            }
        }
    }

    /// Build the next Bulk-IN transfer if a request is pending and response bytes are ready.
    fn fill_in_fifo(st: &mut MeterState, now: f64) {
        if !st.in_fifo.is_empty() {
            return;
        }
        let Some(req) = st.request else { return };
        let Some(front) = st.responses.front() else { return };
        if front.ready_at_s > now {
            return;
        }
        let Some(mut resp) = st.responses.pop_front() else {
            return;
        };
        let n = req.max.min(resp.bytes.len());
        let rest = resp.bytes.split_off(n);
        let eom = rest.is_empty();
        if !eom {
            st.responses.push_front(Pending {
                ready_at_s: resp.ready_at_s,
                bytes: rest,
            });
        }
        let mut t = vec![DEV_DEP_MSG_IN, req.btag, !req.btag, 0];
        t.extend_from_slice(&(n as u32).to_le_bytes());
        t.extend_from_slice(&[u8::from(eom), 0, 0, 0]);
        t.extend_from_slice(&resp.bytes);
        while t.len() % 4 != 0 {
            t.push(0);
        }
        st.in_fifo.extend(t);
        st.in_sent = 0;
        st.request = None;
    }

    fn in_ready_at(st: &MeterState) -> Option<f64> {
        if !st.in_fifo.is_empty() {
            return Some(0.0);
        }
        st.request?;
        st.responses.front().map(|r| r.ready_at_s)
    }

    pub(super) async fn bulk_in(
        &self,
        opened_s: f64,
        endpoint: u8,
        max_len: usize,
        timeout: Duration,
    ) -> Result<Vec<u8>, UsbSimError> {
        if endpoint != BULK_IN_EP {
            return Err(UsbSimError::InvalidParam(format!(
                "endpoint {endpoint:#04x} is not the Bulk-IN endpoint"
            )));
        }
        if max_len == 0 {
            return Err(UsbSimError::InvalidParam("bulk_in of 0 bytes".into()));
        }
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            let now = self.now();
            if !self.handle_alive(opened_s, now) {
                return Err(UsbSimError::NoDevice);
            }
            let notified = self.notify.notified();
            let wake = {
                let mut st = self.lock();
                if st.halted_in {
                    return Err(UsbSimError::Pipe { endpoint });
                }
                Self::fill_in_fifo(&mut st, now);
                if !st.in_fifo.is_empty() {
                    let n = max_len.min(st.in_fifo.len());
                    let out: Vec<u8> = st.in_fifo.drain(..n).collect();
                    st.in_sent += n;
                    tracing::trace!(meter = %self.name, len = out.len(), "PM100 Bulk-IN");
                    return Ok(out);
                }
                Self::in_ready_at(&st)
            };
            let disconnect = self.faults.injector().next_disconnect_s(now);
            let wake = match (wake, disconnect) {
                (Some(a), Some(b)) => Some(a.min(b)),
                (a, b) => a.or(b),
            };
            let wake_instant = wake
                .map(|t| self.world.clock.instant_at(t).min(deadline))
                .unwrap_or(deadline);
            tokio::select! {
                _ = tokio::time::sleep_until(wake_instant) => {}
                _ = notified => {}
            }
            if tokio::time::Instant::now() >= deadline {
                // Last look: the data may have become ready exactly at the deadline.
                let mut st = self.lock();
                Self::fill_in_fifo(&mut st, self.now());
                if st.in_fifo.is_empty() {
                    return Err(UsbSimError::Timeout { transferred: 0 });
                }
            }
        }
    }

    pub(super) fn control_in(
        &self,
        opened_s: f64,
        request_type: u8,
        request: u8,
        value: u16,
        index: u16,
        max_len: usize,
    ) -> Result<Vec<u8>, UsbSimError> {
        let now = self.now();
        if !self.handle_alive(opened_s, now) {
            return Err(UsbSimError::NoDevice);
        }
        let mut st = self.lock();
        let btag = (value & 0xFF) as u8;
        let endpoint = (index & 0xFF) as u8;
        let reply: Vec<u8> = match (request_type, request) {
            (0xA2, INITIATE_ABORT_BULK_OUT) if endpoint == BULK_OUT_EP => {
                let status = match st.out {
                    Some(t) if t.btag == btag => {
                        st.out = None;
                        st.message.clear();
                        STATUS_SUCCESS
                    }
                    Some(_) => STATUS_TRANSFER_NOT_IN_PROGRESS,
                    None if st.last_out_btag == btag && !st.message.is_empty() => {
                        st.message.clear();
                        STATUS_SUCCESS
                    }
                    None => STATUS_FAILED,
                };
                vec![status, btag]
            }
            (0xA2, CHECK_ABORT_BULK_OUT_STATUS) if endpoint == BULK_OUT_EP => {
                let n = st.out.map(|t| t.received).unwrap_or(0) as u32;
                let mut v = vec![STATUS_SUCCESS, 0, 0, 0];
                v.extend_from_slice(&n.to_le_bytes());
                v
            }
            (0xA2, INITIATE_ABORT_BULK_IN) if endpoint == BULK_IN_EP => {
                let in_progress = !st.in_fifo.is_empty() || st.request.is_some();
                let status = if !in_progress {
                    STATUS_FAILED
                } else if st.last_in_btag != btag {
                    STATUS_TRANSFER_NOT_IN_PROGRESS
                } else {
                    st.in_fifo.clear();
                    st.request = None;
                    st.responses.clear();
                    STATUS_SUCCESS
                };
                vec![status, btag]
            }
            (0xA2, CHECK_ABORT_BULK_IN_STATUS) if endpoint == BULK_IN_EP => {
                let more = u8::from(!st.in_fifo.is_empty());
                let mut v = vec![STATUS_SUCCESS, more, 0, 0];
                v.extend_from_slice(&(st.in_sent as u32).to_le_bytes());
                v
            }
            (0xA1, INITIATE_CLEAR) => {
                st.out = None;
                st.message.clear();
                st.request = None;
                st.responses.clear();
                st.in_fifo.clear();
                st.clear_until_s = Some(now + CLEAR_S);
                vec![STATUS_SUCCESS]
            }
            (0xA1, CHECK_CLEAR_STATUS) => match st.clear_until_s {
                Some(t) if now < t => vec![STATUS_PENDING, 0],
                _ => {
                    st.clear_until_s = None;
                    vec![STATUS_SUCCESS, u8::from(!st.in_fifo.is_empty())]
                }
            },
            (0xA1, GET_CAPABILITIES) => {
                let mut v = vec![0u8; 0x18];
                v[0] = STATUS_SUCCESS;
                // bcdUSBTMC 1.00
                v[2] = 0x00;
                v[3] = 0x01;
                // USB488 subclass: bcdUSB488 1.00, 488.2 interface, SCPI device.
                v[12] = 0x00;
                v[13] = 0x01;
                v[14] = 0x04;
                v[15] = 0x08;
                v
            }
            _ => {
                // Unsupported requests are answered with a STALL of the control pipe.
                return Err(UsbSimError::Pipe { endpoint: 0 });
            }
        };
        tracing::debug!(meter = %self.name, request, status = reply.first().copied(), "PM100 control request");
        let mut reply = reply;
        reply.truncate(max_len);
        Ok(reply)
    }

    pub(super) fn clear_halt(&self, opened_s: f64, endpoint: u8) -> Result<(), UsbSimError> {
        if !self.handle_alive(opened_s, self.now()) {
            return Err(UsbSimError::NoDevice);
        }
        let mut st = self.lock();
        match endpoint {
            BULK_OUT_EP => {
                st.halted_out = false;
                st.out = None;
            }
            BULK_IN_EP => st.halted_in = false,
            _ => return Err(UsbSimError::InvalidParam(format!("no endpoint {endpoint:#04x}"))),
        }
        Ok(())
    }
}
