//! HTTP on the wire: reading an answer off a socket, one exchange, and the attackers (slow and oversized
//! requests, floods) that the soak sends.

use super::*;

/// A response as read off the wire.
#[derive(Debug)]
pub struct Answer {
    pub status: u16,
    /// The status line and headers, as sent.
    pub head: String,
    pub body: String,
}

/// Read one response (headers, then a Content-Length body, nothing more of an event stream, or else up to EOF);
/// None when the connection closes first. Shared with the daemon's abuse tests (`tests/http_abuse.rs`).
pub async fn read_answer(stream: &mut (impl tokio::io::AsyncRead + Unpin)) -> Option<Answer> {
    let mut buf = Vec::new();
    let mut chunk = [0u8; 4096];
    let head_end = loop {
        if let Some(i) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            break i + 4;
        }
        match stream.read(&mut chunk).await {
            Ok(0) | Err(_) => return None,
            Ok(n) => buf.extend_from_slice(&chunk[..n]),
        }
    };
    let head = String::from_utf8_lossy(&buf[..head_end]).into_owned();
    let status = head.split_whitespace().nth(1)?.parse().ok()?;
    let length = head.lines().find_map(|l| {
        let (k, v) = l.split_once(':')?;
        k.eq_ignore_ascii_case("content-length")
            .then(|| v.trim().parse::<usize>().ok())?
    });
    let mut body = buf[head_end..].to_vec();
    match length {
        Some(n) => {
            while body.len() < n {
                match stream.read(&mut chunk).await {
                    Ok(0) | Err(_) => break,
                    Ok(k) => body.extend_from_slice(&chunk[..k]),
                }
            }
        }
        // An event stream never ends: its head is the answer.
        None if head.to_ascii_lowercase().contains("text/event-stream") => {}
        None => {
            let _ = stream.read_to_end(&mut body).await;
        }
    }
    Some(Answer {
        status,
        head,
        body: String::from_utf8_lossy(&body).into_owned(),
    })
}

/// Send a request on a new connection and read the answer; Err says what went wrong.
pub async fn exchange(addr: SocketAddr, raw: &[u8]) -> Result<Answer, String> {
    let mut stream = TcpStream::connect(addr)
        .await
        .map_err(|e| format!("connect: {e}"))?;
    stream.write_all(raw).await.map_err(|e| format!("send: {e}"))?;
    read_answer(&mut stream)
        .await
        .ok_or_else(|| "closed without an answer".to_string())
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    Header,
    Body,
    Idle,
}

/// The length a body trickler announces: half the body limit, at most 100 kB.
pub fn slow_body_bytes(limit: usize) -> usize {
    (limit / 2).min(100_000)
}

/// One persistent hostile client: connect, misbehave until the daemon closes the connection, reconnect.
pub(super) async fn attacker(
    kind: Kind,
    addr: SocketAddr,
    cfg: Arc<HttpAbuseConfig>,
    stop: Arc<AtomicBool>,
    stats: Arc<KindStats>,
) {
    let start = match kind {
        Kind::Header => "GET /api/campaigns HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ".to_string(),
        // Within the body limit: the daemon must wait for it (up to its body deadline), not refuse it at once.
        Kind::Body => format!(
            "POST /api/campaigns HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: {}\r\n\r\n[campaign]\n",
            slow_body_bytes(cfg.api.body_limit_bytes)
        ),
        Kind::Idle => String::new(),
    };
    let start = start.as_bytes();
    let mut buf = [0u8; 1024];
    while !stop.load(Ordering::Relaxed) {
        let Ok(mut stream) = TcpStream::connect(addr).await else {
            tokio::time::sleep(cfg.reconnect_after).await;
            continue;
        };
        stats.opened.fetch_add(1, Ordering::Relaxed);
        let mut ended_by_daemon = !start.is_empty() && stream.write_all(start).await.is_err();
        let mut status = None;
        while !ended_by_daemon && !stop.load(Ordering::Relaxed) {
            tokio::select! {
                r = stream.read(&mut buf) => {
                    if let Ok(n) = r && n > 0 {
                        status = std::str::from_utf8(&buf[..n])
                            .ok()
                            .and_then(|s| s.split_whitespace().nth(1))
                            .and_then(|s| s.parse::<u16>().ok());
                    }
                    ended_by_daemon = true;
                }
                _ = tokio::time::sleep(cfg.trickle_period) => {
                    if kind != Kind::Idle && stream.write_all(b"x").await.is_err() {
                        ended_by_daemon = true;
                    }
                }
            }
        }
        if ended_by_daemon {
            match status {
                Some(s) => stats.answered.lock().unwrap_or_else(|e| e.into_inner()).push(s),
                None => {
                    stats.closed.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        drop(stream);
        tokio::time::sleep(cfg.reconnect_after).await;
    }
}

/// One oversized request of kind `k` (0 announced, 1 chunked, 2 streamed): the body is written by its own task
/// while the answer is read, so that a refusal sent before the body is taken is seen.
pub(super) async fn oversized(
    addr: SocketAddr,
    k: usize,
    limit: usize,
    deadline: Duration,
    counts: &mut OversizedCounts,
) {
    counts.sent += 1;
    let over = 2 * limit + 1;
    let head = match k {
        0 => format!(
            "POST /api/campaigns HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
            10 * limit
        ),
        1 => "POST /api/campaigns HTTP/1.1\r\nHost: 127.0.0.1\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n"
            .to_string(),
        _ => format!(
            "POST /api/campaigns HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: {over}\r\nConnection: close\r\n\r\n"
        ),
    };
    let result = tokio::time::timeout(deadline, async move {
        let stream = TcpStream::connect(addr).await.ok()?;
        let (mut rd, mut wr) = stream.into_split();
        let writer = tokio::spawn(async move {
            if wr.write_all(head.as_bytes()).await.is_err() {
                return;
            }
            let piece = vec![b'#'; 16 * 1024];
            let mut sent = 0;
            while k != 0 && sent < over {
                let n = piece.len().min(over - sent);
                let ok = if k == 1 {
                    let framed = [format!("{n:x}\r\n").as_bytes(), &piece[..n], b"\r\n"].concat();
                    wr.write_all(&framed).await.is_ok()
                } else {
                    wr.write_all(&piece[..n]).await.is_ok()
                };
                if !ok {
                    return;
                }
                sent += n;
            }
            if k == 1 {
                let _ = wr.write_all(b"0\r\n\r\n").await;
            }
            // Keep the write half open until the reader is done.
            std::future::pending::<()>().await;
        });
        let answer = read_answer(&mut rd).await;
        writer.abort();
        Some(answer)
    })
    .await;
    match result {
        Err(_) => counts.hung += 1,
        Ok(None) | Ok(Some(None)) => counts.closed += 1,
        Ok(Some(Some(a))) if a.status == 413 => counts.refused_413 += 1,
        Ok(Some(Some(a))) => *counts.other.entry(a.status).or_default() += 1,
    }
}
